"""The CI latency test (CTest label `latency`): `mocapd run` and `mocap-sim replay` as
separate processes on tcp loopback; a synthesized 30 s take at 120 Hz with medium
corruption, in real time. Asserts no frame lost or duplicated, the skeletons right
(accuracy against the ground truth), and generous sanity bounds on latency; prints the
figures into the CI log.

What is asserted about time, and why: a shared 2-core CI host stalls whole processes for
tens to hundreds of milliseconds (a run saw a 1 ms sleep wake 122 ms late, and the
replay's processing latency p50 1.1 ms but p99 150 ms with nothing lost). A frame's
latency as the replay sees it crosses three processes and every stall any of them takes,
plus the queue that builds behind it, so its tail measures the host, not the daemon.
The bounds are therefore:
- the replay-measured processing latency's median within one frame period (a daemon
  that blocks or falls behind on most frames fails it; host stalls move the median
  little);
- the daemon's own latency (receiving the frame that completes a publication to having
  sent it: the pipeline, the encoding and the sends), p99 from its Prometheus histogram
  within 10 ms: a stall only shows there if it starts during the ~0.2 ms of work, so the
  host's noise barely reaches it while a slow or blocking frame path does;
- the replay-measured p99 within 0.5 s: a daemon that stalls for whole seconds fails.
A probe thread sleeps 1 ms at a time for the whole run and the log prints how late it
woke beside the latency figures, so a reader can tell host noise from a regression.

usage: latency_test.py MOCAPD MOCAP_SIM CONFIG_DIR WORK_DIR [SECONDS]
"""
import json
import os
import subprocess
import sys
import threading
import time

from daemon_harness import Daemon, wait_for_metric


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


def histogram_quantile_bound(m, name, labels, q):
    """The upper bound of the Prometheus histogram bucket holding quantile q (seconds)."""
    buckets = sorted((float(dict(l)["le"]), v) for (n, l), v in m.items()
                     if n == name + "_bucket" and all(kv in l for kv in labels))
    total = buckets[-1][1]
    return next(le for le, cumulative in buckets if cumulative >= q * total), total


def main(mocapd, mocap_sim, config_dir, work, seconds="30"):
    daemon = Daemon(mocapd, config_dir, work)
    frames = int(float(seconds) * 120)
    report_path = os.path.join(work, "latency_report.json")
    probe = SchedulingNoiseProbe()
    probe.start()
    try:
        replay = subprocess.run([mocap_sim, "replay", "--humanoid", "mixed", "--seconds", seconds, "--corrupt", "medium",
                                 "--seed", "7", "--timecode", "30", "--to", daemon.input, "--from", daemon.output, "--report", report_path,
                                 "--plot", os.path.join(work, "latency.svg")], capture_output=True, text=True, timeout=600)
        print(replay.stdout, replay.stderr)
        assert replay.returncode == 0, f"replay exited {replay.returncode}"
        actor = (("subject", "actor1"),)
        # Every publication but the lookahead flushed at the end of stream has a triggering frame.
        timed = frames - daemon.lookahead
        m = wait_for_metric(daemon.http_port, "mocapd_processing_latency_seconds_count", actor, timed)
        daemon_p99_s, daemon_count = histogram_quantile_bound(m, "mocapd_processing_latency_seconds", actor, 0.99)
    finally:
        probe_p50, probe_p99, probe_worst = probe.stop()
        code = daemon.stop()
        print(daemon.read_log())
    assert code == 0, "the daemon did not account for every frame"
    with open(report_path) as f:
        r = json.load(f)
    assert r["frames_sent"] == frames, r
    assert r["frames_received"] == frames and r["frames_lost"] == 0 and r["frames_duplicated"] == 0, r
    # Protocol v2: every skeleton carried its marker frame's session id and timecode back.
    assert r["stream_checked"] == frames and r["stream_mismatched"] == 0, r
    p = r["processing_latency"]
    print(f"LATENCY: {frames} frames, processing p50 {p['p50_ms']:.3f} ms, p99 {p['p99_ms']:.3f} ms, "
          f"p99.9 {p['p99.9_ms']:.3f} ms, max {p['max_ms']:.3f} ms; end-to-end p99 {r['end_to_end_latency']['p99_ms']:.3f} ms; "
          f"accuracy {r['accuracy']['mean_joint_position_error_cm']:.3f} cm / {r['accuracy']['mean_joint_rotation_error_deg']:.2f} deg")
    print(f"DAEMON (receive -> sent, its own histogram): {daemon_count:.0f} publications, p99 <= {daemon_p99_s * 1e3:g} ms")
    print(f"SCHEDULING NOISE (1 ms sleeps woke late by): p50 {probe_p50:.3f} ms, p99 {probe_p99:.3f} ms, "
          f"worst {probe_worst:.3f} ms")
    assert p["count"] == frames, p
    frame_period_ms = 1000.0 / 120
    assert p["p50_ms"] < frame_period_ms, f"median processing latency {p['p50_ms']} ms is over one frame period"
    assert daemon_count == timed, f"the daemon's histogram holds {daemon_count} publications, not {timed}"
    assert daemon_p99_s <= 0.010, f"the daemon's own p99 latency is over 10 ms (bucket bound {daemon_p99_s * 1e3:g} ms)"
    assert p["p99_ms"] < 500.0, f"p99 processing latency {p['p99_ms']} ms is over the 0.5 s sanity bound"
    assert r["accuracy"]["mean_joint_position_error_cm"] < 1.0, r["accuracy"]
    # The worst frame is reported where it was, and the p99.9 lies between the mean and it.
    worst = r["accuracy"]["worst_frame"]
    assert worst["subject"] == "actor1" and 0 <= worst["frame_number"] < frames and worst["joint"], worst
    assert (r["accuracy"]["mean_joint_position_error_cm"] <= r["accuracy"]["p999_frame_position_error_cm"]
            <= r["accuracy"]["max_joint_position_error_cm"]), r["accuracy"]
    # The tail holds at least the frames at or above the p99.9, the worst frame among them:
    # its joint's group names it, and the groups' frames add up to no fewer than the rank.
    tail = r["accuracy"]["p999_tail"]
    assert sum(t["frames"] for t in tail) >= max(1, frames - int(0.999 * frames)), tail
    assert all(1 <= t["episodes"] <= t["frames"] for t in tail), tail
    top = max(tail, key=lambda t: t["worst_cm"])
    assert (top["joint"] == worst["joint"] and top["worst_frame_number"] == worst["frame_number"]
            and abs(top["worst_cm"] - r["accuracy"]["max_joint_position_error_cm"]) < 1e-9), (top, worst)
    # Sanity bounds, not the accuracy targets (those are the cleanup benchmark's): the
    # humanoid's twist-prone end joints put the clean-marker rotation error near 2-3 deg.
    assert r["accuracy"]["mean_joint_rotation_error_deg"] < 10.0, r["accuracy"]
    print("latency test passed")


if __name__ == "__main__":
    main(*sys.argv[1:])
