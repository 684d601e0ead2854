"""The CI latency test (CTest label `latency`): `mocapd run` and `mocap-sim replay` as
separate processes on tcp loopback; a synthesized 30 s take at 120 Hz with medium
corruption, in real time. Asserts no frame lost or duplicated, the skeletons right
(accuracy against the ground truth), and generous sanity bounds on latency; prints the
figures into the CI log.

The bounds allow for the CI host's own scheduling noise: a run on a 2-core CI machine
once saw processing p50 0.55 ms but p99 63 ms and max 225 ms, stalls that no code of
ours causes. A probe thread here sleeps 1 ms at a time for the whole run and records how
late it wakes; the p99 bound is 20 ms beyond the worst stall the probe saw, so a
daemon that blocks on its own still fails, and the median must stay within one frame
period.

usage: latency_test.py MOCAPD MOCAP_SIM CONFIG_DIR WORK_DIR [SECONDS]
"""
import json
import os
import subprocess
import sys
import threading
import time

from daemon_harness import Daemon


class SchedulingNoiseProbe(threading.Thread):
    """Sleeps 1 ms at a time and keeps the worst lateness of a wake-up (ms)."""

    def __init__(self):
        super().__init__(daemon=True)
        self.worst_ms = 0.0
        self.lateness_ms = []
        self.running = True

    def run(self):
        while self.running:
            start = time.monotonic()
            time.sleep(0.001)
            late = (time.monotonic() - start) * 1e3 - 1.0
            self.lateness_ms.append(late)
            self.worst_ms = max(self.worst_ms, late)

    def stop(self):
        self.running = False
        self.join()
        ordered = sorted(self.lateness_ms) or [0.0]
        return ordered[len(ordered) // 2], ordered[int(len(ordered) * 0.99)], self.worst_ms


def main(mocapd, mocap_sim, config_dir, work, seconds="30"):
    daemon = Daemon(mocapd, config_dir, work)
    report_path = os.path.join(work, "latency_report.json")
    probe = SchedulingNoiseProbe()
    probe.start()
    try:
        replay = subprocess.run([mocap_sim, "replay", "--humanoid", "mixed", "--seconds", seconds, "--corrupt", "medium",
                                 "--seed", "7", "--to", daemon.input, "--from", daemon.output, "--report", report_path,
                                 "--plot", os.path.join(work, "latency.svg")], capture_output=True, text=True, timeout=600)
        print(replay.stdout, replay.stderr)
        assert replay.returncode == 0, f"replay exited {replay.returncode}"
    finally:
        probe_p50, probe_p99, probe_worst = probe.stop()
        code = daemon.stop()
        print(daemon.read_log())
    assert code == 0, "the daemon did not account for every frame"
    with open(report_path) as f:
        r = json.load(f)
    frames = int(float(seconds) * 120)
    assert r["frames_sent"] == frames, r
    assert r["frames_received"] == frames and r["frames_lost"] == 0 and r["frames_duplicated"] == 0, r
    p = r["processing_latency"]
    print(f"LATENCY: {frames} frames, processing p50 {p['p50_ms']:.3f} ms, p99 {p['p99_ms']:.3f} ms, "
          f"p99.9 {p['p99.9_ms']:.3f} ms, max {p['max_ms']:.3f} ms; end-to-end p99 {r['end_to_end_latency']['p99_ms']:.3f} ms; "
          f"accuracy {r['accuracy']['mean_joint_position_error_cm']:.3f} cm / {r['accuracy']['mean_joint_rotation_error_deg']:.2f} deg")
    print(f"SCHEDULING NOISE (1 ms sleeps woke late by): p50 {probe_p50:.3f} ms, p99 {probe_p99:.3f} ms, "
          f"worst {probe_worst:.3f} ms")
    assert p["count"] == frames, p
    frame_period_ms = 1000.0 / 120
    assert p["p50_ms"] < frame_period_ms, f"median processing latency {p['p50_ms']} ms is over one frame period"
    p99_bound = 20.0 + probe_worst
    assert p["p99_ms"] < p99_bound, (f"p99 processing latency {p['p99_ms']} ms is over the sanity bound "
                                     f"({p99_bound:.1f} ms: 20 ms beyond the host's worst stall)")
    assert r["accuracy"]["mean_joint_position_error_cm"] < 1.0, r["accuracy"]
    # Sanity bounds, not the accuracy targets (those are the cleanup benchmark's): the
    # humanoid's twist-prone end joints put the clean-marker rotation error near 2-3 deg.
    assert r["accuracy"]["mean_joint_rotation_error_deg"] < 10.0, r["accuracy"]
    print("latency test passed")


if __name__ == "__main__":
    main(*sys.argv[1:])
