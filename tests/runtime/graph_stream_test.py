"""Motion graphs end to end as a user runs them: `mocap-sim graph build` over BVH takes
(the built-in humanoid's, written by `mocap-sim synth --truth-bvh`), `graph synth` to a
distance and time (its BVH read back by `mocap-sim info`), `graph match`, the clear
errors of a corrupt graph and of takes of another skeleton, and `mocap-sim replay --graph`
streaming two actors' endless walks through `mocapd run` with nothing lost.

usage: graph_stream_test.py MOCAPD MOCAP_SIM CONFIG_DIR WORK_DIR
"""
import json
import os
import re
import subprocess
import sys

from daemon_harness import Daemon


def sim(mocap_sim, *args, expect=0):
    r = subprocess.run([mocap_sim, *args], capture_output=True, text=True, timeout=120)
    print("$ mocap-sim", " ".join(args))
    print(r.stdout + r.stderr)
    assert expect is None or r.returncode == expect, f"exit {r.returncode}, expected {expect}"
    return r.stdout + r.stderr


def main(mocapd, mocap_sim, config_dir, work):
    os.makedirs(work, exist_ok=True)
    takes = []
    for motion in ("walk", "turn", "reach", "mixed"):
        bvh = os.path.join(work, f"{motion}.bvh")
        sim(mocap_sim, "synth", "--humanoid", motion, "--seconds", "12", "--rate", "30",
            "--out", os.path.join(work, f"{motion}.c3d"), "--truth-bvh", bvh)
        takes.append(bvh)
    graph = os.path.join(work, "graph.json")
    subject = os.path.join(work, "graph_subject.toml")
    out = sim(mocap_sim, "graph", "build", *takes, "--out", graph, "--subject-out", subject)
    assert "endless part" in out and "transitions" in out, out
    with open(subject) as f:
        text = f.read()
    assert text.count("[[joint]]") == 21 and text.count("[[marker]]") > 40, text[:400]
    with open(graph) as f:
        g = json.load(f)
    assert len(g["transitions"]) > 5 and [t["name"] for t in g["takes"]] == ["walk", "turn", "reach", "mixed"], g

    synth_bvh = os.path.join(work, "synth.bvh")
    out = sim(mocap_sim, "graph", "synth", "--graph", graph, "--distance", "8", "--time", "10",
              "--from", "walk:0", "--out", synth_bvh, "--path-out", os.path.join(work, "path.json"))
    miss = float(re.search(r"miss ([+-][0-9.]+) m\)", out).group(1))
    assert abs(miss) <= 0.2, out
    info = sim(mocap_sim, "info", synth_bvh)
    assert re.search(r"frames\s+300\b", info), info  # 10 s at 30 Hz
    out = sim(mocap_sim, "graph", "synth", "--graph", graph, "--distance", "500", "--time", "5",
              "--out", os.path.join(work, "far.bvh"), expect=2)
    assert "nearest one" in out, out
    out = sim(mocap_sim, "graph", "synth", "--graph", graph, "--distance", "5", "--time", "20",
              "--from", "walk:0", "--to", "turn:2", "--out", os.path.join(work, "y.bvh"), expect=1)
    assert "turn:2" in out and "choose a later --to frame" in out, out

    out = sim(mocap_sim, "graph", "match", takes[0], "--graph", graph, "--out", os.path.join(work, "match.bvh"))
    assert "joint velocity difference" in out, out

    # Bad input: a corrupt graph file, a start outside its take, takes of two skeletons.
    bad = os.path.join(work, "bad.json")
    with open(bad, "w") as f:
        f.write(json.dumps(g)[:200])
    out = sim(mocap_sim, "graph", "synth", "--graph", bad, "--distance", "1", "--time", "1", "--out",
              os.path.join(work, "x.bvh"), expect=1)
    assert "bad.json" in out and "not a JSON motion graph" in out, out
    out = sim(mocap_sim, "graph", "synth", "--graph", graph, "--distance", "1", "--time", "1", "--from",
              "walk:99999", "--out", os.path.join(work, "x.bvh"), expect=1)
    assert "walk:99999" in out, out
    cmu = os.path.join(work, "other.bvh")
    with open(cmu, "w") as f:
        f.write("HIERARCHY\nROOT Hips\n{\n OFFSET 0 0 0\n CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation\n"
                " End Site\n {\n  OFFSET 0 10 0\n }\n}\nMOTION\nFrames: 2\nFrame Time: 0.0333333\n0 0 0 0 0 0\n1 0 0 0 0 0\n")
    out = sim(mocap_sim, "graph", "build", takes[0], cmu, "--out", os.path.join(work, "y.json"), expect=1)
    assert "other.bvh" in out and "skeleton differs" in out, out

    # A graph faster than its stream (120 Hz graph, 30 Hz stream) walks several graph frames
    # per stream frame; nothing to receive it: --from "" and as fast as possible.
    fast = os.path.join(work, "graph120.json")
    sim(mocap_sim, "graph", "build", *takes, "--out", fast, "--rate", "120")
    for seed in ("1", "2", "3"):
        out = sim(mocap_sim, "replay", "--graph", fast, "--seconds", "60", "--synth-rate", "30", "--seed", seed,
                  "--push", "--to", "tcp://127.0.0.1:1", "--from", "", "--rate", "max", "--connect-timeout", "0.1",
                  expect=None)
        assert "Segmentation" not in out and "std::" not in out, out

    # The stream: two actors on their own walks through the daemon, medium corruption.
    d = Daemon(mocapd, config_dir, os.path.join(work, "daemon"), subjects=["actor1", "actor2"], rate_hz=120)
    try:
        report = os.path.join(work, "replay.json")
        out = sim(mocap_sim, "replay", "--graph", "humanoid", "--seconds", "8", "--synth-rate", "120",
                  "--subjects", "2", "--corrupt", "medium", "--to", d.input, "--from", d.output, "--report", report)
        assert "each on its own walk" in out, out
        with open(report) as f:
            r = json.load(f)
        assert r["frames_sent"] == 2 * 960 and r["frames_received"] == 2 * 960 and r["frames_lost"] == 0, r
        assert r["accuracy"]["mean_joint_position_error_cm"] < 1.0, r["accuracy"]
        assert d.stop() == 0, "the daemon exited with an error"
    finally:
        if d.process.poll() is None:
            d.process.kill()
        print(d.read_log())
    # A rig that translates below joint 0 (a fixed joint_Root above a free Hips, as Bandai's
    # exporter writes): its accuracy is scored from the global transforms, or the report says
    # why it is not.
    with open(takes[0]) as f:
        text = f.read()
    head, motion = text.split("MOTION\n", 1)
    head = head.replace("ROOT Hips\n{", "ROOT joint_Root\n{\n  OFFSET 0 0 0\n  CHANNELS 6 Xposition Yposition "
                        "Zposition Zrotation Xrotation Yrotation\n  JOINT Hips\n  {", 1) + "}\n"
    lines = motion.splitlines()
    rooted = os.path.join(work, "rooted.bvh")
    with open(rooted, "w") as f:
        f.write(head + "MOTION\n" + "\n".join(lines[:2] + ["0 0 0 0 0 0 " + l for l in lines[2:] if l.strip()]) + "\n")
    rooted_subject = os.path.join(work, "rooted_subject.toml")
    sim(mocap_sim, "synth", "--bvh", rooted, "--rate", "120", "--out", os.path.join(work, "rooted.c3d"),
        "--subject-out", rooted_subject)
    for globals_on in (True, False):
        d = Daemon(mocapd, config_dir, os.path.join(work, f"rooted_{globals_on}"),
                   live=f"model = \"{rooted_subject}\"\n", global_transforms=globals_on)
        try:
            report = os.path.join(work, f"rooted_{globals_on}.json")
            sim(mocap_sim, "replay", rooted, "--synth-rate", "120", "--to", d.input, "--from", d.output,
                "--report", report)
            with open(report) as f:
                r = json.load(f)
            assert r["frames_lost"] == 0, r
            if globals_on:
                assert r["accuracy"]["mean_joint_position_error_cm"] < 0.5, r["accuracy"]
                assert "accuracy_unscored" not in r, r
            else:
                assert "accuracy" not in r, r
                assert "global_transforms" in r["accuracy_unscored"]["reason"], r["accuracy_unscored"]
            assert d.stop() == 0
        finally:
            if d.process.poll() is None:
                d.process.kill()
    print("graph stream test passed")


if __name__ == "__main__":
    main(*sys.argv[1:5])
