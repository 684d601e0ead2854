"""An independent implementation of the mocapd wire protocol, written from
protocol/README.md alone, checked against the running daemon.

Why: the README is the contract a capture bridge or a consumer is written from. The
reference decoder (protocol/python/mocapd_protocol.py) and the C++ code were written by
the same hands as the daemon, so they can agree with the daemon and still disagree with
the document. This file was written by reading only protocol/README.md (plus the config
files and the top-level README for how to start the daemon); it does not import or
mirror the project's code. If the document is wrong or incomplete, this test fails.

What it checks (wire versions 1 and 2):
  a. the README's model-hash examples; the marker-set and skeleton hashes of
     config/demo_subject.toml against the subject description and GET /subjects; our own
     codec: v1 and v2 round trips and sizes (B = 24 in v2), every cut too_short, versions
     other than 1 and 2 unsupported, each stream-block rule (bad_field) and its valid edge
     cases;
  b. the real daemon (PULL input, PUB output, global transforms on, [output]
     protocol_version left at its default) fed with marker frames encoded here: a
     synthetic body moving at 120 Hz in version 2 (capture session S1, rate 120/1, 30 fps
     non-drop timecode with subframes 0..3; a 2-frame gap; then session S2 with the frame
     numbers continuing: a restart), an end of stream, then a second stream in version 1
     with a one-frame gap and a jump of more than max_gap_frames, another end of stream;
  c. every published message is version 2, decodes, has the size of the README's formula
     (with B) and fields in their documented ranges; frame numbers are the ones sent,
     consecutive, once each; capture timestamps are echoed (0 for inserted frames); each
     skeleton frame and cleaned-markers message carries its marker frame's stream block
     (inserted frames: the stream's session and rate, no timecode; version 1 input:
     session 0, no rate, no timecode); the lookahead K is honoured; a session change, a
     jump and an end of stream flush every frame held;
  d. forward kinematics from the description and the local block equals the global block;
  e. the /metrics balance equation, /health "ok" and "accounted" after the end of
     stream, the subject status message's counters; mocapd_frames_skipped_total (gaps and
     the jump), mocapd_capture_restarts_total and mocapd_capture_sessions_changed_total
     (the session change; frames of other sessions that are dropped earlier, a late frame
     and the post-end-of-stream version 1 stream do not count); /subjects' frames_skipped,
     capture_session_id, last_timecode and capture_session_changes;
  f. negative cases: wrong hash or marker count (model_mismatch), wrong rate
     (rate_mismatch), truncated, 35+n+B+13M-sized, bad magic, version 3, a header version
     that disagrees with the payload, each broken stream-block rule (timecode fields,
     flags, rate fraction vs the f32 rate, numerator without denominator and the
     reverse), 3-part and bad end of stream (malformed), NaN (non_finite), unknown
     subject, not a marker frame, oversized, duplicate, out of order (3 back; and 125 back
     with a later capture timestamp, which is late within a session, not a restart);
  g. a second daemon with [output] protocol_version = 1 (global transforms off), fed
     version 2 frames with a drop-frame timecode: everything it publishes is version 1
     with the version 1 sizes (no stream block); its /subjects shows the session and
     "HH:MM:SS;FF.S".

Standard library and pyzmq only.

usage: independent_decoder_test.py MOCAPD CONFIG_DIR WORK_DIR
"""
import json
import math
import os
import re
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
import tomllib
import urllib.error
import urllib.request

import zmq

# Test plumbing only (free loopback ports), shared with the other daemon tests.
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "runtime"))
from daemon_harness import free_ports  # noqa: E402

# ---------------------------------------------------------------------------------------
# The protocol, from protocol/README.md
# ---------------------------------------------------------------------------------------

MAGIC = 0x4450434D  # bytes 4D 43 50 44, "MCPD"
VERSIONS = (1, 2)
VERSION = 2  # what we send by default, and what the daemon publishes by default
SUBJECT_DESCRIPTION, MARKER_FRAME, SKELETON_FRAME, CLEANED_MARKERS, SUBJECT_STATUS, END_OF_STREAM = 1, 2, 3, 4, 5, 6
TYPE_NAMES = {1: "subject description", 2: "marker frame", 3: "skeleton frame", 4: "cleaned markers",
              5: "subject status", 6: "end of stream"}
MAX_MARKERS = 1024
MAX_JOINTS = 512
HEADER = struct.Struct("<IHHII")  # magic, version, type, payload size P, reserved

# The version 2 stream block (README, "Versions and the stream block"): 24 bytes.
STREAM_FMT = "QIIBBBBBBH"
STREAM_SIZE = struct.calcsize("<" + STREAM_FMT)
assert STREAM_SIZE == 24


def print_log_tail(log, title, chars):
    """On a failure: the end of the daemon's log, to see why."""
    log.flush()
    log.seek(0)
    print(f"---- {title} log (tail) ----\n" + log.read()[-chars:] + "\n----", file=sys.stderr)


def stop_all(collector, sender, daemon, log):
    """Whatever started, stopped, whether the checks passed or not."""
    if collector is not None:
        collector.stop()
    if sender is not None:
        sender.sock.close(linger=0)
    if daemon is not None and daemon.poll() is None:
        daemon.kill()
        daemon.wait(timeout=10)
    log.close()


class Stream(tuple):
    """session id, rate numerator, rate denominator, timecode hours, minutes, seconds,
    frames, subframe, timecode flags (bit 0 present, bit 1 drop-frame), timecode rate."""
    FIELDS = ("session", "num", "den", "hours", "minutes", "seconds", "frames", "subframe", "tc_flags", "tc_rate")

    def __new__(cls, session=0, num=0, den=0, hours=0, minutes=0, seconds=0, frames=0, subframe=0, tc_flags=0,
                tc_rate=0):
        return super().__new__(cls, (session, num, den, hours, minutes, seconds, frames, subframe, tc_flags, tc_rate))

    def __getattr__(self, name):
        try:
            return self[Stream.FIELDS.index(name)]
        except ValueError:
            raise AttributeError(name)

    def replace(self, **kw):
        return Stream(*(kw.get(f, v) for f, v in zip(Stream.FIELDS, self)))

    def __repr__(self):
        return "Stream(" + ", ".join(f"{f}={v}" for f, v in zip(Stream.FIELDS, self)) + ")"


NO_STREAM = Stream()  # what a version 1 frame reads as: session 0, no rate fraction, no timecode


def block_size(version):
    """B: 24 in version 2, 0 in version 1."""
    return STREAM_SIZE if version == 2 else 0


def timecode(session, num, den, index, subframe, fps=30):
    """A non-drop timecode at `index` timecode frames since midnight, present (flags bit 0)."""
    frames = index % fps
    secs = index // fps
    return Stream(session, num, den, (secs // 3600) % 24, (secs // 60) % 60, secs % 60, frames, subframe, 1, fps)


def timecode_text(s):
    """/subjects' last_timecode: "HH:MM:SS:FF", ";" before the frames when drop-frame, ".S" with a subframe."""
    return (f"{s.hours:02d}:{s.minutes:02d}:{s.seconds:02d}{';' if s.tc_flags & 2 else ':'}{s.frames:02d}"
            + (f".{s.subframe}" if s.subframe else ""))


class DecodeError(Exception):
    """A decoder status other than ok (README, top: too_short, bad_magic, ...)."""

    def __init__(self, status, detail):
        super().__init__(f"{status}: {detail}")
        self.status = status


def model_hash(names):
    """FNV-1a over each name's bytes plus one zero byte, with the README's initial value."""
    h = 1469598103934665603
    for name in names:
        for b in name.encode("utf-8") + b"\x00":
            h = ((h ^ b) * 1099511628211) & 0xFFFFFFFFFFFFFFFF
    return h


def skeleton_hash_strings(joint_names, parents):
    return [f"{name}/{parent}" for name, parent in zip(joint_names, parents)]


# Payload sizes, the README's formulas (n = the subject name's length in bytes, B the
# stream block's size: 24 in version 2, 0 in version 1).
def marker_frame_size(n, m, version=VERSION):
    return 33 + n + block_size(version) + 13 * m


def skeleton_frame_size(n, j, global_block, version=VERSION):
    return 1 + n + 56 + block_size(version) + (44 if global_block else 16) * j


def description_size(n, marker_names, joint_names):
    return (29 + n + sum(1 + len(x.encode()) for x in marker_names)
            + sum(31 + len(x.encode()) for x in joint_names))


def cleaned_size(n, m, version=VERSION):
    return 1 + n + 36 + block_size(version) + 14 * m


def status_size(n):
    return 1 + n + 44


def end_of_stream_size(n):
    return 1 + n + 8


# --- encoding ----------------------------------------------------------------------------

def message(msg_type, payload, version=VERSION, magic=MAGIC, reserved=0):
    return HEADER.pack(magic, version, msg_type, len(payload), reserved) + payload


def enc_string(s):
    b = s.encode("utf-8")
    assert 1 <= len(b) <= 63, s
    return bytes([len(b)]) + b


def enc_stream(version, stream):
    """The stream block in version 2 (NO_STREAM when none is given), nothing in version 1."""
    if version == 1:
        assert stream is None, "version 1 has no stream block"
        return b""
    return struct.pack("<" + STREAM_FMT, *(NO_STREAM if stream is None else stream))


def encode_marker_frame(subject, hash_, frame, capture_ns, rate, markers, junk=False, version=VERSION, stream=None):
    """markers: list of (x, y, z) or None (an invalid marker: zeros, flags 0). With junk,
    every reserved field and reserved flag bit is set (readers must ignore them)."""
    out = [enc_string(subject), struct.pack("<QQQfHH", hash_, frame, capture_ns, rate, len(markers),
                                            0xBEEF if junk else 0), enc_stream(version, stream)]
    valid, invalid = (0xFF, 0xFE) if junk else (1, 0)
    for p in markers:
        out.append(struct.pack("<fffB", 0.0, 0.0, 0.0, invalid) if p is None else struct.pack("<fffB", *p, valid))
    return message(MARKER_FRAME, b"".join(out), version=version, reserved=0xDEADBEEF if junk else 0)


def encode_end_of_stream(subject, last_frame, version=VERSION):
    return message(END_OF_STREAM, enc_string(subject) + struct.pack("<Q", last_frame), version=version)


def encode_description(subject, marker_hash, skel_hash, rate, k, marker_names, joints):
    """joints: list of (name, parent, offset xyz, rotation wxyz)."""
    out = [enc_string(subject), struct.pack("<QQfHHHH", marker_hash, skel_hash, rate, k, len(marker_names), len(joints), 0)]
    out += [enc_string(x) for x in marker_names]
    for name, parent, off, rot in joints:
        out += [enc_string(name), struct.pack("<h3f4f", parent, *off, *rot)]
    return message(SUBJECT_DESCRIPTION, b"".join(out))


def encode_skeleton_frame(subject, hash_, frame, capture_ns, publish_ns, solve, state, rms, root, local, global_=None,
                          version=VERSION, stream=None):
    flags = 1 if global_ is not None else 0
    out = [enc_string(subject),
           struct.pack("<QQQQBBHHH", hash_, frame, capture_ns, publish_ns, solve, state, flags, len(local), 0),
           enc_stream(version, stream), struct.pack("<f3f", rms, *root)]
    out += [struct.pack("<4f", *q) for q in local]
    if global_ is not None:
        out += [struct.pack("<4f3f", *q, *p) for q, p in global_]
    return message(SKELETON_FRAME, b"".join(out), version=version)


def encode_cleaned(subject, hash_, frame, capture_ns, publish_ns, markers, version=VERSION, stream=None):
    """markers: list of ((x, y, z), status, reason)."""
    out = [enc_string(subject), struct.pack("<QQQQHH", hash_, frame, capture_ns, publish_ns, len(markers), 0),
           enc_stream(version, stream)]
    out += [struct.pack("<3fBB", *p, st, r) for p, st, r in markers]
    return message(CLEANED_MARKERS, b"".join(out), version=version)


def encode_status(subject, state, problems, last, since_ns, f_in, f_out, dropped):
    return message(SUBJECT_STATUS, enc_string(subject) + struct.pack("<BBHQQQQQ", state, problems, 0, last, since_ns,
                                                                     f_in, f_out, dropped))


# --- decoding ----------------------------------------------------------------------------

class Reader:
    def __init__(self, payload):
        self.b = payload
        self.o = 0

    def take(self, fmt):
        size = struct.calcsize("<" + fmt)
        if self.o + size > len(self.b):
            raise DecodeError("too_short", f"field '{fmt}' at payload offset {self.o} is cut off")
        v = struct.unpack_from("<" + fmt, self.b, self.o)
        self.o += size
        return v if len(v) > 1 else v[0]

    def string(self, bad_status):
        length = self.take("B")
        if length == 0 or length > 63:
            raise DecodeError(bad_status, f"name length {length} at payload offset {self.o - 1}")
        if self.o + length > len(self.b):
            raise DecodeError("too_short", "name cut off")
        raw = self.b[self.o:self.o + length]
        self.o += length
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError:
            raise DecodeError(bad_status, f"name {raw!r} is not UTF-8")

    def remaining(self):
        return len(self.b) - self.o


def f32_round(x):
    return struct.unpack("<f", struct.pack("<f", x))[0]


def finite(*xs):
    return all(math.isfinite(x) for x in xs)


def decode_header(msg):
    """(message type, version, payload)."""
    if len(msg) < 16:
        raise DecodeError("too_short", f"{len(msg)} bytes, a header is 16")
    magic, version, msg_type, size, _reserved = HEADER.unpack_from(msg)
    if magic != MAGIC:
        raise DecodeError("bad_magic", f"magic 0x{magic:08X}")
    if version not in VERSIONS:
        raise DecodeError("unsupported_version", f"version {version}")
    if msg_type not in TYPE_NAMES:
        raise DecodeError("wrong_type", f"type {msg_type}")
    if len(msg) < 16 + size:
        raise DecodeError("too_short", f"{len(msg)} bytes, header says 16 + {size}")
    if len(msg) > 16 + size:
        raise DecodeError("size_mismatch", f"{len(msg)} bytes, header says 16 + {size}")
    return msg_type, version, msg[16:]


def expect_size(payload, expected, what):
    if len(payload) < expected:
        raise DecodeError("too_short", f"{what}: payload {len(payload)} bytes, README formula gives {expected}")
    if len(payload) != expected:
        raise DecodeError("size_mismatch", f"{what}: payload {len(payload)} bytes, README formula gives {expected}")


def check_stream(s, marker_rate=None):
    """The stream block's decoder rules, all bad_field. marker_rate: the marker frame's f32 rate."""
    if s.tc_flags & ~0b11:
        raise DecodeError("bad_field", f"timecode flags 0x{s.tc_flags:02x}: a bit other than 0 and 1")
    if s.tc_flags & 2 and not s.tc_flags & 1:
        raise DecodeError("bad_field", "drop-frame (bit 1) without a timecode (bit 0)")
    if s.tc_flags & 1:
        if s.tc_rate == 0:
            raise DecodeError("bad_field", "timecode rate 0")
        if s.hours > 23 or s.minutes > 59 or s.seconds > 59 or s.frames >= s.tc_rate:
            raise DecodeError("bad_field", f"timecode {s.hours}:{s.minutes}:{s.seconds}:{s.frames} at {s.tc_rate} fps")
        if s.tc_flags & 2 and s.tc_rate % 30 != 0:
            raise DecodeError("bad_field", f"drop-frame at {s.tc_rate} fps")
    if (s.num == 0) != (s.den == 0):
        raise DecodeError("bad_field", f"rate fraction {s.num}/{s.den}: exactly one of them is 0")
    if marker_rate is not None and s.num:
        fraction = s.num / s.den
        if abs(marker_rate - fraction) > 1e-4 * fraction:
            raise DecodeError("bad_field", f"rate fraction {s.num}/{s.den} vs the f32 rate {marker_rate}")


def take_stream(r, version, marker_rate=None):
    if version == 1:
        return None
    s = Stream(*r.take(STREAM_FMT))
    check_stream(s, marker_rate)
    return s


def decode_marker_frame(p, version=VERSION):
    r = Reader(p)
    subject = r.string("bad_subject_name")
    hash_, frame, capture_ns, rate, m, _res = r.take("QQQfHH")
    if not math.isfinite(rate) or rate <= 0:
        raise DecodeError("non_finite", f"rate {rate}")
    if m > MAX_MARKERS:
        raise DecodeError("too_many_items", f"M = {m}")
    expect_size(p, marker_frame_size(len(subject.encode()), m, version), "marker frame")
    stream = take_stream(r, version, marker_rate=rate)
    markers = []
    for _ in range(m):
        x, y, z, flags = r.take("fffB")
        valid = bool(flags & 1)
        if valid and not finite(x, y, z):
            raise DecodeError("non_finite", "valid marker with a non-finite coordinate")
        markers.append((x, y, z) if valid else None)
    return dict(version=version, subject=subject, hash=hash_, frame=frame, capture_ns=capture_ns, rate=rate,
                stream=stream, markers=markers)


def decode_skeleton_frame(p, version=VERSION):
    r = Reader(p)
    subject = r.string("bad_subject_name")
    hash_, frame, capture_ns, publish_ns, solve, state, flags, j, _res = r.take("QQQQBBHHH")
    if state > 4:
        raise DecodeError("bad_field", f"subject state {state}")
    if flags & ~1:
        raise DecodeError("bad_field", f"flags 0x{flags:04x}")
    if j > MAX_JOINTS:
        raise DecodeError("too_many_items", f"J = {j}")
    has_global = bool(flags & 1)
    expect_size(p, skeleton_frame_size(len(subject.encode()), j, has_global, version), "skeleton frame")
    stream = take_stream(r, version)
    rms = r.take("f")
    root = r.take("3f")
    local = [r.take("4f") for _ in range(j)]
    global_ = [(r.take("4f"), r.take("3f")) for _ in range(j)] if has_global else None
    floats = [rms, *root, *(c for q in local for c in q)]
    if global_:
        floats += [c for q, pos in global_ for c in (*q, *pos)]
    if not finite(*floats):
        raise DecodeError("non_finite", "a non-finite float in a skeleton frame")
    return dict(version=version, subject=subject, hash=hash_, frame=frame, capture_ns=capture_ns,
                publish_ns=publish_ns, solve=solve, state=state, flags=flags, stream=stream, rms=rms, root=root,
                local=local, global_=global_)


def decode_description(p, version=VERSION):
    r = Reader(p)
    subject = r.string("bad_subject_name")
    marker_hash, skel_hash, rate, k, m, j, _res = r.take("QQfHHHH")
    if not math.isfinite(rate) or rate <= 0:
        raise DecodeError("non_finite", f"rate {rate}")
    if m > MAX_MARKERS or j > MAX_JOINTS:
        raise DecodeError("too_many_items", f"M = {m}, J = {j}")
    if r.remaining() < 2 * m + 32 * j:
        raise DecodeError("size_mismatch", f"{r.remaining()} bytes left for {m} markers and {j} joints")
    markers = [r.string("bad_field") for _ in range(m)]
    joints = []
    for index in range(j):
        name = r.string("bad_field")
        parent = r.take("h")
        offset = r.take("3f")
        rotation = r.take("4f")
        if not finite(*offset, *rotation):
            raise DecodeError("non_finite", f"joint {name}")
        if (index == 0) != (parent == -1) or (index > 0 and not 0 <= parent < index):
            raise DecodeError("bad_field", f"joint {index} ({name}) has parent {parent}")
        joints.append(dict(name=name, parent=parent, offset=offset, rotation=rotation))
    expect_size(p, description_size(len(subject.encode()), markers, [x["name"] for x in joints]), "subject description")
    return dict(version=version, subject=subject, marker_hash=marker_hash, skeleton_hash=skel_hash, rate=rate, k=k,
                markers=markers, joints=joints)


def decode_cleaned(p, version=VERSION):
    r = Reader(p)
    subject = r.string("bad_subject_name")
    hash_, frame, capture_ns, publish_ns, m, _res = r.take("QQQQHH")
    if m > MAX_MARKERS:
        raise DecodeError("too_many_items", f"M = {m}")
    expect_size(p, cleaned_size(len(subject.encode()), m, version), "cleaned markers")
    stream = take_stream(r, version)
    markers = []
    for _ in range(m):
        x, y, z, status, reason = r.take("3fBB")
        if not finite(x, y, z):
            raise DecodeError("non_finite", "cleaned marker coordinate")
        if status > 2 or reason > 10:
            raise DecodeError("bad_field", f"status {status}, reason {reason}")
        markers.append(((x, y, z), status, reason))
    return dict(version=version, subject=subject, hash=hash_, frame=frame, capture_ns=capture_ns,
                publish_ns=publish_ns, stream=stream, markers=markers)


def decode_status(p, version=VERSION):
    r = Reader(p)
    subject = r.string("bad_subject_name")
    expect_size(p, status_size(len(subject.encode())), "subject status")
    state, problems, _res, last, since_ns, f_in, f_out, dropped = r.take("BBHQQQQQ")
    if state > 4:
        raise DecodeError("bad_field", f"state {state}")
    return dict(version=version, subject=subject, state=state, problems=problems, last=last, since_ns=since_ns,
                frames_in=f_in, frames_out=f_out, dropped=dropped)


def decode_end_of_stream(p, version=VERSION):
    r = Reader(p)
    subject = r.string("bad_subject_name")
    expect_size(p, end_of_stream_size(len(subject.encode())), "end of stream")
    return dict(version=version, subject=subject, last=r.take("Q"))


DECODERS = {SUBJECT_DESCRIPTION: decode_description, MARKER_FRAME: decode_marker_frame,
            SKELETON_FRAME: decode_skeleton_frame, CLEANED_MARKERS: decode_cleaned, SUBJECT_STATUS: decode_status,
            END_OF_STREAM: decode_end_of_stream}


def decode(msg):
    msg_type, version, payload = decode_header(msg)
    return msg_type, DECODERS[msg_type](payload, version)


# --- skeleton pose (README "Skeleton pose") ----------------------------------------------

def q_normalise(q):
    n = math.sqrt(sum(c * c for c in q))
    return tuple(c / n for c in q)


def q_mul(a, b):  # Hamilton product, w x y z
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw)


def q_rotate(q, v):  # R(q) v, active
    w, x, y, z = q
    p = q_mul(q_mul(q, (0.0, *v)), (w, -x, -y, -z))
    return p[1:]


def q_axis_angle(axis, angle):
    n = math.sqrt(sum(c * c for c in axis))
    s = math.sin(angle / 2) / n
    return (math.cos(angle / 2), axis[0] * s, axis[1] * s, axis[2] * s)


def q_angle_between(a, b):
    """Rotation angle between two unit quaternions, allowing q and -q."""
    d = abs(sum(x * y for x, y in zip(q_normalise(a), q_normalise(b))))
    return 2.0 * math.acos(min(1.0, d))


def v_add(a, b):
    return tuple(x + y for x, y in zip(a, b))


def forward_kinematics(parents, offsets, root, local):
    """R_W0 = R(q_W0), p_W0 = root translation; R_WJ = R_WP R(q_PJ), p_WJ = p_WP + R_WP offset_J."""
    world = []
    for j, parent in enumerate(parents):
        q = q_normalise(local[j])
        if j == 0:
            world.append((q, tuple(root)))
        else:
            qp, pp = world[parent]
            world.append((q_normalise(q_mul(qp, q)), v_add(pp, q_rotate(qp, offsets[j]))))
    return world


# ---------------------------------------------------------------------------------------
# Test plumbing
# ---------------------------------------------------------------------------------------

class Failure(AssertionError):
    pass


KEEP_GOING = os.environ.get("INDEPENDENT_DECODER_KEEP_GOING") == "1"  # debugging: report every failed check
FAILURES = []


def check(cond, what):
    if not cond:
        if KEEP_GOING:
            FAILURES.append(what)
            print(f"FAILED CHECK: {what}", file=sys.stderr)
            return
        raise Failure(what)


def http_get(port, path):
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}{path}", timeout=5) as r:
            return r.status, r.read().decode()
    except urllib.error.HTTPError as e:
        return e.code, e.read().decode()


LINE = re.compile(r'^([A-Za-z_:][A-Za-z0-9_:]*)(?:\{(.*)\})?\s+(\S+)(?:\s+\S+)?$')
LABEL = re.compile(r'([A-Za-z_][A-Za-z0-9_]*)="((?:[^"\\]|\\.)*)"')


def metrics(port):
    """/metrics (Prometheus text format) as {name: {frozenset(labels): value}}."""
    status, text = http_get(port, "/metrics")
    check(status == 200, f"/metrics answered HTTP {status}")
    out = {}
    for line in text.splitlines():
        if not line or line.startswith("#"):
            continue
        m = LINE.match(line)
        check(m is not None, f"/metrics line not in the text format: {line!r}")
        labels = frozenset(LABEL.findall(m.group(2) or ""))
        out.setdefault(m.group(1), {})[labels] = float(m.group(3))
    return out


def metric_sum(m, name, **labels):
    """Sum of a metric's series whose labels include the given ones."""
    want = set(labels.items())
    return sum(v for ls, v in m.get(name, {}).items() if want <= set(ls))


class Collector(threading.Thread):
    """Receives everything the daemon publishes: (arrival time, topic, message)."""

    def __init__(self, ctx, endpoint):
        super().__init__(daemon=True)
        self.sock = ctx.socket(zmq.SUB)
        self.sock.setsockopt(zmq.RCVHWM, 100000)
        self.sock.setsockopt(zmq.SUBSCRIBE, b"")
        self.sock.connect(endpoint)
        self.items = []
        self.bad_parts = []
        self.stop_event = threading.Event()
        self.lock = threading.Lock()

    def run(self):
        poller = zmq.Poller()
        poller.register(self.sock, zmq.POLLIN)
        while not self.stop_event.is_set():
            if poller.poll(20):
                while True:
                    try:
                        parts = self.sock.recv_multipart(zmq.NOBLOCK)
                    except zmq.Again:
                        break
                    now = time.monotonic()
                    with self.lock:
                        if len(parts) != 2:
                            self.bad_parts.append(parts)
                        else:
                            self.items.append((now, parts[0].decode("utf-8", "replace"), parts[1]))
        self.sock.close(linger=0)

    def snapshot(self):
        with self.lock:
            return list(self.items)

    def stop(self):
        self.stop_event.set()
        self.join(timeout=5)


# ---------------------------------------------------------------------------------------
# The subject model and a synthetic performance (from config/demo_subject.toml)
# ---------------------------------------------------------------------------------------

class Model:
    def __init__(self, path):
        with open(path, "rb") as f:
            doc = tomllib.load(f)
        self.joint_names = [j["name"] for j in doc["joint"]]
        index = {name: i for i, name in enumerate(self.joint_names)}
        self.parents = [index[j["parent"]] if j.get("parent") else -1 for j in doc["joint"]]
        self.offsets = [tuple(j["offset"]) for j in doc["joint"]]
        self.marker_names = [m["name"] for m in doc["marker"]]
        self.markers = [(index[m["joint"]], tuple(m["offset"]), m.get("parent_weight", 0.0),
                         tuple(m.get("parent_offset", (0.0, 0.0, 0.0)))) for m in doc["marker"]]
        self.marker_hash = model_hash(self.marker_names)
        self.skeleton_hash = model_hash(skeleton_hash_strings(self.joint_names, self.parents))

    def pose(self, t):
        """A plausible performance at time t (s): walking forward, turning, legs and arms
        swinging; amplitudes ramp in over the first half second. Returns (root, locals)."""
        ramp = min(1.0, t / 0.5)
        a = ramp * math.sin(2 * math.pi * 0.9 * t)
        rot = {
            "Hips": q_axis_angle((0, 1, 0), ramp * 0.3 * math.sin(0.8 * t)),
            "Spine": q_axis_angle((0, 1, 0), 0.1 * a),
            "Chest": q_axis_angle((1, 0, 0), ramp * 0.05),
            "Neck": q_axis_angle((0, 1, 0), 0.1 * a),
            "LeftArm": q_mul(q_axis_angle((0, 0, 1), -0.9 * ramp), q_axis_angle((0, 1, 0), 0.3 * a)),
            "RightArm": q_mul(q_axis_angle((0, 0, 1), 0.9 * ramp), q_axis_angle((0, 1, 0), 0.3 * a)),
            "LeftForeArm": q_axis_angle((0, 1, 0), 0.5 * ramp + 0.2 * a),
            "RightForeArm": q_axis_angle((0, 1, 0), -0.5 * ramp + 0.2 * a),
            "LeftUpLeg": q_axis_angle((1, 0, 0), -0.4 * a),
            "RightUpLeg": q_axis_angle((1, 0, 0), 0.4 * a),
            "LeftLeg": q_axis_angle((1, 0, 0), 0.3 * ramp * (1 + math.sin(2 * math.pi * 0.9 * t + 1.0))),
            "RightLeg": q_axis_angle((1, 0, 0), 0.3 * ramp * (1 - math.sin(2 * math.pi * 0.9 * t + 1.0))),
        }
        local = [rot.get(name, (1.0, 0.0, 0.0, 0.0)) for name in self.joint_names]
        root = (0.2 * math.sin(0.5 * t), self.offsets[0][1] + 0.02 * a, 0.8 * t - 1.0)
        return root, local

    def markers_at(self, t):
        root, local = self.pose(t)
        world = forward_kinematics(self.parents, self.offsets, root, local)
        out = []
        for joint, offset, w, parent_offset in self.markers:
            q, p = world[joint]
            pos = v_add(p, q_rotate(q, offset))
            if w:
                qp, pp = world[self.parents[joint]]
                pos_p = v_add(pp, q_rotate(qp, parent_offset))
                pos = tuple((1 - w) * a + w * b for a, b in zip(pos, pos_p))
            out.append(pos)
        return root, out


# ---------------------------------------------------------------------------------------
# The test
# ---------------------------------------------------------------------------------------

SUBJECT = "actor1"
RATE = 120.0
K = 12
PERIOD_NS = 8_333_333
WATCHDOG_S = 2.0  # long enough that a flush seen before it comes from the end of stream


def check_readme_examples():
    check(model_hash(["A", "B"]) == 0x90D750ADBE8E9CD0, f"model_hash(['A','B']) = 0x{model_hash(['A', 'B']):016X}")
    check(struct.pack("<Q", model_hash(["A", "B"])) == bytes.fromhex("d09c8ebead50d790"), "wire bytes of ['A','B']")
    check(model_hash(["LASI", "RASI", "LKNE"]) == 0xA8202BCD5876CA3D, "model_hash(['LASI','RASI','LKNE'])")
    check(model_hash(["Hips/-1", "Spine/0"]) == 0x9494F44D33069014, "model_hash(['Hips/-1','Spine/0'])")
    check(model_hash([]) == 0x14650FB0739D0383, "model_hash([])")


def expect_status(msg, status, what):
    try:
        decode(msg)
    except DecodeError as e:
        check(e.status == status, f"{what}: {e.status}, expected {status}")
        return
    raise Failure(f"{what} decoded, expected {status}")


# Stream blocks that break one decoder rule each (README, "Versions and the stream block":
# all bad_field), for a marker frame at 120 Hz (f32 120.0). A daemon drops them as malformed.
GOOD_TC = timecode(7, 120, 1, 36_000 * 30 + 5, 2)  # 10:00:00:05.2 at 30 fps
BAD_STREAMS = [
    ("timecode hours 24", GOOD_TC.replace(hours=24)),
    ("timecode minutes 60", GOOD_TC.replace(minutes=60)),
    ("timecode seconds 60", GOOD_TC.replace(seconds=60)),
    ("timecode frames 30 at 30 fps", GOOD_TC.replace(frames=30)),
    ("timecode rate 0 with a timecode", GOOD_TC.replace(tc_rate=0, frames=0)),
    ("timecode flags bit 2", GOOD_TC.replace(tc_flags=0b101)),
    ("timecode flags bit 7", GOOD_TC.replace(tc_flags=0x81)),
    ("timecode flags bit 2 without a timecode", NO_STREAM.replace(tc_flags=0b100)),
    ("drop-frame without a timecode (flags 2)", GOOD_TC.replace(tc_flags=0b10)),
    ("drop-frame at 25 fps", GOOD_TC.replace(tc_flags=0b11, tc_rate=25)),
    ("drop-frame at 24 fps", GOOD_TC.replace(tc_flags=0b11, tc_rate=24)),
    ("rate fraction 119/1 with an f32 rate of 120", GOOD_TC.replace(num=119, den=1)),
    ("rate fraction 120.013 Hz (0.0108 % off 120)", GOOD_TC.replace(num=120013, den=1000)),
    ("rate numerator without a denominator (120/0)", GOOD_TC.replace(num=120, den=0)),
    ("rate denominator without a numerator (0/1)", GOOD_TC.replace(num=0, den=1)),
]
# ... and stream blocks that are valid (and must be carried through unchanged).
GOOD_STREAMS = [
    ("no rate, no timecode", NO_STREAM),
    ("a u64 session id above 2^63", GOOD_TC.replace(session=0xFEDC_BA98_7654_3210)),
    ("rate fraction 120000/1000", GOOD_TC.replace(num=120000, den=1000)),
    ("rate fraction 120.011 Hz (0.0092 % off 120)", GOOD_TC.replace(num=120011, den=1000)),
    ("timecode 23:59:59:29", GOOD_TC.replace(hours=23, minutes=59, seconds=59, frames=29)),
    ("drop-frame at 30 fps", GOOD_TC.replace(tc_flags=0b11)),
    ("drop-frame at 60 fps, frame 59", GOOD_TC.replace(tc_flags=0b11, tc_rate=60, frames=59)),
    ("timecode bytes set without a timecode (not checked)",
     Stream(7, 120, 1, 99, 99, 99, 99, 99, 0, 0)),
]


def check_codec_round_trips(model):
    """Our encoders against our decoders, sizes against the formulas, the stream block's rules."""
    n = len(SUBJECT)
    stream = timecode(0xFEDC_BA98_7654_3210, 120, 1, 12345, 3)
    for version, st in ((1, None), (2, stream), (2, None)):
        msg = encode_marker_frame(SUBJECT, 7, 8, 9, RATE, [(1.0, 2.0, 3.0), None], version=version, stream=st)
        check(len(msg) == 16 + marker_frame_size(n, 2, version), "marker frame size")
        check(len(msg) - 16 == (33 if version == 1 else 57) + n + 13 * 2, "marker frame size: 33/57 + n + 13 M")
        t, d = decode(msg)
        check(t == MARKER_FRAME and d["markers"] == [(1.0, 2.0, 3.0), None] and d["frame"] == 8,
              "marker frame round trip")
        check(d["version"] == version and d["stream"] == (None if version == 1 else st or NO_STREAM),
              f"marker frame v{version} stream round trip: {d['stream']}")
    joints = [(name, parent, off, (1.0, 0.0, 0.0, 0.0))
              for name, parent, off in zip(model.joint_names, model.parents, model.offsets)]
    for version in VERSIONS:
        msg = message(SUBJECT_DESCRIPTION, encode_description(SUBJECT, 1, 2, RATE, K, model.marker_names, joints)[16:],
                      version=version)
        check(len(msg) == 16 + description_size(n, model.marker_names, model.joint_names), "description size")
        check(decode(msg)[1]["markers"] == model.marker_names, "description round trip")
    local = [(1.0, 0.0, 0.0, 0.0)] * 3
    for version, st in ((1, None), (2, stream)):
        for g in (None, [((1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0))] * 3):
            msg = encode_skeleton_frame(SUBJECT, 1, 2, 3, 4, 0, 0, 0.5, (0.0, 1.0, 0.0), local, g, version=version,
                                        stream=st)
            check(len(msg) == 16 + skeleton_frame_size(n, 3, g is not None, version), "skeleton frame size")
            d = decode(msg)[1]
            check(d["root"] == (0.0, 1.0, 0.0) and d["rms"] == 0.5 and d["stream"] == st, "skeleton frame round trip")
        msg = encode_cleaned(SUBJECT, 1, 2, 3, 4, [((1.0, 2.0, 3.0), 1, 4)], version=version, stream=st)
        d = decode(msg)[1]
        check(len(msg) == 16 + cleaned_size(n, 1, version) and d["markers"][0][2] == 4 and d["stream"] == st,
              "cleaned round trip")
    msg = encode_status(SUBJECT, 4, 3, 5, 6, 7, 8, 9)
    check(len(msg) == 16 + status_size(n) and decode(msg)[1]["dropped"] == 9, "status round trip")
    for version in VERSIONS:
        msg = encode_end_of_stream(SUBJECT, 77, version=version)
        check(len(msg) == 16 + end_of_stream_size(n) and decode(msg)[1]["last"] == 77, "end of stream round trip")
        for cut in range(len(msg)):
            expect_status(msg[:cut], "too_short", f"a {cut}-byte cut of an end of stream")
    # Every cut of a version 2 marker frame is too short; the header's version decides B.
    msg = encode_marker_frame(SUBJECT, 7, 8, 9, RATE, [(1.0, 2.0, 3.0)], stream=stream)
    for cut in range(len(msg)):
        expect_status(msg[:cut], "too_short", f"a {cut}-byte cut of a v2 marker frame")
    v1 = encode_marker_frame(SUBJECT, 7, 8, 9, RATE, [(1.0, 2.0, 3.0)], version=1)
    expect_status(v1[:4] + struct.pack("<H", 2) + v1[6:], "too_short", "a v1 payload under a v2 header")
    expect_status(msg[:4] + struct.pack("<H", 1) + msg[6:], "size_mismatch", "a v2 payload under a v1 header")
    for version in (0, 3, 0xFFFF):
        expect_status(msg[:4] + struct.pack("<H", version) + msg[6:], "unsupported_version", f"version {version}")
    for what, st in BAD_STREAMS:
        expect_status(encode_marker_frame(SUBJECT, 7, 8, 9, RATE, [(1.0, 2.0, 3.0)], stream=st), "bad_field", what)
    for what, st in GOOD_STREAMS:
        check(decode(encode_marker_frame(SUBJECT, 7, 8, 9, RATE, [(1.0, 2.0, 3.0)], stream=st))[1]["stream"] == st,
              f"valid stream block ({what}) does not round trip")
    # The rate fraction is checked against the rate only in marker frames; the other block
    # rules hold in skeleton frames and cleaned markers too.
    st = GOOD_TC.replace(num=119, den=1)
    check(decode(encode_cleaned(SUBJECT, 1, 2, 3, 4, [], stream=st))[1]["stream"] == st, "cleaned: 119/1 is valid")
    for what, st in BAD_STREAMS:
        if "rate fraction 1" not in what:
            expect_status(encode_cleaned(SUBJECT, 1, 2, 3, 4, [], stream=st), "bad_field", f"cleaned markers, {what}")
            expect_status(encode_skeleton_frame(SUBJECT, 1, 2, 3, 4, 0, 0, 0.0, (0.0, 0.0, 0.0), local, stream=st),
                          "bad_field", f"skeleton frame, {what}")


def write_config(work, config_dir, input_port, output_port, http_port, protocol_version=None, global_transforms=True):
    """protocol_version None: leave [output] protocol_version out (the default, 2)."""
    path = os.path.join(work, "mocapd.toml")
    model = os.path.abspath(os.path.join(config_dir, "demo_subject.toml"))
    version_line = "" if protocol_version is None else f"protocol_version = {protocol_version}\n"
    with open(path, "w") as f:
        f.write(f"""format_version = 1
[input]
endpoint = "tcp://127.0.0.1:{input_port}"
pattern = "pull"
[output]
endpoint = "tcp://127.0.0.1:{output_port}"
global_transforms = {"true" if global_transforms else "false"}
send_high_water_mark = 100000
{version_line}[control]
http_port = {http_port}
stats_interval_s = 0.2
watchdog_timeout_s = {WATCHDOG_S}
[pipeline]
lookahead = {K}
[[subject]]
name = "{SUBJECT}"
model = "{model}"
rate_hz = {RATE}
""")
    return path


class Sender:
    def __init__(self, ctx, endpoint):
        self.sock = ctx.socket(zmq.PUSH)
        self.sock.setsockopt(zmq.SNDHWM, 100000)
        self.sock.connect(endpoint)
        self.count = 0  # ZeroMQ messages sent (what mocapd_messages_received_total should count)

    def send(self, msg, topic=f"markers/{SUBJECT}/", parts=2):
        if parts == 1:
            self.sock.send(msg)
        elif parts == 2:
            self.sock.send_multipart([topic.encode(), msg])
        else:
            self.sock.send_multipart([topic.encode(), b"extra", msg])
        self.count += 1


def start_daemon(mocapd, config, log, http_port):
    daemon = subprocess.Popen([mocapd, "run", "--config", config], stdout=log, stderr=subprocess.STDOUT)
    for _ in range(200):
        check(daemon.poll() is None, "the daemon exited at start-up")
        try:
            if http_get(http_port, "/health")[0] == 200:
                return daemon
        except OSError:
            time.sleep(0.05)
    daemon.kill()
    raise Failure("the daemon's /health never answered")


def wait_for_description(collector):
    """The subject description arrives on every stats tick: wait for it (this also means
    our subscription is live)."""
    deadline = time.monotonic() + 5
    while time.monotonic() < deadline:
        for _, topic, msg in collector.snapshot():
            if topic == f"subject/{SUBJECT}/":
                return decode(msg)[1]
        time.sleep(0.05)
    raise Failure("no subject description within 5 s")


def subject_entry(http_port):
    code, body = http_get(http_port, "/subjects")
    check(code == 200, f"GET /subjects: HTTP {code}")
    entry = next((e for e in json.loads(body) if e.get("name") == SUBJECT), None)
    check(entry is not None, f"GET /subjects has no {SUBJECT}: {body[:300]}")
    return entry


def check_stream_fields(entry, want, where):
    """/subjects' stream fields (README, "Frame numbering": skipped frames, session, timecode)."""
    for key in ("frames_skipped", "capture_session_id", "last_timecode", "capture_session_changes"):
        check(key in entry, f"GET /subjects lacks '{key}' ({where})")
    for key, value in want.items():
        check(entry.get(key) == value, f"/subjects {key} {entry.get(key)!r}, expected {value!r} ({where})")


def run_v1_output_daemon(mocapd, config_dir, work, ctx, model):
    """A second daemon with [output] protocol_version = 1, fed version 2 frames (with a
    session, a rate fraction and a drop-frame timecode): everything it publishes is version
    1, with the version 1 sizes (no stream block); /subjects still shows the input's stream."""
    work = os.path.join(work, "v1_output")
    os.makedirs(work, exist_ok=True)
    input_port, output_port, http_port = free_ports(3)
    config = write_config(work, config_dir, input_port, output_port, http_port, protocol_version=1,
                          global_transforms=False)
    log = open(os.path.join(work, "mocapd.log"), "w+")
    daemon = collector = sender = None
    n, M, J = len(SUBJECT.encode()), len(model.marker_names), len(model.joint_names)
    try:
        daemon = start_daemon(mocapd, config, log, http_port)
        collector = Collector(ctx, f"tcp://127.0.0.1:{output_port}")
        collector.start()
        sender = Sender(ctx, f"tcp://127.0.0.1:{input_port}")
        wait_for_description(collector)
        session = 0xABCDEF
        numbers = list(range(500, 524))
        sent = {}
        t_start = time.monotonic()
        for i, number in enumerate(numbers):
            # 29.97 drop-frame timecode from 01:02:03;04, subframes 0..3.
            st = Stream(session, 120, 1, 1, 2, 3, 4 + i // 4, i % 4, 0b11, 30)
            t_ns = 9_000_000_000 + i * PERIOD_NS
            sent[number] = t_ns
            markers = model.markers_at(i / RATE)[1]
            sender.send(encode_marker_frame(SUBJECT, model.marker_hash, number, t_ns, RATE, markers, stream=st))
            delay = t_start + (i + 1) / RATE - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        time.sleep(0.15)
        check_stream_fields(subject_entry(http_port), {"capture_session_id": session, "last_timecode": "01:02:03;09.3",
                                                       "frames_skipped": 0, "capture_session_changes": 0},
                            "protocol_version = 1 daemon, before its end of stream")
        sender.send(encode_end_of_stream(SUBJECT, numbers[-1], version=1))
        t_eos = time.monotonic()
        while time.monotonic() < t_eos + 1.0:
            if any(tp == f"status/{SUBJECT}/" and t > t_eos + 0.05 for t, tp, _ in collector.snapshot()):
                break
            time.sleep(0.02)
        time.sleep(0.05)
        items = collector.snapshot()
        counts = {}
        frames = []
        for _, topic, msg in items:
            msg_type, version, payload = decode_header(msg)
            check(version == 1, f"protocol_version = 1 daemon: version {version} {TYPE_NAMES[msg_type]} on {topic}")
            d = decode(msg)[1]
            counts[msg_type] = counts.get(msg_type, 0) + 1
            want = {SKELETON_FRAME: lambda: skeleton_frame_size(n, J, False, version=1),
                    CLEANED_MARKERS: lambda: cleaned_size(n, M, version=1),
                    SUBJECT_STATUS: lambda: status_size(n),
                    SUBJECT_DESCRIPTION: lambda: description_size(n, model.marker_names, model.joint_names)}[msg_type]()
            check(len(payload) == want, f"protocol_version = 1 daemon: {TYPE_NAMES[msg_type]} payload {len(payload)} "
                                        f"bytes, the version 1 formula gives {want}")
            if msg_type in (SKELETON_FRAME, CLEANED_MARKERS):
                check(d["stream"] is None, "a version 1 message with a stream block")
                check(d["capture_ns"] == sent.get(d["frame"]), f"v1 output: frame {d['frame']} capture timestamp")
                if msg_type == SKELETON_FRAME:
                    check(d["flags"] == 0 and d["global_"] is None, "global block with global_transforms = false")
                    frames.append(d["frame"])
        check(frames == numbers, f"protocol_version = 1 daemon published frames {frames}, expected {numbers}")
        check(all(counts.get(t) for t in (1, 3, 4, 5)), f"protocol_version = 1 daemon: message counts {counts}")
        daemon.send_signal(signal.SIGTERM)
        code = daemon.wait(timeout=10)
        check(code == 0, f"the protocol_version = 1 daemon exited with {code} after SIGTERM")
        return (f"[output] protocol_version = 1 daemon, fed version 2 frames: {len(items)} messages all version 1 with "
                f"the version 1 sizes (B = 0; " + ", ".join(f"{counts[t]} {TYPE_NAMES[t]}" for t in (1, 3, 4, 5))
                + "); /subjects showed the session and the drop-frame timecode 01:02:03;09.3")
    except BaseException:
        print_log_tail(log, "mocapd (protocol_version = 1)", 3000)
        raise
    finally:
        stop_all(collector, sender, daemon, log)


def run(mocapd, config_dir, work):
    summary = []
    check_readme_examples()
    summary.append("README hash examples reproduce")
    model = Model(os.path.join(config_dir, "demo_subject.toml"))
    check_codec_round_trips(model)
    summary.append(f"own codec: v1/v2 round trips and sizes, every cut too_short, versions 0/3/65535 unsupported, "
                   f"{len(BAD_STREAMS)} bad stream blocks bad_field, {len(GOOD_STREAMS)} edge-case blocks valid")
    M, J = len(model.marker_names), len(model.joint_names)
    n = len(SUBJECT.encode())

    os.makedirs(work, exist_ok=True)
    input_port, output_port, http_port = free_ports(3)
    # [output] protocol_version is left out: the default (2) is what is checked.
    config = write_config(work, config_dir, input_port, output_port, http_port)
    log_path = os.path.join(work, "mocapd.log")
    log = open(log_path, "w+")
    daemon = None
    ctx = zmq.Context()
    collector = None
    sender = None
    try:
        daemon = start_daemon(mocapd, config, log, http_port)
        collector = Collector(ctx, f"tcp://127.0.0.1:{output_port}")
        collector.start()
        sender = Sender(ctx, f"tcp://127.0.0.1:{input_port}")
        description = wait_for_description(collector)

        # --- a. hashes ---------------------------------------------------------------
        check(description["marker_hash"] == model.marker_hash,
              f"marker-set hash: description {description['marker_hash']}, computed {model.marker_hash}")
        check(description["skeleton_hash"] == model.skeleton_hash,
              f"skeleton hash: description {description['skeleton_hash']}, computed {model.skeleton_hash}")
        code, body = http_get(http_port, "/subjects")
        check(code == 200, f"GET /subjects: HTTP {code}")
        subjects = json.loads(body)
        check(isinstance(subjects, list), f"GET /subjects is not a JSON list: {body[:300]}")
        entry = next((e for e in subjects if e.get("name") == SUBJECT), None)
        check(entry is not None, f"GET /subjects has no {SUBJECT}: {body[:300]}")
        check(entry.get("marker_set_hash") == model.marker_hash,
              f"/subjects marker_set_hash {entry.get('marker_set_hash')} != {model.marker_hash}")
        check(entry.get("skeleton_hash") == model.skeleton_hash,
              f"/subjects skeleton_hash {entry.get('skeleton_hash')} != {model.skeleton_hash}")
        check_stream_fields(entry, {"frames_skipped": 0, "capture_session_changes": 0}, "before any frame")
        summary.append(f"hashes: marker set {model.marker_hash:#018x}, skeleton {model.skeleton_hash:#018x} "
                       "(description and /subjects agree)")

        # The description's content against the model file.
        check(description["subject"] == SUBJECT and description["markers"] == model.marker_names,
              "description marker names differ from the model's [[marker]] order")
        check([j["name"] for j in description["joints"]] == model.joint_names, "description joint names")
        check([j["parent"] for j in description["joints"]] == model.parents, "description parents")
        for j, joint in enumerate(description["joints"]):
            check(all(abs(a - b) < 1e-6 for a, b in zip(joint["offset"], model.offsets[j])),
                  f"rest offset of {joint['name']}: {joint['offset']} vs model {model.offsets[j]}")
            check(q_angle_between(joint["rotation"], (1.0, 0.0, 0.0, 0.0)) < 1e-6,
                  f"rest rotation of {joint['name']} is {joint['rotation']} (the model has none: identity)")
        check(description["rate"] == RATE and description["k"] == K,
              f"description rate {description['rate']} / K {description['k']}")

        # --- b. the feed -------------------------------------------------------------
        sent = {}         # frame number -> (capture ns, markers sent, send time)
        sent_stream = {}  # frame number -> the stream block sent (NO_STREAM for a version 1 frame)
        truth_root = {}   # frame number -> the performance's root position
        invalid = {}      # frame number -> marker indices we sent invalid or out of volume
        eos_times = []
        F0, N1 = 1_000_000, 300
        T0 = 5_000_000_000_000
        # Phase 1 is version 2: session S1, then S2 from frame F0 + SESSION_CHANGE on with
        # the frame numbers continuing (a capture restart); 120/1 Hz; 30 fps non-drop
        # timecode from 09:59:58:20 (it crosses the hour), subframes 0..3.
        S1, S2 = 0xF00D_CAFE_0000_0001, 0xF00D_CAFE_0000_0002  # above 2^63: all 64 bits count
        FOREIGN = 0x0BAD_5E55_1011  # the session of frames dropped before the session step
        SESSION_CHANGE = 240
        GAP1 = {F0 + 200, F0 + 201}  # never sent: inserted, counted as skipped
        TC0 = (9 * 3600 + 59 * 60 + 58) * 30 + 20
        # |rate - 120| <= 0.12 on the wire's f32: the f32 values just inside are accepted,
        # the one nearest 120.12 (120.12000275, just outside) is not.
        inside_rates = {F0 + 55: 120.1199951171875, F0 + 56: 119.8800048828125}
        outside_rate = 120.12000274658203
        check(f32_round(outside_rate) == outside_rate and all(f32_round(r) == r for r in inside_rates.values()),
              "rate boundary values are f32")
        # The valid edge cases of the stream block ride on frames F0 + 57 ...; F0 + 55's rate
        # fraction must agree with its f32 rate within 0.01 %, F0 + 56 gives none.
        special_streams = {F0 + 55: lambda st: st.replace(num=120120, den=1000),
                           F0 + 56: lambda st: st.replace(num=0, den=0)}
        for k, (_, good_st) in enumerate(GOOD_STREAMS):
            special_streams[F0 + 57 + k] = lambda st, g=good_st: g.replace(session=st.session)
        check(F0 + 57 + len(GOOD_STREAMS) <= F0 + 95, "the stream edge cases reach the duplicate/late negatives")

        def stream_of(i):
            st = timecode(S1 if i < SESSION_CHANGE else S2, 120, 1, TC0 + i // 4, i % 4)
            return special_streams.get(F0 + i, lambda x: x)(st)

        def frame_markers(i):
            root, markers = model.markers_at(i / RATE)
            return root, list(markers)

        def send_good(number, i, t_ns, parts=2, markers=None, rate=RATE, junk=False, topic=f"markers/{SUBJECT}/",
                      version=VERSION, stream=None):
            root, ms = frame_markers(i)
            if markers is not None:
                ms = markers
            msg = encode_marker_frame(SUBJECT, model.marker_hash, number, t_ns, rate, ms, junk=junk, version=version,
                                      stream=stream)
            sent[number] = (t_ns, ms, time.monotonic())  # stamped before the send: the daemon cannot beat it
            sent_stream[number] = NO_STREAM if version == 1 else stream
            sender.send(msg, parts=parts, topic=topic)
            truth_root[number] = root

        expected_drops = {"model_mismatch": 0, "rate_mismatch": 0, "malformed": 0, "non_finite": 0,
                          "unknown_subject": 0, "not_marker_frame": 0, "oversized": 0, "duplicate": 0,
                          "out_of_order": 0}
        attributed = {"model_mismatch", "rate_mismatch", "non_finite", "duplicate", "out_of_order"}

        def negatives(i):
            """Bad messages between good frames; `i` is the last good frame sent (newest)."""
            nxt = F0 + i + 1
            t_ns = T0 + (i + 1) * PERIOD_NS
            _, ms = frame_markers(i + 1)
            st = stream_of(i + 1)
            foreign = st.replace(session=FOREIGN)  # dropped before the session step: no restart
            good = encode_marker_frame(SUBJECT, model.marker_hash, nxt, t_ns, RATE, ms, stream=st)
            if i == 40:  # wrong hash
                sender.send(encode_marker_frame(SUBJECT, model.marker_hash ^ 1, nxt, t_ns, RATE, ms, stream=foreign))
                expected_drops["model_mismatch"] += 1
            elif i == 45:  # right hash, one marker short
                sender.send(encode_marker_frame(SUBJECT, model.marker_hash, nxt, t_ns, RATE, ms[:-1], stream=foreign))
                expected_drops["model_mismatch"] += 1
            elif i == 50:  # rate just over 0.1 % off (its fraction agrees with it: not malformed)
                sender.send(encode_marker_frame(SUBJECT, model.marker_hash, nxt, t_ns, outside_rate, ms,
                                                stream=foreign.replace(num=120120, den=1000)))
                expected_drops["rate_mismatch"] += 1
            elif i == 60:  # truncated: the header's P is no longer met
                sender.send(good[:-5])
                expected_drops["malformed"] += 1
            elif i == 65:  # the old, wrong size formula 35 + n + B + 13 M: two bytes too many
                payload = good[16:] + b"\x00\x00"
                check(len(payload) == 35 + n + 24 + 13 * M, "old-formula payload size")
                sender.send(message(MARKER_FRAME, payload))
                expected_drops["malformed"] += 1
            elif i == 70:  # a valid marker with NaN
                bad = list(ms)
                bad[3] = (float("nan"), 0.0, 0.0)
                sender.send(encode_marker_frame(SUBJECT, model.marker_hash, nxt, t_ns, RATE, bad, stream=foreign))
                expected_drops["non_finite"] += 1
            elif i == 75:  # a subject this daemon does not have
                sender.send(encode_marker_frame("nobody", model.marker_hash, nxt, t_ns, RATE, ms, stream=foreign),
                            topic="markers/nobody/")
                expected_drops["unknown_subject"] += 1
            elif i == 80:  # not a marker frame (type 5)
                sender.send(encode_status(SUBJECT, 0, 0, 1, 2, 3, 4, 5))
                expected_drops["not_marker_frame"] += 1
            elif i == 85:  # three message parts
                sender.send(good, parts=3)
                expected_drops["malformed"] += 1
            elif i == 90:  # over max_message_bytes (65536)
                sender.send(good + bytes(70000))
                expected_drops["oversized"] += 1
            elif i == 95:  # the newest frame again (same session)
                t_dup, ms_dup, _ = sent[F0 + i]
                sender.send(encode_marker_frame(SUBJECT, model.marker_hash, F0 + i, t_dup, RATE, ms_dup,
                                                stream=sent_stream[F0 + i]))
                expected_drops["duplicate"] += 1
            elif i == 100:  # three behind, with its own (earlier) capture timestamp
                t_old, ms_old, _ = sent[F0 + i - 3]
                sender.send(encode_marker_frame(SUBJECT, model.marker_hash, F0 + i - 3, t_old, RATE, ms_old,
                                                stream=sent_stream[F0 + i - 3]))
                expected_drops["out_of_order"] += 1
            elif i == 105:  # bad magic
                sender.send(struct.pack("<I", 0x12345678) + good[4:])
                expected_drops["malformed"] += 1
            elif i == 110:  # end of stream for a subject this daemon does not have
                sender.send(encode_end_of_stream("nobody", 5), topic="markers/nobody/")
                expected_drops["unknown_subject"] += 1
            elif i == 115:  # an end of stream one byte too long
                sender.send(message(END_OF_STREAM, enc_string(SUBJECT) + struct.pack("<Q", F0 + i) + b"\x00"))
                expected_drops["malformed"] += 1
            elif i == 120:  # version 3
                sender.send(good[:4] + struct.pack("<H", 3) + good[6:])
                expected_drops["malformed"] += 1
            elif i == 122:  # the header's version disagrees with the payload's layout, both ways
                v1 = encode_marker_frame(SUBJECT, model.marker_hash, nxt, t_ns, RATE, ms, version=1)
                sender.send(v1[:4] + struct.pack("<H", 2) + v1[6:])
                sender.send(good[:4] + struct.pack("<H", 1) + good[6:])
                expected_drops["malformed"] += 2
            elif i == 125:  # every stream-block rule broken once (bad_field: malformed)
                for _, bad_st in BAD_STREAMS:
                    sender.send(encode_marker_frame(SUBJECT, model.marker_hash, nxt, t_ns, RATE, ms,
                                                    stream=bad_st.replace(session=st.session)))
                    expected_drops["malformed"] += 1
            elif i == 130:  # late within the session: far back (b = 125 >= 120) with a LATER
                # capture timestamp. In version 1 that is a restart; with a session id it is late.
                old = F0 + 5
                sender.send(encode_marker_frame(SUBJECT, model.marker_hash, old, t_ns + PERIOD_NS, RATE, sent[old][1],
                                                stream=sent_stream[old]))
                check(i - 5 >= 120 and t_ns + PERIOD_NS > sent[F0 + i][0], "the late frame's setup")
                expected_drops["out_of_order"] += 1

        # Phase 1: N1 frames in real time, version 2.
        t_start = time.monotonic()
        for i in range(N1):
            number = F0 + i
            if number not in GAP1:
                _, ms = frame_markers(i)
                if 150 <= i < 154:  # one marker missing for 4 frames
                    ms[20] = None
                    invalid.setdefault(number, []).append(20)
                if i == 170:  # a valid sample far outside the capture volume
                    ms[30] = (1000.0, ms[30][1], ms[30][2])
                    invalid.setdefault(number, []).append(30)
                rate = inside_rates.get(number, RATE)  # within ±0.1 %
                # Variations that must not matter: one-part messages (PULL), reserved fields and
                # flag bits set, a topic naming another subject (routing is by the payload).
                send_good(number, i, T0 + i * PERIOD_NS, parts=1 if i % 10 == 3 else 2, markers=ms, rate=rate,
                          junk=i % 10 == 5, topic="markers/someone_else/" if i % 10 == 7 else f"markers/{SUBJECT}/",
                          stream=stream_of(i))
                negatives(i)
            delay = t_start + (i + 1) / RATE - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        phase1 = list(range(F0, F0 + N1))

        # Before the end of stream: the session, last timecode and skipped frames so far.
        time.sleep(0.1)
        want1 = {"capture_session_id": S2, "last_timecode": timecode_text(stream_of(N1 - 1)),
                 "frames_skipped": len(GAP1), "capture_session_changes": 1}
        check_stream_fields(subject_entry(http_port), want1, "end of the version 2 stream")
        m = metrics(http_port)
        for name in ("mocapd_frames_skipped_total", "mocapd_capture_sessions_changed_total",
                     "mocapd_capture_restarts_total"):
            check(name in m, f"/metrics lacks {name}")
        check(metric_sum(m, "mocapd_frames_skipped_total", subject=SUBJECT) == len(GAP1),
              f"frames_skipped {metric_sum(m, 'mocapd_frames_skipped_total', subject=SUBJECT)} after a "
              f"{len(GAP1)}-frame gap")
        check(metric_sum(m, "mocapd_capture_sessions_changed_total", subject=SUBJECT) == 1,
              f"capture_sessions_changed {metric_sum(m, 'mocapd_capture_sessions_changed_total', subject=SUBJECT)} "
              "after one session change (frames of other sessions dropped before the session step do not count)")
        check(metric_sum(m, "mocapd_capture_restarts_total", subject=SUBJECT) == 1,
              f"capture_restarts {metric_sum(m, 'mocapd_capture_restarts_total', subject=SUBJECT)} after one session "
              "change (a late frame within a session is no restart)")
        summary.append(f"version 2 stream: session change at frame {F0 + SESSION_CHANGE} (numbers continuing) = 1 "
                       f"restart + 1 session change; late frame 125 back with a later timestamp = out_of_order; "
                       f"{len(GAP1)}-frame gap = {len(GAP1)} skipped; /subjects: {want1}")

        eos_times.append(time.monotonic())
        sender.send(encode_end_of_stream(SUBJECT, F0 + N1 - 1))

        # The flush must come from the end of stream, well before the watchdog would fire.
        deadline = eos_times[0] + WATCHDOG_S * 0.75
        while time.monotonic() < deadline:
            if any(decode(m)[1]["frame"] == phase1[-1] for _, tp, m in collector.snapshot()
                   if tp == f"skeleton/{SUBJECT}/"):
                break
            time.sleep(0.01)
        else:
            raise Failure(f"the last frame was not published within {WATCHDOG_S * 0.75:.1f} s of the end of stream")

        # Meanwhile, a second daemon publishing version 1.
        summary.append(run_v1_output_daemon(mocapd, config_dir, work, ctx, model))

        # After the end of stream, past the watchdog timeout: "ok", not degraded.
        delay = eos_times[0] + WATCHDOG_S + 0.3 - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        code, body = http_get(http_port, "/health")
        health1 = json.loads(body)
        check(code == 200 and health1.get("status") == "ok",
              f"/health {WATCHDOG_S + 0.3:.1f} s after the end of stream: HTTP {code} {body}")
        check(health1.get("accounted") is True, f"/health accounted after the end of stream: {body}")
        summary.append(f"/health after end of stream (+{WATCHDOG_S + 0.3:.1f} s): ok, accounted")

        # Phase 2: a fresh stream in version 1 (any number accepted) with one missing frame
        # number, then a jump of more than max_gap_frames (240 at 120 Hz: max_gap_ms 2000).
        # The capture clock goes on with the numbers (frames lost, not renumbered: README,
        # "Frame numbering", a jump the clock does not share is no loss).
        T1 = 77_000_000_000
        JUMP_FROM, JUMP_TO = 49, 350
        phase2 = list(range(10, JUMP_FROM + 1)) + list(range(JUMP_TO, JUMP_TO + 20))
        inserted_v1 = {30}
        t_start = time.monotonic()
        for i, number in enumerate(phase2):
            if number not in inserted_v1:
                send_good(number, N1 + i, T1 + (number - phase2[0]) * PERIOD_NS, version=1)
            delay = t_start + (i + 1) / RATE - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        skipped = len(GAP1) + len(inserted_v1) + (JUMP_TO - JUMP_FROM - 1)
        time.sleep(0.1)
        entry2 = subject_entry(http_port)
        check_stream_fields(entry2, {"capture_session_id": 0, "frames_skipped": skipped}, "end of the version 1 stream")
        eos_times.append(time.monotonic())
        sender.send(encode_end_of_stream(SUBJECT, phase2[-1], version=1))
        time.sleep(WATCHDOG_S + 0.3)
        inserted = GAP1 | inserted_v1
        # Streams, each ended by a flush: (frame numbers, when the flush was caused).
        segments = [(phase1[:SESSION_CHANGE], sent[F0 + SESSION_CHANGE][2]), (phase1[SESSION_CHANGE:], eos_times[0]),
                    ([f for f in phase2 if f <= JUMP_FROM], sent[JUMP_TO][2]),
                    ([f for f in phase2 if f >= JUMP_TO], eos_times[1])]
        segment_of = {f: seg for seg in segments for f in seg[0]}
        # What an inserted frame carries: the session and rate of its stream, no timecode.
        inserted_stream = {f: Stream(S1, 120, 1) for f in GAP1} | {f: NO_STREAM for f in inserted_v1}

        # --- c. every published message ------------------------------------------------
        items = collector.snapshot()
        check(not collector.bad_parts, f"{len(collector.bad_parts)} output messages had other than 2 parts")
        kinds = {SUBJECT_DESCRIPTION: "subject", SKELETON_FRAME: "skeleton", CLEANED_MARKERS: "cleaned",
                 SUBJECT_STATUS: "status"}
        counts = {}
        skeletons, cleaned, statuses = [], [], []
        for when, topic, msg in items:
            try:
                msg_type, d = decode(msg)
            except DecodeError as e:
                raise Failure(f"a message on {topic} does not decode: {e} (length {len(msg)}, "
                              f"header {msg[:16].hex(' ')})")
            counts[msg_type] = counts.get(msg_type, 0) + 1
            check(msg_type in kinds, f"unexpected {TYPE_NAMES[msg_type]} on {topic}")
            check(topic == f"{kinds[msg_type]}/{SUBJECT}/", f"{TYPE_NAMES[msg_type]} on topic {topic}")
            check(d["subject"] == SUBJECT, f"subject {d['subject']!r} on {topic}")
            # The default [output] protocol_version is 2: every message, whatever the input's.
            check(d["version"] == 2, f"a version {d['version']} {TYPE_NAMES[msg_type]} from a default daemon")
            if msg_type == SUBJECT_DESCRIPTION:
                check(d == description, "the subject description changed between ticks")
            elif msg_type == SKELETON_FRAME:
                check(len(msg) - 16 == 1 + n + 56 + 24 + 44 * J, "skeleton frame size: 1 + n + 56 + B + 44 J, B = 24")
                skeletons.append((when, d))
            elif msg_type == CLEANED_MARKERS:
                check(len(msg) - 16 == 1 + n + 36 + 24 + 14 * M, "cleaned markers size: 1 + n + 36 + B + 14 M, B = 24")
                cleaned.append((when, d))
            else:
                statuses.append((when, d))
        check(len(description["joints"]) == J and len(description["markers"]) == M, "description counts")

        # Skeleton and cleaned alternate, same frame number and timestamps.
        frames = [decode(m) for _, tp, m in items if decode_header(m)[0] in (SKELETON_FRAME, CLEANED_MARKERS)]
        check(len(frames) % 2 == 0, f"{len(frames)} skeleton + cleaned messages: not in pairs")
        for (t1, s), (t2, c) in zip(frames[0::2], frames[1::2]):
            check(t1 == SKELETON_FRAME and t2 == CLEANED_MARKERS,
                  f"published frame {s['frame']}: expected a skeleton frame then its cleaned markers")
            check((s["frame"], s["capture_ns"], s["publish_ns"]) == (c["frame"], c["capture_ns"], c["publish_ns"]),
                  f"skeleton/cleaned of frame {s['frame']} disagree on number or timestamps")
            # Subject state: 2 lost iff the final solve had too few markers (status 2), else 1
            # repairing iff a marker of the frame was repaired or unrecoverable, else 0.
            want = 2 if s["solve"] == 2 else 1 if any(st != 0 for _, st, _ in c["markers"]) else 0
            check(s["state"] == want, f"frame {s['frame']}: subject state {s['state']}, expected {want} "
                                      f"(solve status {s['solve']})")

        # The stream block: each skeleton frame and cleaned-markers message carries its
        # marker frame's, unchanged; an inserted frame its stream's session and rate, no timecode.
        junk_tc_frames = {F0 + 57 + k for k, (what, _) in enumerate(GOOD_STREAMS) if "not checked" in what}
        junk_tc_seen = set()
        for _, d in skeletons + cleaned:
            f = d["frame"]
            want_st = inserted_stream[f] if f in inserted else sent_stream[f]
            if f in junk_tc_frames and d["stream"] != want_st:
                # README: "unchanged" and, for the six timecode bytes without bit 0, "write
                # zeros": a writer that zeroes them satisfies the second.
                check(d["stream"] == want_st.replace(hours=0, minutes=0, seconds=0, frames=0, subframe=0, tc_rate=0),
                      f"frame {f}: stream block {d['stream']}, sent {want_st}")
                junk_tc_seen.add("zeroed")
            else:
                check(d["stream"] == want_st, f"frame {f}: stream block {d['stream']}, expected {want_st}")
                if f in junk_tc_frames:
                    junk_tc_seen.add("echoed")
        summary.append("stream blocks: every skeleton/cleaned message carries its marker frame's (inserted: session "
                       "and rate, no timecode; version 1 input: session 0, no rate, no timecode); timecode bytes sent "
                       f"without a timecode were {'/'.join(sorted(junk_tc_seen))}")

        numbers = [d["frame"] for _, d in skeletons]
        check(numbers == phase1 + phase2,
              f"published frame numbers: {len(numbers)} frames, expected {len(phase1) + len(phase2)}; "
              f"first difference at {next((k for k, (a, b) in enumerate(zip(numbers, phase1 + phase2)) if a != b), None)}")
        now_ns = time.time_ns()
        phase_of = {f: 0 for f in phase1} | {f: 1 for f in phase2}
        worst_rms = 0.0
        root_err = []
        for when, s in skeletons:
            f = s["frame"]
            check(s["hash"] == model.skeleton_hash, f"frame {f}: skeleton hash {s['hash']}")
            want_ts = 0 if f in inserted else sent[f][0]
            check(s["capture_ns"] == want_ts, f"frame {f}: capture timestamp {s['capture_ns']}, sent {want_ts}")
            check(abs(s["publish_ns"] - now_ns) < 60e9, f"frame {f}: publish timestamp {s['publish_ns']} is not now")
            check(s["solve"] <= 3, f"frame {f}: final solve status {s['solve']}")
            check(s["state"] <= 2, f"frame {f}: subject state {s['state']} in a skeleton frame")
            check(s["flags"] == 1 and s["global_"] is not None, f"frame {f}: no global block with global_transforms")
            check(len(s["local"]) == J, f"frame {f}: {len(s['local'])} joints")
            check(s["rms"] >= 0, f"frame {f}: negative RMS")
            worst_rms = max(worst_rms, s["rms"])
            # K frames of lookahead: frame f leaves only once frame f + K (or the next one
            # sent, when f + K was inserted) of its stream has been sent, or on the flush
            # that ends its stream (session change, jump, end of stream).
            seg, flush_time = segment_of[f]
            release = next((sent[g][2] for g in seg if g >= f + K and g in sent), flush_time)
            check(when >= release, f"frame {f} was published before frame {f + K} or its stream's flush")
            if f in truth_root and phase_of[f] == 0 and f >= F0 + 30:
                root_err.append(math.dist(s["root"], truth_root[f]))
        check(sorted(numbers) == sorted(set(numbers)), "a frame was published twice")

        # Cleaned markers: observed samples are the values sent, bit for bit.
        observed = repaired = unrecoverable = 0
        for _, c in cleaned:
            f = c["frame"]
            check(c["hash"] == model.marker_hash, f"cleaned {f}: hash {c['hash']}")
            check(len(c["markers"]) == M, f"cleaned {f}: {len(c['markers'])} markers")
            ms_sent = sent[f][1] if f in sent and f not in inserted else None
            for idx, (pos, st, reason) in enumerate(c["markers"]):
                if st == 0:
                    observed += 1
                    check(reason == 0, f"cleaned {f} marker {idx}: observed with reason {reason}")
                    check(ms_sent is not None and ms_sent[idx] is not None and idx not in invalid.get(f, []),
                          f"cleaned {f} marker {idx}: 'observed' but nothing valid was sent")
                    check(struct.pack("<3f", *pos) == struct.pack("<3f", *ms_sent[idx]),
                          f"cleaned {f} marker {idx}: observed {pos} != sent {ms_sent[idx]}")
                elif st == 1:
                    repaired += 1
                    check(reason >= 1, f"cleaned {f} marker {idx}: repaired with reason 0")
                else:
                    unrecoverable += 1
                    check(reason == 0 and pos == (0.0, 0.0, 0.0),
                          f"cleaned {f} marker {idx}: unrecoverable with reason {reason} at {pos}")
            for idx in invalid.get(f, []) if phase_of[f] == 0 else []:
                pos, st, reason = c["markers"][idx]
                check(st != 0, f"cleaned {f} marker {idx}: sent missing/out of volume, published as observed")
                check(st == 2 or reason == 1, f"cleaned {f} marker {idx}: a missing sample repaired with reason {reason}")
            if f in inserted:
                check(all(st != 0 for _, st, _ in c["markers"]), f"inserted frame {f} has observed markers")

        # --- d. forward kinematics against the global block ---------------------------
        parents = [j["parent"] for j in description["joints"]]
        offsets = [j["offset"] for j in description["joints"]]
        worst_p = worst_r = 0.0
        for _, s in skeletons:
            world = forward_kinematics(parents, offsets, s["root"], s["local"])
            for j, ((q, p), (gq, gp)) in enumerate(zip(world, s["global_"])):
                dp = math.dist(p, gp)
                dr = q_angle_between(q, gq)
                worst_p, worst_r = max(worst_p, dp), max(worst_r, dr)
                check(dp < 1e-3, f"frame {s['frame']} joint {j}: FK position {p} vs global block {gp} ({dp:.2e} m)")
                check(dr < 1e-3, f"frame {s['frame']} joint {j}: FK rotation {q} vs global block {gq} ({dr:.2e} rad)")
        summary.append(f"FK from description + local block vs global block over {len(skeletons)} frames x {J} joints: "
                       f"worst {worst_p * 1e3:.4f} mm, {worst_r:.2e} rad")
        check(max(root_err) < 0.05, f"root translation is {max(root_err):.3f} m from the performance's root")
        summary.append(f"solved root vs the synthetic performance: mean {sum(root_err) / len(root_err) * 1e3:.2f} mm, "
                       f"max {max(root_err) * 1e3:.2f} mm (world frame unchanged); worst solve RMS {worst_rms * 1e3:.2f} mm")

        # --- e. status messages, /metrics balance, /health ---------------------------
        check(statuses, "no subject status message")
        for _, st in statuses:
            check(st["problems"] & 0b11 == 0, f"subject status problems byte 0x{st['problems']:02x}")
        after_eos = [st for t, st in statuses if t > eos_times[1] + 0.05]
        check(after_eos, "no subject status after the end of stream")
        last = after_eos[-1]
        check(last["state"] == 4, f"subject status state {last['state']} after an end of stream (expected 4 waiting)")
        check(last["last"] == phase2[-1], f"status last accepted frame {last['last']}, expected {phase2[-1]}")
        t_last = next(t for t, st in statuses if st is last)
        since = (t_last - sent[phase2[-1]][2]) * 1e9
        check(since - 0.5e9 <= last["since_ns"] <= since + 0.01e9,
              f"status: {last['since_ns'] / 1e9:.3f} s since the last accepted frame, we sent it {since / 1e9:.3f} s "
              "before receiving the status")

        m = metrics(http_port)
        received = metric_sum(m, "mocapd_messages_received_total")
        published = metric_sum(m, "mocapd_frames_published_total")
        dropped = metric_sum(m, "mocapd_frames_dropped_total")
        pending = metric_sum(m, "mocapd_frames_pending")
        control = metric_sum(m, "mocapd_control_messages_total")
        retired_p = metric_sum(m, "mocapd_retired_frames_published_total")
        missing = [x for x in ("mocapd_messages_received_total", "mocapd_frames_published_total",
                               "mocapd_frames_dropped_total", "mocapd_frames_pending", "mocapd_control_messages_total",
                               "mocapd_retired_frames_published_total", "mocapd_retired_frames_dropped_total")
                   if x not in m]
        check(not missing, f"/metrics lacks the balance-equation series {missing}")
        retired_d = metric_sum(m, "mocapd_retired_frames_dropped_total")
        rhs = published + retired_p + retired_d + dropped + pending + control
        check(received == rhs, f"balance: messages_received {received} != published {published} + retired "
                               f"{retired_p}+{retired_d} + dropped {dropped} + pending {pending} + control {control}")
        check(received == sender.count, f"messages_received {received}, we sent {sender.count}")
        good_sent = len(phase1) + len(phase2) - len(inserted)
        check(published == good_sent, f"frames_published {published}, expected the {good_sent} received frames "
                                      "(inserted frames excluded)")
        check(metric_sum(m, "mocapd_frames_inserted_total", subject=SUBJECT) == len(inserted), "frames_inserted")
        # Skipped: the two gaps and the whole of the jump. Restarts: the session change S1 -> S2
        # and the jump. The version 1 stream's first frame (session 0 after S2's last frame)
        # follows an end of stream, which already made it "a fresh start": it is neither a
        # restart nor a session change. (The README's "Session" step compares with "the last
        # accepted frame" and does not say whether an end of stream forgets its session; this
        # is the daemon's reading, the one that keeps restarts for unannounced restarts.)
        got = {name: metric_sum(m, f"mocapd_{name}_total", subject=SUBJECT)
               for name in ("frames_skipped", "capture_restarts", "capture_sessions_changed")}
        want = {"frames_skipped": skipped, "capture_restarts": 2, "capture_sessions_changed": 1}
        check(got == want, f"/metrics at the end: {got}, expected {want}")
        _, body = http_get(http_port, "/subjects")
        entry = next((e for e in json.loads(body) if e.get("name") == SUBJECT), {})
        check_stream_fields(entry, {"frames_skipped": skipped, "capture_session_changes": 1}, "at the end")
        summary.append(f"version 1 stream: gap of 1 + jump of {JUMP_TO - JUMP_FROM - 1} numbers: frames_skipped "
                       f"{int(got['frames_skipped'])} in all; restarts {int(got['capture_restarts'])}, session changes "
                       f"{int(got['capture_sessions_changed'])}; /subjects last_timecode for version 1 input: "
                       f"{entry2.get('last_timecode')!r}")
        check(pending == 0 and control == 2, f"pending {pending}, control messages {control} (2 end of stream)")
        for reason, want in expected_drops.items():
            got = metric_sum(m, "mocapd_frames_dropped_total", reason=reason)
            check(got == want, f"dropped as {reason}: {got}, expected {want}")
            if reason in attributed:
                got_s = metric_sum(m, "mocapd_frames_dropped_total", reason=reason, subject=SUBJECT)
                check(got_s == want, f"dropped as {reason} charged to {SUBJECT}: {got_s}, expected {want}")
        check(dropped == sum(expected_drops.values()), f"dropped {dropped} in all")
        check(metric_sum(m, "mocapd_samples_out_of_volume_total", subject=SUBJECT) == 1, "samples_out_of_volume")
        s_received = metric_sum(m, "mocapd_frames_received_total", subject=SUBJECT)
        s_published = metric_sum(m, "mocapd_frames_published_total", subject=SUBJECT)
        s_dropped = metric_sum(m, "mocapd_frames_dropped_total", subject=SUBJECT)
        s_pending = metric_sum(m, "mocapd_frames_pending", subject=SUBJECT)
        check(s_received == s_published + s_dropped + s_pending,
              f"{SUBJECT}: received {s_received} != published {s_published} + dropped {s_dropped} + pending {s_pending}")
        check(last["frames_out"] == len(skeletons), f"status frames out {last['frames_out']}, published {len(skeletons)}")
        check(last["frames_in"] == s_received, f"status frames in {last['frames_in']}, /metrics {s_received}")
        check(last["dropped"] == s_dropped, f"status frames dropped {last['dropped']}, /metrics {s_dropped}")
        summary.append(f"/metrics balance: {int(received)} received = {int(published)} published + "
                       f"{int(dropped)} dropped + {int(pending)} pending + {int(control)} control"
                       f" + {int(retired_p + retired_d)} retired")
        summary.append("drops by reason: " + ", ".join(f"{k} {v}" for k, v in expected_drops.items()))

        code, body = http_get(http_port, "/health")
        health = json.loads(body)
        check(code == 200 and health.get("status") == "ok", f"/health at the end: HTTP {code} {body}")
        check(health.get("accounted") is True, f"/health accounted: {body}")
        _, body = http_get(http_port, "/subjects")
        entry = next((e for e in json.loads(body) if e.get("name") == SUBJECT), {})
        for key in ("rejecting_input", "model_suspect", "model_distance_mm"):
            check(key in entry, f"GET /subjects lacks '{key}' (README, Frame accounting and health)")
        check(entry.get("rejecting_input") is False and entry.get("model_suspect") is False,
              f"/subjects flags: rejecting_input {entry.get('rejecting_input')}, model_suspect {entry.get('model_suspect')}, "
              f"model_distance_mm {entry.get('model_distance_mm')}")

        summary.insert(2, f"decoded {len(items)} messages: " + ", ".join(
            f"{counts.get(t, 0)} {TYPE_NAMES[t]}" for t in (1, 3, 4, 5)) + "; every size = the README formula")
        summary.insert(3, f"frames {phase1[0]}..{phase1[-1]}, {phase2[0]}..{JUMP_FROM} and {JUMP_TO}..{phase2[-1]} "
                          f"published once each, in order, timestamps echoed (inserted frames {sorted(inserted)}: 0), "
                          f"every message version 2 (the default); cleaned samples: {observed} "
                          f"observed (bit-exact), {repaired} repaired, {unrecoverable} unrecoverable")

        # Shutdown: exit 0 means every frame accounted for; one last status message.
        t_term = time.monotonic()
        daemon.send_signal(signal.SIGTERM)
        code = daemon.wait(timeout=10)
        check(code == 0, f"mocapd exited with {code} after SIGTERM")
        time.sleep(0.2)
        final = [decode(msg)[1] for t, tp, msg in collector.snapshot() if t > t_term and tp == f"status/{SUBJECT}/"]
        check(final, "no subject status message at shutdown")
        summary.append(f"SIGTERM: exit 0, {len(final)} status message(s) at shutdown")
        return summary
    except BaseException:
        print_log_tail(log, "mocapd", 4000)
        raise
    finally:
        stop_all(collector, sender, daemon, log)
        ctx.term()


def main(argv):
    if len(argv) != 4:
        print(__doc__.strip().splitlines()[-1], file=sys.stderr)
        return 2
    t0 = time.monotonic()
    try:
        summary = run(argv[1], argv[2], argv[3])
        if FAILURES:
            print("\n".join("  " + line for line in summary))
            raise Failure(f"{len(FAILURES)} checks failed: " + "; ".join(FAILURES))
    except (Failure, DecodeError) as e:
        print(f"FAIL: {e}", file=sys.stderr)
        return 1
    for line in summary:
        print("  " + line)
    print(f"independent decoder test passed in {time.monotonic() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
