// Seeded marker-take corruption with a ground-truth mask.
#include "sim/corruption.hpp"

#include <algorithm>
#include <cmath>
#include <map>
#include <nlohmann/json.hpp>
#include <random>
#include <stdexcept>

namespace mocapd {

const char* to_string(CorruptionKind kind) {
  switch (kind) {
    case CorruptionKind::kNone: return "none";
    case CorruptionKind::kGap: return "gap";
    case CorruptionKind::kSwap: return "swap";
    case CorruptionKind::kPop: return "pop";
    case CorruptionKind::kFrozen: return "frozen";
    case CorruptionKind::kFallenOff: return "fallen_off";
  }
  return "?";
}

CorruptionSeverity ParseCorruptionSeverity(const std::string& name) {
  if (name == "light") return CorruptionSeverity::kLight;
  if (name == "medium") return CorruptionSeverity::kMedium;
  if (name == "heavy") return CorruptionSeverity::kHeavy;
  throw std::invalid_argument("unknown corruption severity '" + name +
                              "' (expected light, medium or heavy)");
}

double TargetCorruptedFraction(CorruptionSeverity severity) {
  switch (severity) {
    case CorruptionSeverity::kLight: return 0.05;
    case CorruptionSeverity::kMedium: return 0.15;
    case CorruptionSeverity::kHeavy: return 0.30;
  }
  return 0.15;
}

namespace {

class Corruptor {
 public:
  Corruptor(const C3dTake& clean, const MarkerSet* markers, const CorruptionOptions& options)
      : clean_(clean), options_(options), rng_(options.seed) {
    out_.take = clean;
    frames_ = clean.num_frames;
    points_ = clean.num_points();
    out_.truth.assign(static_cast<size_t>(frames_) * static_cast<size_t>(points_),
                      CorruptionKind::kNone);
    // Occlusion clusters: markers on the same joint vanish together.
    std::map<int, std::vector<int>> by_joint;
    for (int p = 0; p < points_; ++p) {
      int key = -1 - p;
      if (markers != nullptr)
        if (auto m = markers->FindMarker(clean.labels[static_cast<size_t>(p)]))
          key = markers->primary_joint(m->value);
      by_joint[key].push_back(p);
    }
    for (auto& [joint, members] : by_joint) clusters_.push_back(members);
  }

  CorruptedTake Run() {
    const double target =
        TargetCorruptedFraction(options_.severity) * static_cast<double>(frames_) * points_;
    // One of each kind first, so every detector has work at every severity; then a mix
    // dominated by occlusion, as in real captures, until the target fraction is reached.
    Swap();
    Frozen();
    FallenOff();
    Pop();
    Gap(/*open_end=*/true);
    Gap(/*open_start=*/false);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    for (int guard = 0; guard < 100000 && static_cast<double>(corrupted_) < target; ++guard) {
      const double r = u(rng_);
      if (r < 0.62)
        Gap(false);
      else if (r < 0.80)
        Pop();
      else if (r < 0.90)
        Swap();
      else
        Frozen();
    }
    Jitter();
    out_.corrupted_fraction =
        static_cast<double>(corrupted_) / (static_cast<double>(frames_) * points_);
    return std::move(out_);
  }

 private:
  size_t Index(int f, int p) const {
    return static_cast<size_t>(f) * static_cast<size_t>(points_) + static_cast<size_t>(p);
  }
  int Uniform(int lo, int hi) {
    return std::uniform_int_distribution<int>(lo, std::max(lo, hi))(rng_);
  }
  double UniformReal(double lo, double hi) {
    return std::uniform_real_distribution<double>(lo, hi)(rng_);
  }

  void Mark(int f, int p, CorruptionKind kind) {
    CorruptionKind& t = out_.truth[Index(f, p)];
    if (t == CorruptionKind::kNone) ++corrupted_;
    t = kind;
  }
  bool Valid(int f, int p) const { return out_.take.valid(f, p); }

  // 1/120 s to 2 s, log-uniform: most occlusions are short, a few are long. In seconds,
  // not frames: an occlusion is the body's, so the same take captured at 60 and 240 Hz
  // loses the same stretches of time (counted in frames, a 60 Hz take's gaps averaged
  // 28 % longer than a 240 Hz take's). At least one frame.
  int GapLength() {
    const double shortest_frames = clean_.rate_hz / 120.0, longest_frames = 2.0 * clean_.rate_hz;
    const double frames =
        std::exp(UniformReal(std::log(shortest_frames), std::log(std::max(1.0, longest_frames))));
    return std::max(1, static_cast<int>(std::round(frames)));
  }

  void Gap(bool open_end) {
    if (frames_ < 2 || clusters_.empty()) return;
    const auto& cluster =
        clusters_[static_cast<size_t>(Uniform(0, static_cast<int>(clusters_.size()) - 1))];
    const int length = GapLength();
    int first = Uniform(-length / 3, frames_ - 1);
    if (open_end) first = std::max(0, frames_ - length);
    const int last = std::min(frames_ - 1, first + length - 1);
    first = std::max(0, first);
    bool any = false;
    for (int p : cluster) {
      if (any && UniformReal(0, 1) > 0.7) continue;
      any = true;
      for (int f = first; f <= last; ++f) {
        out_.take.at(f, p) = Vec3::Constant(kNaN);
        out_.take.residuals[Index(f, p)] = -1.0f;
        Mark(f, p, CorruptionKind::kGap);
      }
      out_.events.push_back({CorruptionKind::kGap, p, -1, first, last});
    }
  }

  void Pop() {
    const int p = Uniform(0, points_ - 1);
    const int first = Uniform(0, frames_ - 1);
    // 1 to 3 frames at 120 Hz, as many frames as that is at the take's rate (at least one).
    const int last = std::min(
        frames_ - 1, first + Uniform(0, static_cast<int>(std::lround(clean_.rate_hz / 60.0))));
    Vec3 dir(UniformReal(-1, 1), UniformReal(-1, 1), UniformReal(-1, 1));
    if (dir.norm() < 1e-6) dir = Vec3::UnitX();
    const Vec3 offset = dir.normalized() * UniformReal(0.05, 0.5);
    for (int f = first; f <= last; ++f) {
      if (!Valid(f, p)) continue;
      out_.take.at(f, p) += offset;
      Mark(f, p, CorruptionKind::kPop);
    }
    out_.events.push_back({CorruptionKind::kPop, p, -1, first, last});
  }

  void Frozen() {
    const int p = Uniform(0, points_ - 1);
    const int first = Uniform(1, frames_ - 1);
    const int last = std::min(frames_ - 1, first + Uniform(static_cast<int>(0.2 * clean_.rate_hz),
                                                           static_cast<int>(clean_.rate_hz)));
    if (!Valid(first - 1, p)) return;
    const Vec3 held = out_.take.at(first - 1, p);
    for (int f = first; f <= last; ++f) {
      if (!Valid(f, p)) continue;
      out_.take.at(f, p) = held;
      Mark(f, p, CorruptionKind::kFrozen);
    }
    out_.events.push_back({CorruptionKind::kFrozen, p, -1, first, last});
  }

  void FallenOff() {
    if (frames_ < 4) return;
    const int p = Uniform(0, points_ - 1);
    const int first = Uniform(frames_ / 2, frames_ - 1);
    if (!Valid(first - 1, p)) return;
    // The marker drops to the floor (the lowest any marker gets) below where it came off.
    double floor = 1e300;
    for (size_t i = 0; i < clean_.positions.size(); ++i)
      if (clean_.residuals[i] >= 0.0f)
        floor = std::min(floor, clean_.positions[i][options_.up_axis]);
    Vec3 rest = out_.take.at(first - 1, p);
    rest[options_.up_axis] = floor;
    for (int f = first; f < frames_; ++f) {
      if (!Valid(f, p)) continue;
      out_.take.at(f, p) = rest;
      Mark(f, p, CorruptionKind::kFallenOff);
    }
    out_.events.push_back({CorruptionKind::kFallenOff, p, -1, first, frames_ - 1});
  }

  void Swap() {
    // Look for two markers passing within 10 cm at some frame; swap their labels from
    // there for 0.2-2 s.
    for (int attempt = 0; attempt < 50; ++attempt) {
      const int f0 = Uniform(0, frames_ - 1);
      int best_i = -1, best_j = -1;
      double best = 0.10;
      for (int i = 0; i < points_; ++i) {
        if (!Valid(f0, i)) continue;
        for (int j = i + 1; j < points_; ++j) {
          if (!Valid(f0, j)) continue;
          const double d = (out_.take.at(f0, i) - out_.take.at(f0, j)).norm();
          if (d < best && d > 0.02) {
            best = d;
            best_i = i;
            best_j = j;
          }
        }
      }
      if (best_i < 0) continue;
      const int last = std::min(frames_ - 1, f0 + Uniform(static_cast<int>(0.2 * clean_.rate_hz),
                                                          static_cast<int>(2.0 * clean_.rate_hz)));
      for (int f = f0; f <= last; ++f) {
        // A second swap over the same samples would undo the first.
        if (!Valid(f, best_i) || !Valid(f, best_j) ||
            out_.truth[Index(f, best_i)] == CorruptionKind::kSwap ||
            out_.truth[Index(f, best_j)] == CorruptionKind::kSwap)
          continue;
        std::swap(out_.take.at(f, best_i), out_.take.at(f, best_j));
        Mark(f, best_i, CorruptionKind::kSwap);
        Mark(f, best_j, CorruptionKind::kSwap);
      }
      out_.events.push_back({CorruptionKind::kSwap, best_i, best_j, f0, last});
      return;
    }
  }

  void Jitter() {
    for (int p = 0; p < points_; ++p) {
      std::normal_distribution<double> noise(
          0.0, UniformReal(options_.jitter_min_m, options_.jitter_max_m));
      for (int f = 0; f < frames_; ++f)
        if (Valid(f, p)) out_.take.at(f, p) += Vec3(noise(rng_), noise(rng_), noise(rng_));
    }
  }

  const C3dTake& clean_;
  CorruptionOptions options_;
  std::mt19937_64 rng_;
  CorruptedTake out_;
  std::vector<std::vector<int>> clusters_;
  int frames_ = 0, points_ = 0;
  long corrupted_ = 0;
};

}  // namespace

CorruptedTake CorruptTake(const C3dTake& clean, const MarkerSet* markers,
                          const CorruptionOptions& options) {
  if (clean.num_frames < 2 || clean.num_points() < 2)
    throw std::invalid_argument("corruption: take needs at least 2 frames and 2 points");
  if (options.up_axis < 0 || options.up_axis > 2)
    throw std::invalid_argument("corruption: up_axis must be 0, 1 or 2");
  if (!(options.jitter_min_m >= 0.0 && options.jitter_max_m >= options.jitter_min_m))
    throw std::invalid_argument("corruption: expected 0 <= jitter_min_m <= jitter_max_m");
  return Corruptor(clean, markers, options).Run();
}

nlohmann::json CorruptionTruthJson(const CorruptedTake& corrupted,
                                   const CorruptionOptions& options) {
  const char* severity = options.severity == CorruptionSeverity::kLight    ? "light"
                         : options.severity == CorruptionSeverity::kMedium ? "medium"
                                                                           : "heavy";
  nlohmann::json j = {{"severity", severity},
                      {"seed", options.seed},
                      {"frames", corrupted.take.num_frames},
                      {"labels", corrupted.take.labels},
                      {"corrupted_fraction", corrupted.corrupted_fraction},
                      {"events", nlohmann::json::array()}};
  for (const CorruptionEvent& e : corrupted.events) {
    nlohmann::json ev = {{"kind", to_string(e.kind)},
                         {"marker", corrupted.take.labels[static_cast<size_t>(e.marker)]},
                         {"first_frame", e.first_frame},
                         {"last_frame", e.last_frame}};
    if (e.other >= 0) ev["other"] = corrupted.take.labels[static_cast<size_t>(e.other)];
    j["events"].push_back(ev);
  }
  return j;
}

}  // namespace mocapd
