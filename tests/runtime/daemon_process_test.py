"""`mocapd run` as a process, end to end over tcp loopback: the replay simulator feeds a
corrupted take, the Python example subscriber decodes the live stream, SIGHUP reloads
(a broken config is refused and the daemon goes on), /metrics parses as Prometheus text
with a real parser, and SIGTERM flushes everything with every frame accounted for.

usage: daemon_process_test.py MOCAPD MOCAP_SIM CONFIG_DIR WORK_DIR
"""
import json
import os
import signal
import subprocess
import sys
import time

from daemon_harness import Daemon, http_get as get, wait_for_metric

HERE = os.path.dirname(os.path.abspath(__file__))
SUBSCRIBER = os.path.join(HERE, "..", "..", "protocol", "python", "example_subscriber.py")


def main(mocapd, mocap_sim, config_dir, work):
    d = Daemon(mocapd, config_dir, work)
    ports = [d.input_port, d.output_port, d.http_port]
    config = d.config
    daemon = d.process
    try:
        subscriber = subprocess.Popen([sys.executable, SUBSCRIBER, "--endpoint", f"tcp://127.0.0.1:{ports[1]}",
                                       "--subject", "actor1", "--frames", "600", "--timeout", "60"],
                                      stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        time.sleep(0.5)  # let the subscription reach the daemon's PUB
        report = os.path.join(work, "replay.json")
        replay = subprocess.Popen([mocap_sim, "replay", "--humanoid", "walk", "--seconds", "5", "--corrupt", "medium",
                                   "--to", f"tcp://127.0.0.1:{ports[0]}", "--from", f"tcp://127.0.0.1:{ports[1]}",
                                   "--report", report], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        time.sleep(1.5)
        # A reload mid-stream with the same subject: nothing may be lost or re-timed.
        daemon.send_signal(signal.SIGHUP)
        time.sleep(0.5)
        # A broken config is refused; the daemon keeps running the old one.
        with open(config, "a") as f:
            f.write("bogus_field = 1\n")
        daemon.send_signal(signal.SIGHUP)
        out, _ = replay.communicate(timeout=60)
        print(out)
        assert replay.returncode == 0, f"replay failed: {replay.returncode}"
        with open(report) as f:
            r = json.load(f)
        assert r["frames_sent"] == 600 and r["frames_received"] == 600 and r["frames_lost"] == 0, r
        assert r["accuracy"]["mean_joint_position_error_cm"] < 2.0, r["accuracy"]

        sub_out, _ = subscriber.communicate(timeout=60)
        print(sub_out)
        assert subscriber.returncode == 0, "the example subscriber did not decode the stream"
        assert "summary: actor1: 600 skeleton frames, frames 0..599, 0 discontinuities, 21 joints described" in sub_out, sub_out

        # Wait for the last messages (the end of stream) to show before asserting on the counts.
        m = wait_for_metric(ports[2], "mocapd_messages_received_total", (), 601)
        actor = (("subject", "actor1"),)
        assert m[("mocapd_frames_published_total", actor)] == 600, m
        assert m[("mocapd_messages_received_total", ())] == 601  # 600 frames + end of stream
        assert m[("mocapd_reloads_total", ())] == 1
        assert m[("mocapd_reload_failures_total", ())] == 1
        dropped = sum(v for (name, _), v in m.items() if name == "mocapd_frames_dropped_total")
        assert dropped == 0, dropped
        assert m[("mocapd_processing_latency_seconds_count", actor)] > 0
        status, health = get(ports[2], "/health")
        assert status == 200 and json.loads(health)["accounted"] is True, health
        subjects = json.loads(get(ports[2], "/subjects")[1])
        assert subjects[0]["name"] == "actor1" and subjects[0]["frames_published"] == 600, subjects

        assert d.stop() == 0, "the daemon exited with an error"
    finally:
        if daemon.poll() is None:
            daemon.kill()
        text = d.read_log()
        print(text)
    assert "reload failed, keeping the running config" in text and "bogus_field" in text, "the broken reload was not reported"
    assert "reload: kept as they run (lookahead and timing carry on): actor1" in text, "the reload did not say what it did to the subject"
    assert "every frame accounted for" in text
    print("daemon process test passed")


if __name__ == "__main__":
    main(*sys.argv[1:5])
