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
    assert m["version"] == 2 and m["stream"]["session_id"] == 0x0123456789ABCDEF and m["stream"]["rate"] == (120, 1)
    assert mocapd_protocol.format_timecode(m["stream"]["timecode"]) == "01:02:03:04.2"
    kind, v1 = mocapd_protocol.decode(read(directory, "marker_frame_v1.bin"))
    assert v1["version"] == 1 and v1["stream"] is None and v1["markers"] == m["markers"]
    assert m["markers"][0] == (0.5, 1.25, -0.75) and m["markers"][1] is None and m["markers"][2] == (-1.5, 0.0, 2.0)
    kind, s = mocapd_protocol.decode(read(directory, "skeleton_frame.bin"))
    assert kind == "skeleton_frame"
    assert s["publish_time_ns"] == 987754321 and s["root_translation"] == (0.25, 0.875, -3.5)
    assert s["rotations"][1] == (0.5, 0.5, 0.5, 0.5)
    assert s["subject_state"] == "repairing" and s["global_transforms"] is None
    assert s["stream"]["rate"] == (120000, 1001) and s["stream"]["session_id"] == 42
    assert mocapd_protocol.format_timecode(s["stream"]["timecode"]) == "23:59:59;29.3"
    bad_solve = bytearray(read(directory, "skeleton_frame.bin"))
    bad_solve[mocapd_protocol.HEADER.size + 1 + len("actor1") + 32] = 4  # no such final solve status
    expect_error(bytes(bad_solve), "bad_field")
    kind, g = mocapd_protocol.decode(read(directory, "skeleton_frame_globals.bin"))
    assert g["global_transforms"][1] == ((0.5, -0.5, 0.5, -0.5), (0.5, 1.0, -3.0))
    kind, d = mocapd_protocol.decode(read(directory, "subject_description.bin"))
    assert kind == "subject_description" and d["markers"] == ["LASI", "RASI", "LKNE"]
    assert d["marker_set_hash"] == m["model_hash"] and d["lookahead_frames"] == 12
    assert [j["name"] for j in d["joints"]] == ["Hips", "Spine"] and d["joints"][1]["parent"] == 0
    assert d["joints"][0]["offset"] == (0.0, 0.875, 0.0)
    kind, c = mocapd_protocol.decode(read(directory, "cleaned_markers.bin"))
    assert kind == "cleaned_markers"
    assert [x["status"] for x in c["markers"]] == ["observed", "repaired", "unrecoverable"]
    assert c["markers"][1] == {"position": (0.25, 1.0, -0.5), "status": "repaired", "reason": "missing"}
    assert c["markers"][2]["position"] is None
    kind, st = mocapd_protocol.decode(read(directory, "subject_status.bin"))
    assert kind == "subject_status" and st["state"] == "stalled" and st["since_last_input_ns"] == 1500000000
    assert st["rejecting_input"] and not st["model_suspect"]
    assert st["frames_in"] == 1235 and st["frames_out"] == 1223
    kind, cal = mocapd_protocol.decode(read(directory, "calibration_status.bin"))
    assert kind == "calibration_status" and cal["state"] == "collecting" and cal["skeleton_hash"] == 77
    assert cal["refinements"] == 3 and cal["height_m"] == 1.75 and cal["collected_s"] == 12.5
    assert cal["joints"][0] == {"directions_covered": 0, "calibrated": True, "ready": True,
                                "uncertainty_mm": 0.0, "moved_mm": 0.5}
    assert cal["joints"][1]["ready"] is False and cal["joints"][1]["moved_mm"] is None
    for name in ("skeleton_frame_globals.bin", "subject_description.bin", "cleaned_markers.bin", "subject_status.bin",
                 "calibration_status.bin"):
        data = read(directory, name)
        for n in range(len(data)):
            try:
                mocapd_protocol.decode(data[:n])
            except ValueError as e:
                assert str(e) in ("too_short", "size_mismatch"), (name, n, str(e))
            else:
                raise AssertionError(f"{name} truncated to {n} bytes decoded")
    expect_error(read(directory, "marker_frame_truncated.bin"), "too_short")
    expect_error(read(directory, "bad_magic.bin"), "bad_magic")
    expect_error(b"", "too_short")
    # The encoders write what the C++ encoder writes, byte for byte.
    assert mocapd_protocol.names_hash(["LASI", "RASI", "LKNE"]) == m["model_hash"]
    points = [(0.5, 1.25, -0.75), None, (-1.5, 0.0, 2.0)]
    encoded = mocapd_protocol.encode_marker_frame("actor1", m["model_hash"], 1234, 987654321, 120.0, points,
                                                  session_id=m["stream"]["session_id"], rate=(120, 1),
                                                  timecode=m["stream"]["timecode"])
    assert encoded == read(directory, "marker_frame.bin")
    encoded = mocapd_protocol.encode_marker_frame("actor1", m["model_hash"], 1234, 987654321, 120.0, points,
                                                  version=1)
    assert encoded == read(directory, "marker_frame_v1.bin")
    # Out-of-range stream fields are refused: 30 frames at 30 fps, drop-frame at 25 fps.
    for bad in ({"hours": 1, "minutes": 0, "seconds": 0, "frames": 30, "rate": 30},
                {"hours": 1, "minutes": 0, "seconds": 0, "frames": 0, "rate": 25, "drop_frame": True}):
        expect_error(mocapd_protocol.encode_marker_frame("actor1", 1, 1, 1, 120.0, points, timecode=bad),
                     "bad_field")
    expect_error(mocapd_protocol.encode_marker_frame("actor1", 1, 1, 1, 120.0, points, rate=(119, 1)), "bad_field")
    eos = mocapd_protocol.decode(mocapd_protocol.encode_end_of_stream("actor1", 77))
    assert eos == ("end_of_stream", {"subject": "actor1", "last_frame": 77})
    print("1 passed, 0 failed")


if __name__ == "__main__":
    main(sys.argv[1])
