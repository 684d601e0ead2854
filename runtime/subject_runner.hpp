// One live subject inside the daemon: checks each incoming marker frame against the
// subject's model and frame sequence, feeds the cleanup pipeline (inserting all-missing
// frames for missing frame numbers, re-synchronising on a capture restart), and encodes
// every published frame for the output sink. No sockets here, so the frame accounting
// can be tested directly; the data plane owns the sockets. Accept, Flush and the
// encoders allocate nothing after the first frames (the pipeline and the messages are
// sized at construction).
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "filters/cleanup_pipeline.hpp"
#include "filters/retarget.hpp"
#include "protocol/messages.hpp"
#include "runtime/daemon_config.hpp"

namespace mocapd {

class LiveViewSlot;
class LiveCalibration;
struct LiveSwap;

/// Why an incoming message was not turned into a published frame.
enum class DropReason : uint8_t {
  kOversized,       ///< Longer than input.max_message_bytes.
  kMalformed,       ///< Failed to decode (bad header, sizes, fields) or had too many parts.
  kNonFinite,       ///< A valid marker or the rate was NaN or Inf.
  kNotMarkerFrame,  ///< A well-formed message of another type.
  kUnknownSubject,  ///< No configured subject of that name.
  kModelMismatch,   ///< Marker-set hash or marker count differs from the subject's model.
  kRateMismatch,    ///< Capture rate differs from the subject's configured rate.
  kDuplicate,       ///< The frame number just received, again.
  kOutOfOrder,      ///< Older than the newest frame already received.
};
inline constexpr int kDropReasonCount = 9;
const char* to_string(DropReason reason);

/// What made input unstable: a re-synchronisation, a repeated frame (duplicate or out of
/// order: `reason`), or a switch between frames taken and frames dropped as `reason`.
struct UnstableCause {
  enum class Kind : uint8_t { kResynchronisation, kRepeatedFrame, kTakenAndDropped };
  Kind kind = Kind::kResynchronisation;
  DropReason reason = DropReason::kMalformed;  ///< (not for a re-synchronisation)
  bool operator==(const UnstableCause&) const = default;
};

/// Where a runner's output goes (the data plane's PUB socket, or a test's recorder).
class OutputSink {
 public:
  virtual ~OutputSink() = default;
  virtual void Send(std::string_view topic, std::span<const uint8_t> message) = 0;
};

/// Fixed latency buckets (upper bounds, seconds) for the Prometheus histogram.
inline constexpr std::array<double, 13> kLatencyBucketsS = {
    25e-6, 50e-6, 100e-6, 250e-6, 500e-6, 1e-3, 2.5e-3, 5e-3, 10e-3, 25e-3, 50e-3, 100e-3, 1.0};

struct LatencyHistogram {
  std::array<uint64_t, kLatencyBucketsS.size() + 1> counts{};  ///< Last: above every bound.
  double sum_s = 0.0;
  uint64_t count = 0;
  void Add(double seconds);
};

struct SubjectCounters {
  uint64_t frames_in = 0;           ///< Marker frames received for this subject (accepted or not).
  uint64_t frames_accepted = 0;     ///< Pushed into the pipeline.
  uint64_t frames_published = 0;    ///< Published frames that came in (not inserted).
  uint64_t frames_inserted = 0;     ///< All-missing frames pushed for missing frame numbers...
  uint64_t inserted_published = 0;  ///< ...and how many of those were published.
  std::array<uint64_t, kDropReasonCount> dropped{};
  uint64_t restarts = 0;  ///< Capture restarts and long jumps re-synchronised.
  /// Frame numbers that never arrived: forward gaps within a capture session, bridged with
  /// inserted frames or (too long) re-synchronised. Lost before the daemon or by the sender.
  uint64_t frames_skipped = 0;
  uint64_t session_changes = 0;  ///< Restarts a v2 sender announced with a new session id.
  uint64_t stalls = 0;           ///< Times the watchdog saw the input stall.
  uint64_t ends_of_stream = 0;  ///< End-of-stream messages (not frames: outside the frame balance).
  /// Character frames sent: one per published frame while the subject drives a character.
  uint64_t character_frames_published = 0;
  LatencyHistogram processing;  ///< Receive of the frame that completed a publication -> its send.
  uint64_t last_frame_number = 0;
  // What the log says of an event, as it was when it happened: the control plane reads
  // these counters once a second, by when last_frame_number has moved on.
  double stall_silence_s = 0.0;      ///< The last stall: how long no frame had come...
  uint64_t stall_last_frame = 0;     ///< ...after this frame number.
  uint64_t resumes = 0;              ///< Stalls ended by a frame accepted...
  uint64_t resume_frame = 0;         ///< ...the last of which this was...
  double resume_silence_s = 0.0;     ///< ...after this long without a frame taken.
  uint64_t resync_frame = 0;         ///< The frame the last re-synchronised stream began at...
  uint64_t resync_from_frame = 0;    ///< ...the last frame taken before it...
  uint64_t resync_from_session = 0;  ///< ...and their capture sessions (0: a v1 sender).
  uint64_t resync_session = 0;       ///< (the session of resync_frame)
  protocol::StreamInfo last_stream;  ///< The last accepted frame's session, rate and timecode.
  uint64_t dropped_total() const;
};

/// What a subject's character is and how it matched the actor, for /subjects.
struct CharacterInfo {
  std::string file;
  int joints = 0;
  int bones_matched = 0;  ///< Roles found on both rigs (of 21).
  double scale = 1.0;     ///< The leg-length ratio, character over actor.
  std::string stands_on;  ///< The axis its rest pose stands on, e.g. "+y".
};

class SubjectRunner {
 public:
  /// Copies what it needs from the configs; they need not outlive the runner.
  SubjectRunner(const SubjectConfig& config, const DaemonConfig& daemon);

  const std::string& name() const { return name_; }
  int rank() const { return rank_; }
  const std::string& fingerprint() const { return fingerprint_; }

  /// Takes one decoded marker frame of this subject, received at receive_ns (steady
  /// clock). Publishes whatever became final through sink. Returns the drop reason if
  /// the frame was rejected (and counts it), nothing otherwise.
  std::optional<DropReason> Accept(const protocol::MarkerFrameMessage& frame, int64_t receive_ns,
                                   OutputSink& sink);
  /// Counts a frame of this subject as dropped for reason: one Accept rejected, or one
  /// that failed to decode after its subject's name (frame holds what was read of it). A
  /// drop numbered within the gap the next frame taken bridges is not counted again as a
  /// skipped number.
  std::optional<DropReason> Drop(const protocol::MarkerFrameMessage& frame, DropReason reason,
                                 int64_t receive_ns);
  /// Publishes everything still held in the lookahead (shutdown, reload, restart).
  void Flush(OutputSink& sink);
  /// The sender says the stream ended: publish the lookahead now; the next frame starts afresh.
  void EndOfStream(OutputSink& sink);
  /// Marks the subject stalled if no input came for timeout_ns: publishes the frames the
  /// lookahead holds (open gaps one-sided) and a status message, once when it happens;
  /// returns true on that transition.
  bool CheckStall(int64_t now_ns, int64_t timeout_ns, OutputSink& sink);
  /// Publishes the subject's description and status (every stats tick).
  void PublishDescription(OutputSink& sink);
  void PublishStatus(int64_t now_ns, OutputSink& sink);

  /// Frames in the pipeline not yet published (received and inserted ones).
  uint64_t pending() const;
  /// Of those, the received ones: frames in = published + dropped + this.
  uint64_t pending_received() const {
    return pending() - (counters_.frames_inserted - counters_.inserted_published);
  }
  protocol::SubjectState state() const { return state_; }
  /// How long nothing but drops must go on (and over how many frames at least) before the
  /// input is called rejected; the daemon holds its own drops before any subject is named
  /// to the same.
  static constexpr uint64_t kRejectingMinFrames = 10;
  static constexpr int64_t kRejectingAfterNs = 500'000'000;
  /// Every frame received over the last half second (10 at least) was dropped: the reason
  /// of the last. Judged by the time the drops span, not their count: counted at the
  /// subject's rate, a 60 Hz sender into a 360 Hz subject was flagged after 3 s. That time
  /// is the longer of their arrival and their capture (their frame numbers at the rate
  /// they were sent at): a backlog or a replay at full speed arrives in a burst, and 480
  /// frames of a 100 Hz take, every one dropped, left /health ok.
  std::optional<DropReason> rejecting() const {
    return consecutive_dropped_ >= kRejectingMinFrames &&
                   std::max(last_dropped_ns_ - first_dropped_ns_, dropped_capture_span_ns_) >=
                       kRejectingAfterNs
               ? std::optional<DropReason>(last_drop_)
               : std::nullopt;
  }
  /// The stream re-synchronised, was sent frames it had already taken (duplicate, out
  /// of order), or switched between taking and dropping frames, kUnstableEvents times within
  /// kUnstableWithinNs, and the last of those was less than kUnstableWithinNs before
  /// now_ns. No capture restarts that often, and ZeroMQ neither repeats nor reorders: two
  /// bridges sending one subject, or one writing a new session id into every frame (the
  /// cleanup without its lookahead, or half the input dropped, and /health ok).
  bool unstable_input(int64_t now_ns) const {
    return unstable_ && now_ns - last_unstable_event_ns_ <= kUnstableWithinNs;
  }
  /// The commonest cause among the last kUnstableEvents events (the latest of equals): a
  /// sender writing NaN into some frames was told "two senders for one subject?".
  UnstableCause unstable_cause() const;
  /// How far the received samples sit from the model's markers in the solved pose (the
  /// distance two thirds of a frame's samples come within, averaged over about a second),
  /// metres; a model that
  /// does not fit the actor (another subject's, the wrong scale) keeps it high and is
  /// suspect.
  double model_distance_m() const { return model_distance_m_; }
  bool model_suspect() const { return model_suspect_; }
  /// The character it drives (empty: none), for /subjects.
  std::optional<CharacterInfo> character_info() const;
  /// The rate the last frame dropped as rate_mismatch said it was captured at (0: none).
  double mismatched_rate_hz() const { return mismatched_rate_hz_; }
  /// The last model_mismatch frame's marker-set hash and marker count.
  std::pair<uint64_t, size_t> mismatched_model() const { return mismatched_model_; }
  int64_t last_receive_ns() const { return last_receive_ns_; }
  /// When a frame for this subject last arrived, taken or dropped (-1: never).
  int64_t last_input_ns() const { return last_input_ns_; }
  /// Receive time of the frame that published the first of the current run of frames in
  /// which no marker was observed (-1: the last frame published had one): a pose guessed
  /// from nothing, whether the subject reads lost or repairing. -1 too once the stream ended
  /// or stalled: nothing is published or guessed then (an actor who left the volume before
  /// an end of stream held /health degraded for good).
  int64_t unobserved_since_ns() const {
    return state_ == protocol::SubjectState::kWaiting || state_ == protocol::SubjectState::kStalled
               ? -1
               : unobserved_since_ns_;
  }
  const SubjectCounters& counters() const { return counters_; }
  const CleanupCounters& cleanup_counters() const { return pipeline_->counters(); }
  /// The daemon stops: nothing more is published, so the last status says waiting (it
  /// said tracking, and a display showed the actor live after the daemon had exited).
  void StopPublishing() { state_ = protocol::SubjectState::kWaiting; }
  /// Carries the counters of a runner this one replaces (a reload changed its model), and
  /// its input's state: a stalled subject stays stalled, and a live one is watched for a
  /// stall from its last frame (rebuilt as waiting, a dead sender's subject read ok).
  void InheritCounters(const SubjectRunner& previous);
  const protocol::SubjectDescriptionMessage& description() const { return description_; }
  /// From now on, hands a published frame to the browser view's slot while someone
  /// watches (at most the view's rate; never waiting for it).
  void AttachLiveView(std::shared_ptr<LiveViewSlot> slot) { live_view_ = std::move(slot); }
  /// Makes this a live-calibrated subject: the template is scaled to the first usable
  /// frame, frames are offered to the calibration, and its calibrated subject swaps in at
  /// a frame boundary: solved in the shadow of the published one until it is warm, then
  /// cross-faded in (no frame lost, no pop).
  void AttachLiveCalibration(std::shared_ptr<LiveCalibration> calibration);
  /// Calibrated subjects swapped in (0 or 1), and whether a swap is under way.
  int swaps() const { return swaps_; }
  bool swapping() const { return swap_ != nullptr; }
  /// The swapped-in subject's poses are still being faded in.
  bool fading() const { return actor_fade_.active(); }
  /// The last swap: how far the subjects' joints differed when it began, and its fade.
  double fade_differ_deg() const { return actor_fade_.differ_deg(); }
  double fade_seconds() const { return actor_fade_.frames() / rate_hz_; }
  /// The same for the character the subject drives.
  bool character_fading() const { return character_fade_.active(); }
  double character_fade_differ_deg() const { return character_fade_.differ_deg(); }
  double character_fade_seconds() const { return character_fade_.frames() / rate_hz_; }
  ~SubjectRunner();

 private:
  // A fade from one solve onto another: at its start each joint's new rotation is
  // corrected back to the old one's (new * C = old) and each translated joint (the root,
  // a character's free hips under a fixed root) moved back onto the old one's, and that
  // correction, fixed from then on, decays to nothing. Not a slerp between
  // the two solves as they go on: two rotations near 180 degrees apart would have their
  // shortest path flip sides mid-fade (seen: a forearm turning 167 degrees in one frame on
  // CMU 01_01). It lasts a quarter of a second, or as long as undoing the largest
  // correction at kDegPerSecond takes: the template and the calibrated subject can
  // disagree on a segment's twist by 100 degrees and more.
  class PoseFade {
   public:
    static constexpr double kDegPerSecond = 60.0;
    void Resize(const Skeleton& skeleton);  // allocates
    void Start(const Pose& from, const Pose& to, double rate_hz);
    void Stop() { left_ = 0; }
    bool active() const { return left_ > 0; }
    int frames() const { return frames_; }
    double differ_deg() const { return differ_deg_; }
    /// The next frame of the fade applied to `current`; needs active().
    const Pose& Next(const Pose& current);

   private:
    std::vector<Vec3> correction_;  // per joint, new * exp(c) = old at the start
    std::vector<Vec3> offset_;      // per joint, old - new translation at the start
    int frames_ = 0, left_ = 0;
    double differ_deg_ = 0.0;
    Pose blended_;
  };
  struct Stamp {
    uint64_t frame_number = 0;
    uint64_t capture_ns = 0;
    bool inserted = false;
    /// Inserted with the hole's guide for samples (PrepareHoleGuide): published as repaired.
    bool guided = false;
    protocol::StreamInfo stream;  ///< Carried to the outputs (an inserted frame: no timecode).
  };
  /// A hole in the frame numbers longer than the lookahead is bridged all at once, both of
  /// its ends known: its inserted frames get samples moved from the last frame taken to the
  /// arriving one, the whole body rigidly (the best rotation and translation between the
  /// two, interpolated) and each marker's remainder linearly. Inserted empty, the skeleton
  /// held still through the hole and then swept to its far end over the lookahead's frames
  /// (1.6 m in 12 frames for a 1.5 s hole in a walk). False (nothing prepared) when the two
  /// ends share fewer than 3 samples.
  bool PrepareHoleGuide(std::span<const Vec3> from, std::span<const Vec3> to);
  /// The guide's samples at fraction t (0..1) of the way, into hole_guide_.
  void FillHoleGuide(double t);
  void Push(std::span<const Vec3> positions, const Stamp& stamp, int64_t receive_ns,
            OutputSink& sink);
  void Publish(int64_t trigger_receive_ns, OutputSink& sink);
  void UpdateModelDistance(int64_t frame, const CleanFrame& out);
  void Resynchronise(OutputSink& sink);
  void CountDrop(DropReason reason, int64_t receive_ns, const protocol::MarkerFrameMessage& frame);
  void ShowLive(const CleanFrame& out, int64_t index, const Stamp& stamp, uint64_t publish_ns);
  void ScaleTemplate(std::span<const Vec3> positions, OutputSink& sink);
  /// Trades the published subject (pipeline, model, retargeter, description) for
  /// incoming's, which then holds the old one; the counts carry over.
  void AdoptSubject(LiveSwap& incoming);
  /// Makes a subject the published one at once (nothing pending: flushed before).
  void Install(std::unique_ptr<LiveSwap> subject, OutputSink& sink);
  void SwitchModel(OutputSink& sink);  // the swap's subject becomes the published one
  void EndSwap();                      // its leftovers go back to the calibration
  void ResetPipelines();               // a restart: both pipelines start afresh

  std::string name_;
  int rank_ = 0;
  std::string fingerprint_;
  uint64_t marker_hash_ = 0;
  uint64_t skeleton_hash_ = 0;
  double rate_hz_ = 0.0;
  double mismatched_rate_hz_ = 0.0;
  std::pair<uint64_t, size_t> mismatched_model_{0, 0};
  std::string character_path_;
  int max_gap_frames_ = 0;
  int restart_backjump_frames_ = 0;
  bool publish_cleaned_ = true;
  bool publish_globals_ = false;
  std::shared_ptr<const Skeleton> skeleton_;
  std::shared_ptr<const MarkerSet> markers_;
  std::unique_ptr<CleanupPipeline> pipeline_;
  int64_t frame_base_ = 0;     ///< Frames pushed before pipeline_'s first (a swap's offset).
  std::vector<Stamp> stamps_;  ///< Ring by pipeline frame: what each pushed frame was.
  int64_t pushed_ = 0;         ///< Frames pushed since the last reset.
  int64_t published_ = 0;      ///< Frames published since the last reset.
  bool started_ = false;
  bool resynchronised_ = false;  // the next frame accepted begins the new stream
  // The stream a jump back with an older clock interrupted (v1): its newest frame and time.
  struct Interrupted {
    uint64_t newest = 0;
    uint64_t capture_ns = 0;
  };
  std::optional<Interrupted> interrupted_;
  uint64_t next_frame_number_ = 0;
  uint64_t last_capture_ns_ = 0;
  // The sender's capture clock, judged on consecutive frames: trusted while every pair seen
  // stepped a frame period (+-50 %), or once the last kClockPairs did again. A forward jump
  // in frame numbers that a trusted clock does not share was no loss; a clock in other
  // units, or stamped at bursty sends, is not judged. Trusted before any disagreement, not
  // only after kClockPairs agreed: a second bridge joining in the first frames had its
  // 100-frame lead bridged with 99 inserted frames.
  static constexpr int kClockPairs = 8;
  bool clock_disagreed_ = false;
  int clock_agreeing_pairs_ = 0;
  bool clock_trusted() const { return !clock_disagreed_ || clock_agreeing_pairs_ >= kClockPairs; }
  void NoteUnstableEvent(int64_t receive_ns, UnstableCause cause);
  static constexpr size_t kUnstableEvents = 5;
  static constexpr int64_t kUnstableWithinNs = 2'000'000'000;
  std::array<int64_t, kUnstableEvents> unstable_events_ns_{-1, -1, -1, -1, -1};  // a ring
  std::array<UnstableCause, kUnstableEvents> unstable_causes_{};                 // beside it
  size_t next_unstable_slot_ = 0;
  int64_t last_unstable_event_ns_ = 0;
  bool unstable_ = false;
  int64_t last_receive_ns_ = -1;
  int64_t last_input_ns_ = -1;
  int64_t unobserved_since_ns_ = -1;
  protocol::SubjectState state_ = protocol::SubjectState::kWaiting;
  uint64_t consecutive_dropped_ = 0;
  uint64_t dropped_ahead_ = 0;    ///< Drops since the last frame taken numbered past it.
  int64_t first_dropped_ns_ = 0;  ///< Receive times of the first and last of those drops.
  int64_t last_dropped_ns_ = 0;
  uint64_t first_dropped_number_ = 0;  ///< Frame number and session of the first of them.
  uint64_t first_dropped_session_ = 0;
  bool first_dropped_numbered_ = false;  ///< It decoded: its number can be trusted.
  int64_t dropped_capture_span_ns_ = 0;  ///< The capture time their frame numbers span.
  DropReason last_drop_ = DropReason::kMalformed;
  std::vector<Vec3> received_;           ///< Ring like stamps_: each held frame's samples.
  std::vector<double> distances_;        ///< Publish scratch: sample-to-model distances.
  double model_distance_m_ = 0.0;        // running mean over about a second
  int64_t distance_frames_ = 0;          // frames in the mean since the start or a swap
  double model_distance_weight_ = 0.01;  // its weight per frame
  double model_suspect_m_ = 0.02;
  bool model_suspect_ = false;
  SubjectCounters counters_;
  std::vector<Vec3> missing_;  ///< An all-missing frame.
  // The hole guide (PrepareHoleGuide), sized at construction.
  std::vector<Vec3> hole_from_, hole_remainder_, hole_guide_;
  Vec3 hole_from_centre_ = Vec3::Zero(), hole_to_centre_ = Vec3::Zero();
  Quat hole_turn_ = Quat::Identity();
  KinematicsWorkspace kinematics_;
  protocol::SubjectDescriptionMessage description_;
  protocol::SkeletonFrameMessage skeleton_message_;
  protocol::CleanedMarkersMessage cleaned_message_;
  protocol::SubjectStatusMessage status_message_;
  // Retargeting onto the subject's character, when configured.
  std::unique_ptr<Retargeter> retargeter_;
  protocol::SkeletonFrameMessage character_message_;
  protocol::SubjectDescriptionMessage character_description_;
  std::string character_topic_;
  std::vector<uint8_t> buffer_;
  std::shared_ptr<LiveViewSlot> live_view_;
  // Live calibration.
  std::shared_ptr<LiveCalibration> live_;
  bool live_scaled_ = false;
  uint64_t scale_tries_ = 0;
  std::unique_ptr<LiveSwap> swap_;       ///< The incoming subject, warming up in the shadow.
  std::unique_ptr<LiveSwap> leftovers_;  ///< Waiting to go back to the calibration thread.
  int64_t shadow_base_ = 0;              ///< Frames pushed before the shadow pipeline's first.
  int64_t shadow_outputs_ = 0;
  bool shadow_has_output_ = false;  ///< The last push gave the shadow an output.
  int warm_frames_ = 0;
  int swaps_ = 0;
  PoseFade actor_fade_;  ///< The published skeleton, from the outgoing subject's solve.
  // The character, from what the outgoing subject's retargeter last published: the
  // incoming retargeter, warmed on the incoming subject's own solves, goes on from them,
  // and its output fades in from the last character frame the stage saw. (Retargeting the
  // actor's faded pose instead threw a CMU actor's character hand 20 cm at the swap: the
  // new subject's bones are not the old one's.)
  PoseFade character_fade_;
  bool character_fade_pending_ = false;  ///< Start it at the next published frame.
  /// The shadow's last retargeted frame (its pipeline's numbering; -1: none): the frame a
  /// swap publishes first was retargeted by the incoming retargeter already, and solving
  /// it again would see the feet stand still for a frame.
  int64_t shadow_retargeted_ = -1;
  Pose last_character_;                                      ///< The last character pose published.
  std::optional<KinematicsWorkspace> character_kinematics_;  ///< Of the faded character pose.
  /// The character's joints as last published (the retargeter's, or the fade's).
  const KinematicsWorkspace* published_character_ = nullptr;
  std::string calibration_topic_;
  std::string skeleton_topic_, cleaned_topic_, description_topic_, status_topic_;
};

/// Topic strings: "<kind>/<subject>/" so that a prefix subscription to one subject never
/// matches another whose name it starts (actor1 vs actor10).
std::string Topic(std::string_view kind, std::string_view subject);

}  // namespace mocapd
