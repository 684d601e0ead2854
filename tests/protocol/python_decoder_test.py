"""Checks protocol/python/mocapd_protocol.py against messages the C++ encoder wrote."""
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "..", "protocol", "python"))
import mocapd_protocol  # noqa: E402


def read(directory, name):
    with open(os.path.join(directory, name), "rb") as f:
        return f.read()


def expect_error(data, status):
    try:
        mocapd_protocol.decode(data)
    except ValueError as e:
        assert str(e) == status, f"expected {status}, got {e}"
        return
    raise AssertionError(f"expected {status}, decoded fine")


def main(directory):
    kind, m = mocapd_protocol.decode(read(directory, "marker_frame.bin"))
    assert kind == "marker_frame"
    assert m["subject"] == "actor1" and m["frame"] == 1234 and m["capture_time_ns"] == 987654321
    assert m["rate_hz"] == 120.0
    assert m["markers"][0] == (0.5, 1.25, -0.75) and m["markers"][1] is None and m["markers"][2] == (-1.5, 0.0, 2.0)
    kind, s = mocapd_protocol.decode(read(directory, "skeleton_frame.bin"))
    assert kind == "skeleton_frame"
    assert s["publish_time_ns"] == 987754321 and s["root_translation"] == (0.25, 0.875, -3.5)
    assert s["rotations"][1] == (0.5, 0.5, 0.5, 0.5)
    expect_error(read(directory, "marker_frame_truncated.bin"), "too_short")
    expect_error(read(directory, "bad_magic.bin"), "bad_magic")
    expect_error(b"", "too_short")
    print("1 passed, 0 failed")


if __name__ == "__main__":
    main(sys.argv[1])
