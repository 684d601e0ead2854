"""Reference decoder for the mocapd wire protocol, versions 1 and 2 (see protocol/README.md):
every message type the daemon sends or receives; plus encoders for what a capture bridge
sends (marker frames, end of stream). Version 2 frames carry a stream block (capture
session, exact rate, SMPTE timecode), decoded as the "stream" field (None in version 1).

Standard library only. Every decode function raises ValueError naming the problem
(the same status names as the C++ decoder) for a malformed message.
"""
import math
import struct

MAGIC = 0x4450434D
VERSION = 2  # what the encoders write unless told otherwise
VERSIONS = (1, 2)
HEADER = struct.Struct("<IHHII")
STREAM_BLOCK = struct.Struct("<QIIBBBBBBH")  # session, rate num/den, hh mm ss ff sub flags, tc fps
SUBJECT_DESCRIPTION = 1
MARKER_FRAME = 2
SKELETON_FRAME = 3
CLEANED_MARKERS = 4
SUBJECT_STATUS = 5
END_OF_STREAM = 6
CALIBRATION_STATUS = 7
CALIBRATION_STATES = ("waiting", "collecting", "calibrated", "failed")
SUBJECT_STATES = ("tracking", "repairing", "lost", "stalled", "waiting")
MARKER_STATUS = ("observed", "repaired", "unrecoverable")
MASK_REASONS = ("none", "missing", "disagreement", "residual", "spike", "rigid_distance", "swap", "frozen",
                "fallen_off", "small_track", "trimmed")
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

    def subject(self, error="bad_subject_name"):
        (length,) = self.take("<B")
        if length == 0 or length > 63:
            raise ValueError(error)
        if self.offset + length > len(self.data):
            raise ValueError("too_short")
        name = self.data[self.offset:self.offset + length].decode("utf-8")
        self.offset += length
        return name


def decode_header(data):
    """Returns (type, payload_size, version) after checking magic, version and size."""
    if len(data) < HEADER.size:
        raise ValueError("too_short")
    magic, version, msg_type, payload, _reserved = HEADER.unpack_from(data, 0)
    if magic != MAGIC:
        raise ValueError("bad_magic")
    if version not in VERSIONS:
        raise ValueError("unsupported_version")
    if len(data) - HEADER.size < payload:
        raise ValueError("too_short")
    if len(data) - HEADER.size != payload:
        raise ValueError("size_mismatch")
    return msg_type, payload, version


def _stream_bytes(version):
    return STREAM_BLOCK.size if version >= 2 else 0


def _read_stream(r, version, rate_hz=None):
    """Version 2's stream block as a dict (None in version 1); bad_field when out of range."""
    if version < 2:
        return None
    session, num, den, hh, mm, ss, ff, sub, flags, tc_rate = r.take(STREAM_BLOCK.format)
    if flags & ~3:
        raise ValueError("bad_field")
    timecode = None
    if flags & 1:
        drop = bool(flags & 2)
        if not (tc_rate > 0 and hh < 24 and mm < 60 and ss < 60 and ff < tc_rate) or (drop and tc_rate % 30):
            raise ValueError("bad_field")
        timecode = {"hours": hh, "minutes": mm, "seconds": ss, "frames": ff, "subframe": sub,
                    "drop_frame": drop, "rate": tc_rate}
    elif flags:
        raise ValueError("bad_field")
    if (num == 0) != (den == 0):
        raise ValueError("bad_field")
    if num and rate_hz is not None and abs(num / den - rate_hz) > 1e-4 * (num / den):
        raise ValueError("bad_field")
    return {"session_id": session, "rate": (num, den) if num else None, "timecode": timecode}


def format_timecode(tc):
    """HH:MM:SS:FF (';' before the frames when drop-frame), '.S' with a subframe."""
    text = "%02d:%02d:%02d%s%02d" % (tc["hours"], tc["minutes"], tc["seconds"], ";" if tc["drop_frame"] else ":",
                                     tc["frames"])
    return text + (".%d" % tc["subframe"] if tc["subframe"] else "")


def decode_marker_frame(data):
    msg_type, _, version = decode_header(data)
    if msg_type != MARKER_FRAME:
        raise ValueError("wrong_type")
    r = Reader(data, HEADER.size)
    subject = r.subject()
    model_hash, frame, capture_ns, rate, count, _reserved = r.take("<QQQfHH")
    if not math.isfinite(rate) or rate <= 0:
        raise ValueError("non_finite")
    if count > MAX_MARKERS:
        raise ValueError("too_many_items")
    if len(data) - r.offset != _stream_bytes(version) + 13 * count:
        raise ValueError("size_mismatch")
    stream = _read_stream(r, version, rate)
    markers = []
    for _ in range(count):
        x, y, z, flags = r.take("<fffB")
        valid = bool(flags & 1)
        if valid and not all(math.isfinite(v) for v in (x, y, z)):
            raise ValueError("non_finite")
        markers.append((x, y, z) if valid else None)
    return {"subject": subject, "model_hash": model_hash, "frame": frame, "capture_time_ns": capture_ns,
            "rate_hz": rate, "markers": markers, "version": version, "stream": stream}


def _finite(values):
    if not all(math.isfinite(v) for v in values):
        raise ValueError("non_finite")
    return values


def _check_type(data, expected):
    msg_type, _, version = decode_header(data)
    if msg_type != expected:
        raise ValueError("wrong_type")
    return Reader(data, HEADER.size), version


def decode_skeleton_frame(data):
    r, version = _check_type(data, SKELETON_FRAME)
    subject = r.subject()
    model_hash, frame, capture_ns, publish_ns, status, state, flags, count, _reserved = r.take("<QQQQBBHHH")
    if status > 3 or state >= len(SUBJECT_STATES) or flags & ~1:
        raise ValueError("bad_field")
    if count > MAX_JOINTS:
        raise ValueError("too_many_items")
    globals_present = bool(flags & 1)
    if len(data) - r.offset != _stream_bytes(version) + 16 + (16 + (28 if globals_present else 0)) * count:
        raise ValueError("size_mismatch")
    stream = _read_stream(r, version)
    (residual,) = _finite(r.take("<f"))
    root = _finite(r.take("<fff"))
    rotations = [_finite(r.take("<ffff")) for _ in range(count)]
    global_transforms = [(_finite(r.take("<ffff")), _finite(r.take("<fff"))) for _ in range(count)] if globals_present else None
    return {"subject": subject, "model_hash": model_hash, "frame": frame, "capture_time_ns": capture_ns,
            "publish_time_ns": publish_ns, "status": status, "subject_state": SUBJECT_STATES[state],
            "residual_m": residual, "root_translation": root, "rotations": rotations,
            "global_transforms": global_transforms, "version": version, "stream": stream}


def decode_subject_description(data):
    r, version = _check_type(data, SUBJECT_DESCRIPTION)
    subject = r.subject()
    marker_hash, skeleton_hash, rate, lookahead, markers, joints, _reserved = r.take("<QQfHHHH")
    if not math.isfinite(rate) or rate <= 0:
        raise ValueError("non_finite")
    if markers > MAX_MARKERS or joints > MAX_JOINTS:
        raise ValueError("too_many_items")
    if len(data) - r.offset < 2 * markers + 32 * joints:
        raise ValueError("size_mismatch")
    marker_names = [r.subject("bad_field") for _ in range(markers)]
    joint_list = []
    for j in range(joints):
        name = r.subject("bad_field")
        (parent,) = r.take("<h")
        if (j == 0) != (parent == -1) or parent >= j or parent < -1:
            raise ValueError("bad_field")
        offset = _finite(r.take("<fff"))
        rotation = _finite(r.take("<ffff"))
        joint_list.append({"name": name, "parent": parent, "offset": offset, "rest_rotation": rotation})
    if r.offset != len(data):
        raise ValueError("size_mismatch")
    return {"subject": subject, "marker_set_hash": marker_hash, "skeleton_hash": skeleton_hash, "rate_hz": rate,
            "lookahead_frames": lookahead, "markers": marker_names, "joints": joint_list}


def decode_cleaned_markers(data):
    r, version = _check_type(data, CLEANED_MARKERS)
    subject = r.subject()
    model_hash, frame, capture_ns, publish_ns, count, _reserved = r.take("<QQQQHH")
    if count > MAX_MARKERS:
        raise ValueError("too_many_items")
    if len(data) - r.offset != _stream_bytes(version) + 14 * count:
        raise ValueError("size_mismatch")
    stream = _read_stream(r, version)
    markers = []
    for _ in range(count):
        position = _finite(r.take("<fff"))
        status, reason = r.take("<BB")
        if status >= len(MARKER_STATUS) or reason >= len(MASK_REASONS):
            raise ValueError("bad_field")
        markers.append({"position": None if status == 2 else position, "status": MARKER_STATUS[status],
                        "reason": MASK_REASONS[reason]})
    return {"subject": subject, "model_hash": model_hash, "frame": frame, "capture_time_ns": capture_ns,
            "publish_time_ns": publish_ns, "markers": markers, "version": version, "stream": stream}


def decode_subject_status(data):
    r, version = _check_type(data, SUBJECT_STATUS)
    subject = r.subject()
    state, problems, _r16, last_frame, since_ns, frames_in, frames_out, dropped = r.take("<BBHQQQQQ")
    if r.offset != len(data):
        raise ValueError("size_mismatch")
    if state >= len(SUBJECT_STATES):
        raise ValueError("bad_field")
    return {"subject": subject, "state": SUBJECT_STATES[state],
            "model_suspect": bool(problems & 1), "rejecting_input": bool(problems & 2),
            "unstable_input": bool(problems & 4),
            "last_frame": last_frame,
            "since_last_input_ns": since_ns, "frames_in": frames_in, "frames_out": frames_out,
            "frames_dropped": dropped}


def decode_end_of_stream(data):
    r, version = _check_type(data, END_OF_STREAM)
    subject = r.subject()
    (last_frame,) = r.take("<Q")
    if r.offset != len(data):
        raise ValueError("size_mismatch")
    return {"subject": subject, "last_frame": last_frame}


def decode_calibration_status(data):
    r, version = _check_type(data, CALIBRATION_STATUS)
    subject = r.subject()
    skeleton_hash, state, _r8, refinements, height, collected, count = r.take("<QBBHffH")
    if count > MAX_JOINTS:
        raise ValueError("too_many_items")
    if len(data) - r.offset != 10 * count:
        raise ValueError("size_mismatch")
    # The C++ decoder's order: the state, the floats before the joints, then each joint.
    if state >= len(CALIBRATION_STATES):
        raise ValueError("bad_field")
    if not (math.isfinite(height) and math.isfinite(collected)):
        raise ValueError("non_finite")
    joints = []
    for _ in range(count):
        covered, flags, uncertainty, moved = r.take("<BBff")
        if covered > 3:
            raise ValueError("bad_field")
        if not (math.isfinite(uncertainty) and math.isfinite(moved)):
            raise ValueError("non_finite")
        joints.append({"directions_covered": covered, "calibrated": bool(flags & 1), "ready": bool(flags & 2),
                       "uncertainty_mm": None if uncertainty < 0 else uncertainty,
                       "moved_mm": None if moved < 0 else moved})
    return {"subject": subject, "skeleton_hash": skeleton_hash, "state": CALIBRATION_STATES[state],
            "refinements": refinements, "height_m": height, "collected_s": collected, "joints": joints}


DECODERS = {
    SUBJECT_DESCRIPTION: ("subject_description", decode_subject_description),
    MARKER_FRAME: ("marker_frame", decode_marker_frame),
    SKELETON_FRAME: ("skeleton_frame", decode_skeleton_frame),
    CLEANED_MARKERS: ("cleaned_markers", decode_cleaned_markers),
    SUBJECT_STATUS: ("subject_status", decode_subject_status),
    END_OF_STREAM: ("end_of_stream", decode_end_of_stream),
    CALIBRATION_STATUS: ("calibration_status", decode_calibration_status),
}


def decode(data):
    """Decodes any message by its header's type; returns (kind, fields)."""
    msg_type, _, _ = decode_header(data)
    if msg_type not in DECODERS:
        raise ValueError("wrong_type")
    kind, decoder = DECODERS[msg_type]
    return kind, decoder(data)


def names_hash(names):
    """The model hash: 64-bit FNV-1a over the names in order, each followed by a zero byte."""
    h = 1469598103934665603
    for name in names:
        for byte in name.encode("utf-8") + b"\0":
            h ^= byte
            h = (h * 1099511628211) & 0xFFFFFFFFFFFFFFFF
    return h


def _message(msg_type, payload, version=VERSION):
    if version not in VERSIONS:
        raise ValueError("unsupported_version")
    return HEADER.pack(MAGIC, version, msg_type, len(payload), 0) + payload


def _name(name):
    raw = name.encode("utf-8")
    if not 1 <= len(raw) <= 63:
        raise ValueError("names must be 1..63 bytes")
    return struct.pack("<B", len(raw)) + raw


def encode_stream(session_id=0, rate=None, timecode=None):
    """Version 2's stream block. rate: (numerator, denominator) or None; timecode: a dict
    as decoded (hours, minutes, seconds, frames, subframe, drop_frame, rate) or None."""
    num, den = rate if rate else (0, 0)
    if timecode is None:
        return STREAM_BLOCK.pack(session_id, num, den, 0, 0, 0, 0, 0, 0, 0)
    flags = 1 | (2 if timecode.get("drop_frame") else 0)
    return STREAM_BLOCK.pack(session_id, num, den, timecode["hours"], timecode["minutes"], timecode["seconds"],
                             timecode["frames"], timecode.get("subframe", 0), flags, timecode["rate"])


def encode_marker_frame(subject, model_hash, frame, capture_time_ns, rate_hz, markers, version=VERSION,
                        session_id=0, rate=None, timecode=None):
    """markers: a list, in the subject's marker order, of (x, y, z) in metres or None (missing).
    Version 2 (the default) adds the stream block: session_id, rate (numerator, denominator),
    timecode (see encode_stream)."""
    if len(markers) > MAX_MARKERS:
        raise ValueError("too_many_items")
    body = [_name(subject), struct.pack("<QQQfHH", model_hash, frame, capture_time_ns, rate_hz, len(markers), 0)]
    if version >= 2:
        body.append(encode_stream(session_id, rate, timecode))
    for m in markers:
        body.append(struct.pack("<fffB", 0.0, 0.0, 0.0, 0) if m is None else struct.pack("<fffB", m[0], m[1], m[2], 1))
    return _message(MARKER_FRAME, b"".join(body), version)


def encode_end_of_stream(subject, last_frame, version=VERSION):
    return _message(END_OF_STREAM, _name(subject) + struct.pack("<Q", last_frame), version)
