"""`mocap-sim record` then `mocap-sim replay RECORDING` through `mocapd run`: a stream
recorded from a publisher plays back into the daemon with nothing lost; a recorder
killed mid-way leaves a recording that still replays.

usage: record_replay_test.py MOCAPD MOCAP_SIM CONFIG_DIR WORK_DIR
"""
import json
import os
import signal
import subprocess
import sys
import time

from daemon_harness import Daemon, free_ports


def record(mocap_sim, work, name, seconds, kill_after=None, captures=1):
    (port,) = free_ports(1)
    endpoint = f"tcp://127.0.0.1:{port}"
    path = os.path.join(work, name)
    recorder = subprocess.Popen([mocap_sim, "record", "--from", endpoint, "--out", path], stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT, text=True)
    time.sleep(0.3)
    # Each further capture is the capture restarting: its frame numbers start again from 0
    # under a new session id.
    for _ in range(captures - 1):
        r = subprocess.run([mocap_sim, "replay", "--humanoid", "walk", "--seconds", str(seconds), "--to", endpoint,
                            "--from", ""], capture_output=True, text=True, timeout=60)
        assert r.returncode == 0, r.stdout + r.stderr
    sender = subprocess.Popen([mocap_sim, "replay", "--humanoid", "walk", "--seconds", str(seconds), "--corrupt", "medium",
                               "--to", endpoint, "--from", ""], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    if kill_after is not None:
        time.sleep(kill_after)
        recorder.send_signal(signal.SIGKILL)  # no chance to close the file
        sender.communicate(timeout=60)
    else:
        out, _ = sender.communicate(timeout=60)
        assert sender.returncode == 0, out
        time.sleep(0.3)
        recorder.send_signal(signal.SIGINT)
    out, _ = recorder.communicate(timeout=30)
    print(out)
    if kill_after is None:
        # Ctrl-C is how a recording is stopped: it ended in "Interrupted system call", exit 1.
        assert recorder.returncode == 0 and "wrote " + path in out, (recorder.returncode, out)
    return path


def replay(mocapd, mocap_sim, config_dir, work, path):
    daemon = Daemon(mocapd, config_dir, os.path.join(work, "daemon_" + os.path.basename(path)))
    report = path + ".json"
    try:
        r = subprocess.run([mocap_sim, "replay", path, "--to", daemon.input, "--from", daemon.output, "--report", report],
                           capture_output=True, text=True, timeout=120)
        print(r.stdout, r.stderr)
        assert r.returncode == 0, r.returncode
    finally:
        assert daemon.stop() == 0
    with open(report) as f:
        return json.load(f), r.stdout


def main(mocapd, mocap_sim, config_dir, work):
    os.makedirs(work, exist_ok=True)
    full = record(mocap_sim, work, "full.mcr", 3)
    info = json.loads(subprocess.run([mocap_sim, "info", full, "--json"], capture_output=True, text=True,
                                     check=True).stdout)
    assert info["format"] == "recording" and info["frames"] == 360, info
    stream = info["streams"][0]
    assert stream["frames"] == 360 and stream["frames_skipped"] == 0 and stream["sessions"] == 1, stream
    r, _ = replay(mocapd, mocap_sim, config_dir, work, full)
    assert r["frames_sent"] == 360 and r["frames_received"] == 360 and r["frames_lost"] == 0, r
    cut = record(mocap_sim, work, "killed.mcr", 3, kill_after=1.5)
    r, out = replay(mocapd, mocap_sim, config_dir, work, cut)
    assert 60 < r["frames_sent"] < 360 and r["frames_lost"] == 0, r
    # A capture that restarted: the same frame numbers in two sessions. Matched by number
    # alone, the replay called 120 frames lost and 120 duplicated, and exited 2.
    restarted = record(mocap_sim, work, "restarted.mcr", 1, captures=2)
    info = json.loads(subprocess.run([mocap_sim, "info", restarted, "--json"], capture_output=True, text=True,
                                     check=True).stdout)
    assert info["streams"][0]["sessions"] == 2 and info["streams"][0]["frames"] == 240, info
    r, _ = replay(mocapd, mocap_sim, config_dir, work, restarted)
    assert r["frames_sent"] == 240 and r["frames_received"] == 240, r
    assert r["frames_lost"] == 0 and r["frames_duplicated"] == 0, r
    print("record / replay test passed")


if __name__ == "__main__":
    main(*sys.argv[1:5])
