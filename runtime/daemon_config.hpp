// The daemon's configuration (`mocapd run --config FILE`, format documented field by
// field in config/mocapd.toml): endpoints, subjects and their model files, lookahead,
// window and detector thresholds, frame-accounting limits and the control plane. Loading
// validates everything and throws with the file, line and field of the first problem, so
// a typo is caught at start-up (or at a SIGHUP reload, which then keeps the old config).
#pragma once

#include <map>
#include <memory>
#include <string>
#include <vector>

#include "filters/cleanup_pipeline.hpp"
#include "filters/retarget.hpp"
#include "filters/subject_calibration.hpp"
#include "formats/marker_set.hpp"
#include "formats/subject_file.hpp"
#include "protocol/curve.hpp"

namespace mocapd {

enum class InputPattern { kSub, kPull };

/// A subject the daemon calibrates from its own stream (`calibrate = "live"`): it is
/// solved at once with the template humanoid scaled to the first usable frame, then the
/// subject calibrated from the frames seen so far swaps in once the motion has shown every joint.
struct LiveCalibrationConfig {
  bool enabled = false;
  std::string marker_set;           ///< As configured: a built-in set's name or a path.
  MarkerSetDefinition set;          ///< ...read at load.
  std::vector<std::string> labels;  ///< The stream's marker order (default: the set's).
  std::string out_path;             ///< Where the calibrated subject is written.
  double min_seconds = 10.0;        ///< Motion collected before the first refinement.
  double max_seconds = 60.0;        ///< The last refinement by then swaps in, ready or not.
  /// Interleaved subsets averaged with the whole take's solve in each refinement
  /// (SubjectCalibrationOptions::interleaved_solves; 1: one solve, ~3.5x quicker).
  int interleaved_solves = SubjectCalibrationOptions{}.interleaved_solves;
};

struct SubjectConfig {
  std::string name;        ///< Topic name; frames must carry it.
  int rank = 0;            ///< Its place in the daemon's subject list (set per worker).
  std::string model_path;  ///< Resolved against the config file's directory ("": live).
  double rate_hz = 120.0;
  CleanupOptions cleanup;  ///< Pipeline options (rate, lookahead, window, thresholds).
  SubjectModel model;      ///< Loaded from model_path (live: the template at 1.75 m).
  LiveCalibrationConfig live;
  // Retargeting (optional): the character this actor drives, published beside it.
  std::string character_path;  ///< BVH; empty: no retargeting.
  std::shared_ptr<const Skeleton> character;
  RetargetMap character_map;
  RetargetOptions retarget;
  /// What the map was made from, to make it again for a live calibration's subject.
  std::vector<BvhEndSite> character_end_sites;
  std::map<std::string, std::string> character_joint_map;
};

struct DaemonConfig {
  std::string source;  ///< The file it came from (for messages and reloads).
  // Input.
  std::string input_endpoint = "tcp://127.0.0.1:5555";
  InputPattern input_pattern = InputPattern::kSub;
  bool subscribe_all = false;  ///< SUB: every topic, not just the configured subjects'.
  int receive_high_water_mark = 10000;
  size_t max_message_bytes = 65536;
  /// Data-plane threads, each solving its own subjects (0: one per core, at most one per
  /// subject; a PULL input or subscribe = "all" has one). Fixed at start-up.
  int workers = 0;
  bool pin_workers = false;  ///< Pin worker i to core i (mod the cores).
  /// Scale-out: this daemon solves only the configured subjects whose shard (a hash of the
  /// name, SubjectShard) is shard_index of shard_count; several daemons with the same
  /// subject list and shards 0/n .. n-1/n on one capture feed solve each subject once.
  int shard_index = 0;
  int shard_count = 1;
  std::vector<std::string> other_shards_subjects;  ///< Configured, left to other shards.
  // Output.
  std::string output_endpoint = "tcp://127.0.0.1:5556";
  int send_high_water_mark = 1000;
  bool publish_cleaned_markers = true;
  bool publish_global_transforms = false;
  /// Wire version of everything published: 2 carries each frame's capture session, exact
  /// rate and timecode; 1 for consumers written before version 2.
  int output_protocol_version = 2;
  // Control plane.
  bool http_enabled = true;
  std::string http_address = "127.0.0.1";
  int http_port = 8480;  ///< 0: any free port (logged at start-up).
  /// A file holding the bearer token every HTTP request must carry ("": none); the token
  /// itself is read at load.
  std::string http_token_file;
  std::string http_token;
  int http_max_connections = 64;
  /// The browser live view on the HTTP port (`/`, WebSocket `/live`).
  bool live_view = true;
  double live_view_rate_hz = 30.0;         ///< Frames a second sent to each page.
  int live_view_max_viewers = 8;           ///< Pages open at once; more are refused (503).
  double live_view_close_stalled_s = 5.0;  ///< A page that takes nothing this long is closed.
  double stats_interval_s = 1.0;
  double watchdog_timeout_s = 0.5;
  double model_suspect_mm = 20.0;  ///< Median sample-to-model distance that flags a model.
  double log_interval_s = 10.0;
  bool allow_remote = false;
  // Security: ZeroMQ CURVE on the input and output sockets. Fixed at start-up, except the
  // allow-list, which a reload re-reads.
  bool curve = false;
  std::string curve_key_file;  ///< This daemon's key pair (a .key_secret certificate).
  curve::KeyPair curve_keys;
  /// Directory of the clients' public certificates (*.key) that may connect to the
  /// daemon's CURVE servers: consumers of the output, pushers into a PULL input.
  std::string curve_authorized_keys_dir;
  std::vector<curve::AuthorizedKey> curve_authorized_keys;
  /// SUB input: the capture publisher's public certificate (the daemon is its client).
  std::string curve_input_server_key_file;
  std::string curve_input_server_key;
  // Frame accounting, in time so that it holds at any capture rate (the defaults are the
  // 240 and 120 frames they were at 120 Hz). A config may still give them in frames
  // (max_gap_frames, restart_backjump_frames: taken as given at every rate); -1: from time.
  static constexpr int kMaxGapFrames = 100'000;
  double max_gap_s = 2.0;
  double restart_backjump_s = 1.0;
  int max_gap_frames = -1;
  int restart_backjump_frames = -1;
  /// The rules above in frames at a subject's rate.
  int MaxGapFrames(double rate_hz) const;
  int RestartBackjumpFrames(double rate_hz) const;
  std::vector<SubjectConfig> subjects;

  const SubjectConfig* FindSubject(const std::string& name) const;
};

/// The shard a subject belongs to among shard_count: the 64-bit FNV-1a hash of its name
/// (the wire's model-hash recipe over the one name) modulo shard_count, so every daemon
/// and every operator's script computes the same split.
int SubjectShard(const std::string& name, int shard_count);

/// Parses and validates a config; subject model paths are resolved against base_dir
/// and loaded. Throws std::runtime_error "SOURCE:LINE: field 'a.b': problem".
DaemonConfig ParseDaemonConfig(const std::string& text, const std::string& source_name,
                               const std::string& base_dir);
DaemonConfig LoadDaemonConfig(const std::string& path);

/// What a subject's pipeline is built from (its model and every option it uses): a reload
/// keeps a running pipeline, and its lookahead, when this has not changed.
std::string SubjectFingerprint(const SubjectConfig& subject, const DaemonConfig& config);

/// True for endpoints that only the local machine can reach (loopback tcp, ipc, inproc).
bool IsLocalEndpoint(const std::string& endpoint);

}  // namespace mocapd
