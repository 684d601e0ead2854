"""Scale-out on ZeroMQ: two `mocapd run` daemons with the same subject list and shards
0/2 and 1/2 subscribe to one capture feed (`mocap-sim replay` with N actors); a consumer
subscribes to both. Every subject must be solved by exactly one daemon, the one its
shard names (FNV-1a of the name, modulo 2, as protocol/README.md's hash), with every
frame it was sent published once; each daemon's accounting balances and it exits 0.

usage: scale_out_test.py MOCAPD MOCAP_SIM CONFIG_DIR WORK_DIR
"""
import os
import subprocess
import sys
import threading
import time

import zmq

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "protocol", "python"))
import mocapd_protocol  # noqa: E402
from daemon_harness import Daemon, free_ports, metrics  # noqa: E402

SUBJECTS = [f"actor{k}" for k in range(1, 7)]
SECONDS = 3.0
RATE = 120


def shard_of(name, count):
    return mocapd_protocol.names_hash([name]) % count


class Consumer(threading.Thread):
    """Subscribes to every daemon's skeleton frames; counts them per (daemon, subject, frame)."""

    def __init__(self, ctx, endpoints):
        super().__init__(daemon=True)
        self.socks = []
        for e in endpoints:
            s = ctx.socket(zmq.SUB)
            s.setsockopt(zmq.SUBSCRIBE, b"skeleton/")
            s.connect(e)
            self.socks.append(s)
        self.seen = {}  # (subject, frame) -> list of daemon indices
        self.running = True

    def run(self):
        poller = zmq.Poller()
        for s in self.socks:
            poller.register(s, zmq.POLLIN)
        while self.running:
            for sock, _ in poller.poll(50):
                _, body = sock.recv_multipart()
                kind, m = mocapd_protocol.decode(body)
                if kind == "skeleton_frame":
                    self.seen.setdefault((m["subject"], m["frame"]), []).append(self.socks.index(sock))

    def stop(self):
        self.running = False
        self.join(timeout=5)
        for s in self.socks:
            s.close(linger=0)


def main(mocapd, mocap_sim, config_dir, work):
    expected = {name: shard_of(name, 2) for name in SUBJECTS}
    assert set(expected.values()) == {0, 1}, f"pick names that land on both shards: {expected}"
    (feed_port,) = free_ports(1)
    feed = f"tcp://127.0.0.1:{feed_port}"
    daemons = [Daemon(mocapd, config_dir, os.path.join(work, f"shard{i}"), subjects=SUBJECTS, input=feed,
                      shard=f"{i}/2") for i in range(2)]
    ctx = zmq.Context()
    consumer = Consumer(ctx, [d.output for d in daemons])
    consumer.start()
    time.sleep(0.3)  # the consumer's subscriptions reach the daemons
    try:
        # The replay binds the feed and waits until every actor's topic is subscribed: by
        # one daemon or the other, never both (each subscribes to its own shard's).
        replay = subprocess.run([mocap_sim, "replay", "--humanoid", "walk", "--seconds", str(SECONDS),
                                 "--subjects", str(len(SUBJECTS)), "--to", feed, "--from", ""],
                                capture_output=True, text=True, timeout=60)
        assert replay.returncode == 0, replay.stdout + replay.stderr
        frames = int(SECONDS * RATE)
        deadline = time.monotonic() + 10
        while len(consumer.seen) < frames * len(SUBJECTS) and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.2)
        solved_by = {}
        for (subject, frame), who in consumer.seen.items():
            assert len(who) == 1, f"{subject} frame {frame} published {len(who)} times (daemons {who})"
            solved_by.setdefault(subject, set()).add(who[0])
        for name in SUBJECTS:
            assert solved_by.get(name) == {expected[name]}, \
                f"{name}: solved by {solved_by.get(name)}, its shard is {expected[name]}"
            got = sorted(f for (s, f) in consumer.seen if s == name)
            assert got == list(range(frames)), f"{name}: {len(got)} of {frames} frames published"
        for i, d in enumerate(daemons):
            m = metrics(d.http_port)
            mine = [n for n in SUBJECTS if expected[n] == i]
            received = m[("mocapd_messages_received_total", ())]
            published = sum(v for (k, labels), v in m.items() if k == "mocapd_frames_published_total")
            dropped = sum(v for (k, labels), v in m.items() if k == "mocapd_frames_dropped_total")
            control = m[("mocapd_control_messages_total", ())]
            subjects = sorted(dict(labels)["subject"] for (k, labels) in m if k == "mocapd_frames_published_total")
            assert subjects == sorted(mine), (i, subjects, mine)
            assert received == published + dropped + control and dropped == 0, (i, received, published, dropped, control)
            assert published == frames * len(mine), (i, published)
            print(f"shard {i}/2: solved {', '.join(mine)}: {received:.0f} messages in = {published:.0f} published + "
                  f"{control:.0f} ends of stream, none dropped")
        for d in daemons:
            assert d.stop() == 0, d.read_log()
    finally:
        consumer.stop()
        for d in daemons:
            if d.process.poll() is None:
                d.process.kill()
        ctx.term()
    print(f"scale-out test passed: {len(SUBJECTS)} actors over 2 daemons, each solved once, every frame accounted for")


if __name__ == "__main__":
    main(*sys.argv[1:5])
