// Summaries of take files for `mocap-sim info`: frames, rate, units, labels or joints,
// for C3D each marker's missing fraction and gap count, and for a recorded capture stream
// (.mcr) each subject's frames, rate, sessions and the frames its numbers say were lost.
#pragma once

#include <string>
#include <vector>

#include <nlohmann/json_fwd.hpp>

namespace mocapd {

struct PointInfo {
  std::string label;
  std::string kind;  ///< "marker" or the model-output group (ANGLES, POWERS ...)
  double missing_fraction = 0.0;
  int gaps = 0;         ///< Runs of consecutive missing frames.
  int longest_gap = 0;  ///< Frames.
};

/// One subject's marker stream in a recording (`mocap-sim record`).
struct RecordedStreamInfo {
  std::string subject;
  int64_t frames = 0;
  uint64_t first_frame = 0;
  uint64_t last_frame = 0;
  /// Frame numbers skipped within a capture session: frames lost before the recorder.
  int64_t frames_skipped = 0;
  /// Frames whose number repeats or goes back within a session.
  int64_t frames_out_of_order = 0;
  /// Capture sessions: a new v2 session id, or (v1) the frame numbers starting again.
  int sessions = 0;
  int markers = 0;  ///< The most markers in one frame.
  double rate_hz = 0.0;
  int end_of_stream = 0;
  int protocol_version = 0;      ///< The newest version among its frames.
  int min_protocol_version = 0;  ///< The oldest (a sender that mixes them: a new session each).
  double seconds = 0.0;          ///< From its first frame's arrival to its last's.
};

struct TakeInfo {
  std::string path;
  std::string format;  ///< "c3d", "bvh" or "recording"
  int frames = 0;
  double rate_hz = 0.0;
  double seconds = 0.0;  ///< frames / rate, or for a recording the span of its arrivals
  std::string units;
  std::string processor;                     ///< C3D only
  std::vector<std::string> analog_channels;  ///< C3D only: the analog channels' labels.
  int analog_samples_per_frame = 0;          ///< C3D only.
  std::vector<PointInfo> points;             ///< C3D only
  int64_t origin_samples_missing = 0;        ///< C3D only: samples at (0, 0, 0) read as missing
  std::vector<std::string> notes;            ///< C3D only: the reader's notes (C3dTake::notes)
  bool units_guessed = false;                ///< BVH only: from the bones' size, not given.
  std::vector<std::string> joints;           ///< BVH only: "name (type)"
  int end_sites = 0;
  std::vector<RecordedStreamInfo> streams;  ///< Recording only, in order of appearance.
  int64_t messages = 0;                     ///< Recording only.
  int64_t undecodable_marker_frames = 0;    ///< Recording only: marker frames that fail.
  int64_t undecodable_messages = 0;         ///< Recording only: neither a marker frame nor an end.
  size_t ignored_tail_bytes = 0;            ///< Recording only: an interrupted last record.
};

/// Reads a take (a recording by its magic bytes, else by extension .c3d / .bvh,
/// case-insensitive) and summarises it. Throws the reader's errors, or
/// std::invalid_argument for an unknown extension.
TakeInfo InspectTake(const std::string& path);
std::string FormatTakeInfo(const TakeInfo& info);
nlohmann::json TakeInfoJson(const TakeInfo& info);

/// Lower-cased file extension without the dot ("" if none).
std::string FileExtension(const std::string& path);

}  // namespace mocapd
