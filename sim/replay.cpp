// The replay simulator: sender, receiver and the latency / accuracy report.
#include "sim/replay.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <mutex>
#include <random>
#include <sstream>
#include <stdexcept>
#include <thread>
#include <zmq.hpp>

#include "filters/pose_error.hpp"
#include "protocol/messages.hpp"
#include "sim/bvh.hpp"
#include "sim/corruption.hpp"
#include "sim/humanoid.hpp"
#include "sim/humanoid_subject.hpp"
#include "sim/marker_layout.hpp"
#include "sim/subject_file.hpp"
#include "sim/synthesis.hpp"
#include "sim/take_frames.hpp"

namespace mocapd {
namespace {

using Clock = std::chrono::steady_clock;

int64_t SteadyNs() { return std::chrono::duration_cast<std::chrono::nanoseconds>(Clock::now().time_since_epoch()).count(); }

uint64_t WallNs() {
  return static_cast<uint64_t>(std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::system_clock::now().time_since_epoch()).count());
}

// Actors stand this far apart along x, so that copies of one take never overlap.
constexpr double kActorSpacingM = 2.5;

LatencySummary Summarise(std::vector<double> ms) {
  LatencySummary s;
  s.count = ms.size();
  if (ms.empty()) return s;
  double sum = 0.0;
  for (double v : ms) sum += v;
  s.mean_ms = sum / static_cast<double>(ms.size());
  s.p50_ms = Quantile(ms, 0.5);
  s.p90_ms = Quantile(ms, 0.9);
  s.p99_ms = Quantile(ms, 0.99);
  s.p999_ms = Quantile(ms, 0.999);
  s.max_ms = *std::max_element(ms.begin(), ms.end());
  return s;
}

nlohmann::json SummaryJson(const LatencySummary& s) {
  return {{"count", s.count}, {"p50_ms", s.p50_ms}, {"p90_ms", s.p90_ms}, {"p99_ms", s.p99_ms},
          {"p99.9_ms", s.p999_ms}, {"max_ms", s.max_ms}, {"mean_ms", s.mean_ms}};
}

std::string SubjectName(const ReplayOptions& o, int k) { return o.subject_prefix + std::to_string(k + 1); }

// Per subject: what was sent when, and what came back.
struct SubjectTrack {
  std::string name;
  std::string topic;
  C3dTake take;
  Vec3 offset = Vec3::Zero();
  std::vector<int64_t> sent_ns;      ///< By sequence number; 0 = not sent.
  std::vector<int64_t> received_ns;  ///< 0 = not received.
  std::vector<int64_t> flushed_ns;   ///< Per loop: when end-of-stream went out.
};

}  // namespace

ReplaySource HumanoidReplaySource(const std::string& motion, double seconds, double rate_hz, double noise_mm, uint64_t seed) {
  ReplaySource s;
  const SubjectModel model = MakeHumanoidSubject("actor1");
  s.skeleton = model.skeleton;
  s.markers = model.markers;
  s.rate_hz = rate_hz;
  s.truth = MakeHumanoidMotion(*s.skeleton, ParseHumanoidMotion(motion), seconds, rate_hz);
  std::mt19937_64 rng(seed);
  s.take = SynthesizeMarkers(*s.skeleton, *s.markers, s.truth, rate_hz, noise_mm * 1e-3, &rng);
  char d[160];
  std::snprintf(d, sizeof(d), "built-in humanoid, %s, %.1f s at %.0f Hz, %.1f mm noise", motion.c_str(), seconds, rate_hz, noise_mm);
  s.description = d;
  return s;
}

ReplaySource BvhReplaySource(const std::string& path, double rate_hz, const std::string& units) {
  BvhReadOptions read;
  read.units = units;
  const BvhTake bvh = ReadBvh(path, read);
  ReplaySource s;
  s.rate_hz = rate_hz > 0 ? rate_hz : bvh.rate_hz();
  s.skeleton = std::make_shared<const Skeleton>(bvh.skeleton);
  s.markers = std::make_shared<const MarkerSet>(
      bvh.skeleton, PlaceMarkers(bvh.skeleton, MatchHumanoidRoles(bvh.skeleton), DefaultMarkerLayout(), bvh.end_sites));
  s.truth = ResampleMotion(bvh.skeleton, bvh.frames, bvh.rate_hz(), s.rate_hz);
  std::mt19937_64 rng(1);
  s.take = SynthesizeMarkers(*s.skeleton, *s.markers, s.truth, s.rate_hz, 0.0, &rng);
  s.description = path + " (markers synthesized, " + std::to_string(static_cast<int>(s.rate_hz)) + " Hz)";
  return s;
}

ReplaySource C3dReplaySource(const std::string& path, const std::string& subject_path) {
  ReplaySource s;
  const SubjectModel model = subject_path.empty() ? MakeHumanoidSubject("actor1") : ReadSubjectModel(subject_path);
  s.skeleton = model.skeleton;
  s.markers = model.markers;
  s.take = ReadC3d(path);
  s.rate_hz = s.take.rate_hz;
  s.description = path;
  return s;
}

ReplayReport RunReplay(const ReplaySource& source, const ReplayOptions& o) {
  if (o.subjects < 1 || o.loops < 1) throw std::invalid_argument("replay: subjects and loops must be at least 1");
  const int n = source.take.num_frames;
  if (n < 1) throw std::invalid_argument("replay: the take has no frames");
  const size_t total = static_cast<size_t>(n) * static_cast<size_t>(o.loops);
  const double rate = o.rate_hz > 0 ? o.rate_hz : source.rate_hz;
  const bool max_rate = o.rate_hz < 0;
  const int64_t period_ns = static_cast<int64_t>(1e9 / rate);
  const TakeMarkerMap map(*source.markers, source.take);
  const uint64_t marker_hash = protocol::MarkerSetHash(*source.markers);

  std::vector<SubjectTrack> tracks(static_cast<size_t>(o.subjects));
  for (int k = 0; k < o.subjects; ++k) {
    SubjectTrack& t = tracks[static_cast<size_t>(k)];
    t.name = SubjectName(o, k);
    t.topic = "markers/" + t.name + "/";
    t.offset = Vec3(kActorSpacingM * k, 0.0, 0.0);
    t.sent_ns.assign(total, 0);
    t.received_ns.assign(total, 0);
    t.flushed_ns.assign(static_cast<size_t>(o.loops), 0);
    if (!o.corrupt.empty()) {
      CorruptionOptions c;
      c.severity = ParseCorruptionSeverity(o.corrupt);
      c.seed = o.seed + static_cast<uint64_t>(k);
      t.take = CorruptTake(source.take, source.markers.get(), c).take;
    } else if (k == 0) {
      t.take = source.take;
    }
  }
  auto take_of = [&](size_t k) -> const C3dTake& { return tracks[k].take.num_frames > 0 ? tracks[k].take : tracks[0].take; };

  zmq::context_t context;
  zmq::socket_t out(context, o.push ? zmq::socket_type::push : zmq::socket_type::xpub);
  out.set(zmq::sockopt::sndhwm, 0);  // never drop a frame on our side
  out.set(zmq::sockopt::linger, 2000);
  try {
    if (o.push) out.connect(o.to);
    else out.bind(o.to);
  } catch (const zmq::error_t& e) {
    throw std::runtime_error("replay: cannot " + std::string(o.push ? "connect to " : "bind ") + o.to + ": " + e.what());
  }
  std::optional<zmq::socket_t> in;
  if (!o.from.empty()) {
    in.emplace(context, zmq::socket_type::sub);
    in->set(zmq::sockopt::rcvhwm, 0);
    in->set(zmq::sockopt::subscribe, "skeleton/");
    in->set(zmq::sockopt::subscribe, "subject/");
    in->connect(o.from);
  }

  // Handshake: the daemon subscribed to our frames, and we hold its subject descriptions.
  ReplayReport report;
  report.source = source.description;
  report.rate_hz = rate;
  report.subjects = o.subjects;
  const int64_t deadline = SteadyNs() + static_cast<int64_t>(o.connect_timeout_s * 1e9);
  std::vector<bool> subscribed(tracks.size(), o.push), described(tracks.size(), !in.has_value());
  auto all = [](const std::vector<bool>& v) { return std::all_of(v.begin(), v.end(), [](bool b) { return b; }); };
  while (!(all(subscribed) && all(described))) {
    if (SteadyNs() > deadline) {
      for (size_t k = 0; k < tracks.size(); ++k) {
        if (!subscribed[k])
          throw std::runtime_error("replay: nothing subscribed to " + tracks[k].topic + " on " + o.to + " within " +
                                   std::to_string(o.connect_timeout_s) + " s (is the daemon running with subject '" + tracks[k].name + "'?)");
        if (!described[k])
          throw std::runtime_error("replay: no description of subject '" + tracks[k].name + "' from " + o.from + " within " +
                                   std::to_string(o.connect_timeout_s) + " s (is the daemon publishing there, with that subject?)");
      }
    }
    std::vector<zmq::pollitem_t> items = {{out.handle(), 0, ZMQ_POLLIN, 0}};
    if (in) items.push_back({in->handle(), 0, ZMQ_POLLIN, 0});
    zmq::poll(items.data(), items.size(), std::chrono::milliseconds(20));
    zmq::message_t m;
    while (!o.push && out.recv(m, zmq::recv_flags::dontwait)) {
      const std::string sub = m.to_string();
      if (sub.empty() || sub[0] != 1) continue;
      for (size_t k = 0; k < tracks.size(); ++k)
        if (tracks[k].topic.starts_with(sub.substr(1))) subscribed[k] = true;
    }
    while (in && in->recv(m, zmq::recv_flags::dontwait)) {
      zmq::message_t body;
      if (!m.more() || !in->recv(body)) continue;
      protocol::SubjectDescriptionMessage d;
      if (!m.to_string().starts_with("subject/") ||
          protocol::DecodeSubjectDescription({static_cast<const uint8_t*>(body.data()), body.size()}, &d) != protocol::DecodeStatus::kOk)
        continue;
      for (size_t k = 0; k < tracks.size(); ++k) {
        if (tracks[k].name != d.subject) continue;
        if (d.marker_set_hash != marker_hash)
          throw std::runtime_error("replay: the daemon's subject '" + d.subject + "' has another marker set than this take's (model hash mismatch)");
        described[k] = true;
        report.lookahead = d.lookahead_frames;
      }
    }
  }

  // Receiver: stamps each skeleton frame on arrival and scores it against the truth.
  std::atomic<bool> receiving{true};
  std::atomic<uint64_t> received{0}, duplicated{0};
  std::mutex accuracy_mutex;
  PoseErrorAccumulator accuracy(*source.skeleton);
  std::thread receiver;
  if (in) {
    receiver = std::thread([&] {
      zmq::pollitem_t item = {in->handle(), 0, ZMQ_POLLIN, 0};
      protocol::SkeletonFrameMessage skeleton;
      KinematicsWorkspace solved_fk(*source.skeleton), truth_fk(*source.skeleton);
      Pose solved = RestPose(*source.skeleton), truth;
      zmq::message_t topic, body;
      while (receiving.load()) {
        zmq::poll(&item, 1, std::chrono::milliseconds(5));
        while (in->recv(topic, zmq::recv_flags::dontwait)) {
          if (!topic.more() || !in->recv(body)) continue;
          const int64_t now = SteadyNs();
          if (!topic.to_string().starts_with("skeleton/")) continue;
          if (protocol::DecodeSkeletonFrame({static_cast<const uint8_t*>(body.data()), body.size()}, &skeleton) != protocol::DecodeStatus::kOk)
            continue;
          size_t k = 0;
          while (k < tracks.size() && tracks[k].name != skeleton.subject) ++k;
          if (k == tracks.size() || skeleton.frame_number >= total) continue;
          int64_t& stamp = tracks[k].received_ns[skeleton.frame_number];
          if (stamp != 0) {
            ++duplicated;
            continue;
          }
          stamp = now;
          ++received;
          if (source.truth.empty() || static_cast<int>(skeleton.rotations.size()) != source.skeleton->num_joints()) continue;
          for (size_t j = 0; j < skeleton.rotations.size(); ++j) solved.rotation[j] = skeleton.rotations[j].normalized();
          solved.translation[0] = skeleton.root_translation;
          truth = source.truth[skeleton.frame_number % static_cast<uint64_t>(n)];
          truth.translation[0] += tracks[k].offset;
          ForwardKinematics(*source.skeleton, solved, &solved_fk);
          ForwardKinematics(*source.skeleton, truth, &truth_fk);
          std::lock_guard lock(accuracy_mutex);
          accuracy.Add(truth_fk, solved_fk);
        }
      }
    });
  }

  // Sender, paced by the steady clock.
  protocol::MarkerFrameMessage message;
  message.model_hash = marker_hash;
  message.rate_hz = static_cast<float>(source.rate_hz);
  std::vector<uint8_t> bytes;
  auto send = [&](const std::string& topic, const std::vector<uint8_t>& b) {
    out.send(zmq::buffer(topic), zmq::send_flags::sndmore);
    out.send(zmq::buffer(b), zmq::send_flags::none);
  };
  auto send_end_of_stream = [&](size_t loop) {
    for (SubjectTrack& t : tracks) {
      protocol::EncodeEndOfStream({t.name, (loop + 1) * static_cast<uint64_t>(n) - 1}, &bytes);
      t.flushed_ns[loop] = SteadyNs();
      send(t.topic, bytes);
    }
  };
  const int64_t start = SteadyNs();
  int64_t next_status = start + 1'000'000'000;
  uint64_t sent = 0;
  for (size_t seq = 0; seq < total; ++seq) {
    if (o.stop != nullptr && o.stop->load()) break;
    if (!max_rate) {
      const int64_t due = start + static_cast<int64_t>(seq) * period_ns;
      std::this_thread::sleep_until(Clock::time_point(std::chrono::nanoseconds(due)));
    }
    const int f = static_cast<int>(seq % static_cast<size_t>(n));
    for (size_t k = 0; k < tracks.size(); ++k) {
      SubjectTrack& t = tracks[k];
      map.FillMessage(take_of(k), f, &message);
      for (size_t m = 0; m < message.positions.size(); ++m)
        if (message.valid[m]) message.positions[m] += t.offset;
      message.subject = t.name;
      message.frame_number = seq;
      message.capture_time_ns = WallNs();
      protocol::EncodeMarkerFrame(message, &bytes);
      t.sent_ns[seq] = SteadyNs();
      send(t.topic, bytes);
      ++sent;
    }
    if (o.end_of_stream && f == n - 1) send_end_of_stream(seq / static_cast<size_t>(n));
    if (o.on_status && SteadyNs() >= next_status) {
      char line[160];
      std::snprintf(line, sizeof(line), "t=%6.1fs  sent %8llu frames  received %8llu skeletons", static_cast<double>(SteadyNs() - start) * 1e-9,
                    static_cast<unsigned long long>(sent), static_cast<unsigned long long>(received.load()));
      o.on_status(line);
      next_status += 1'000'000'000;
    }
  }
  const int64_t send_end = SteadyNs();
  if (in) {
    const int64_t drain_deadline = SteadyNs() + static_cast<int64_t>(o.drain_timeout_s * 1e9);
    while (received.load() < sent && SteadyNs() < drain_deadline) std::this_thread::sleep_for(std::chrono::milliseconds(5));
    receiving = false;
    receiver.join();
  }

  report.frames_sent = sent;
  report.send_seconds = static_cast<double>(send_end - start) * 1e-9;
  if (!in) return report;
  report.frames_received = received.load();
  report.frames_duplicated = duplicated.load();
  report.frames_lost = sent - std::min<uint64_t>(sent, report.frames_received);
  std::vector<double> e2e;
  e2e.reserve(sent);
  report.processing_ms.reserve(sent);
  const auto K = static_cast<size_t>(report.lookahead);
  for (const SubjectTrack& t : tracks) {
    for (size_t seq = 0; seq < total; ++seq) {
      if (t.sent_ns[seq] == 0 || t.received_ns[seq] == 0) continue;
      e2e.push_back(static_cast<double>(t.received_ns[seq] - t.sent_ns[seq]) * 1e-6);
      // The frame that let this one out: K later in the same loop, or the end of stream.
      const size_t loop = seq / static_cast<size_t>(n);
      const size_t trigger = seq + K;
      int64_t trigger_ns = 0;
      if (trigger / static_cast<size_t>(n) == loop && trigger < total) trigger_ns = t.sent_ns[trigger];
      else if (o.end_of_stream) trigger_ns = t.flushed_ns[loop];
      if (trigger_ns == 0) continue;
      const double ms = static_cast<double>(t.received_ns[seq] - trigger_ns) * 1e-6;
      report.processing_ms.push_back(ms);
      if (ms * 1e6 > static_cast<double>(period_ns)) ++report.frames_late;
    }
  }
  report.end_to_end = Summarise(e2e);
  report.processing = Summarise(report.processing_ms);
  report.throughput_fps = report.send_seconds > 0 ? static_cast<double>(report.frames_received) / report.send_seconds : 0.0;
  if (accuracy.frames() > 0) {
    report.has_truth = true;
    report.mean_position_error_cm = accuracy.mean_position_error_m() * 100.0;
    report.max_position_error_cm = accuracy.max_position_error_m() * 100.0;
    report.mean_rotation_error_deg = accuracy.mean_rotation_error_rad() * 180.0 / M_PI;
  }
  return report;
}

nlohmann::json ReplayReport::ToJson() const {
  nlohmann::json j = {{"source", source},
                      {"rate_hz", rate_hz},
                      {"subjects", subjects},
                      {"lookahead_frames", lookahead},
                      {"frames_sent", frames_sent},
                      {"frames_received", frames_received},
                      {"frames_lost", frames_lost},
                      {"frames_duplicated", frames_duplicated},
                      {"frames_late", frames_late},
                      {"send_seconds", send_seconds},
                      {"throughput_fps", throughput_fps},
                      {"end_to_end_latency", SummaryJson(end_to_end)},
                      {"processing_latency", SummaryJson(processing)}};
  if (has_truth)
    j["accuracy"] = {{"mean_joint_position_error_cm", mean_position_error_cm},
                     {"max_joint_position_error_cm", max_position_error_cm},
                     {"mean_joint_rotation_error_deg", mean_rotation_error_deg}};
  return j;
}

std::string ReplayReport::FormatTable() const {
  std::ostringstream s;
  char line[200];
  auto row = [&](const char* name, const std::string& value) {
    std::snprintf(line, sizeof(line), "  %-34s %s\n", name, value.c_str());
    s << line;
  };
  auto num = [](double v, int decimals) {
    char b[40];
    std::snprintf(b, sizeof(b), "%.*f", decimals, v);
    return std::string(b);
  };
  s << "replay: " << source << "\n";
  row("subjects x rate", std::to_string(subjects) + " x " + num(rate_hz, 0) + " Hz, lookahead K = " + std::to_string(lookahead));
  row("frames sent / received", std::to_string(frames_sent) + " / " + std::to_string(frames_received));
  row("frames lost / duplicated / late", std::to_string(frames_lost) + " / " + std::to_string(frames_duplicated) + " / " + std::to_string(frames_late));
  row("throughput (skeletons/s)", num(throughput_fps, 1));
  std::snprintf(line, sizeof(line), "  %-34s %8s %8s %8s %8s %8s\n", "latency (ms)", "p50", "p90", "p99", "p99.9", "max");
  s << line;
  for (const auto& [name, l] : {std::pair<const char*, const LatencySummary&>{"  end to end (sent -> skeleton)", end_to_end},
                                {"  processing (beyond lookahead)", processing}}) {
    std::snprintf(line, sizeof(line), "  %-34s %8.3f %8.3f %8.3f %8.3f %8.3f\n", name, l.p50_ms, l.p90_ms, l.p99_ms, l.p999_ms, l.max_ms);
    s << line;
  }
  if (has_truth) {
    row("joint position error mean (cm)", num(mean_position_error_cm, 3));
    row("joint position error max (cm)", num(max_position_error_cm, 3));
    row("joint rotation error mean (deg)", num(mean_rotation_error_deg, 3));
  }
  return s.str();
}

std::string LatencyHistogramSvg(const std::vector<double>& latencies_ms, const std::string& title) {
  // Log-spaced bins from 10 us to 100 ms; anything outside lands in the end bins.
  constexpr int kBins = 48;
  constexpr double kLo = 0.01, kHi = 100.0;
  std::vector<int> counts(kBins, 0);
  for (double v : latencies_ms) {
    const double x = std::log10(std::clamp(v, kLo, kHi) / kLo) / std::log10(kHi / kLo);
    ++counts[static_cast<size_t>(std::min(kBins - 1, static_cast<int>(x * kBins)))];
  }
  const int peak = std::max(1, *std::max_element(counts.begin(), counts.end()));
  const double w = 720, h = 360, left = 60, right = 20, top = 40, bottom = 50;
  const double plot_w = w - left - right, plot_h = h - top - bottom;
  std::ostringstream s;
  s << "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"" << w << "\" height=\"" << h << "\" font-family=\"sans-serif\" font-size=\"12\">\n";
  s << "<rect width=\"100%\" height=\"100%\" fill=\"white\"/>\n";
  std::string escaped;
  for (char c : title) escaped += c == '<' ? "&lt;" : c == '&' ? "&amp;" : std::string(1, c);
  s << "<text x=\"" << w / 2 << "\" y=\"22\" text-anchor=\"middle\" font-size=\"14\">" << escaped << "</text>\n";
  for (int b = 0; b < kBins; ++b) {
    const double bh = plot_h * counts[static_cast<size_t>(b)] / peak;
    s << "<rect x=\"" << left + plot_w * b / kBins << "\" y=\"" << top + plot_h - bh << "\" width=\"" << plot_w / kBins - 1 << "\" height=\"" << bh
      << "\" fill=\"#4878a8\"><title>" << counts[static_cast<size_t>(b)] << "</title></rect>\n";
  }
  s << "<line x1=\"" << left << "\" y1=\"" << top + plot_h << "\" x2=\"" << left + plot_w << "\" y2=\"" << top + plot_h << "\" stroke=\"black\"/>\n";
  s << "<line x1=\"" << left << "\" y1=\"" << top << "\" x2=\"" << left << "\" y2=\"" << top + plot_h << "\" stroke=\"black\"/>\n";
  const char* ticks[] = {"0.01", "0.1", "1", "10", "100"};
  for (int d = 0; d <= 4; ++d) {
    const double x = left + plot_w * d / 4.0;
    s << "<text x=\"" << x << "\" y=\"" << top + plot_h + 16 << "\" text-anchor=\"middle\">" << ticks[d] << "</text>\n";
  }
  s << "<text x=\"" << left + plot_w / 2 << "\" y=\"" << h - 12 << "\" text-anchor=\"middle\">processing latency (ms, log scale)</text>\n";
  s << "<text x=\"14\" y=\"" << top + plot_h / 2 << "\" transform=\"rotate(-90 14 " << top + plot_h / 2
    << ")\" text-anchor=\"middle\">frames</text>\n";
  s << "<text x=\"" << left + 4 << "\" y=\"" << top + 12 << "\">peak " << peak << "</text>\n";
  if (!latencies_ms.empty()) {
    for (const auto& [q, name] : {std::pair{0.5, "p50"}, std::pair{0.99, "p99"}}) {
      const double v = Quantile(latencies_ms, q);
      const double x = left + plot_w * std::log10(std::clamp(v, kLo, kHi) / kLo) / std::log10(kHi / kLo);
      s << "<line x1=\"" << x << "\" y1=\"" << top << "\" x2=\"" << x << "\" y2=\"" << top + plot_h << "\" stroke=\"#c04040\" stroke-dasharray=\"4 3\"/>\n";
      s << "<text x=\"" << x + 3 << "\" y=\"" << top + 26 + (q > 0.9 ? 14 : 0) << "\" fill=\"#c04040\">" << name << " " << v << " ms</text>\n";
    }
  }
  s << "</svg>\n";
  return s.str();
}

}  // namespace mocapd
