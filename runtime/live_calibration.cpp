// Live calibration: frame collection, refinements, readiness and the hand-over.
#include "runtime/live_calibration.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>

#include "formats/retarget_map.hpp"
#include "formats/subject_from_markers.hpp"
#include "runtime/subject_runner.hpp"

namespace mocapd {
namespace {

// Each joint's centre relative to its parent's (its offset): what a refinement moves. Not
// in the pelvis's frame, where a spine's change would move every joint above it.
std::vector<Vec3> RestCentres(const Skeleton& skeleton) {
  std::vector<Vec3> centres;
  for (int j = 0; j < skeleton.num_joints(); ++j)
    centres.push_back(skeleton.joint(j).parent.is_valid() ? skeleton.joint(j).offset
                                                          : Vec3::Zero());
  return centres;
}

}  // namespace

const char* to_string(LiveCalibrationState state) {
  return protocol::to_string(static_cast<protocol::CalibrationState>(state));
}

LiveCalibration::LiveCalibration(const SubjectConfig& subject, const DaemonConfig& daemon)
    : subject_(subject),
      fingerprint_(SubjectFingerprint(subject, daemon)),
      output_version_(daemon.output_protocol_version),
      markers_(static_cast<size_t>(subject.model.markers->num_markers())) {
  // Kept frames are about kSampleHz whatever the capture rate: refinements cost the same
  // at 60 and 360 Hz, and neighbouring frames at 360 Hz add nothing but noise.
  sample_every_ = std::max(1, static_cast<int>(std::lround(subject.rate_hz / kSampleHz)));
  const double kept_hz = subject.rate_hz / sample_every_;
  capacity_ =
      static_cast<size_t>(std::ceil(std::min(subject.live.max_seconds, kMaxKeptSeconds) * kept_hz));
  frames_.assign(capacity_ * markers_, Vec3::Constant(kNaN));
  const Skeleton& skeleton = *subject.model.skeleton;
  for (int j = 0; j < skeleton.num_joints(); ++j) {
    JointReadiness r;
    r.name = skeleton.joint(j).name;
    status_.joints.push_back(r);
  }
  status_message_.version = static_cast<uint16_t>(output_version_);
  status_message_.subject = subject.name;
  status_message_.joints.resize(static_cast<size_t>(skeleton.num_joints()));
  status_bytes_.reserve(128 + protocol::kMaxSubjectName + 10 * status_message_.joints.size());
  EncodeStatus();
}

std::string JointsNotReady(const std::vector<JointReadiness>& joints) {
  std::string names;
  for (const JointReadiness& j : joints)
    if (!j.ready) names += (names.empty() ? "" : ", ") + j.name;
  return names;
}

void LiveCalibration::Started(double height_m) {
  // An end of a stream that never started to collect is no end of this one.
  stream_ended_.store(false, std::memory_order_release);
  height_m_.store(height_m);
  started_.store(true, std::memory_order_release);
}

void LiveCalibration::Offer(std::span<const Vec3> frame) {
  if (!started_.load(std::memory_order_relaxed) || frame.size() != markers_) return;
  if (offered_++ % static_cast<uint64_t>(sample_every_) != 0) return;
  std::unique_lock lock(frames_mutex_, std::try_to_lock);
  if (!lock.owns_lock()) return;  // the calibration is copying: one sample fewer
  Vec3* slot = frames_.data() + kept_ % capacity_ * markers_;
  for (size_t m = 0; m < markers_; ++m)
    slot[m] = Plausible(frame[m]) ? frame[m] : Vec3::Constant(kNaN);
  ++kept_;
}

std::unique_ptr<LiveSwap> LiveCalibration::TakeSwap() {
  std::unique_lock lock(swap_mutex_, std::try_to_lock);
  if (!lock.owns_lock() || !swap_) return nullptr;
  swap_ready_.store(false, std::memory_order_release);
  return std::move(swap_);
}

bool LiveCalibration::Retire(std::unique_ptr<LiveSwap>& leftovers) {
  std::unique_lock lock(swap_mutex_, std::try_to_lock);
  if (!lock.owns_lock()) return false;
  // The vector was reserved: pushing allocates nothing on the data plane.
  if (retired_.size() == retired_.capacity()) return false;
  retired_.push_back(std::move(leftovers));
  swaps_.fetch_add(1, std::memory_order_relaxed);
  return true;
}

void LiveCalibration::Collect() {
  std::vector<std::unique_ptr<LiveSwap>> freed;
  {
    std::lock_guard lock(swap_mutex_);
    for (auto& r : retired_) freed.push_back(std::move(r));
    retired_.clear();
    retired_.reserve(4);
  }
}

void LiveCalibration::SendStatus(OutputSink& sink, std::string_view topic, uint64_t skeleton_hash) {
  std::unique_lock lock(status_mutex_, std::try_to_lock);
  if (!lock.owns_lock()) return;  // being updated: the next tick has it
  status_message_.skeleton_hash = skeleton_hash;
  protocol::EncodeCalibrationStatus(status_message_, &status_bytes_);
  sink.Send(topic, status_bytes_);
}

void LiveCalibration::EncodeStatus() {
  protocol::CalibrationStatusMessage& m = status_message_;
  m.state = static_cast<protocol::CalibrationState>(status_.state);
  m.refinements = static_cast<uint16_t>(std::min(status_.refinements, 65535));
  m.height_m = static_cast<float>(status_.height_m);
  m.collected_s = static_cast<float>(status_.collected_s);
  for (size_t j = 0; j < m.joints.size() && j < status_.joints.size(); ++j) {
    const JointReadiness& r = status_.joints[j];
    m.joints[j].directions_covered = static_cast<uint8_t>(std::clamp(r.directions_covered, 0, 3));
    m.joints[j].flags = static_cast<uint8_t>((r.method.empty() ? 0 : protocol::kJointCalibrated) |
                                             (r.ready ? protocol::kJointReady : 0));
    m.joints[j].uncertainty_mm =
        std::isfinite(r.uncertainty_mm) ? static_cast<float>(r.uncertainty_mm) : -1.0f;
    m.joints[j].moved_mm = std::isfinite(r.moved_mm) ? static_cast<float>(r.moved_mm) : -1.0f;
  }
}

LiveCalibrationStatus LiveCalibration::Status() const {
  std::lock_guard lock(status_mutex_);
  LiveCalibrationStatus status = status_;
  status.swaps = swaps_.load(std::memory_order_relaxed);
  return status;
}

std::optional<SubjectModel> LiveCalibration::CalibratedModel() const {
  std::lock_guard lock(status_mutex_);
  return calibrated_;
}

bool LiveCalibration::Refine(bool force) {
  if (done_ || !started_.load(std::memory_order_acquire)) return false;
  const bool stream_ended = stream_ended_.exchange(false, std::memory_order_acq_rel);
  const double kept_hz = subject_.rate_hz / sample_every_;
  const double height = height_m_.load();
  // A copy of what was kept, oldest first, as a take the calibration reads.
  C3dTake take;
  size_t kept = 0;
  {
    std::lock_guard lock(frames_mutex_);
    kept = kept_;
    const size_t count = std::min(kept, capacity_);
    const double collected = static_cast<double>(count) / kept_hz;
    {
      std::lock_guard status(status_mutex_);
      status_.state = LiveCalibrationState::kCollecting;
      status_.height_m = height;
      status_.collected_s = collected;
      EncodeStatus();
    }
    const bool enough = collected >= subject_.live.min_seconds;
    if (stream_ended && !enough)
      spdlog::info(
          "subject '{}': the stream ended after {:.1f} s of motion, short of "
          "calibration_min_s ({:.0f} s); the live calibration goes on with the next stream",
          subject_.name, collected, subject_.live.min_seconds);
    // A refinement every few seconds of new motion: each costs a bundle adjustment.
    const bool due = static_cast<double>(kept - kept_at_last_refinement_) / kept_hz >= 3.0;
    if (!force && (!enough || (!due && !stream_ended))) return false;
    if (count == 0) return false;
    take.labels = subject_.live.labels;
    take.model_output_kind.assign(take.labels.size(), "");
    take.descriptions.assign(take.labels.size(), "");
    take.rate_hz = kept_hz;
    take.Allocate(static_cast<int>(count));
    const size_t first = kept - count;
    for (size_t f = 0; f < count; ++f) {
      const Vec3* frame = frames_.data() + (first + f) % capacity_ * markers_;
      for (size_t m = 0; m < markers_; ++m) {
        const auto fi = static_cast<int>(f), mi = static_cast<int>(m);
        take.at(fi, mi) = frame[m];
        take.residuals[f * markers_ + m] = frame[m].allFinite() ? 0.0f : -1.0f;
      }
    }
  }
  kept_at_last_refinement_ = kept;
  const double collected = take.num_frames / kept_hz;
  // Measured on everything offered, not on what the storage still holds. An ended stream
  // with enough motion is the last chance too: nothing more comes.
  const bool last_chance = static_cast<double>(kept) / kept_hz >= subject_.live.max_seconds ||
                           (stream_ended && collected >= subject_.live.min_seconds);

  MarkersOnlyOptions options;
  options.marker_set = subject_.live.marker_set;
  options.solve.interleaved_solves = subject_.live.interleaved_solves;
  MarkersOnlyCalibration calibration;
  try {
    calibration = CalibrateFromMarkers(std::span<const C3dTake>(&take, 1), options, subject_.name);
  } catch (const std::exception& e) {
    std::lock_guard status(status_mutex_);
    status_.message = e.what();
    ++status_.refinements;
    if (last_chance) {
      status_.state = LiveCalibrationState::kFailed;
      done_ = true;
      spdlog::warn(
          "subject '{}': live calibration failed after {:.0f} s ({}); the template "
          "scaled to the actor stays",
          subject_.name, collected, e.what());
    }
    EncodeStatus();
    return false;
  }

  // Readiness: how each centre is determined, and whether it still moves.
  const std::vector<Vec3> centres = RestCentres(*calibration.model.skeleton);
  // A joint no marker rides, on its segment or below, is held by the template's prior
  // whatever the motion (a Plug-in Gait toe): more motion will not make it readier.
  const Skeleton& skeleton = *calibration.model.skeleton;
  std::vector<uint8_t> observable(static_cast<size_t>(skeleton.num_joints()), 0);
  for (int m = 0; m < calibration.model.markers->num_markers(); ++m)
    for (int j = calibration.model.markers->primary_joint(m);
         j >= 0 && !observable[static_cast<size_t>(j)];
         j = skeleton.joint(j).parent.is_valid() ? skeleton.joint(j).parent.value : -1)
      observable[static_cast<size_t>(j)] = 1;
  bool ready = true;
  std::string not_ready;  // for the log, when the last chance calibrates anyway
  {
    std::lock_guard status(status_mutex_);
    ++status_.refinements;
    status_.message.clear();
    status_.median_residual_mm = calibration.solve.median_residual_m * 1e3;
    for (size_t j = 0; j < status_.joints.size() && j < calibration.solve.joints.size(); ++j) {
      const JointCalibrationReport& report = calibration.solve.joints[j];
      JointReadiness& r = status_.joints[j];
      r.method = report.method;
      r.directions_covered = report.directions_covered;
      r.uncertainty_mm = report.method == "root" ? 0.0 : report.uncertainty_m * 1e3;
      r.moved_mm = last_centres_.empty() ? -1.0 : (centres[j] - last_centres_[j]).norm() * 1e3;
      r.ready = report.method == "root" || report.directions_covered >= kReadyDirections ||
                !observable[j];
      ready = ready && r.ready;
    }
    not_ready = JointsNotReady(status_.joints);
    EncodeStatus();
  }
  last_centres_ = centres;
  if (!ready && !last_chance) return false;

  // Everything the data plane will need, built here.
  std::unique_ptr<LiveSwap> swap;
  try {
    swap =
        Build(InTemplateOrder(calibration, TemplateSubject(subject_.live.set, subject_.live.labels,
                                                           height, subject_.name)));
  } catch (const std::exception& e) {
    std::lock_guard status(status_mutex_);
    status_.state = LiveCalibrationState::kFailed;
    status_.message = std::string("the calibrated subject could not be built: ") + e.what();
    EncodeStatus();
    done_ = true;
    spdlog::error("subject '{}': {}", subject_.name, status_.message);
    return false;
  }
  std::string written, write_error;
  try {
    WriteSubjectModel(subject_.live.out_path, swap->model);
    written = subject_.live.out_path;
  } catch (const std::exception& e) {
    write_error = e.what();
    spdlog::warn("subject '{}': the calibrated subject could not be written: {}", subject_.name,
                 write_error);
  }
  const SubjectModel swap_model = swap->model;
  {
    std::lock_guard lock(swap_mutex_);
    retired_.reserve(4);
    swap_ = std::move(swap);
    swap_ready_.store(true, std::memory_order_release);
  }
  {
    std::lock_guard status(status_mutex_);
    status_.state = LiveCalibrationState::kCalibrated;
    calibrated_ = swap_model;
    status_.written_to = written;
    status_.message = written.empty()
                          ? "calibrated; the subject file could not be written: " + write_error
                          : "calibrated; written to " + written;
    EncodeStatus();
  }
  done_ = true;
  spdlog::info(
      "subject '{}': calibrated live from {:.0f} s of motion ({} refinements, median "
      "residual {:.1f} mm){}{}{}{}",
      subject_.name, collected, status_.refinements, calibration.solve.median_residual_m * 1e3,
      written.empty() ? "" : ", written to ", written,
      not_ready.empty() ? "" : "; the motion did not show, so the template's prior placed: ",
      not_ready);
  return true;
}

std::unique_ptr<LiveSwap> LiveCalibration::Build(SubjectModel model) const {
  auto swap = std::make_unique<LiveSwap>();
  swap->model = std::move(model);
  swap->pipeline = std::make_unique<CleanupPipeline>(swap->model.skeleton, swap->model.markers,
                                                     subject_.cleanup);
  if (subject_.character) {
    swap->retargeter = std::make_unique<Retargeter>(
        swap->model.skeleton, subject_.character,
        MakeRetargetMap(*swap->model.skeleton, {}, *subject_.character,
                        subject_.character_end_sites, subject_.character_joint_map),
        subject_.retarget);
  }
  swap->description =
      protocol::DescribeSubject(subject_.name, *swap->model.skeleton, *swap->model.markers,
                                static_cast<float>(subject_.rate_hz), subject_.cleanup.lookahead);
  swap->description.version = static_cast<uint16_t>(output_version_);
  return swap;
}

std::shared_ptr<LiveCalibration> LiveCalibrationBoard::Attach(const SubjectConfig& subject,
                                                              const DaemonConfig& daemon) {
  std::lock_guard lock(mutex_);
  auto& slot = by_subject_[subject.name];
  if (!slot || slot->fingerprint() != SubjectFingerprint(subject, daemon))
    slot = std::make_shared<LiveCalibration>(subject, daemon);
  return slot;
}

std::vector<std::shared_ptr<LiveCalibration>> LiveCalibrationBoard::All() const {
  std::lock_guard lock(mutex_);
  std::vector<std::shared_ptr<LiveCalibration>> all;
  for (const auto& [name, calibration] : by_subject_) all.push_back(calibration);
  return all;
}

std::optional<LiveCalibrationStatus> LiveCalibrationBoard::StatusOf(
    const std::string& subject) const {
  std::lock_guard lock(mutex_);
  const auto it = by_subject_.find(subject);
  if (it == by_subject_.end()) return std::nullopt;
  return it->second->Status();
}

}  // namespace mocapd
