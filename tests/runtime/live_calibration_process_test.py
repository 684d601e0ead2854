"""Live calibration end to end, as processes: `mocap-sim synth` makes a range of motion
with the CMU marker set (soft tissue, noise); a `mocapd run` daemon whose subject has
calibrate = "live" and no model is fed it by `mocap-sim replay --marker-set cmu-41`. The
subject must be solved from the first frames (the template scaled to the actor), report
its joints' readiness on calibration/<subject>/ and in /subjects, swap in the calibrated
subject while the stream runs (a new description, every frame still published once, in
order), write the subject file, which `mocapd process` then uses as any subject, and
count it all in /metrics; the daemon's accounting balances.

usage: live_calibration_process_test.py MOCAPD MOCAP_SIM CONFIG_DIR WORK_DIR
"""
import json
import os
import subprocess
import sys
import threading

import zmq

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "protocol", "python"))
import mocapd_protocol  # noqa: E402
from daemon_harness import Daemon, http_get, metrics  # noqa: E402

SECONDS = 20.0
RATE = 120
PASSES = 2


class Consumer(threading.Thread):
    """Everything the daemon publishes for actor1, decoded, in arrival order."""

    def __init__(self, ctx, endpoint):
        super().__init__(daemon=True)
        self.sock = ctx.socket(zmq.SUB)
        for topic in (b"skeleton/actor1/", b"subject/actor1/", b"calibration/actor1/"):
            self.sock.setsockopt(zmq.SUBSCRIBE, topic)
        self.sock.connect(endpoint)
        self.messages = []
        self.stop = False

    def run(self):
        while not self.stop:
            if self.sock.poll(100):
                topic, data = self.sock.recv_multipart()
                self.messages.append(mocapd_protocol.decode(data))


def main():
    mocapd, mocap_sim, config_dir, work = sys.argv[1:5]
    os.makedirs(work, exist_ok=True)
    take = os.path.join(work, "rom.c3d")
    subprocess.run([mocap_sim, "synth", "--humanoid", "rom", "--seconds", str(SECONDS), "--rate", str(RATE),
                    "--marker-set", "cmu-41", "--soft-tissue-mm", "5", "--noise-mm", "1", "--out", take],
                   check=True, capture_output=True)
    out = os.path.join(work, "actor1.calibrated.toml")
    if os.path.exists(out):
        os.remove(out)
    daemon = Daemon(mocapd, config_dir, work, rate_hz=RATE,
                    live=f"calibrate = \"live\"\nmarker_set = \"cmu-41\"\ncalibration_min_s = 8\n"
                         f"calibration_out = \"{out}\"\n")
    ctx = zmq.Context()
    consumer = Consumer(ctx, daemon.output)
    consumer.start()
    try:
        # Twice, at twice the take's rate: the range of motion shows the last joints near its
        # end, and the calibration thread runs below the workers' priority (slow on a busy
        # machine), so the swap may come during the second pass.
        replay = subprocess.run([mocap_sim, "replay", take, "--marker-set", "cmu-41", "--rate", str(2 * RATE),
                                 "--loop", str(PASSES),
                                 "--to", daemon.input, "--from", daemon.output,
                                 "--report", os.path.join(work, "replay.json")],
                                capture_output=True, text=True, timeout=90)
        assert replay.returncode == 0, replay.stdout + replay.stderr
        report = json.load(open(os.path.join(work, "replay.json")))
        assert report["frames_lost"] == 0, report

        _, text = http_get(daemon.http_port, "/subjects")
        calibration = json.loads(text)[0]["calibration"]
        assert calibration["state"] == "calibrated", calibration
        assert calibration["swapped_in"] == 1, calibration
        assert calibration["written_to"] == out and os.path.exists(out), calibration
        assert all(j["ready"] for j in calibration["joints"]), calibration["joints"]
        assert abs(calibration["height_m"] - 1.75) < 0.2, calibration
        m = metrics(daemon.http_port)
        assert m[("mocapd_live_calibration_state", (("subject", "actor1"),))] == 2
        assert m[("mocapd_live_calibration_swaps_total", (("subject", "actor1"),))] == 1
    finally:
        code = daemon.stop()
        consumer.stop = True
        consumer.join()
    assert code == 0, "the daemon's accounting did not balance:\n" + daemon.read_log()

    # Every frame of every pass published once, in order, across the swap; the calibrated
    # subject was described before its first frame; the wire said collecting, then calibrated.
    frames = [f["frame"] for kind, f in consumer.messages if kind == "skeleton_frame"]
    # (The replay numbers frames on across passes; each pass is a new capture session.)
    assert frames == list(range(frames[0], frames[0] + len(frames))), "frames lost or repeated"
    assert len(frames) == PASSES * int(SECONDS * RATE), len(frames)
    offsets = []
    for kind, d in consumer.messages:
        if kind == "subject_description" and (not offsets or d["joints"][1]["offset"] != offsets[-1]):
            offsets.append(d["joints"][1]["offset"])
    assert len(offsets) >= 2, "no description of the calibrated subject"
    states = [c["state"] for kind, c in consumer.messages if kind == "calibration_status"]
    assert "collecting" in states and states[-1] == "calibrated", states[:3] + states[-3:]
    last = [c for kind, c in consumer.messages if kind == "calibration_status"][-1]
    assert len(last["joints"]) == 21 and all(j["ready"] for j in last["joints"])

    # The written subject is a subject like any other.
    solved = subprocess.run([mocapd, "process", "--subject", out, "--in", take,
                             "--out-bvh", os.path.join(work, "solved.bvh")], capture_output=True, text=True)
    assert solved.returncode == 0, solved.stdout + solved.stderr
    print(f"live calibration: calibrated from {calibration['collected_s']:.1f} s of motion, "
          f"{calibration['refinements']} refinement(s), median residual {calibration['median_residual_mm']:.1f} mm; "
          f"{len(frames)} frames published once each across the swap")


if __name__ == "__main__":
    main()
