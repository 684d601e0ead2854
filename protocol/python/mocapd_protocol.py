"""Reference decoder for the mocapd wire protocol, version 1 (see protocol/README.md).

Standard library only. Every decode function raises ValueError naming the problem
(the same status names as the C++ decoder) for a malformed message.
"""
import math
import struct

MAGIC = 0x4450434D
VERSION = 1
HEADER = struct.Struct("<IHHII")
MARKER_FRAME = 2
SKELETON_FRAME = 3
MAX_MARKERS = 1024
MAX_JOINTS = 512


class Reader:
    def __init__(self, data, offset):
        self.data = data
        self.offset = offset

    def take(self, fmt):
        size = struct.calcsize(fmt)
        if self.offset + size > len(self.data):
            raise ValueError("too_short")
        values = struct.unpack_from(fmt, self.data, self.offset)
        self.offset += size
        return values

    def subject(self):
        (length,) = self.take("<B")
        if length == 0 or length > 63:
            raise ValueError("bad_subject_name")
        if self.offset + length > len(self.data):
            raise ValueError("too_short")
        name = self.data[self.offset:self.offset + length].decode("utf-8")
        self.offset += length
        return name


def decode_header(data):
    """Returns (type, payload_size) after checking magic, version and size."""
    if len(data) < HEADER.size:
        raise ValueError("too_short")
    magic, version, msg_type, payload, _reserved = HEADER.unpack_from(data, 0)
    if magic != MAGIC:
        raise ValueError("bad_magic")
    if version != VERSION:
        raise ValueError("unsupported_version")
    if len(data) - HEADER.size < payload:
        raise ValueError("too_short")
    if len(data) - HEADER.size != payload:
        raise ValueError("size_mismatch")
    return msg_type, payload


def decode_marker_frame(data):
    msg_type, _ = decode_header(data)
    if msg_type != MARKER_FRAME:
        raise ValueError("wrong_type")
    r = Reader(data, HEADER.size)
    subject = r.subject()
    model_hash, frame, capture_ns, rate, count, _reserved = r.take("<QQQfHH")
    if not math.isfinite(rate) or rate <= 0:
        raise ValueError("non_finite")
    if count > MAX_MARKERS:
        raise ValueError("too_many_items")
    if len(data) - r.offset != 13 * count:
        raise ValueError("size_mismatch")
    markers = []
    for _ in range(count):
        x, y, z, flags = r.take("<fffB")
        valid = bool(flags & 1)
        if valid and not all(math.isfinite(v) for v in (x, y, z)):
            raise ValueError("non_finite")
        markers.append((x, y, z) if valid else None)
    return {"subject": subject, "model_hash": model_hash, "frame": frame, "capture_time_ns": capture_ns,
            "rate_hz": rate, "markers": markers}


def decode_skeleton_frame(data):
    msg_type, _ = decode_header(data)
    if msg_type != SKELETON_FRAME:
        raise ValueError("wrong_type")
    r = Reader(data, HEADER.size)
    subject = r.subject()
    model_hash, frame, capture_ns, publish_ns, status, _flags, count, residual, tx, ty, tz = r.take("<QQQQBBHffff")
    if count > MAX_JOINTS:
        raise ValueError("too_many_items")
    if len(data) - r.offset != 16 * count:
        raise ValueError("size_mismatch")
    if not all(math.isfinite(v) for v in (residual, tx, ty, tz)):
        raise ValueError("non_finite")
    rotations = []
    for _ in range(count):
        q = r.take("<ffff")
        if not all(math.isfinite(v) for v in q):
            raise ValueError("non_finite")
        rotations.append(q)
    return {"subject": subject, "model_hash": model_hash, "frame": frame, "capture_time_ns": capture_ns,
            "publish_time_ns": publish_ns, "status": status, "residual_m": residual,
            "root_translation": (tx, ty, tz), "rotations": rotations}


def decode(data):
    """Decodes any message by its header's type."""
    msg_type, _ = decode_header(data)
    if msg_type == MARKER_FRAME:
        return "marker_frame", decode_marker_frame(data)
    if msg_type == SKELETON_FRAME:
        return "skeleton_frame", decode_skeleton_frame(data)
    raise ValueError("wrong_type")
