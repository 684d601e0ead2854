// Cleanup accuracy benchmark (issue "Marker cleanup", item 10): BVH takes (the ../shared
// Bandai takes when present, else the built-in humanoid) at 120 Hz with the default
// virtual marker set, corrupted at each severity with several seeds, processed by the
// streaming pipeline at K = 0, 4, 12, beside three baselines run on the same corrupted
// markers: IK on the raw markers, linear gap fill + IK, cubic (Catmull-Rom) gap fill + IK.
// Reports the solved skeleton's mean global joint position (cm) and rotation (deg) error,
// the cleaned-marker RMSE on corrupted samples (mm), the jerk ratio against the truth and
// the number of pops (a joint moving faster than the truth's own motion by more than
// kPopExcessSpeedMps, 2 cm per frame at 120 Hz; a run of such frames is one pop).
// Usage: cleanup_accuracy [--seeds N] [--severity light|medium|heavy]... [--rates 60,120,240]
// [--lookahead K (ours only, any K)] [--jitter-mm MIN,MAX] [--explain-pops] [--explain-worst]
// [--explain-rejections] [--trace TAKE:FROM:TO:MARKER,...] [--digest] [--oracle] [TAKE.bvh ...]
// --explain-worst explains each run's worst frame (over 3 cm) the way --explain-pops does.
// --oracle adds rows that bound what detection and lookahead could gain: the same pipeline
// on each corrupted take with every injected sample removed (perfect detection), at K and
// at 2 s of lookahead, and with those gaps filled offline (Catmull-Rom) before it.
// --digest prints, per row of ours, a hash of every published bit (markers, status,
// reasons, weights, poses): a change meant to alter no arithmetic must keep it.
// MOCAPD_EXPLAIN_BACK=N shows N frames before each pop (default 4); MOCAPD_EXP_<FIELD>
// variables override a few options for experiments (see RunPipeline); MOCAPD_TAIL_CM=X lists
// the frames more than X cm off; MOCAPD_SPLIT=1 prints, under each row of ours, the mean
// joint error on clean segments and on the rest.
#include <algorithm>
#include <cctype>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <map>
#include <sstream>
#include <string>
#include <type_traits>
#include <utility>
#include <variant>

#include "bench/bench_takes.hpp"
#include "filters/cleanup_pipeline.hpp"
#include "filters/pose_error.hpp"
#include "sim/corruption.hpp"
#include "sim/graph_stream.hpp"
#include "sim/replay_sources.hpp"
#include "sim/synthesis.hpp"

using namespace mocapd;

namespace {

struct Scores {
  double pos_cm = 0, rot_deg = 0, marker_rmse_mm = 0, jerk_ratio = 0;
  int pops = 0;
  struct Pop {
    int frame, joint;
    double excess_m;  // the joint's motion beyond the truth's
  };
  std::vector<Pop> pop_frames;                                   ///< each pop's worst joint
  std::vector<std::vector<Vec3>> estimated_joints, true_joints;  ///< per frame (for --explain-pops)
  std::vector<Pose> estimated_poses;  ///< per frame (for --trace: the solved markers' residuals)
  double p50_us = 0, p99_us = 0;
  /// The per-frame joint error (the worst joint's in each frame): its maximum over the
  /// take, the frame and joint where it is, and its 99.9th percentile.
  double worst_frame_cm = 0, p999_frame_cm = 0;
  int worst_frame = -1, worst_joint = -1;
  /// The same over the joints whose own segment's markers are all clean in that frame (at
  /// least two, nothing injected): what issue 14 asks to be solved from its own markers,
  /// whatever happened to the rest. Negative: not measured (the baselines).
  double clean_worst_frame_cm = -1, clean_p999_frame_cm = -1;
  int clean_worst_frame = -1, clean_worst_joint = -1;
  uint64_t digest = 0;  ///< FNV-1a over every published frame (--digest)
  /// Joint position error (cm) summed over the joint-frames whose segment is clean, and
  /// over the rest (MOCAPD_SPLIT): where a mean's difference between rates comes from.
  struct Sum {
    double total = 0;
    long count = 0;
    void Add(double v) {
      total += v;
      ++count;
    }
    void Add(const Sum& o) {
      total += o.total;
      count += o.count;
    }
    double mean() const { return count > 0 ? total / static_cast<double>(count) : 0.0; }
  };
  Sum clean_joint_error, other_joint_error;
};

// MOCAPD_TAIL_CM=X lists every frame whose worst joint is more than X cm off (the tail
// that makes a p99.9), to see which episodes a change moved.
const double g_tail_cm =
    std::getenv("MOCAPD_TAIL_CM") ? std::atof(std::getenv("MOCAPD_TAIL_CM")) : 0.0;

// A pop is a joint outrunning the truth by this speed. In m/s, not cm per frame: 2 cm a
// frame was 1.2 m/s at 60 Hz and 4.8 m/s at 240 Hz, so the same jump spread over the
// frames of a faster capture went uncounted. And a run of pop frames is one pop, which
// a faster capture would otherwise count several times.
constexpr double kPopExcessSpeedMps = 2.4;

// Accumulates a solved take against the truth.
class Scorer {
 public:
  /// label names the run in the MOCAPD_TAIL_CM lines.
  Scorer(const Skeleton& sk, const std::vector<Pose>& truth, double rate_hz, std::string label)
      : sk_(sk), truth_(truth), errors_(sk), rate_hz_(rate_hz), label_(std::move(label)) {}
  void Add(int frame, const Pose& pose) { estimates_[frame] = pose; }
  /// Per frame of the take, per joint: its own segment's markers are all clean.
  void SetCleanSegments(std::vector<std::vector<uint8_t>> clean) {
    clean_segments_ = std::move(clean);
  }
  Scores Finish() {
    Scores s;
    KinematicsWorkspace t(sk_), e(sk_), tp(sk_), ep(sk_);
    std::vector<std::vector<Vec3>> est_p, tru_p;
    std::vector<int> frames;
    for (const auto& [f, pose] : estimates_) {
      frames.push_back(f);
      ForwardKinematics(sk_, truth_[static_cast<size_t>(f)], &t);
      ForwardKinematics(sk_, pose, &e);
      errors_.Add(t, e);
      est_p.push_back(e.p_WJ);
      s.estimated_poses.push_back(pose);
      tru_p.push_back(t.p_WJ);
    }
    s.pos_cm = errors_.mean_position_error_m() * 100;
    s.rot_deg = errors_.mean_rotation_error_rad() * 180 / M_PI;
    double jerk_e = 0, jerk_t = 0;
    for (size_t f = 3; f < est_p.size(); ++f) {
      for (size_t j = 0; j < est_p[f].size(); ++j) {
        jerk_e +=
            (est_p[f][j] - 3 * est_p[f - 1][j] + 3 * est_p[f - 2][j] - est_p[f - 3][j]).norm();
        jerk_t +=
            (tru_p[f][j] - 3 * tru_p[f - 1][j] + 3 * tru_p[f - 2][j] - tru_p[f - 3][j]).norm();
      }
    }
    s.jerk_ratio = jerk_t > 0 ? jerk_e / jerk_t : 0;
    const double pop_step_m = kPopExcessSpeedMps / rate_hz_;
    bool in_pop = false;
    for (size_t f = 1; f < est_p.size(); ++f) {
      double worst = pop_step_m;
      int worst_joint = -1;
      for (size_t j = 0; j < est_p[f].size(); ++j) {
        const double excess =
            (est_p[f][j] - est_p[f - 1][j]).norm() - (tru_p[f][j] - tru_p[f - 1][j]).norm();
        if (excess > worst) {
          worst = excess;
          worst_joint = static_cast<int>(j);
        }
      }
      if (worst_joint >= 0 && !in_pop) {
        ++s.pops;
        s.pop_frames.push_back({static_cast<int>(f), worst_joint, worst});
      }
      in_pop = worst_joint >= 0;
    }
    std::vector<double> frame_errors, clean_frame_errors;
    for (size_t f = 0; f < est_p.size(); ++f) {
      double worst = 0.0, clean_worst = 0.0;
      bool any_clean = false;
      int joint = -1;
      const auto clean_frame = static_cast<size_t>(frames[f]);
      for (size_t j = 0; j < est_p[f].size(); ++j) {
        const double error = (est_p[f][j] - tru_p[f][j]).norm();
        if (error > worst) {
          worst = error;
          joint = static_cast<int>(j);
        }
        const bool clean = clean_frame < clean_segments_.size() && clean_segments_[clean_frame][j];
        any_clean = any_clean || clean;
        (clean ? s.clean_joint_error : s.other_joint_error).Add(error * 100);
        if (clean && error > clean_worst) {
          clean_worst = error;
          if (error * 100 > s.clean_worst_frame_cm) {
            s.clean_worst_frame_cm = error * 100;
            s.clean_worst_frame = frames[f];
            s.clean_worst_joint = static_cast<int>(j);
          }
        }
      }
      frame_errors.push_back(worst * 100);
      if (g_tail_cm > 0.0 && worst * 100 > g_tail_cm && joint >= 0)
        std::printf("tail %s frame %d %s %.1f cm\n", label_.c_str(), frames[f],
                    sk_.joint(joint).name.c_str(), worst * 100);
      // A frame with no clean segment says nothing of them: left out, not counted as 0.
      if (any_clean) clean_frame_errors.push_back(clean_worst * 100);
      if (worst * 100 > s.worst_frame_cm) {
        s.worst_frame_cm = worst * 100;
        s.worst_frame = static_cast<int>(f);
        s.worst_joint = joint;
      }
    }
    s.p999_frame_cm = Quantile(frame_errors, 0.999);
    if (!clean_segments_.empty()) {
      s.clean_worst_frame_cm = std::max(s.clean_worst_frame_cm, 0.0);
      s.clean_p999_frame_cm =
          clean_frame_errors.empty() ? 0.0 : Quantile(clean_frame_errors, 0.999);
    }
    s.estimated_joints = std::move(est_p);
    s.true_joints = std::move(tru_p);
    return s;
  }

 private:
  const Skeleton& sk_;
  const std::vector<Pose>& truth_;
  PoseErrorAccumulator errors_;
  double rate_hz_;
  std::map<int, Pose> estimates_;
  std::vector<std::vector<uint8_t>> clean_segments_;
  std::string label_;
};

// Per frame, per joint: the joint's own segment carries at least two markers and nothing
// was injected into any of them (no noise beyond the capture's, no gap, no swap...).
std::vector<std::vector<uint8_t>> CleanSegments(const MarkerSet& markers, const CorruptedTake& bad,
                                                int joints) {
  std::vector<int> on_segment(static_cast<size_t>(joints), 0);
  for (int m = 0; m < markers.num_markers(); ++m)
    ++on_segment[static_cast<size_t>(markers.primary_joint(m))];
  std::vector<std::vector<uint8_t>> clean(static_cast<size_t>(bad.take.num_frames));
  for (int f = 0; f < bad.take.num_frames; ++f) {
    auto& row = clean[static_cast<size_t>(f)];
    row.assign(static_cast<size_t>(joints), 0);
    for (int j = 0; j < joints; ++j)
      row[static_cast<size_t>(j)] = on_segment[static_cast<size_t>(j)] >= 2;
    for (int m = 0; m < markers.num_markers(); ++m)
      if (bad.at(f, m) != CorruptionKind::kNone)
        row[static_cast<size_t>(markers.primary_joint(m))] = 0;
  }
  return clean;
}

Scores SolveBaseline(const bench::BenchTake& take, const C3dTake& markers, double rate_hz) {
  const Skeleton& sk = take.bvh.skeleton;
  IkState ik(sk, *take.markers);
  std::vector<Vec3> obs(static_cast<size_t>(take.markers->num_markers()));
  std::vector<double> w(obs.size());
  Scorer scorer(sk, take.motion, rate_hz, take.name + " ik-baseline");
  for (int f = 0; f < markers.num_frames; ++f) {
    for (size_t m = 0; m < obs.size(); ++m) {
      obs[m] = markers.at(f, static_cast<int>(m));
      w[m] = markers.valid(f, static_cast<int>(m)) ? 1.0 : 0.0;
    }
    SolveIk(sk, *take.markers, IkOptions{}, obs, w, &ik);
    scorer.Add(f, ik.pose());
  }
  return scorer.Finish();
}

// The corrupted take with every injected sample removed, as if detection were perfect:
// what an offline fill over the whole take can do with only the data the corruption left.
C3dTake WithInjectedSamplesRemoved(const CorruptedTake& bad) {
  C3dTake out = bad.take;
  for (int f = 0; f < out.num_frames; ++f)
    for (int p = 0; p < out.num_points(); ++p)
      if (bad.at(f, p) != CorruptionKind::kNone) {
        // Missing as the pipeline reads it (a non-finite position) and as C3D says it.
        out.at(f, p) = Vec3::Constant(std::numeric_limits<double>::quiet_NaN());
        out.residuals[static_cast<size_t>(f) * static_cast<size_t>(out.num_points()) +
                      static_cast<size_t>(p)] = -1.0f;
      }
  return out;
}

bool g_explain_pops = false;
bool g_oracle = false;
bool g_digest = false;
bool g_explain_worst = false;
bool g_explain_rejections = false;

// FNV-1a over raw bytes: a refactoring that claims to change no arithmetic must leave
// every published bit, and so this digest, as it was.
void Digest(uint64_t* h, const void* data, size_t bytes) {
  const auto* p = static_cast<const unsigned char*>(data);
  for (size_t i = 0; i < bytes; ++i) *h = (*h ^ p[i]) * 1099511628211ull;
}
template <typename T>
void DigestVector(uint64_t* h, const std::vector<T>& v) {
  Digest(h, v.data(), v.size() * sizeof(T));
}
int g_explain_back =
    std::getenv("MOCAPD_EXPLAIN_BACK") ? std::atoi(std::getenv("MOCAPD_EXPLAIN_BACK")) : 4;

// One letter per repair reason for --explain-pops and --trace: m missing, d disagreement,
// r residual, k spike, i rigid distance, w swap, z frozen, f fallen off, l small track,
// t trimmed.
char ReasonLetter(MaskReason reason) {
  static constexpr char kLetters[kMaskReasonCount + 1] = "-mdrkiwzflt";
  return kLetters[static_cast<size_t>(reason)];
}
struct Trace {
  std::string take;  ///< a substring of the take's name; empty: no trace
  int from = 0, to = -1;
  std::vector<std::string> markers;
} g_trace;

// Parses TAKE:FROM:TO:MARKER,MARKER...
bool ParseTrace(const std::string& spec, Trace* trace) {
  std::istringstream in(spec);
  std::string from, to, markers;
  if (!std::getline(in, trace->take, ':') || !std::getline(in, from, ':') ||
      !std::getline(in, to, ':') || !std::getline(in, markers))
    return false;
  trace->from = std::atoi(from.c_str());
  trace->to = std::atoi(to.c_str());
  std::istringstream names(markers);
  for (std::string name; std::getline(names, name, ',');) trace->markers.push_back(name);
  return !trace->take.empty() && !trace->markers.empty();
}

// variant names the run in --explain-worst/--explain-pops lines ("" for the plain one).
Scores RunPipeline(const bench::BenchTake& take, const CorruptedTake& bad, const C3dTake& clean,
                   int lookahead, double rate_hz, const std::string& variant = "") {
  const auto skeleton = std::make_shared<const Skeleton>(take.bvh.skeleton);
  CleanupOptions options;
  options.lookahead = lookahead;
  options.rate_hz = rate_hz;
  // Experiments without rebuilding: MOCAPD_EXP_<FIELD>=value for a few options.
  if (const char* v = std::getenv("MOCAPD_EXP_REPAIRED_WEIGHT"))
    options.repaired_weight = std::atof(v);
  if (const char* v = std::getenv("MOCAPD_EXP_FINAL_TEMPORAL"))
    options.final_ik.temporal_weight = std::atof(v);
  if (const char* v = std::getenv("MOCAPD_EXP_FINAL_GAIN"))
    options.final_ik.prediction_velocity_gain = std::atof(v);
  if (const char* v = std::getenv("MOCAPD_EXP_ROBUST_GAIN"))
    options.robust_ik.prediction_velocity_gain = std::atof(v);
  if (const char* v = std::getenv("MOCAPD_EXP_FINAL_ITERS"))
    options.final_ik.max_iterations = std::atoi(v);
  if (const char* v = std::getenv("MOCAPD_EXP_NAIVE_ITERS"))
    options.naive_ik.max_iterations = std::atoi(v);
  if (const char* v = std::getenv("MOCAPD_EXP_ROBUST_ITERS"))
    options.robust_ik.max_iterations = std::atoi(v);
  // Any scalar cleanup option by its C++ name, in SI units: MOCAPD_EXP_SPIKE_M=0.05.
  for (const CleanupOptionField& f : CleanupOptionFields()) {
    std::string name = "MOCAPD_EXP_";
    for (const char* c = f.name; *c != '\0'; ++c) name += static_cast<char>(std::toupper(*c));
    if (const char* v = std::getenv(name.c_str()))
      std::visit(
          [&](auto member) {
            options.*member =
                static_cast<std::remove_reference_t<decltype(options.*member)>>(std::atof(v));
          },
          f.member);
  }
  // MOCAPD_EXP_TEMPORAL_RATE_POWER=p scales the final and anchor solves' temporal weight
  // by (rate / 120 Hz)^p.
  if (const char* v = std::getenv("MOCAPD_EXP_TEMPORAL_RATE_POWER")) {
    const double scale = std::pow(rate_hz / 120.0, std::atof(v));
    options.final_ik.temporal_weight *= scale;
    options.anchor_ik.temporal_weight *= scale;
  }
  // MOCAPD_EXP_GAIN_RATE=1 takes the IK prediction gains as given per 120 Hz frame: the
  // velocity then decays at the same rate per second at any capture rate.
  if (std::getenv("MOCAPD_EXP_GAIN_RATE")) {
    for (IkOptions* ik : {&options.final_ik, &options.anchor_ik, &options.robust_ik})
      ik->prediction_velocity_gain = std::pow(ik->prediction_velocity_gain, 120.0 / rate_hz);
  }
  CleanupPipeline pipeline(skeleton, take.markers, options);
  Scorer scorer(*skeleton, take.motion, rate_hz,
                take.name + " mocapd K=" + std::to_string(lookahead));
  scorer.SetCleanSegments(CleanSegments(*take.markers, bad, skeleton->num_joints()));
  std::vector<Vec3> obs(static_cast<size_t>(take.markers->num_markers()));
  std::vector<double> times;
  double sq = 0;
  long n = 0;
  std::vector<std::vector<MaskReason>> reasons;  // per published frame (for --explain-pops)
  std::vector<std::vector<MarkerStatus>> statuses;
  std::vector<std::vector<Vec3>> published;
  std::vector<std::vector<double>> weights;
  uint64_t digest = 14695981039346656037ull;
  auto collect = [&]() {
    const CleanFrame& o = pipeline.output();
    if (g_digest) {
      DigestVector(&digest, o.markers);
      DigestVector(&digest, o.status);
      DigestVector(&digest, o.reason);
      DigestVector(&digest, o.weight);
      DigestVector(&digest, o.pose.rotation);
      DigestVector(&digest, o.pose.translation);
    }
    if (g_explain_pops || g_explain_rejections) {
      reasons.push_back(o.reason);
      statuses.push_back(o.status);
      published.push_back(o.markers);
      weights.push_back(o.weight);
    }
    scorer.Add(static_cast<int>(o.frame), o.pose);
    for (size_t m = 0; m < obs.size(); ++m) {
      if (bad.at(static_cast<int>(o.frame), static_cast<int>(m)) == CorruptionKind::kNone ||
          !o.markers[m].allFinite())
        continue;
      sq += (o.markers[m] - clean.at(static_cast<int>(o.frame), static_cast<int>(m))).squaredNorm();
      ++n;
    }
  };
  for (int f = 0; f < bad.take.num_frames; ++f) {
    for (size_t m = 0; m < obs.size(); ++m) obs[m] = bad.take.at(f, static_cast<int>(m));
    const auto t0 = std::chrono::steady_clock::now();
    const bool ready = pipeline.Push(obs);
    // The first K + 1 frames hold the three solvers' cold starts: timed apart.
    if (f > lookahead)
      times.push_back(
          std::chrono::duration<double, std::micro>(std::chrono::steady_clock::now() - t0).count());
    if (ready) collect();
  }
  while (pipeline.Flush()) collect();
  Scores s = scorer.Finish();
  if (g_explain_worst && s.worst_frame >= 0 && s.worst_frame_cm > 3.0) {
    std::printf("worst frame %s%s K=%d %.0f Hz: frame %d joint %s %.1f cm off\n", take.name.c_str(),
                variant.c_str(), lookahead, rate_hz, s.worst_frame,
                skeleton->joint(s.worst_joint).name.c_str(), s.worst_frame_cm);
    s.pop_frames.push_back({s.worst_frame, s.worst_joint, s.worst_frame_cm / 100});
  }
  if (g_explain_worst && s.clean_worst_frame >= 0)
    std::printf("worst clean-segment joint %s%s K=%d %.0f Hz: frame %d joint %s %.1f cm off\n",
                take.name.c_str(), variant.c_str(), lookahead, rate_hz, s.clean_worst_frame,
                skeleton->joint(s.clean_worst_joint).name.c_str(), s.clean_worst_frame_cm);
  if (g_explain_rejections) {
    // Clean samples (nothing injected) the pipeline did not publish as observed, in runs
    // of at least 0.1 s: a detector convicting good data, which no lookahead excuses.
    struct Run {
      int marker, first, last;
    };
    std::vector<Run> runs;
    for (int m = 0; m < take.markers->num_markers(); ++m) {
      int start = -1;
      for (int g = 0; g <= static_cast<int>(statuses.size()); ++g) {
        const bool rejected =
            g < static_cast<int>(statuses.size()) && bad.at(g, m) == CorruptionKind::kNone &&
            statuses[static_cast<size_t>(g)][static_cast<size_t>(m)] != MarkerStatus::kObserved;
        if (rejected && start < 0) start = g;
        if (!rejected && start >= 0) {
          if (g - start >= 0.1 * rate_hz) runs.push_back({m, start, g - 1});
          start = -1;
        }
      }
    }
    std::sort(runs.begin(), runs.end(),
              [](const Run& a, const Run& b) { return a.last - a.first > b.last - b.first; });
    for (size_t k = 0; k < std::min<size_t>(runs.size(), 5); ++k) {
      const Run& r = runs[k];
      std::printf("rejected clean %s %.0f Hz: %s frames %d-%d (%.2f s):", take.name.c_str(),
                  rate_hz, take.markers->marker(r.marker).name.c_str(), r.first, r.last,
                  (r.last - r.first + 1) / rate_hz);
      for (int g = r.first; g <= r.last && g < r.first + 40; ++g)
        std::printf("%c",
                    ReasonLetter(reasons[static_cast<size_t>(g)][static_cast<size_t>(r.marker)]));
      std::printf("\n");
    }
  }
  if (g_trace.take.empty() ? false : take.name.find(g_trace.take) != std::string::npos) {
    // Frame by frame: each traced marker's published status (as in --explain-pops), the
    // reason it was masked for (which an unrecoverable 'x' hides), the injected truth, its
    // error against the clean take (e, cm), the solved skeleton's marker against the clean
    // take (s, cm) and final-solve weight (w).
    for (int g = g_trace.from; g <= g_trace.to && g < static_cast<int>(published.size()); ++g) {
      // The frame's worst joint first: its error against the truth (cm).
      int worst_joint = 0;
      double worst_error = 0.0;
      const auto ug0 = static_cast<size_t>(g);
      if (ug0 < s.estimated_joints.size())
        for (size_t j = 0; j < s.estimated_joints[ug0].size(); ++j) {
          const double error = (s.estimated_joints[ug0][j] - s.true_joints[ug0][j]).norm();
          if (error > worst_error) {
            worst_error = error;
            worst_joint = static_cast<int>(j);
          }
        }
      std::printf("trace %d %s %.1f", g, skeleton->joint(worst_joint).name.c_str(),
                  worst_error * 100);
      // The solved skeleton's own markers (its model of each sample) against the truth.
      std::vector<Vec3> solved(static_cast<size_t>(take.markers->num_markers()));
      if (static_cast<size_t>(g) < s.estimated_poses.size()) {
        KinematicsWorkspace ws(*skeleton);
        ForwardKinematics(*skeleton, s.estimated_poses[static_cast<size_t>(g)], &ws);
        EvaluateMarkers(*take.markers, ws, solved);
      }
      for (const std::string& name : g_trace.markers) {
        const auto found = take.markers->FindMarker(name);
        if (!found) continue;
        const int m = found->value;
        const auto ug = static_cast<size_t>(g), um = static_cast<size_t>(m);
        const MarkerStatus st = statuses[ug][um];
        const char c = st == MarkerStatus::kObserved        ? 'o'
                       : st == MarkerStatus::kUnrecoverable ? 'x'
                                                            : ReasonLetter(reasons[ug][um]);
        std::printf(" %s %c%c%c e%.1f s%.1f w%.2f", name.c_str(), c, ReasonLetter(reasons[ug][um]),
                    ".gspzf"[static_cast<int>(bad.at(g, m))],
                    (published[ug][um] - clean.at(g, m)).norm() * 100,
                    (solved[um] - clean.at(g, m)).norm() * 100, weights[ug][um]);
      }
      std::printf("\n");
    }
  }
  if (g_explain_pops) {
    // Each pop: the joint, and what its markers were around it (o observed, repaired as
    // the reason's letter, x unrecoverable; upper case where the injector had corrupted
    // the sample).
    if (!s.pop_frames.empty())
      for (const CorruptionEvent& e : bad.events)
        if (e.kind == CorruptionKind::kSwap)
          std::printf("swap %s frames %d-%d: %s <-> %s\n", take.name.c_str(), e.first_frame,
                      e.last_frame, take.markers->marker(e.marker).name.c_str(),
                      take.markers->marker(e.other).name.c_str());
    for (const auto& [f, j, excess] : s.pop_frames) {
      std::printf("pop %s%s K=%d frame %d joint %s +%.1fcm:", take.name.c_str(), variant.c_str(),
                  lookahead, f, skeleton->joint(j).name.c_str(), excess * 100);
      const int parent = skeleton->joint(j).parent.value;
      for (int m = 0; m < take.markers->num_markers(); ++m) {
        if (take.markers->primary_joint(m) != j && take.markers->primary_joint(m) != parent)
          continue;
        std::printf(" %s[", take.markers->marker(m).name.c_str());
        for (int g = std::max(0, f - 6);
             g <= std::min<int>(f + 2, static_cast<int>(reasons.size()) - 1); ++g) {
          const MarkerStatus st = statuses[static_cast<size_t>(g)][static_cast<size_t>(m)];
          char c = st == MarkerStatus::kObserved ? 'o'
                   : st == MarkerStatus::kUnrecoverable
                       ? 'x'
                       : ReasonLetter(reasons[static_cast<size_t>(g)][static_cast<size_t>(m)]);
          if (bad.at(g, m) != CorruptionKind::kNone) c = static_cast<char>(std::toupper(c));
          std::printf("%c%s", g == f ? '|' : c, g == f ? std::string(1, c).c_str() : "");
        }
        // The injected truth over the same frames: . fine, g gap, s swap, p pop, z frozen, f fallen
        // off.
        std::printf("/");
        for (int g = std::max(0, f - 6);
             g <= std::min<int>(f + 2, static_cast<int>(reasons.size()) - 1); ++g)
          std::printf("%c", ".gspzf"[static_cast<int>(bad.at(g, m))]);
        std::printf("]");
      }
      std::printf("\n");
      // What the injector did to those markers over the 2 s before it (a swapped label
      // can carry a frozen or fallen-off trajectory: the letters show only the swap).
      for (const CorruptionEvent& e : bad.events) {
        if (e.last_frame < f - static_cast<int>(2.0 * rate_hz) || e.first_frame > f) continue;
        const int jm = take.markers->primary_joint(e.marker);
        const int jo = e.other >= 0 ? take.markers->primary_joint(e.other) : -2;
        if (jm != j && jm != parent && jo != j && jo != parent) continue;
        std::printf("    injected %s frames %d-%d: %s%s%s\n", to_string(e.kind), e.first_frame,
                    e.last_frame, take.markers->marker(e.marker).name.c_str(),
                    e.other >= 0 ? " <-> " : "",
                    e.other >= 0 ? take.markers->marker(e.other).name.c_str() : "");
      }
      // Frame by frame around it: the joint's step (estimate / truth, cm) and each of its
      // markers' published step (cm) and final-solve weight.
      for (int g = std::max(1, f - g_explain_back);
           g <= std::min<int>(f + 1, static_cast<int>(published.size()) - 1); ++g) {
        const auto ug = static_cast<size_t>(g), uj = static_cast<size_t>(j);
        std::printf("    %d joint %.1f/%.1f", g,
                    (s.estimated_joints[ug][uj] - s.estimated_joints[ug - 1][uj]).norm() * 100,
                    (s.true_joints[ug][uj] - s.true_joints[ug - 1][uj]).norm() * 100);
        for (int m = 0; m < take.markers->num_markers(); ++m) {
          if (take.markers->primary_joint(m) != j && take.markers->primary_joint(m) != parent)
            continue;
          const auto um = static_cast<size_t>(m);
          std::printf(" %s %.1f w%.2f", take.markers->marker(m).name.c_str(),
                      (published[ug][um] - published[ug - 1][um]).norm() * 100, weights[ug][um]);
        }
        std::printf("\n");
      }
    }
  }
  s.marker_rmse_mm = n > 0 ? std::sqrt(sq / static_cast<double>(n)) * 1e3 : 0;
  s.p50_us = Quantile(times, 0.5);
  s.p99_us = Quantile(times, 0.99);
  s.digest = digest;
  return s;
}

// A command-line whole number >= least (>= 0), or -1 (not a number, trailing text, less).
long WholeAtLeast(const char* text, long least) {
  char* end = nullptr;
  errno = 0;
  const long value = std::strtol(text, &end, 10);
  return end == text || *end != '\0' || errno != 0 || value < least ? -1 : value;
}

// One actor of the graph replay, offline: the soak's exact stream (walk, chunks,
// corruption), so its worst frames can be explained and traced.
int RunGraphActor(const std::string& graph, int actor, uint64_t seed, double seconds,
                  const std::vector<std::string>& severities, const std::vector<double>& rates,
                  int lookahead) {
  const GraphReplaySource source = GraphSource(graph);
  std::printf(
      "| actor | severity | rate (Hz) | Δpos (cm) | Δrot (deg) | worst frame / p99.9 (cm) | "
      "pops | clean segments' worst frame / p99.9 (cm) |\n|---|---|---|---|---|---|---|---|\n");
  for (const std::string& severity : severities)
    for (const double rate : rates) {
      GraphActorStream stream = ReplayGraphActor(source, seed, actor - 1, rate, severity);
      const auto frames = static_cast<uint64_t>(std::llround(seconds * rate));
      GraphStreamChunk whole = WholeGraphStream(&stream, frames);
      bench::BenchTake take;
      take.name = "actor" + std::to_string(actor);
      take.bvh = MakeBvhTake(*source.library->skeleton, whole.truth, 1.0 / rate);
      take.motion = std::move(whole.truth);
      take.markers = source.markers;
      const Scores s = RunPipeline(take, whole.corrupted, whole.clean, lookahead, rate);
      std::printf("| %s | %s | %.0f | %.3f | %.2f | %.1f / %.1f | %d | %.1f / %.1f |\n",
                  take.name.c_str(), severity.c_str(), rate, s.pos_cm, s.rot_deg, s.worst_frame_cm,
                  s.p999_frame_cm, s.pops, s.clean_worst_frame_cm, s.clean_p999_frame_cm);
      std::fflush(stdout);
    }
  return 0;
}

}  // namespace

constexpr const char* kUsage =
    "Usage: cleanup_accuracy [--seeds N] [--severity light|medium|heavy]... [--rates 60,120,240]\n"
    "  [--lookahead K (ours only, any K >= 0)] [--jitter-mm MIN,MAX] [--explain-pops]\n"
    "  [--explain-worst] [--explain-rejections] [--trace TAKE:FROM:TO:MARKER,...] [--digest]\n"
    "  [--oracle] [TAKE.bvh ...]\n"
    "  [--graph-actor K [--graph humanoid|FILE] [--graph-seconds S] [--graph-seed N]]\n"
    "Without takes: the ../shared Bandai takes when present, else the built-in humanoid.\n"
    "--oracle: also the pipeline on each corrupted take with every injected sample removed\n"
    "(perfect detection) at K and at 2 s of lookahead, and with those gaps filled offline.\n"
    "--graph-actor: instead, actor K of `mocap-sim replay --graph` (the soak's stream: the\n"
    "same walk, chunks and corruption, for --graph-seconds at each rate; no noise), run once\n"
    "per severity and rate at --lookahead (default 12).\n";

int Run(int argc, char** argv) {
  int seeds = 2;
  int only_lookahead = -1;                          // -1: the baselines and K = 0, 4, 12
  std::pair<double, double> jitter_mm{-1.0, -1.0};  // < 0: the corruption's default
  std::vector<double> rates;
  std::vector<std::string> severities, paths;
  int graph_actor = 0;  // 1-based; 0: takes, -1: given but not a positive whole number
  std::string graph = "humanoid";
  double graph_seconds = 300.0;
  long graph_seed = 1;  // -1: not a whole number >= 0
  for (int i = 1; i < argc; ++i) {
    if (std::strcmp(argv[i], "--seeds") == 0 && i + 1 < argc)
      seeds = std::atoi(argv[++i]);
    else if (std::strcmp(argv[i], "--explain-pops") == 0)
      g_explain_pops = true;
    else if (std::strcmp(argv[i], "--explain-worst") == 0)
      g_explain_pops = g_explain_worst = true;
    else if (std::strcmp(argv[i], "--explain-rejections") == 0)
      g_explain_rejections = true;
    else if (std::strcmp(argv[i], "--oracle") == 0)
      g_oracle = true;
    else if (std::strcmp(argv[i], "--digest") == 0)
      g_digest = true;
    else if (std::strcmp(argv[i], "--graph-actor") == 0 && i + 1 < argc)
      graph_actor = static_cast<int>(std::clamp(WholeAtLeast(argv[++i], 1), -1L, 1000000L));
    else if (std::strcmp(argv[i], "--graph") == 0 && i + 1 < argc)
      graph = argv[++i];
    else if (std::strcmp(argv[i], "--graph-seconds") == 0 && i + 1 < argc)
      graph_seconds = std::atof(argv[++i]);
    else if (std::strcmp(argv[i], "--graph-seed") == 0 && i + 1 < argc)
      graph_seed = WholeAtLeast(argv[++i], 0);
    else if (std::strcmp(argv[i], "--trace") == 0 && i + 1 < argc) {
      if (!ParseTrace(argv[++i], &g_trace)) {
        std::fprintf(stderr, "--trace expects TAKE:FROM:TO:MARKER[,MARKER...], got '%s'\n",
                     argv[i]);
        return 1;
      }
      g_explain_pops = true;  // the trace reads what --explain-pops keeps
    } else if (std::strcmp(argv[i], "--lookahead") == 0 && i + 1 < argc)
      only_lookahead = std::atoi(argv[++i]);
    else if (std::strcmp(argv[i], "--jitter-mm") == 0 && i + 1 < argc) {
      // MIN,MAX: each marker's Gaussian jitter sigma is drawn in [MIN, MAX] mm.
      std::stringstream list(argv[++i]);
      std::string lo, hi;
      if (!std::getline(list, lo, ',') || !std::getline(list, hi)) {
        std::fprintf(stderr, "--jitter-mm expects MIN,MAX (mm), got '%s'\n", argv[i]);
        return 1;
      }
      jitter_mm = {std::atof(lo.c_str()), std::atof(hi.c_str())};
    } else if (std::strcmp(argv[i], "--severity") == 0 && i + 1 < argc)
      severities.emplace_back(argv[++i]);
    else if (std::strcmp(argv[i], "--rates") == 0 && i + 1 < argc) {
      std::stringstream list(argv[++i]);
      for (std::string r; std::getline(list, r, ',');) rates.push_back(std::atof(r.c_str()));
    } else if (std::strcmp(argv[i], "--help") == 0 || std::strcmp(argv[i], "-h") == 0) {
      std::fputs(kUsage, stdout);
      return 0;
    } else if (argv[i][0] == '-') {
      std::fprintf(stderr, "cleanup_accuracy: unknown option or missing value '%s'\n%s", argv[i],
                   kUsage);
      return 2;
    } else {
      paths.emplace_back(argv[i]);
    }
  }
  if (severities.empty()) severities = {"light", "medium", "heavy"};
  if (rates.empty()) rates = {120.0};
  if (graph_actor < 0 || graph_seed < 0 || !(graph_seconds > 0) || !std::isfinite(graph_seconds)) {
    std::fprintf(stderr,
                 "cleanup_accuracy: --graph-actor takes a whole number >= 1, --graph-seed one "
                 ">= 0, --graph-seconds a positive number of seconds\n");
    return 2;
  }
  for (const double rate : rates)
    if (!(rate > 0) || !std::isfinite(rate)) {
      std::fprintf(stderr, "cleanup_accuracy: --rates takes positive rates in Hz\n");
      return 2;
    }
  if (graph_actor > 0)
    return RunGraphActor(graph, graph_actor, static_cast<uint64_t>(graph_seed), graph_seconds,
                         severities, rates, only_lookahead < 0 ? 12 : only_lookahead);
  if (paths.empty()) paths = bench::SharedBvhTakes();
  if (paths.empty()) paths.emplace_back("");
  std::printf(
      "| severity | rate (Hz) | method | Δpos (cm) | Δrot (deg) | marker RMSE on corrupted samples "
      "(mm) | worst frame / p99.9 (cm) | jerk ratio | pops | per-frame p50 / p99 (us) | clean "
      "segments' worst frame / p99.9 (cm) |\n");
  std::printf("|---|---|---|---|---|---|---|---|---|---|---|\n");
  for (const std::string& severity_name : severities) {
    for (const double rate : rates) {
      std::vector<bench::BenchTake> takes;
      for (const auto& p : paths) takes.push_back(bench::LoadBenchTake(p, rate));
      std::map<std::string, std::vector<Scores>> results;
      for (const bench::BenchTake& take : takes) {
        const C3dTake clean =
            SynthesizeMarkers(take.bvh.skeleton, *take.markers, take.motion, rate);
        for (int seed = 1; seed <= seeds; ++seed) {
          CorruptionOptions co;
          co.severity = ParseCorruptionSeverity(severity_name);
          co.seed = static_cast<uint64_t>(seed);
          if (jitter_mm.first >= 0.0) {
            co.jitter_min_m = jitter_mm.first * 1e-3;
            co.jitter_max_m = jitter_mm.second * 1e-3;
          }
          const CorruptedTake bad = CorruptTake(clean, take.markers.get(), co);
          if (g_oracle) {
            // What detection cannot be blamed for: every injected sample removed before the
            // pipeline sees the take, at this lookahead and at 2 s of it.
            CorruptedTake masked = bad;
            masked.take = WithInjectedSamplesRemoved(bad);
            const int k = only_lookahead >= 0 ? only_lookahead : 12;
            const int long_k = static_cast<int>(std::lround(2.0 * rate));
            results["oracle mask, mocapd K=" + std::to_string(k)].push_back(
                RunPipeline(take, masked, clean, k, rate, " (oracle mask)"));
            results["oracle mask, mocapd 2 s"].push_back(
                RunPipeline(take, masked, clean, long_k, rate, " (oracle mask)"));
            // ... and every gap filled offline (Catmull-Rom over the whole take) before.
            CorruptedTake filled = masked;
            filled.take = bench::FillGaps(masked.take, true);
            results["oracle mask + cubic fill, mocapd K=" + std::to_string(k)].push_back(
                RunPipeline(take, filled, clean, k, rate, " (oracle mask + cubic fill)"));
          }
          if (only_lookahead >= 0) {
            results["mocapd K=" + std::to_string(only_lookahead)].push_back(
                RunPipeline(take, bad, clean, only_lookahead, rate));
            continue;
          }
          results["raw IK"].push_back(SolveBaseline(take, bad.take, rate));
          results["linear fill + IK"].push_back(
              SolveBaseline(take, bench::FillGaps(bad.take, false), rate));
          results["cubic fill + IK"].push_back(
              SolveBaseline(take, bench::FillGaps(bad.take, true), rate));
          for (int k : {0, 4, 12})
            results["mocapd K=" + std::to_string(k)].push_back(
                RunPipeline(take, bad, clean, k, rate));
        }
      }
      std::vector<std::string> methods = {"raw IK",     "linear fill + IK", "cubic fill + IK",
                                          "mocapd K=0", "mocapd K=4",       "mocapd K=12"};
      if (only_lookahead >= 0 && only_lookahead != 0 && only_lookahead != 4 && only_lookahead != 12)
        methods.push_back("mocapd K=" + std::to_string(only_lookahead));
      if (g_oracle) {
        methods.push_back("oracle mask, mocapd K=" +
                          std::to_string(only_lookahead >= 0 ? only_lookahead : 12));
        methods.push_back("oracle mask, mocapd 2 s");
        methods.push_back("oracle mask + cubic fill, mocapd K=" +
                          std::to_string(only_lookahead >= 0 ? only_lookahead : 12));
      }
      for (const std::string& method_name : methods) {
        const char* method = method_name.c_str();
        const auto& v = results[method_name];
        if (v.empty()) continue;
        Scores mean;
        uint64_t digest = 14695981039346656037ull;
        for (const Scores& s : v) {
          Digest(&digest, &s.digest, sizeof(s.digest));
          mean.pos_cm += s.pos_cm / v.size();
          mean.rot_deg += s.rot_deg / v.size();
          mean.marker_rmse_mm += s.marker_rmse_mm / v.size();
          mean.jerk_ratio += s.jerk_ratio / v.size();
          mean.pops += s.pops;
          mean.p50_us += s.p50_us / v.size();
          mean.p99_us = std::max(mean.p99_us, s.p99_us);
          mean.worst_frame_cm = std::max(mean.worst_frame_cm, s.worst_frame_cm);
          mean.p999_frame_cm = std::max(mean.p999_frame_cm, s.p999_frame_cm);
          mean.clean_worst_frame_cm = std::max(mean.clean_worst_frame_cm, s.clean_worst_frame_cm);
          mean.clean_p999_frame_cm = std::max(mean.clean_p999_frame_cm, s.clean_p999_frame_cm);
          mean.clean_joint_error.Add(s.clean_joint_error);
          mean.other_joint_error.Add(s.other_joint_error);
        }
        const bool ours = method_name.find("mocapd") != std::string::npos;
        char rmse[32] = "-", timing[48] = "-", clean[48] = "-";
        if (ours) {
          std::snprintf(rmse, sizeof(rmse), "%.1f", mean.marker_rmse_mm);
          std::snprintf(timing, sizeof(timing), "%.0f / %.0f", mean.p50_us, mean.p99_us);
        }
        if (mean.clean_worst_frame_cm >= 0)
          std::snprintf(clean, sizeof(clean), "%.1f / %.1f", mean.clean_worst_frame_cm,
                        mean.clean_p999_frame_cm);
        std::printf("| %s | %.0f | %s | %.2f | %.2f | %s | %.1f / %.1f | %.2f | %d | %s | %s |\n",
                    severity_name.c_str(), rate, method, mean.pos_cm, mean.rot_deg, rmse,
                    mean.worst_frame_cm, mean.p999_frame_cm, mean.jerk_ratio, mean.pops, timing,
                    clean);
        if (ours && std::getenv("MOCAPD_SPLIT"))
          std::printf(
              "split %s %.0f %s: clean segments %.3f cm over %ld joint-frames, the rest "
              "%.3f cm over %ld\n",
              severity_name.c_str(), rate, method, mean.clean_joint_error.mean(),
              mean.clean_joint_error.count, mean.other_joint_error.mean(),
              mean.other_joint_error.count);
        if (g_digest && ours)
          std::printf("digest %s %.0f %s: %016llx\n", severity_name.c_str(), rate, method,
                      static_cast<unsigned long long>(digest));
        std::fflush(stdout);
      }
    }
  }
  std::printf(
      "\n%zu takes x %d seeds per severity and rate; pops summed over all runs; worst frame, "
      "p99.9 and p99 are the worst run's (a frame's error: its worst joint's).\n",
      paths.size(), seeds);
  return 0;
}

int main(int argc, char** argv) {
  return mocapd::bench::RunReportingErrors("cleanup_accuracy", Run, argc, argv);
}
