#!/usr/bin/env python3
"""Example consumer of a running mocapd: subscribes to its skeleton frames (and subject
descriptions and status), decodes them with mocapd_protocol, and prints what it sees.

    python3 protocol/python/example_subscriber.py --endpoint tcp://127.0.0.1:5556 --subject actor1
    # a daemon with security.curve = true: this consumer's key pair (its .key in the
    # daemon's authorized_keys directory) and the daemon's public key
    python3 protocol/python/example_subscriber.py --curve-key me.key_secret --curve-server-key mocapd.key

Needs only the standard library and Debian's python3-zmq. A game-engine or MotionBuilder
bridge would start from here: the subject description gives joint names, parents and
rest offsets; each skeleton frame gives the root translation and every joint's local
rotation (w, x, y, z) in that order.
"""
import argparse
import os
import sys
import time

import zmq
import zmq.auth

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import mocapd_protocol  # noqa: E402


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--endpoint", default="tcp://127.0.0.1:5556", help="the daemon's output (PUB) endpoint")
    parser.add_argument("--subject", default="", help="only this subject (default: all)")
    parser.add_argument("--frames", type=int, default=0, help="exit after this many skeleton frames (0: run until Ctrl-C)")
    parser.add_argument("--timeout", type=float, default=0.0, help="give up after this many seconds (0: never)")
    parser.add_argument("--quiet", action="store_true", help="print only the summary")
    parser.add_argument("--curve-key", default="", help="CURVE: this consumer's key pair (NAME.key_secret from mocapd keygen)")
    parser.add_argument("--curve-server-key", default="", help="CURVE: the daemon's public key (NAME.key)")
    args = parser.parse_args()
    if bool(args.curve_key) != bool(args.curve_server_key):
        parser.error("CURVE needs both --curve-key and --curve-server-key")

    context = zmq.Context()
    socket = context.socket(zmq.SUB)
    socket.setsockopt(zmq.RCVHWM, 0)
    suffix = args.subject + "/" if args.subject else ""
    for kind in ("skeleton/", "subject/", "status/", "character/"):
        socket.setsockopt(zmq.SUBSCRIBE, (kind + suffix).encode())
    if args.curve_key:
        # mocapd keygen writes ZeroMQ certificates, which pyzmq reads as they are.
        public, secret = zmq.auth.load_certificate(args.curve_key)
        server_public, _ = zmq.auth.load_certificate(args.curve_server_key)
        if not secret:
            parser.error(f"{args.curve_key}: no secret-key (give the .key_secret file)")
        socket.curve_publickey, socket.curve_secretkey, socket.curve_serverkey = public, secret, server_public
    socket.connect(args.endpoint)

    joints = {}  # subject -> joint names, from its description
    frames = {}  # subject -> list of frame numbers received
    character_frames = {}  # subject -> frames of the character it drives (retargeting)
    errors = 0
    start = time.monotonic()
    last_print = 0.0
    total = 0
    try:
        while args.frames == 0 or total < args.frames:
            if args.timeout and time.monotonic() - start > args.timeout:
                print(f"timeout after {args.timeout} s", file=sys.stderr)
                break
            if not socket.poll(100):
                continue
            topic, body = socket.recv_multipart()
            try:
                kind, message = mocapd_protocol.decode(body)
            except ValueError as e:
                errors += 1
                print(f"undecodable message on {topic!r}: {e}", file=sys.stderr)
                continue
            if topic.startswith(b"character/"):
                # A subject's retargeted character: its skeleton frames and description.
                if kind == "skeleton_frame":
                    character_frames.setdefault(message["subject"], []).append(message["frame"])
                elif kind == "subject_description" and not args.quiet and message["subject"] not in character_frames:
                    print(f"subject {message['subject']} drives a character with {len(message['joints'])} joints")
                continue
            if kind == "subject_description":
                if message["subject"] not in joints and not args.quiet:
                    names = [j["name"] for j in message["joints"]]
                    print(f"subject {message['subject']}: {len(names)} joints ({', '.join(names[:4])} ...), "
                          f"{len(message['markers'])} markers, {message['rate_hz']:.0f} Hz, lookahead {message['lookahead_frames']}")
                joints[message["subject"]] = [j["name"] for j in message["joints"]]
            elif kind == "subject_status":
                if message["state"] == "stalled" and not args.quiet:
                    print(f"subject {message['subject']} stalled: no input for {message['since_last_input_ns'] / 1e9:.2f} s")
            elif kind == "skeleton_frame":
                frames.setdefault(message["subject"], []).append(message["frame"])
                total += 1
                now = time.monotonic()
                if not args.quiet and now - last_print >= 1.0:
                    root = message["root_translation"]
                    latency_ms = (message["publish_time_ns"] - message["capture_time_ns"]) / 1e6
                    stream = message.get("stream")
                    timecode = ""
                    if stream and stream["timecode"]:
                        timecode = " tc " + mocapd_protocol.format_timecode(stream["timecode"])
                    print(f"{message['subject']} frame {message['frame']:6d}{timecode} {message['subject_state']:9s} "
                          f"root ({root[0]:+.3f}, {root[1]:+.3f}, {root[2]:+.3f}) m  residual {message['residual_m'] * 1e3:.2f} mm  "
                          f"capture->publish {latency_ms:.1f} ms")
                    last_print = now
    except KeyboardInterrupt:
        pass
    for subject, numbers in sorted(frames.items()):
        gaps = sum(1 for a, b in zip(numbers, numbers[1:]) if b != a + 1)
        print(f"summary: {subject}: {len(numbers)} skeleton frames, frames {numbers[0]}..{numbers[-1]}, "
              f"{gaps} discontinuities, {len(joints.get(subject, []))} joints described")
    for subject, numbers in sorted(character_frames.items()):
        print(f"summary: {subject}: {len(numbers)} character frames")
    print(f"summary: {total} skeleton frames, {errors} undecodable messages")
    if total == 0 and args.curve_key:
        # A refused CURVE handshake is silent on this side: say what to check.
        print("no frame: with CURVE, is this key's .key in the daemon's authorized_keys, and "
              "--curve-server-key the daemon's public key? (the daemon counts refusals in "
              "mocapd_curve_clients_refused_total)", file=sys.stderr)
    return 0 if errors == 0 and (args.frames == 0 or total >= args.frames) else 1


if __name__ == "__main__":
    sys.exit(main())
