"""Trusted peers only, as processes: keys from `mocapd keygen`, a daemon with
security.curve = true, `mocap-sim replay` as its capture publisher and authorized
consumer, and the Python example subscriber (pyzmq reads the keygen certificates as they
are). An authorized viewer receives every frame; a stranger's key and a peer without
CURVE get nothing and are counted; a forged capture publisher gets no frame in; revoking
the viewer's key with a reload refuses its next connection.

usage: curve_process_test.py MOCAPD MOCAP_SIM CONFIG_DIR WORK_DIR
"""
import os
import shutil
import signal
import subprocess
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from daemon_harness import Daemon, metrics, wait_for_metric  # noqa: E402

SUBSCRIBER = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "protocol", "python", "example_subscriber.py")
SECONDS = 2.0
RATE = 120


def keygen(mocapd, base):
    r = subprocess.run([mocapd, "keygen", "--out", base], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return base


def subscriber(daemon, key, frames, timeout):
    args = [sys.executable, SUBSCRIBER, "--endpoint", daemon.output, "--frames", str(frames), "--timeout", str(timeout), "--quiet"]
    if key:
        args += ["--curve-key", key + ".key_secret", "--curve-server-key", daemon.keys_dir + "/mocapd.key"]
    return subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def received(process):
    out = process.communicate(timeout=60)[0]
    for line in out.splitlines():
        if line.startswith("summary: ") and "skeleton frames," in line and "undecodable" in line:
            return int(line.split()[1]), out
    raise AssertionError("no summary from the subscriber:\n" + out)


def counter(port, name, socket):
    return metrics(port).get((name, (("socket", socket),)), 0)


def main(mocapd, mocap_sim, config_dir, work):
    shutil.rmtree(work, ignore_errors=True)
    daemon = Daemon(mocapd, config_dir, work, curve=True)
    outsiders = os.path.join(work, "outsiders")
    os.makedirs(outsiders)
    try:
        viewer = keygen(mocapd, os.path.join(daemon.keys_dir, "authorized", "viewer"))
        stranger = keygen(mocapd, os.path.join(outsiders, "stranger"))
        again = subprocess.run([mocapd, "keygen", "--out", stranger], capture_output=True, text=True)
        assert again.returncode == 1 and "already exists" in again.stderr, again.stderr
        daemon.signal(signal.SIGHUP)  # the allow-list is re-read: the viewer is in
        wait_for_metric(daemon.http_port, "mocapd_reloads_total", (), 1)

        frames = int(SECONDS * RATE)
        trusted = subscriber(daemon, viewer, frames, 30)
        strange = subscriber(daemon, stranger, 1, 6)
        plain = subscriber(daemon, None, 1, 6)
        time.sleep(0.5)  # subscriptions (or refusals) settle
        replay = subprocess.run([mocap_sim, "replay", "--humanoid", "walk", "--seconds", str(SECONDS), "--to", daemon.input,
                                 "--from", daemon.output, *daemon.replay_curve_args], capture_output=True, text=True, timeout=60)
        assert replay.returncode == 0, replay.stdout + replay.stderr
        assert f"frames sent / received             {frames} / {frames}" in replay.stdout, replay.stdout
        got, out = received(trusted)
        assert got == frames, f"the authorized viewer got {got} of {frames}:\n{out}"
        for name, process in (("stranger", strange), ("peer without CURVE", plain)):
            got, out = received(process)
            assert got == 0, f"the {name} got {got} frames:\n{out}"
        assert counter(daemon.http_port, "mocapd_curve_clients_refused_total", "output") >= 1
        assert counter(daemon.http_port, "mocapd_curve_handshake_failures_total", "output") >= 1
        assert counter(daemon.http_port, "mocapd_curve_clients_accepted_total", "output") >= 2  # replay + viewer

        # A forged capture feed: the stranger publishes on a port the daemon does not
        # trust... the daemon's own input, after the real publisher left. The daemon takes
        # nothing from it: its handshakes fail (counted on the input).
        before = metrics(daemon.http_port)[("mocapd_messages_received_total", ())]
        forged = subprocess.run([mocap_sim, "replay", "--humanoid", "walk", "--seconds", "1", "--to", daemon.input, "--from", "",
                                 "--connect-timeout", "2", "--curve-key", stranger + ".key_secret",
                                 "--curve-server-key", daemon.keys_dir + "/mocapd.key"], capture_output=True, text=True, timeout=60)
        assert forged.returncode != 0 and "nothing subscribed" in forged.stderr, forged.stdout + forged.stderr
        assert metrics(daemon.http_port)[("mocapd_messages_received_total", ())] == before
        assert counter(daemon.http_port, "mocapd_curve_handshake_failures_total", "input") >= 1

        # Revoked: the viewer's key leaves the allow-list; its next connection is refused.
        refused = counter(daemon.http_port, "mocapd_curve_clients_refused_total", "output")
        os.remove(viewer + ".key")
        daemon.signal(signal.SIGHUP)
        wait_for_metric(daemon.http_port, "mocapd_reloads_total", (), 2)
        revoked = subscriber(daemon, viewer, 1, 3)
        got, out = received(revoked)
        assert got == 0, out
        assert counter(daemon.http_port, "mocapd_curve_clients_refused_total", "output") > refused
        assert daemon.stop() == 0, daemon.read_log()
        log = daemon.read_log()
        assert "CURVE: refused a client on the output" in log, log
    finally:
        if daemon.process.poll() is None:
            daemon.process.kill()
    print(f"CURVE test passed: the authorized viewer got all {frames} frames; a stranger, a peer without CURVE, "
          "a forged publisher and a revoked key got none, each counted")


if __name__ == "__main__":
    main(*sys.argv[1:5])
