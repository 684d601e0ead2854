"""Shared by the Python tests that run `mocapd run` as a process: free ports, a config
on them, start-up and shutdown."""
import os
import shutil
import signal
import socket
import subprocess
import time
import urllib.request

from prometheus_client.parser import text_string_to_metric_families


def free_ports(n):
    sockets = [socket.socket() for _ in range(n)]
    for s in sockets:
        s.bind(("127.0.0.1", 0))
    ports = [s.getsockname()[1] for s in sockets]
    for s in sockets:
        s.close()
    return ports


def http_get(port, path, token=None):
    request = urllib.request.Request(f"http://127.0.0.1:{port}{path}")
    if token:
        request.add_header("Authorization", f"Bearer {token}")
    with urllib.request.urlopen(request, timeout=5) as r:
        return r.status, r.read().decode()


def metrics(port, token=None):
    """The daemon's /metrics, parsed by a real Prometheus parser: {(sample name, sorted labels): value}."""
    _, text = http_get(port, "/metrics", token)
    values = {}
    for family in text_string_to_metric_families(text):
        for sample in family.samples:
            values[(sample.name, tuple(sorted(sample.labels.items())))] = sample.value
    return values


def wait_for_metric(port, name, labels, at_least, timeout_s=5.0):
    """Polls /metrics until a sample reaches a value: the daemon refreshes its statistics
    snapshot every 20 ms, so the newest messages show a little after they arrived."""
    deadline = time.monotonic() + timeout_s
    m = metrics(port)
    while m.get((name, labels), 0) < at_least and time.monotonic() < deadline:
        time.sleep(0.05)
        m = metrics(port)
    return m


class Daemon:
    """`mocapd run` on fresh loopback ports with the demo subject; logs to WORK/mocapd.log.
    input: the capture feed to connect to (default: a fresh port); shard: "I/N" or None;
    workers: [input] workers (None: the default, one per core); live: a subject's lines for
    calibrate = "live" (None: the demo subject's model)."""

    def __init__(self, mocapd, config_dir, work, lookahead=12, subjects=("actor1",), rate_hz=120.0, input=None,
                 shard=None, workers=None, curve=False, http_token=None, live=None, global_transforms=False):
        os.makedirs(work, exist_ok=True)
        security = ""
        # curve: fresh keys (`mocapd keygen`) for the daemon and for the replay, which is both
        # its capture publisher and an authorized consumer; replay_curve_args passes them on.
        self.replay_curve_args = []
        self.keys_dir = None
        self.http_token = http_token
        control = ""
        if http_token:  # every HTTP request must then carry it
            with open(os.path.join(work, "http.token"), "w") as f:
                f.write(http_token + "\n")
            control = f"http_token_file = \"{os.path.join(work, 'http.token')}\"\n"
        if curve:
            keys = self.keys_dir = os.path.join(work, "keys")
            shutil.rmtree(keys, ignore_errors=True)
            os.makedirs(os.path.join(keys, "authorized"))
            for name in ("mocapd", "authorized/replay"):
                subprocess.run([mocapd, "keygen", "--out", os.path.join(keys, name)], check=True, capture_output=True)
            security = (f"[security]\ncurve = true\nkey_file = \"{keys}/mocapd.key_secret\"\n"
                        f"authorized_keys = \"{keys}/authorized\"\ninput_server_key_file = \"{keys}/authorized/replay.key\"\n")
            self.replay_curve_args = ["--curve-key", f"{keys}/authorized/replay.key_secret", "--curve-server-key", f"{keys}/mocapd.key"]
        self.lookahead = lookahead
        self.input_port, self.output_port, self.http_port = free_ports(3)
        self.input = input or f"tcp://127.0.0.1:{self.input_port}"
        self.output = f"tcp://127.0.0.1:{self.output_port}"
        self.config = os.path.join(work, "mocapd.toml")
        model = os.path.abspath(os.path.join(config_dir, "demo_subject.toml"))
        with open(self.config, "w") as f:
            shard_line = f"shard = \"{shard}\"\n" if shard else ""
            if workers is not None:
                shard_line += f"workers = {workers}\n"
            globals_line = "global_transforms = true\n" if global_transforms else ""
            f.write(f"format_version = 1\n[input]\nendpoint = \"{self.input}\"\n{shard_line}[output]\nendpoint = \"{self.output}\"\n{globals_line}"
                    f"[control]\nhttp_port = {self.http_port}\nstats_interval_s = 0.2\n{control}{security}[pipeline]\nlookahead = {lookahead}\n")
            for name in subjects:
                # live: the lines of a subject calibrated from its stream, instead of a model.
                source = live if live is not None else f"model = \"{model}\"\n"
                f.write(f"[[subject]]\nname = \"{name}\"\n{source}rate_hz = {rate_hz}\n")
        self.log = open(os.path.join(work, "mocapd.log"), "w+")
        self.process = subprocess.Popen([mocapd, "run", "--config", self.config], stdout=self.log, stderr=subprocess.STDOUT)
        for _ in range(200):
            assert self.process.poll() is None, "the daemon exited at start-up:\n" + self.read_log()
            try:
                if http_get(self.http_port, "/health", http_token)[0] == 200:
                    return
            except OSError:
                time.sleep(0.05)
        raise AssertionError("the daemon's /health never answered")

    def signal(self, sig):
        self.process.send_signal(sig)

    def stop(self):
        """SIGTERM; returns the exit code (0: every frame accounted for)."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
        try:
            return self.process.wait(timeout=30)
        except subprocess.TimeoutExpired:
            self.process.kill()
            raise

    def read_log(self):
        self.log.flush()
        self.log.seek(0)
        return self.log.read()


def add_run_arguments(parser, root, seconds):
    """The command-line options the bench scripts share: the binaries, actors, rate, length."""
    parser.add_argument("--mocapd", default=os.path.join(root, "build", "release", "runtime", "mocapd"))
    parser.add_argument("--mocap-sim", dest="mocap_sim", default=os.path.join(root, "build", "release", "sim", "mocap-sim"))
    parser.add_argument("--subjects", type=int, default=4)
    parser.add_argument("--rate", type=float, default=240.0)
    parser.add_argument("--seconds", type=float, default=seconds)
