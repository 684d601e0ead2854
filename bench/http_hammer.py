#!/usr/bin/env python3
"""What scraping costs the data plane: the daemon (N actors at a rate, fed by
`mocap-sim replay`, medium corruption) is run twice, once quiet and once while client
threads request /metrics as fast as they can. Prints the replay's processing latency
percentiles for both runs and the request rate the hammer reached.

    bench/http_hammer.py --subjects 4 --rate 240 --seconds 20 --threads 4
"""
import argparse
import json
import os
import socket
import subprocess
import sys
import threading
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, os.path.join(ROOT, "tests", "runtime"))
from daemon_harness import Daemon, add_run_arguments  # noqa: E402


def hammer(port, stop, counts, index):
    request = f"GET /metrics HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n\r\n".encode()
    while not stop.is_set():
        with socket.create_connection(("127.0.0.1", port), timeout=5) as s:
            s.sendall(request)
            while s.recv(65536):
                pass
        counts[index] += 1


def run(args, work, threads):
    names = [f"actor{k + 1}" for k in range(args.subjects)]
    daemon = Daemon(args.mocapd, os.path.join(ROOT, "config"), work, subjects=names, rate_hz=args.rate)
    stop = threading.Event()
    counts = [0] * threads
    workers = [threading.Thread(target=hammer, args=(daemon.http_port, stop, counts, i)) for i in range(threads)]
    report = os.path.join(work, "replay.json")
    try:
        t0 = time.monotonic()
        for w in workers:
            w.start()
        replay = subprocess.run([args.mocap_sim, "replay", "--humanoid", "mixed", "--seconds", str(args.seconds),
                                 "--synth-rate", str(args.rate), "--subjects", str(args.subjects), "--corrupt", "medium",
                                 "--to", daemon.input, "--from", daemon.output, "--report", report],
                                capture_output=True, text=True)
        elapsed = time.monotonic() - t0
        stop.set()
        for w in workers:
            w.join()
        if replay.returncode != 0:
            raise RuntimeError(replay.stdout + replay.stderr)
    finally:
        stop.set()
        code = daemon.stop()
    with open(report) as f:
        p = json.load(f)["processing_latency"]
    rate = sum(counts) / elapsed
    print(f"{threads} hammer thread(s), {rate:7.0f} /metrics requests/s: processing p50 {p['p50_ms']:.3f} "
          f"p99 {p['p99_ms']:.3f} p99.9 {p['p99.9_ms']:.3f} max {p['max_ms']:.3f} ms; daemon exit {code}", flush=True)
    return p, rate


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_run_arguments(parser, ROOT, seconds=20.0)
    parser.add_argument("--threads", type=int, default=4)
    parser.add_argument("--work", default=os.path.join(ROOT, "build", "http_hammer"))
    args = parser.parse_args()
    quiet, _ = run(args, os.path.join(args.work, "quiet"), 0)
    loud, rate = run(args, os.path.join(args.work, "hammered"), args.threads)
    print(f"p99 moved {100 * (loud['p99_ms'] / quiet['p99_ms'] - 1):+.0f} % under {rate:.0f} requests/s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
