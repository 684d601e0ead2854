// The replay's schedule: sends what a producer makes (marker frames and ends of stream,
// each with its due time) over ZeroMQ, paced by the steady clock, while a receiver thread
// stamps every skeleton that comes back and scores it against the truth; then turns the
// stamps into the latency report. Shared by the take replay and the recording replay.
#pragma once

#include <cstdint>
#include <functional>
#include <string>
#include <unordered_map>
#include <vector>

#include "filters/skeleton.hpp"
#include "protocol/messages.hpp"
#include "sim/replay.hpp"

namespace mocapd::replay {

/// One message to send, produced in order by a FrameProducer.
struct Outgoing {
  size_t subject = 0;
  uint64_t session = 0;  ///< Its capture session where frames are told apart by it (0: not).
  uint64_t frame_number = 0;
  bool end_of_stream = false;
  int64_t due_ns = 0;  ///< Since the start; < 0: as soon as possible.
};

/// Per subject: every message sent (in send order) and when each frame's skeleton came back.
struct SubjectLog {
  std::string name;
  std::string topic;
  Vec3 offset = Vec3::Zero();  ///< Where this actor stands (takes: for the truth).
  struct Sent {
    uint64_t session;
    uint64_t frame_number;
    int64_t sent_ns;
    bool end_of_stream;
  };
  std::vector<Sent> sent;
  /// A frame by its capture session and number: a recording of a capture that restarted
  /// holds the same numbers twice, and matched by number alone its second session read
  /// as lost and duplicated.
  struct FrameKey {
    uint64_t session = 0;
    uint64_t frame_number = 0;
    bool operator==(const FrameKey&) const = default;
  };
  struct FrameKeyHash {
    size_t operator()(const FrameKey& k) const {
      return std::hash<uint64_t>{}(k.frame_number ^ (k.session * 0x9E3779B97F4A7C15ull));
    }
  };
  /// Frame -> arrival (0: not yet); holds every frame that will be sent, inserted before
  /// the run so the receiver thread never changes its shape.
  std::unordered_map<FrameKey, int64_t, FrameKeyHash> received_ns;
  /// The daemon's lookahead K for this subject, from its descriptions: (arrival, K), the
  /// first before the run, then each change (a reload) as the receiver heard it.
  std::vector<std::pair<int64_t, int>> lookahead_since;
  /// K in effect for a skeleton that arrived at arrival_ns.
  int LookaheadAt(int64_t arrival_ns) const;
};

/// Encodes the next message into bytes; false when there is nothing more to send.
using FrameProducer = std::function<bool(Outgoing*, std::vector<uint8_t>*)>;
/// The truth for a received skeleton frame, or nullptr when unknown.
using TruthLookup =
    std::function<const Pose*(size_t subject, uint64_t frame_number, Pose* scratch)>;

/// What a schedule needs beyond its producer.
struct ScheduleSetup {
  uint64_t marker_hash = 0;
  bool check_hash = false;  ///< Refuse a daemon whose subject has another marker set.
  /// Refuse a daemon whose subject is configured for another rate than capture_rate_hz (not
  /// for a recording, whose subjects may each have their own).
  bool check_rate = false;
  TruthLookup truth;                    ///< May be empty.
  const Skeleton* skeleton = nullptr;   ///< The truth's skeleton (nullptr: no accuracy).
  double frame_period_s = 1.0 / 120.0;  ///< A frame later than this is "late".
  /// The frames' own rate (their frame numbers count these), which may differ from the
  /// rate they are sent at (--rate).
  double capture_rate_hz = 120.0;
  /// The stream block a subject's frame was sent with, which a v2 daemon must echo (empty:
  /// not checked).
  std::function<protocol::StreamInfo(size_t subject, uint64_t frame_number)> sent_stream;
  /// Skeletons are matched to sent frames by session id and number (a recording, whose
  /// capture may have restarted), not by number alone.
  bool key_by_session = false;
};

/// Runs the schedule: handshake with the daemon (it subscribed to every subject's topic
/// and described every subject), send, drain, report. Throws std::runtime_error naming
/// the endpoint when the handshake times out or a socket cannot be set up.
ReplayReport RunSchedule(std::vector<SubjectLog>& logs, const FrameProducer& produce,
                         const ScheduleSetup& setup, const ReplayOptions& options);

/// Steady-clock time, ns.
int64_t SteadyNs();

}  // namespace mocapd::replay
