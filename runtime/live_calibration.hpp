// Live calibration of a subject from its own stream (`calibrate = "live"` in a
// [[subject]]): the data plane offers every frame (a decimated copy, taken only with
// try_lock, into storage sized once); a calibration thread refines the subject from what
// was collected, reports each joint's readiness (how well the motion so far determines
// its centre, and how far it moved since the last refinement) and, once every joint is
// ready, builds everything the data plane needs to swap the subject in
// (model, pipeline, retargeter, description) and writes it to a subject file the operator
// can reuse. The swap comes once every joint is ready and calibration_min_s of motion was
// seen, or at calibration_max_s with the last refinement. Readiness is coverage, not
// convergence: on a synthetic range of motion, centres still move 2-15 mm between
// refinements of a growing take (a different subset of poses each time), while their
// coverage says plainly when the motion has shown each joint. The data plane takes the swap with
// try_lock and hands back what it retires, so it never allocates, frees or waits for the
// calibration.
#pragma once

#include <atomic>
#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "filters/cleanup_pipeline.hpp"
#include "filters/retarget.hpp"
#include "protocol/messages.hpp"
#include "runtime/daemon_config.hpp"

namespace mocapd {

class OutputSink;

enum class LiveCalibrationState : uint8_t {
  kWaiting = 0,     ///< No usable frame yet (the template at 1.75 m solves what comes).
  kCollecting = 1,  ///< The template scaled to the actor solves; motion is being collected.
  kCalibrated = 2,  ///< The calibrated subject was handed to the data plane.
  kFailed = 3,      ///< No calibration by calibration_max_s: the scaled template stays.
};
const char* to_string(LiveCalibrationState state);

struct JointReadiness {
  std::string name;
  std::string method;          ///< As the calibration says ("functional", "prior", ...); "" before.
  int directions_covered = 0;  ///< Of its centre's 3 directions, those the motion determines.
  double uncertainty_mm = -1.0;  ///< Of the centre (motion and prior); -1 before.
  double moved_mm = -1.0;        ///< Since the previous refinement; -1 before a second one.
  /// The motion determines the centre in at least kReadyDirections directions (a hinge's
  /// axis never is; the root is ready once calibrated, and so is a joint no marker rides
  /// on or below, which only the template can place).
  bool ready = false;
};

/// The joints not ready yet, comma-separated ("" when all are), for the log.
std::string JointsNotReady(const std::vector<JointReadiness>& joints);

struct LiveCalibrationStatus {
  LiveCalibrationState state = LiveCalibrationState::kWaiting;
  double height_m = 0.0;     ///< The template's scale, from the first usable frame.
  double collected_s = 0.0;  ///< Motion kept for the calibration (the newest, up to a cap).
  int refinements = 0;
  double median_residual_mm = -1.0;
  std::vector<JointReadiness> joints;
  std::string message;     ///< The last refinement's problem, or where the subject went.
  std::string written_to;  ///< The calibrated subject's file, once written.
  uint64_t swaps = 0;      ///< Calibrated subjects the data plane swapped in.
};

/// What the data plane swaps in, built off the data plane. Once swapped in, the same
/// object goes back (LiveCalibration::Retire) holding what it replaced: the outgoing
/// model, pipeline and retargeter, freed off the data plane.
struct LiveSwap {
  SubjectModel model;
  std::unique_ptr<CleanupPipeline> pipeline;
  std::unique_ptr<Retargeter> retargeter;  ///< When the subject drives a character.
  protocol::SubjectDescriptionMessage description;
};

class LiveCalibration {
 public:
  /// Copies what it needs. Frames are kept at about kSampleHz, at most kMaxKeptSeconds.
  LiveCalibration(const SubjectConfig& subject, const DaemonConfig& daemon);

  static constexpr double kSampleHz = 30.0;
  static constexpr double kMaxKeptSeconds = 120.0;
  static constexpr int kReadyDirections = 2;

  const std::string& subject() const { return subject_.name; }
  const std::string& fingerprint() const { return fingerprint_; }
  const LiveCalibrationConfig& config() const { return subject_.live; }

  // --- Data plane (never allocates or waits).
  /// The template was scaled to the actor (the first usable frame): collecting starts.
  void Started(double height_m);
  /// A received frame (the subject's marker order, NaN where missing); kept when its turn
  /// comes (about kSampleHz) and the calibration thread is not reading.
  void Offer(std::span<const Vec3> frame);
  /// A sample the calibration may use: finite and inside any capture volume (exporters
  /// write 1e30 or FLT_MAX for "not seen").
  static bool Plausible(const Vec3& p) { return p.allFinite() && p.cwiseAbs().maxCoeff() < 1e4; }
  /// The stream ended (an end-of-stream message): the next refinement is the last, if
  /// calibration_min_s of motion was collected. Nothing more will come before another
  /// stream, and a take shorter than calibration_max_s whose every joint never became
  /// ready (a range of motion that does not move the toes) was never calibrated.
  void StreamEnded() { stream_ended_.store(true, std::memory_order_release); }
  /// The refinement an ended stream is owed, if it has not had it yet (a stop right after
  /// a take's end came before the calibration thread's next pass, and nothing was written).
  bool RefineIfStreamEnded() {
    return stream_ended_.load(std::memory_order_acquire) ? Refine() : false;
  }
  /// The calibrated subject, once there is one (a runner built after it starts from it).
  std::optional<SubjectModel> CalibratedModel() const;
  /// A calibrated subject waits to be swapped in.
  bool SwapReady() const { return swap_ready_.load(std::memory_order_acquire); }
  /// Takes it (nullptr when busy or none).
  std::unique_ptr<LiveSwap> TakeSwap();
  /// Hands back a swap's leftovers to be freed off the data plane; false when busy (try
  /// again later).
  bool Retire(std::unique_ptr<LiveSwap>& leftovers);
  /// On the stats tick: publishes the calibration's status message (encoded by the
  /// calibration thread) on topic; skipped when busy.
  void SendStatus(OutputSink& sink, std::string_view topic, uint64_t skeleton_hash);

  /// Everything a swap to `model` needs (pipeline, retargeter, description). Allocates.
  std::unique_ptr<LiveSwap> Build(SubjectModel model) const;

  // --- Calibration thread.
  /// Refines when due (enough new motion since the last refinement) or when forced;
  /// returns true if a calibrated subject was handed over. Runs the bundle adjustment
  /// (hundreds of milliseconds), so never on the data plane.
  bool Refine(bool force = false);
  /// Frees what the data plane retired.
  void Collect();
  LiveCalibrationStatus Status() const;

 private:
  void EncodeStatus();  // status_mutex_ held
  SubjectConfig subject_;
  std::string fingerprint_;
  int output_version_ = 2;
  int sample_every_ = 1;  ///< Frames per kept sample.
  size_t markers_ = 0;
  size_t capacity_ = 0;  ///< Frames kept at most.
  // Written by the data plane under frames_mutex_ (try_lock), read by the calibration.
  std::mutex frames_mutex_;
  std::vector<Vec3> frames_;  ///< Ring of capacity_ frames.
  size_t kept_ = 0;           ///< Frames written so far (the ring holds the newest).
  uint64_t offered_ = 0;
  std::atomic<bool> started_{false};
  std::atomic<bool> stream_ended_{false};
  std::atomic<double> height_m_{0.0};
  size_t kept_at_last_refinement_ = 0;
  std::vector<Vec3> last_centres_;  ///< Per joint, in the pelvis frame at rest.
  // The hand-over.
  std::mutex swap_mutex_;
  std::unique_ptr<LiveSwap> swap_;
  std::atomic<bool> swap_ready_{false};
  std::vector<std::unique_ptr<LiveSwap>> retired_;
  std::atomic<uint64_t> swaps_{0};          ///< Counted by the data plane, which must not wait.
  std::optional<SubjectModel> calibrated_;  ///< Under status_mutex_.
  // What is reported.
  mutable std::mutex status_mutex_;
  LiveCalibrationStatus status_;
  protocol::CalibrationStatusMessage status_message_;
  std::vector<uint8_t> status_bytes_;
  bool done_ = false;  ///< Handed over or failed: no more refinements.
};

/// Every live calibration of a daemon, by subject, shared by the workers (which attach
/// each to its runner), the calibration thread and the statistics.
class LiveCalibrationBoard {
 public:
  /// The subject's calibration: the running one if its configuration is unchanged (a
  /// reload keeps what was collected), a new one otherwise.
  std::shared_ptr<LiveCalibration> Attach(const SubjectConfig& subject, const DaemonConfig& daemon);
  std::vector<std::shared_ptr<LiveCalibration>> All() const;
  std::optional<LiveCalibrationStatus> StatusOf(const std::string& subject) const;

 private:
  mutable std::mutex mutex_;
  std::map<std::string, std::shared_ptr<LiveCalibration>> by_subject_;
};

}  // namespace mocapd
