// Per-subject frame accounting, sequencing and output encoding for the daemon.
#include "runtime/subject_runner.hpp"

#include "formats/subject_from_markers.hpp"
#include "runtime/live_calibration.hpp"
#include "runtime/live_view.hpp"

#include <chrono>
#include <cmath>
#include <tuple>
#include <utility>

namespace mocapd {
namespace {

uint64_t WallClockNs() {
  return static_cast<uint64_t>(std::chrono::duration_cast<std::chrono::nanoseconds>(
                                   std::chrono::system_clock::now().time_since_epoch())
                                   .count());
}

// Frame numbers compared as serial numbers (RFC 1982): a is newer than b if it is less
// than half the number space ahead, so a stream that wraps at 2^64 goes on (compared as
// plain numbers, a gap across the wrap dropped every later frame as out of order).
uint64_t Ahead(uint64_t a, uint64_t b) { return a - b; }
bool Newer(uint64_t a, uint64_t b) { return a != b && Ahead(a, b) < (uint64_t{1} << 63); }

// How far a sender's capture clock moved from `from` to `to`, negative if it went back.
double ClockStepS(uint64_t to, uint64_t from) {
  return static_cast<double>(static_cast<int64_t>(to - from)) * 1e-9;
}

int64_t SteadyNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

// A sample's status and reason as published: one of a hole's guided frames, which the
// cleanup took as observed, was never captured, so it is repaired (missing).
std::pair<uint8_t, uint8_t> PublishedStatus(bool guided, MarkerStatus status, MaskReason reason) {
  if (guided && status == MarkerStatus::kObserved)
    return {static_cast<uint8_t>(MarkerStatus::kRepaired),
            static_cast<uint8_t>(MaskReason::kMissing)};
  return {static_cast<uint8_t>(status), static_cast<uint8_t>(reason)};
}

// A frame the subject had already taken: noted as unstable at every such drop.
bool IsRepeat(DropReason reason) {
  return reason == DropReason::kDuplicate || reason == DropReason::kOutOfOrder;
}

}  // namespace

const char* to_string(DropReason reason) {
  switch (reason) {
    case DropReason::kOversized: return "oversized";
    case DropReason::kMalformed: return "malformed";
    case DropReason::kNonFinite: return "non_finite";
    case DropReason::kNotMarkerFrame: return "not_marker_frame";
    case DropReason::kUnknownSubject: return "unknown_subject";
    case DropReason::kModelMismatch: return "model_mismatch";
    case DropReason::kRateMismatch: return "rate_mismatch";
    case DropReason::kDuplicate: return "duplicate";
    case DropReason::kOutOfOrder: return "out_of_order";
  }
  return "?";
}

std::string Topic(std::string_view kind, std::string_view subject) {
  std::string t(kind);
  t += '/';
  t += subject;
  t += '/';
  return t;
}

void LatencyHistogram::Add(double seconds) {
  size_t b = 0;
  while (b < kLatencyBucketsS.size() && seconds > kLatencyBucketsS[b]) ++b;
  ++counts[b];
  sum_s += seconds;
  ++count;
}

uint64_t SubjectCounters::dropped_total() const {
  uint64_t n = 0;
  for (uint64_t d : dropped) n += d;
  return n;
}

SubjectRunner::SubjectRunner(const SubjectConfig& config, const DaemonConfig& daemon)
    : name_(config.name),
      rank_(config.rank),
      fingerprint_(SubjectFingerprint(config, daemon)),
      marker_hash_(protocol::MarkerSetHash(*config.model.markers)),
      skeleton_hash_(protocol::SkeletonHash(*config.model.skeleton)),
      rate_hz_(config.rate_hz),
      max_gap_frames_(daemon.MaxGapFrames(config.rate_hz)),
      restart_backjump_frames_(daemon.RestartBackjumpFrames(config.rate_hz)),
      publish_cleaned_(daemon.publish_cleaned_markers),
      publish_globals_(daemon.publish_global_transforms),
      skeleton_(config.model.skeleton),
      markers_(config.model.markers),
      pipeline_(std::make_unique<CleanupPipeline>(config.model.skeleton, config.model.markers,
                                                  config.cleanup)),
      stamps_(static_cast<size_t>(config.cleanup.lookahead + 2)),
      missing_(static_cast<size_t>(config.model.markers->num_markers()), Vec3::Constant(kNaN)),
      kinematics_(*config.model.skeleton),
      description_(
          protocol::DescribeSubject(config.name, *config.model.skeleton, *config.model.markers,
                                    static_cast<float>(config.rate_hz), config.cleanup.lookahead)),
      skeleton_topic_(Topic("skeleton", config.name)),
      cleaned_topic_(Topic("cleaned", config.name)),
      description_topic_(Topic("subject", config.name)),
      status_topic_(Topic("status", config.name)) {
  const auto joints = static_cast<size_t>(skeleton_->num_joints());
  const auto markers = static_cast<size_t>(config.model.markers->num_markers());
  // The model distance is averaged over about a second.
  model_distance_weight_ = std::min(1.0, 1.0 / config.rate_hz);
  model_suspect_m_ = daemon.model_suspect_mm * 1e-3;
  received_.assign(stamps_.size() * markers, Vec3::Constant(kNaN));
  hole_from_.assign(markers, Vec3::Constant(kNaN));
  hole_remainder_ = hole_guide_ = hole_from_;
  distances_.reserve(markers);
  skeleton_message_.subject = name_;
  skeleton_message_.model_hash = skeleton_hash_;
  skeleton_message_.rotations.resize(joints);
  if (publish_globals_) {
    skeleton_message_.global_rotations.resize(joints);
    skeleton_message_.global_positions.resize(joints);
  }
  cleaned_message_.subject = name_;
  cleaned_message_.model_hash = marker_hash_;
  cleaned_message_.positions.resize(markers);
  cleaned_message_.status.resize(markers);
  cleaned_message_.reason.resize(markers);
  status_message_.subject = name_;
  const auto version = static_cast<uint16_t>(daemon.output_protocol_version);
  description_.version = skeleton_message_.version = cleaned_message_.version = version;
  status_message_.version = character_message_.version = character_description_.version = version;
  if (config.character) {
    retargeter_ = std::make_unique<Retargeter>(config.model.skeleton, config.character,
                                               config.character_map, config.retarget);
    character_path_ = config.character_path;
    const Skeleton& c = *config.character;
    character_fade_.Resize(c);
    last_character_ = RestPose(c);
    character_kinematics_.emplace(c);
    character_topic_ = Topic("character", config.name);
    character_message_.subject = name_;
    character_message_.model_hash = protocol::SkeletonHash(c);
    character_message_.rotations.resize(static_cast<size_t>(c.num_joints()));
    if (publish_globals_) {
      character_message_.global_rotations.resize(static_cast<size_t>(c.num_joints()));
      character_message_.global_positions.resize(static_cast<size_t>(c.num_joints()));
    }
    // The character's description: its joints (it carries no markers).
    protocol::SubjectDescriptionMessage& d = character_description_;
    d.subject = name_;
    d.marker_set_hash = 0;
    d.skeleton_hash = character_message_.model_hash;
    d.rate_hz = static_cast<float>(config.rate_hz);
    d.lookahead_frames = static_cast<uint16_t>(config.cleanup.lookahead);
    for (const Joint& j : c.joints()) {
      d.joint_names.push_back(j.name);
      d.joint_parents.push_back(static_cast<int16_t>(j.parent.is_valid() ? j.parent.value : -1));
      d.rest_offsets.push_back(j.offset);
      d.rest_rotations.push_back(j.rest_rotation);
    }
  }
  // The largest message this runner encodes, so encoding never grows the buffer.
  const size_t character_joints =
      config.character ? static_cast<size_t>(config.character->num_joints()) : 0;
  buffer_.reserve(256 + 64 * markers + 128 * std::max(joints, character_joints));
}

SubjectRunner::~SubjectRunner() = default;

void SubjectRunner::AttachLiveCalibration(std::shared_ptr<LiveCalibration> calibration) {
  live_ = std::move(calibration);
  calibration_topic_ = Topic("calibration", name_);
  // Warm: the lookahead and half a second of history for the incoming subject's detectors
  // and solves. In seconds, so any rate swaps alike.
  const int lookahead = pipeline_->options().lookahead;
  warm_frames_ = std::max(lookahead + 2, static_cast<int>(std::lround(0.5 * rate_hz_)));
  actor_fade_.Resize(*skeleton_);
  // Calibrated already (a reload rebuilt this subject's runner): start from that subject.
  if (std::optional<SubjectModel> calibrated = live_->CalibratedModel()) {
    class Nowhere : public OutputSink {
     public:
      void Send(std::string_view, std::span<const uint8_t>) override {}
    } nowhere;  // nothing was published yet
    Install(live_->Build(std::move(*calibrated)), nowhere);
  }
}

std::optional<CharacterInfo> SubjectRunner::character_info() const {
  if (!retargeter_) return std::nullopt;
  return CharacterInfo{.file = character_path_,
                       .joints = retargeter_->target().num_joints(),
                       .bones_matched = static_cast<int>(retargeter_->map().bones.size()),
                       .scale = retargeter_->scale(),
                       .stands_on = AxisName(retargeter_->map().target_up)};
}

uint64_t SubjectRunner::pending() const { return static_cast<uint64_t>(pushed_ - published_); }

void SubjectRunner::CountDrop(DropReason reason, int64_t receive_ns,
                              const protocol::MarkerFrameMessage& frame) {
  // A drop right after a frame taken (and, in Accept, a frame taken right after drops):
  // input switching between what the subject takes and what it cannot (two bridges with
  // different marker orders taking turns) lost half its frames with /health ok, since no
  // half second was all drops. Repeated frames note their own event, one per frame.
  if (started_ && consecutive_dropped_ == 0 && !IsRepeat(reason))
    NoteUnstableEvent(receive_ns, {UnstableCause::Kind::kTakenAndDropped, reason});
  last_input_ns_ = receive_ns;
  ++counters_.frames_in;
  ++counters_.dropped[static_cast<size_t>(reason)];
  // Drops on either side of a silence (a few at one stream's end, a few at the next's
  // start an hour later) are no half second of them, unless the rejection already stands.
  const bool after_silence =
      consecutive_dropped_ > 0 && receive_ns - last_dropped_ns_ > kRejectingAfterNs;
  // A frame that failed to decode has no number to trust.
  const bool numbered = reason != DropReason::kMalformed && reason != DropReason::kNonFinite;
  if (consecutive_dropped_ == 0 || (after_silence && !rejecting())) {
    consecutive_dropped_ = 0;
    first_dropped_ns_ = receive_ns;
    first_dropped_number_ = frame.frame_number;
    first_dropped_numbered_ = numbered;
    first_dropped_session_ = frame.stream.session_id;
    dropped_capture_span_ns_ = 0;
  }
  ++consecutive_dropped_;
  last_dropped_ns_ = receive_ns;
  // At the rate the frame says it was captured at where the cleanup could run at it (a
  // rate_mismatch frame's own), else at the subject's.
  const double capture_hz = frame.rate_hz >= kMinCaptureRateHz && frame.rate_hz <= kMaxCaptureRateHz
                                ? static_cast<double>(frame.rate_hz)
                                : rate_hz_;
  if (numbered && first_dropped_numbered_ && frame.frame_number > first_dropped_number_ &&
      frame.stream.session_id == first_dropped_session_) {
    const double span_s =
        static_cast<double>(frame.frame_number - first_dropped_number_) / capture_hz;
    dropped_capture_span_ns_ =
        std::max(dropped_capture_span_ns_, static_cast<int64_t>(std::min(span_s, 1e6) * 1e9));
  }
  last_drop_ = reason;
}

void SubjectRunner::NoteUnstableEvent(int64_t receive_ns, UnstableCause cause) {
  // Flagged until kUnstableWithinNs pass with no such event at all, so the flag does not
  // flap and "stable again" is true when it is said.
  if (receive_ns - last_unstable_event_ns_ > kUnstableWithinNs) unstable_ = false;
  last_unstable_event_ns_ = receive_ns;
  unstable_events_ns_[next_unstable_slot_] = receive_ns;
  unstable_causes_[next_unstable_slot_] = cause;
  next_unstable_slot_ = (next_unstable_slot_ + 1) % kUnstableEvents;
  const int64_t oldest = unstable_events_ns_[next_unstable_slot_];  // of the last five
  if (oldest >= 0 && receive_ns - oldest <= kUnstableWithinNs) unstable_ = true;
}

UnstableCause SubjectRunner::unstable_cause() const {
  UnstableCause commonest;
  size_t most = 0;
  // From the latest back, so the latest of equally common causes is kept.
  for (size_t back = 1; back <= kUnstableEvents; ++back) {
    const size_t slot = (next_unstable_slot_ + kUnstableEvents - back) % kUnstableEvents;
    if (unstable_events_ns_[slot] < 0) break;
    size_t count = 0;
    for (size_t other = 0; other < kUnstableEvents; ++other)
      count += unstable_events_ns_[other] >= 0 && unstable_causes_[other] == unstable_causes_[slot];
    if (count > most) {
      most = count;
      commonest = unstable_causes_[slot];
    }
  }
  return commonest;
}

bool SubjectRunner::PrepareHoleGuide(std::span<const Vec3> from, std::span<const Vec3> to) {
  // Only samples the cleanup would take as positions at all: a sender's 1e30 for "not
  // seen" would throw the whole body's fit off.
  const double volume = pipeline_->options().capture_volume_m;
  const auto usable = [volume](const Vec3& p) {
    return p.allFinite() && p.cwiseAbs().maxCoeff() <= volume;
  };
  for (size_t m = 0; m < from.size(); ++m) {
    const bool both = usable(from[m]) && usable(to[m]);
    hole_from_[m] = both ? from[m] : Vec3::Constant(kNaN);
    hole_guide_[m] = both ? to[m] : Vec3::Constant(kNaN);  // the far end, for the fit
  }
  // The rigid fit, then once more without the samples it leaves far off (a ghost, a swapped
  // label): they would tilt the whole body's path.
  Mat3 turn = Mat3::Identity();
  for (int pass = 0; pass < 2; ++pass) {
    Vec3 from_centre = Vec3::Zero(), to_centre = Vec3::Zero();
    int shared = 0;
    for (size_t m = 0; m < from.size(); ++m)
      if (hole_from_[m].allFinite()) {
        from_centre += hole_from_[m];
        to_centre += hole_guide_[m];
        ++shared;
      }
    if (shared < 3) return false;
    from_centre /= shared;
    to_centre /= shared;
    Mat3 covariance = Mat3::Zero();
    for (size_t m = 0; m < from.size(); ++m)
      if (hole_from_[m].allFinite())
        covariance += (hole_guide_[m] - to_centre) * (hole_from_[m] - from_centre).transpose();
    // Kabsch: the rotation taking the first cloud onto the second, never a reflection.
    const Eigen::JacobiSVD<Mat3> svd(covariance, Eigen::ComputeFullU | Eigen::ComputeFullV);
    Mat3 fix = Mat3::Identity();
    fix(2, 2) = (svd.matrixU() * svd.matrixV().transpose()).determinant() < 0.0 ? -1.0 : 1.0;
    turn = svd.matrixU() * fix * svd.matrixV().transpose();
    if (!turn.allFinite()) return false;
    hole_from_centre_ = from_centre;
    hole_to_centre_ = to_centre;
    for (size_t m = 0; m < from.size(); ++m)
      hole_remainder_[m] =
          hole_from_[m].allFinite()
              ? Vec3(hole_guide_[m] - (turn * (hole_from_[m] - from_centre) + to_centre))
              : Vec3::Constant(kNaN);
    if (pass == 1) break;
    // Far off: beyond three times the median remainder and a limb's length in the hole.
    distances_.clear();
    for (const Vec3& r : hole_remainder_)
      if (r.allFinite()) distances_.push_back(r.norm());
    const auto middle = distances_.begin() + static_cast<std::ptrdiff_t>(distances_.size() / 2);
    std::nth_element(distances_.begin(), middle, distances_.end());
    const double far = std::max(3.0 * *middle, 0.5);
    for (size_t m = 0; m < from.size(); ++m)
      if (hole_remainder_[m].allFinite() && hole_remainder_[m].norm() > far)
        hole_from_[m] = Vec3::Constant(kNaN);
  }
  hole_turn_ = Quat(turn).normalized();
  return true;
}

void SubjectRunner::FillHoleGuide(double t) {
  const Quat turn = Quat::Identity().slerp(t, hole_turn_);
  const Vec3 centre = hole_from_centre_ + t * (hole_to_centre_ - hole_from_centre_);
  for (size_t m = 0; m < hole_guide_.size(); ++m)
    hole_guide_[m] = turn * (hole_from_[m] - hole_from_centre_) + centre + t * hole_remainder_[m];
}

void SubjectRunner::InheritCounters(const SubjectRunner& previous) {
  counters_ = previous.counters_;
  last_input_ns_ = previous.last_input_ns_;
  last_receive_ns_ = previous.last_receive_ns_;
  state_ = previous.state_;
  started_ = false;
}

std::optional<DropReason> SubjectRunner::Drop(const protocol::MarkerFrameMessage& frame,
                                              DropReason reason, int64_t receive_ns) {
  // A frame that arrived and was dropped is counted once, as dropped: not again as a
  // skipped number when the next frame taken bridges over it (a sender at the wrong rate
  // for 90 frames showed 90 dropped and 90 skipped). An undecodable frame whose number was
  // not read has number 0, never ahead.
  if (started_ &&
      Ahead(frame.frame_number, next_frame_number_) <= static_cast<uint64_t>(max_gap_frames_) &&
      frame.stream.session_id == counters_.last_stream.session_id)
    ++dropped_ahead_;
  CountDrop(reason, receive_ns, frame);
  return reason;
}

std::optional<DropReason> SubjectRunner::Accept(const protocol::MarkerFrameMessage& frame,
                                                int64_t receive_ns, OutputSink& sink) {
  auto drop = [&](DropReason reason) { return Drop(frame, reason, receive_ns); };
  if (frame.model_hash != marker_hash_ || frame.positions.size() != missing_.size()) {
    mismatched_model_ = {frame.model_hash, frame.positions.size()};
    return drop(DropReason::kModelMismatch);
  }
  // The configured rate, or its NTSC rate (1000/1001 of it: 119.88 Hz for 120), each
  // within 0.1 %. A capture locked to video runs 0.1 % slow, which every rule of the cleanup
  // takes in its stride; at one tolerance alone, the float rounding of how a sender wrote
  // the rate decided (119.88 dropped, 120000/1001 taken).
  // A subject configured at an NTSC rate (119.88: not whole, and 1001/1000 of it is) takes
  // its nominal rate too (120 was dropped, while a 120 subject took 119.88); for 120, 120.12
  // is another rate.
  if (!protocol::CaptureRateAccepted(frame.rate_hz, rate_hz_)) {
    mismatched_rate_hz_ = frame.rate_hz;
    return drop(DropReason::kRateMismatch);
  }

  const bool consecutive = started_ && frame.frame_number == next_frame_number_ &&
                           frame.stream.session_id == counters_.last_stream.session_id;
  // A v2 sender says when its capture restarted: frame numbers of another session are not
  // comparable, whatever their values.
  if (started_ && frame.stream.session_id != counters_.last_stream.session_id) {
    ++counters_.session_changes;
    Resynchronise(sink);
  }
  // Before any bridging: the inserted frames' publishing sets the state, and a stall
  // ended by a frame past a gap went unlogged.
  const bool resumes_stall = state_ == protocol::SubjectState::kStalled;
  const int64_t silence_ns = last_receive_ns_ < 0 ? 0 : receive_ns - last_receive_ns_;
  if (started_ && frame.frame_number != next_frame_number_) {
    if (Newer(frame.frame_number, next_frame_number_)) {
      const uint64_t missing = Ahead(frame.frame_number, next_frame_number_);
      // The stream a long jump back interrupted goes on (newer number and clock): the
      // jump was one late packet, and the numbers between were published already.
      // Bridged, they went out a second time as repaired frames (71 at 60 Hz).
      const bool interrupted_goes_on = interrupted_.has_value() &&
                                       Newer(frame.frame_number, interrupted_->newest) &&
                                       frame.capture_time_ns > interrupted_->capture_ns;
      // Numbers far ahead of the capture clock (two bridges sending one subject, a
      // renumbered stream): nothing was lost. Bridged, a bridge 100 frames ahead of the
      // other had 99 frames inserted for each of its own, and they were counted as skipped.
      // A clock gone back (the other bridge stamped a moment earlier) shares no jump either.
      const bool numbers_outran_clock = clock_trusted() && frame.capture_time_ns != 0 &&
                                        last_capture_ns_ != 0 &&
                                        ClockStepS(frame.capture_time_ns, last_capture_ns_) <
                                            0.5 * (static_cast<double>(missing) + 1.0) / rate_hz_;
      if (!interrupted_goes_on && !numbers_outran_clock)
        counters_.frames_skipped += missing - std::min(missing, dropped_ahead_);
      if (interrupted_goes_on || numbers_outran_clock ||
          missing > static_cast<uint64_t>(max_gap_frames_)) {
        // Not to be bridged (published already, no loss, or too long): start over from
        // this frame.
        Resynchronise(sink);
      } else {
        // Longer than the lookahead, the hole is guided from the last frame taken (the
        // newest pushed) to this one; within it, the cleanup's own fills bridge it.
        const size_t markers = missing_.size();
        const bool guided =
            pushed_ > 0 && missing > static_cast<uint64_t>(pipeline_->options().lookahead) &&
            PrepareHoleGuide(
                std::span<const Vec3>(
                    received_.data() + static_cast<size_t>(pushed_ - 1) % stamps_.size() * markers,
                    markers),
                frame.positions);
        for (uint64_t k = 0; k < missing; ++k) {
          Stamp inserted{next_frame_number_, 0, true, guided, counters_.last_stream};
          inserted.stream.has_timecode = false;  // not known without the capture's clock
          if (guided) FillHoleGuide(static_cast<double>(k + 1) / static_cast<double>(missing + 1));
          Push(guided ? hole_guide_ : missing_, inserted, receive_ns, sink);
          ++counters_.frames_inserted;
        }
      }
    } else {
      const uint64_t back = next_frame_number_ - 1 - frame.frame_number;
      // A restart of the capture numbers frames from the start again while its clock goes
      // on; a late packet has an older timestamp. A long jump back is a restart either way.
      // A session id (v2) settles it: within one session, older is late, never a restart.
      const bool restart = frame.stream.session_id == 0 &&
                           (back >= static_cast<uint64_t>(restart_backjump_frames_) ||
                            (back > 0 && frame.capture_time_ns > last_capture_ns_));
      if (!restart) {
        NoteUnstableEvent(receive_ns,
                          {UnstableCause::Kind::kRepeatedFrame,
                           back == 0 ? DropReason::kDuplicate : DropReason::kOutOfOrder});
        // ++frames_in happens in the drop, so the last frame number stays the newest.
        return drop(back == 0 ? DropReason::kDuplicate : DropReason::kOutOfOrder);
      }
      // Far back with an older clock: a capture whose clock restarted too, or a packet
      // late by more than restart_backjump. Taken as a restart; what follows tells.
      const bool older_clock = frame.capture_time_ns != 0 && last_capture_ns_ != 0 &&
                               frame.capture_time_ns < last_capture_ns_;
      const Interrupted interrupted{next_frame_number_ - 1, last_capture_ns_};
      Resynchronise(sink);
      if (older_clock) interrupted_ = interrupted;
    }
  }
  ++counters_.frames_in;
  ++counters_.frames_accepted;
  if (started_ && consecutive_dropped_ > 0 && !IsRepeat(last_drop_))
    NoteUnstableEvent(receive_ns, {UnstableCause::Kind::kTakenAndDropped, last_drop_});
  consecutive_dropped_ = 0;
  dropped_ahead_ = 0;
  started_ = true;
  last_receive_ns_ = receive_ns;
  last_input_ns_ = receive_ns;
  if (consecutive && frame.capture_time_ns != 0 && last_capture_ns_ != 0) {
    const double step_s = ClockStepS(frame.capture_time_ns, last_capture_ns_);
    const bool agrees = std::abs(step_s * rate_hz_ - 1.0) <= 0.5;
    clock_disagreed_ = clock_disagreed_ || !agrees;
    clock_agreeing_pairs_ = agrees ? std::min(clock_agreeing_pairs_ + 1, kClockPairs) : 0;
  }
  last_capture_ns_ = frame.capture_time_ns;
  counters_.last_frame_number = frame.frame_number;
  counters_.last_stream = frame.stream;
  if (resumes_stall) {
    ++counters_.resumes;
    counters_.resume_frame = frame.frame_number;
    counters_.resume_silence_s = static_cast<double>(silence_ns) * 1e-9;
  }
  if (resynchronised_) {
    counters_.resync_frame = frame.frame_number;
    counters_.resync_session = frame.stream.session_id;
    NoteUnstableEvent(receive_ns, {UnstableCause::Kind::kResynchronisation});
  }
  resynchronised_ = false;
  if (state_ == protocol::SubjectState::kWaiting || state_ == protocol::SubjectState::kStalled)
    state_ = protocol::SubjectState::kTracking;
  if (live_) {
    if (!live_scaled_) ScaleTemplate(frame.positions, sink);
    live_->Offer(frame.positions);
    if (leftovers_) (void)live_->Retire(leftovers_);
    if (!swap_ && !leftovers_ && live_->SwapReady()) {
      swap_ = live_->TakeSwap();
      shadow_base_ = pushed_;
      shadow_outputs_ = 0;
      shadow_has_output_ = false;
    }
  }
  Push(frame.positions,
       Stamp{frame.frame_number, frame.capture_time_ns, false, false, frame.stream}, receive_ns,
       sink);
  return std::nullopt;
}

void SubjectRunner::ScaleTemplate(std::span<const Vec3> positions, OutputSink& sink) {
  // A try at most every 0.1 s: estimating allocates (once it succeeds, never again).
  const auto every = std::max<uint64_t>(1, static_cast<uint64_t>(0.1 * rate_hz_));
  if (scale_tries_++ % every != 0) return;
  size_t valid = 0;
  for (const Vec3& p : positions) valid += LiveCalibration::Plausible(p);
  if (10 * valid < 6 * positions.size()) return;
  std::vector<Vec3> gated(positions.begin(), positions.end());
  for (Vec3& p : gated)
    if (!LiveCalibration::Plausible(p)) p = Vec3::Constant(kNaN);
  const std::optional<double> height = EstimateHeight(*skeleton_, *markers_, 1.75, gated);
  if (!height) return;
  // What the unscaled template held goes out as it was; the scaled one starts with this
  // frame. Building it allocates, once, like the runner's construction.
  Flush(sink);
  Install(
      live_->Build(TemplateSubject(live_->config().set, live_->config().labels, *height, name_)),
      sink);
  live_->Started(*height);
}

void SubjectRunner::AdoptSubject(LiveSwap& incoming) {
  std::swap(pipeline_, incoming.pipeline);
  pipeline_->AdoptCounters(incoming.pipeline->counters());
  std::swap(skeleton_, incoming.model.skeleton);
  std::swap(markers_, incoming.model.markers);
  if (incoming.retargeter) std::swap(retargeter_, incoming.retargeter);
  published_character_ = nullptr;  // may be the outgoing retargeter's
  std::swap(description_, incoming.description);
  skeleton_hash_ = description_.skeleton_hash;
  skeleton_message_.model_hash = skeleton_hash_;
}

void SubjectRunner::Install(std::unique_ptr<LiveSwap> subject, OutputSink& sink) {
  AdoptSubject(*subject);
  pushed_ = published_ = 0;
  frame_base_ = 0;
  live_scaled_ = true;
  PublishDescription(sink);
}

void SubjectRunner::PoseFade::Resize(const Skeleton& skeleton) {
  blended_ = RestPose(skeleton);
  correction_.assign(blended_.rotation.size(), Vec3::Zero());
  offset_.assign(blended_.translation.size(), Vec3::Zero());
}

void SubjectRunner::PoseFade::Start(const Pose& from, const Pose& to, double rate_hz) {
  differ_deg_ = 0.0;
  for (size_t j = 0; j < from.rotation.size(); ++j) {
    Quat c = to.rotation[j].conjugate() * from.rotation[j];
    if (c.w() < 0) c.coeffs() = -c.coeffs();  // the short way: at most 180 degrees
    const Eigen::AngleAxisd turn(c.normalized());
    correction_[j] = turn.angle() * turn.axis();
    differ_deg_ = std::max(differ_deg_, turn.angle() * 180.0 / M_PI);
  }
  for (size_t j = 0; j < from.translation.size(); ++j)
    offset_[j] = from.translation[j] - to.translation[j];
  frames_ = static_cast<int>(std::clamp(
      std::ceil(std::max(0.25, differ_deg_ / kDegPerSecond) * rate_hz), 1.0, 3.0 * rate_hz));
  left_ = frames_;
}

const Pose& SubjectRunner::PoseFade::Next(const Pose& current) {
  const double share = left_ / (frames_ + 1.0);  // of the correction still applied
  --left_;
  for (size_t j = 0; j < blended_.rotation.size(); ++j) {
    const Vec3 c = share * correction_[j];
    const double angle = c.norm();
    blended_.rotation[j] =
        angle > 0 ? Quat(current.rotation[j] * Quat(Eigen::AngleAxisd(angle, c / angle)))
                  : current.rotation[j];
  }
  for (size_t j = 0; j < blended_.translation.size(); ++j)
    blended_.translation[j] = current.translation[j] + share * offset_[j];
  return blended_;
}

void SubjectRunner::SwitchModel(OutputSink& sink) {
  AdoptSubject(*swap_);
  std::swap(frame_base_, shadow_base_);
  actor_fade_.Start(swap_->pipeline->output().pose, pipeline_->output().pose, rate_hz_);
  // The character's fade starts from its last published frame, at the next one.
  character_fade_pending_ = retargeter_ != nullptr && published_ > 0;
  ++swaps_;
  // The new model's fit is measured afresh: the template's distance, averaged on, held a
  // well calibrated subject "model suspect" for a second after its cross-fade.
  distance_frames_ = 0;
  // The outgoing subject is not needed for the fade: back to the calibration thread.
  EndSwap();
  // Consumers learn the new rest pose before its first frame.
  PublishDescription(sink);
}

void SubjectRunner::EndSwap() {
  leftovers_ = std::move(swap_);
  shadow_has_output_ = false;
  if (live_) (void)live_->Retire(leftovers_);
}

void SubjectRunner::ResetPipelines() {
  pipeline_->Reset();
  frame_base_ = 0;
  // A new stream: nothing to fade from.
  actor_fade_.Stop();
  character_fade_.Stop();
  character_fade_pending_ = false;
  shadow_retargeted_ = -1;
  if (!swap_) return;
  // A restart while warming: the incoming subject warms up again on the new stream.
  swap_->pipeline->Reset();
  if (swap_->retargeter) swap_->retargeter->Reset();
  shadow_base_ = shadow_outputs_ = 0;
  shadow_has_output_ = false;
}

void SubjectRunner::Resynchronise(OutputSink& sink) {
  Flush(sink);
  ResetPipelines();
  if (retargeter_) retargeter_->Reset();
  pushed_ = published_ = 0;
  started_ = false;
  ++counters_.restarts;
  counters_.resync_from_frame = counters_.last_frame_number;
  counters_.resync_from_session = counters_.last_stream.session_id;
  resynchronised_ = true;
  interrupted_.reset();
  unobserved_since_ns_ = -1;  // the new stream is judged afresh
}

void SubjectRunner::EndOfStream(OutputSink& sink) {
  Flush(sink);
  ResetPipelines();
  if (retargeter_) retargeter_->Reset();
  pushed_ = published_ = 0;
  started_ = false;
  interrupted_.reset();
  // An ended stream is waiting for the next one, not stalled: the watchdog stays quiet.
  state_ = protocol::SubjectState::kWaiting;
  if (live_) live_->StreamEnded();
  // The next stream is judged afresh: its first frames are not "unobserved for" the
  // minutes since this one ended, and its clock is not distrusted for this one's.
  unobserved_since_ns_ = -1;
  clock_disagreed_ = false;
  clock_agreeing_pairs_ = 0;
  // A stream whose every frame was dropped and then ended is no fixed sender: the rejection
  // stands until a frame is taken (it was cleared here, and logged as over).
  ++counters_.ends_of_stream;
}

void SubjectRunner::Push(std::span<const Vec3> positions, const Stamp& stamp, int64_t receive_ns,
                         OutputSink& sink) {
  const size_t slot = static_cast<size_t>(pushed_) % stamps_.size();
  stamps_[slot] = stamp;
  std::copy(positions.begin(), positions.end(), received_.begin() + slot * positions.size());
  ++pushed_;
  next_frame_number_ = stamp.frame_number + 1;
  if (swap_) {
    shadow_has_output_ = swap_->pipeline->Push(positions);
    if (shadow_has_output_) {
      ++shadow_outputs_;
      if (swap_->retargeter) {
        (void)swap_->retargeter->Retarget(swap_->pipeline->output().pose);
        shadow_retargeted_ = swap_->pipeline->output().frame + shadow_base_;
      }
    }
  }
  if (pipeline_->Push(positions)) Publish(receive_ns, sink);
}

void SubjectRunner::Flush(OutputSink& sink) {
  // While a swap warms up, both pipelines flush in step: the incoming one may take over at
  // any of these frames, and its frame indices must stay aligned with the published one's.
  while (pipeline_->Flush()) {
    if (swap_) shadow_has_output_ = swap_->pipeline->Flush();
    Publish(-1, sink);
  }
  if (swap_) {
    while (swap_->pipeline->Flush()) {
    }
    shadow_has_output_ = false;
  }
}

void SubjectRunner::Publish(int64_t trigger_receive_ns, OutputSink& sink) {
  const int64_t index = pipeline_->output().frame + frame_base_;
  // A swap: once the incoming subject has solved long enough in the shadow, it becomes the
  // published one, the correction back to the outgoing one's pose fading (PoseFade).
  if (swap_ && shadow_outputs_ >= warm_frames_ && shadow_has_output_ &&
      swap_->pipeline->output().frame + shadow_base_ == index)
    SwitchModel(sink);
  const CleanFrame& out = pipeline_->output();
  const Pose* pose = actor_fade_.active() ? &actor_fade_.Next(out.pose) : &out.pose;
  const Stamp& stamp = stamps_[static_cast<size_t>(index) % stamps_.size()];
  ++published_;
  if (stamp.inserted) {
    ++counters_.inserted_published;
  } else {
    ++counters_.frames_published;
  }
  const uint64_t publish_ns = WallClockNs();
  bool repaired = false, observed = false;
  for (MarkerStatus s : out.status) {
    repaired |= s != MarkerStatus::kObserved;
    observed |= s == MarkerStatus::kObserved;
  }
  // A hole's guided samples were never captured: the frame is repaired throughout.
  if (stamp.guided) {
    repaired = true;
    observed = false;
  }
  const bool lost = out.final_solve.status == IkStatus::kTooFewMarkers;
  if (observed)
    unobserved_since_ns_ = -1;
  else if (unobserved_since_ns_ < 0)
    unobserved_since_ns_ = trigger_receive_ns;
  state_ = lost       ? protocol::SubjectState::kLost
           : repaired ? protocol::SubjectState::kRepairing
                      : protocol::SubjectState::kTracking;

  protocol::SkeletonFrameMessage& s = skeleton_message_;
  s.stream = stamp.stream;
  s.frame_number = stamp.frame_number;
  s.capture_time_ns = stamp.capture_ns;
  s.publish_time_ns = publish_ns;
  s.status = static_cast<uint8_t>(out.final_solve.status);
  s.subject_state = state_;
  s.residual_m = std::isfinite(out.final_solve.rms_residual_m)
                     ? static_cast<float>(out.final_solve.rms_residual_m)
                     : 0.0f;
  s.root_translation = pose->translation[0];
  for (size_t j = 0; j < s.rotations.size(); ++j) s.rotations[j] = pose->rotation[j];
  ForwardKinematics(*skeleton_, *pose, &kinematics_);
  if (!stamp.guided) UpdateModelDistance(index, out);
  if (publish_globals_) {
    for (size_t j = 0; j < s.rotations.size(); ++j) {
      s.global_rotations[j] = Quat(kinematics_.R_WJ[j]);
      s.global_positions[j] = kinematics_.p_WJ[j];
    }
  }
  protocol::EncodeSkeletonFrame(s, &buffer_);
  sink.Send(skeleton_topic_, buffer_);

  if (publish_cleaned_) {
    protocol::CleanedMarkersMessage& c = cleaned_message_;
    c.stream = stamp.stream;
    c.frame_number = stamp.frame_number;
    c.capture_time_ns = stamp.capture_ns;
    c.publish_time_ns = publish_ns;
    for (size_t m = 0; m < c.positions.size(); ++m) {
      c.positions[m] = out.markers[m];
      std::tie(c.status[m], c.reason[m]) =
          PublishedStatus(stamp.guided, out.status[m], out.reason[m]);
    }
    protocol::EncodeCleanedMarkers(c, &buffer_);
    sink.Send(cleaned_topic_, buffer_);
  }
  if (retargeter_) {
    // The first frame after a swap may have been retargeted in the shadow already.
    const Pose* character_pose = character_fade_pending_ && shadow_retargeted_ == index
                                     ? &retargeter_->pose()
                                     : &retargeter_->Retarget(out.pose);
    if (character_fade_pending_) {
      character_fade_.Start(last_character_, *character_pose, rate_hz_);
      character_fade_pending_ = false;
    }
    const KinematicsWorkspace* character_kinematics = &retargeter_->kinematics();
    if (character_fade_.active()) {
      character_pose = &character_fade_.Next(*character_pose);
      ForwardKinematics(retargeter_->target(), *character_pose, &*character_kinematics_);
      character_kinematics = &*character_kinematics_;
    }
    const Pose& character = *character_pose;
    published_character_ = character_kinematics;
    std::copy(character.rotation.begin(), character.rotation.end(),
              last_character_.rotation.begin());
    std::copy(character.translation.begin(), character.translation.end(),
              last_character_.translation.begin());
    protocol::SkeletonFrameMessage& c = character_message_;
    c.stream = stamp.stream;
    c.frame_number = stamp.frame_number;
    c.capture_time_ns = stamp.capture_ns;
    c.publish_time_ns = publish_ns;
    c.status = static_cast<uint8_t>(retargeter_->summary().ik.status);
    c.subject_state = state_;
    c.residual_m = std::isfinite(retargeter_->summary().ik.rms_residual_m)
                       ? static_cast<float>(retargeter_->summary().ik.rms_residual_m)
                       : 0.0f;
    c.root_translation = character.translation[0];
    for (size_t j = 0; j < c.rotations.size(); ++j) c.rotations[j] = character.rotation[j];
    if (publish_globals_) {
      const KinematicsWorkspace& k = *character_kinematics;
      for (size_t j = 0; j < c.rotations.size(); ++j) {
        c.global_rotations[j] = Quat(k.R_WJ[j]);
        c.global_positions[j] = k.p_WJ[j];
      }
    }
    protocol::EncodeSkeletonFrame(c, &buffer_);
    sink.Send(character_topic_, buffer_);
    ++counters_.character_frames_published;
  }
  if (live_view_ && live_view_->Watched()) ShowLive(out, index, stamp, publish_ns);
  if (trigger_receive_ns >= 0)
    counters_.processing.Add(static_cast<double>(SteadyNs() - trigger_receive_ns) * 1e-9);
}

void SubjectRunner::ShowLive(const CleanFrame& out, int64_t index, const Stamp& stamp,
                             uint64_t publish_ns) {
  // The steady clock paces the copies: a wall-clock step must not freeze the view.
  LiveViewFrame* v = live_view_->BeginWrite(SteadyNs());
  if (v == nullptr) return;  // too soon, or being read
  v->frame_number = stamp.frame_number;
  v->published_ns = static_cast<int64_t>(publish_ns);
  v->stream = stamp.stream;
  v->state = state_;
  v->residual_m = skeleton_message_.residual_m;
  const size_t markers = v->raw.size();
  const auto received = received_.begin() + static_cast<ptrdiff_t>(static_cast<size_t>(index) %
                                                                   stamps_.size() * markers);
  std::copy(received, received + static_cast<ptrdiff_t>(markers), v->raw.begin());
  for (size_t m = 0; m < markers; ++m) {
    v->cleaned[m] = out.markers[m];
    std::tie(v->status[m], v->reason[m]) =
        PublishedStatus(stamp.guided, out.status[m], out.reason[m]);
  }
  std::copy(kinematics_.p_WJ.begin(), kinematics_.p_WJ.end(), v->joints.begin());
  if (published_character_ != nullptr)
    std::copy(published_character_->p_WJ.begin(), published_character_->p_WJ.end(),
              v->character_joints.begin());
  live_view_->EndWrite();
}

bool SubjectRunner::CheckStall(int64_t now_ns, int64_t timeout_ns, OutputSink& sink) {
  if (last_receive_ns_ < 0 || state_ == protocol::SubjectState::kStalled ||
      state_ == protocol::SubjectState::kWaiting || now_ns - last_receive_ns_ <= timeout_ns)
    return false;
  // The frames the lookahead holds go out now (their open gaps one-sided): a consumer
  // must not wait for a feed that may never come back to see them.
  Flush(sink);
  state_ = protocol::SubjectState::kStalled;
  unobserved_since_ns_ = -1;
  ++counters_.stalls;
  counters_.stall_silence_s = static_cast<double>(now_ns - last_receive_ns_) * 1e-9;
  counters_.stall_last_frame = counters_.last_frame_number;
  PublishStatus(now_ns, sink);
  return true;
}

// Every received sample counts, not only those the cleanup kept: the cleanup keeps the
// samples that fit, so a model that fits badly shows as samples thrown away rather than as
// large residuals of the kept ones. The distance two thirds of the samples come within:
// corruption of under a third of them (swaps, spikes) does not move it, and a model that
// fits only most of the body does (another actor's proportions: 40 % of a clean stream's
// samples thrown away while the median, 13 mm, stayed under the 20 mm that flags). A received
// sample whose label the cleanup holds as missing is left out: what the ingest gates took as no
// position at all (beyond the capture volume, a whole frame that jumped; counted, one
// frame 1 km off held the subject "model suspect" for 5 s, its distance decaying from
// 13 m), and a sample the swap detector moved onto another, missing label.
void SubjectRunner::UpdateModelDistance(int64_t frame, const CleanFrame& out) {
  // A fade's poses are neither subject's solve: they fit neither model.
  if (actor_fade_.active()) return;
  const size_t count = missing_.size();
  const Vec3* received = received_.data() + static_cast<size_t>(frame) % stamps_.size() * count;
  distances_.clear();
  for (size_t m = 0; m < count; ++m) {
    if (!received[m].allFinite() || out.reason[m] == MaskReason::kMissing) continue;
    const double d =
        (received[m] - EvaluateMarker(markers_->marker(static_cast<int>(m)), kinematics_)).norm();
    if (std::isfinite(d)) distances_.push_back(d);
  }
  if (distances_.size() < 3) return;
  // (n - 1) * 2 / 3: of 3 samples the middle one, so one bad sample of few is outvoted.
  const auto third =
      distances_.begin() + static_cast<std::ptrdiff_t>((distances_.size() - 1) * 2 / 3);
  std::nth_element(distances_.begin(), third, distances_.end());
  // After a swap the mean starts afresh: a plain mean of the frames so far until it has as
  // many as the running mean spans, so no single first frame stands for the new model.
  ++distance_frames_;
  const double weight =
      std::max(model_distance_weight_, 1.0 / static_cast<double>(distance_frames_));
  model_distance_m_ += weight * (*third - model_distance_m_);
  // A live subject's template is an approximation until its calibration swaps in.
  if (model_distance_m_ > model_suspect_m_ && !(live_ && swaps_ == 0)) model_suspect_ = true;
  if (model_distance_m_ < 0.75 * model_suspect_m_) model_suspect_ = false;
}

void SubjectRunner::PublishDescription(OutputSink& sink) {
  protocol::EncodeSubjectDescription(description_, &buffer_);
  sink.Send(description_topic_, buffer_);
  if (retargeter_) {
    protocol::EncodeSubjectDescription(character_description_, &buffer_);
    sink.Send(character_topic_, buffer_);
  }
}

void SubjectRunner::PublishStatus(int64_t now_ns, OutputSink& sink) {
  protocol::SubjectStatusMessage& m = status_message_;
  m.state = state_;
  m.problems = static_cast<uint8_t>((model_suspect_ ? protocol::kProblemModelSuspect : 0) |
                                    (rejecting() ? protocol::kProblemRejectingInput : 0) |
                                    (unstable_input(now_ns) ? protocol::kProblemUnstableInput : 0));
  m.last_frame_number = counters_.last_frame_number;
  m.since_last_input_ns =
      last_receive_ns_ < 0 ? 0
                           : static_cast<uint64_t>(std::max<int64_t>(0, now_ns - last_receive_ns_));
  m.frames_in = counters_.frames_in;
  m.frames_out = counters_.frames_published + counters_.inserted_published;
  m.frames_dropped = counters_.dropped_total();
  protocol::EncodeSubjectStatus(m, &buffer_);
  sink.Send(status_topic_, buffer_);
  if (live_) live_->SendStatus(sink, calibration_topic_, skeleton_hash_);
}

}  // namespace mocapd
