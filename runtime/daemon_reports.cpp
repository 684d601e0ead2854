// What the daemon's HTTP endpoint serves: Prometheus metrics (serialised by
// prometheus-cpp, so the exposition format is the library's, not hand-rolled), and JSON
// for /subjects and /health.
#include <prometheus/counter.h>
#include <prometheus/gauge.h>
#include <prometheus/histogram.h>
#include <prometheus/registry.h>
#include <prometheus/text_serializer.h>
#include <spdlog/fmt/fmt.h>
#include <nlohmann/json.hpp>

#include "runtime/daemon.hpp"

#include <algorithm>
#include <cstdio>

namespace mocapd {
namespace {

// The drop series that can count anything. A message is charged to a subject only once
// its name is read and configured: a size over the limit, another message type or an
// unknown name are never a subject's; the subject's own checks (model, rate, numbering)
// never leave a drop unattributed. Exported at zero, the others were pairs no daemon can
// produce on every dashboard.
bool ChargeableToSubject(DropReason reason) {
  return reason != DropReason::kOversized && reason != DropReason::kNotMarkerFrame &&
         reason != DropReason::kUnknownSubject;
}
bool LeftUnattributed(DropReason reason) {
  return reason == DropReason::kOversized || reason == DropReason::kMalformed ||
         reason == DropReason::kNonFinite || reason == DropReason::kNotMarkerFrame ||
         reason == DropReason::kUnknownSubject;
}

}  // namespace

std::string FormatPrometheusMetrics(const DaemonStats& stats) {
  using prometheus::BuildCounter;
  using prometheus::BuildGauge;
  using prometheus::BuildHistogram;
  prometheus::Registry registry;
  auto counter = [&](const std::string& name,
                     const std::string& help) -> prometheus::Family<prometheus::Counter>& {
    return BuildCounter().Name(name).Help(help).Register(registry);
  };
  auto gauge = [&](const std::string& name,
                   const std::string& help) -> prometheus::Family<prometheus::Gauge>& {
    return BuildGauge().Name(name).Help(help).Register(registry);
  };
  gauge("mocapd_up", "1 while the data plane is running").Add({}).Set(stats.running ? 1 : 0);
  gauge("mocapd_uptime_seconds", "Seconds since the data plane started")
      .Add({})
      .Set(stats.uptime_s);
  counter("mocapd_messages_received_total", "Messages received on the input socket")
      .Add({})
      .Increment(static_cast<double>(stats.messages_in));
  counter("mocapd_control_messages_total", "End-of-stream messages accepted")
      .Add({})
      .Increment(static_cast<double>(stats.control_messages));
  counter("mocapd_reloads_total", "Configuration reloads applied")
      .Add({})
      .Increment(static_cast<double>(stats.reloads));
  counter("mocapd_reload_failures_total", "Configuration reloads refused (invalid config)")
      .Add({})
      .Increment(static_cast<double>(stats.reload_failures));
  counter("mocapd_http_unauthorized_total", "HTTP requests refused: no or a wrong bearer token")
      .Add({})
      .Increment(static_cast<double>(stats.http_unauthorized));
  counter("mocapd_http_over_connections_total",
          "HTTP connections closed unanswered: control.http_max_connections were open")
      .Add({})
      .Increment(static_cast<double>(stats.http_over_connections));
  counter("mocapd_http_foreign_host_total",
          "HTTP requests refused: a loopback server asked under another host name")
      .Add({})
      .Increment(static_cast<double>(stats.http_foreign_host));
  if (stats.live_view) {
    gauge("mocapd_live_viewers", "Browser pages open on the live view")
        .Add({})
        .Set(stats.live_viewers);
    const LiveViewCounters& live = stats.live_counters;
    struct LiveCount {
      const char* name;
      const char* help;
      uint64_t value;
    };
    for (const LiveCount& c :
         {LiveCount{"mocapd_live_messages_sent_total", "Live-view messages sent to pages",
                    live.messages_sent},
          LiveCount{"mocapd_live_messages_skipped_total",
                    "Live-view messages skipped: the page was still taking the last one",
                    live.messages_skipped},
          LiveCount{
              "mocapd_live_viewers_closed_slow_total",
              "Live-view pages closed for taking nothing for control.live_view_close_stalled_s",
              live.viewers_closed_slow},
          LiveCount{"mocapd_live_viewers_refused_total",
                    "Live-view pages refused: control.live_view_max_viewers were open",
                    live.viewers_refused},
          LiveCount{"mocapd_live_unknown_subject_total",
                    "Live-view sockets refused: ?subject= names no subject of this daemon",
                    live.unknown_subject},
          LiveCount{"mocapd_live_viewers_closed_bad_input_total",
                    "Live-view pages closed for what they sent: a malformed WebSocket frame, "
                    "a message over 4 kB",
                    live.viewers_closed_bad_input}})
      counter(c.name, c.help).Add({}).Increment(static_cast<double>(c.value));
  }
  if (stats.curve) {
    auto& accepted = counter("mocapd_curve_clients_accepted_total",
                             "CURVE clients admitted: key in security.authorized_keys");
    auto& refused = counter("mocapd_curve_clients_refused_total",
                            "CURVE clients refused: key not in security.authorized_keys");
    auto& failed = counter("mocapd_curve_handshake_failures_total",
                           "Handshakes failed otherwise: a peer without CURVE or other keys");
    for (int i = 0; i < kCurveSocketCount; ++i) {
      const prometheus::Labels socket = {{"socket", CurveSocketName(static_cast<CurveSocket>(i))}};
      accepted.Add(socket).Increment(static_cast<double>(stats.curve_counts.accepted[i]));
      refused.Add(socket).Increment(static_cast<double>(stats.curve_counts.refused[i]));
      failed.Add(socket).Increment(static_cast<double>(stats.curve_counts.handshake_failures[i]));
    }
  }
  counter("mocapd_output_send_failures_total", "Messages the PUB socket could not queue")
      .Add({})
      .Increment(static_cast<double>(stats.output_send_failures));
  counter("mocapd_retired_frames_published_total", "Frames published by subjects a reload removed")
      .Add({})
      .Increment(static_cast<double>(stats.retired_published));
  counter("mocapd_retired_frames_dropped_total", "Frames dropped by subjects a reload removed")
      .Add({})
      .Increment(static_cast<double>(stats.retired_dropped));

  auto& received = counter("mocapd_frames_received_total", "Marker frames received per subject");
  auto& published =
      counter("mocapd_frames_published_total", "Received frames published (cleaned and solved)");
  auto& inserted = counter("mocapd_frames_inserted_total",
                           "All-missing frames inserted for missing frame numbers");
  auto& dropped = counter("mocapd_frames_dropped_total",
                          "Input messages dropped, by subject (empty if unknown) and reason");
  auto& pending = gauge("mocapd_frames_pending", "Frames held in the lookahead");
  auto& restarts = counter("mocapd_capture_restarts_total",
                           "Capture restarts or long frame-number jumps re-synchronised");
  auto& skipped = counter("mocapd_frames_skipped_total",
                          "Frame numbers that never arrived (forward gaps within a session)");
  auto& sessions = counter("mocapd_capture_sessions_changed_total",
                           "Capture restarts announced by a new session id (protocol v2)");
  auto& stalls =
      counter("mocapd_input_stalls_total", "Times the watchdog saw a subject's input stall");
  auto& state =
      gauge("mocapd_subject_state", "0 tracking, 1 repairing, 2 lost, 3 stalled, 4 waiting");
  auto& repaired =
      counter("mocapd_samples_repaired_total", "Published marker samples repaired, by detector");
  auto& unrecoverable = counter("mocapd_samples_unrecoverable_total",
                                "Published marker samples with no data to repair from");
  auto& iterations = counter("mocapd_solve_iterations_total", "IK iterations over all solves");
  auto& failures = counter("mocapd_solve_failures_total", "IK solves that failed numerically");
  auto& cold = counter("mocapd_solve_cold_starts_total", "IK solves that started cold");
  auto& out_of_volume =
      counter("mocapd_samples_out_of_volume_total",
              "Samples beyond the capture volume (1e30, FLT_MAX), taken as missing");
  auto& glitches = counter("mocapd_glitch_frames_total",
                           "Whole frames that jumped further than a body moves, taken as missing");
  auto& resyncs = counter("mocapd_capture_resyncs_total",
                          "Whole-frame jumps that persisted, taken as a re-synchronisation");
  auto& character_published =
      counter("mocapd_character_frames_published_total",
              "Retargeted character frames published, by subject and character file");
  auto& calibration_state =
      gauge("mocapd_live_calibration_state",
            "Live calibration: 0 waiting, 1 collecting, 2 calibrated, 3 failed");
  auto& calibration_collected = gauge("mocapd_live_calibration_collected_seconds",
                                      "Live calibration: seconds of motion collected");
  auto& calibration_ready =
      gauge("mocapd_live_calibration_joints_ready", "Live calibration: joints ready");
  auto& calibration_swaps = counter("mocapd_live_calibration_swaps_total",
                                    "Live calibration: calibrated subjects swapped in");
  auto& latency = BuildHistogram()
                      .Name("mocapd_processing_latency_seconds")
                      .Help("From receiving the frame that completes a publication to sending it")
                      .Register(registry);
  const prometheus::Histogram::BucketBoundaries bounds(kLatencyBucketsS.begin(),
                                                       kLatencyBucketsS.end());
  for (int r = 0; r < kDropReasonCount; ++r)
    if (LeftUnattributed(static_cast<DropReason>(r)))
      dropped.Add({{"subject", ""}, {"reason", to_string(static_cast<DropReason>(r))}})
          .Increment(static_cast<double>(stats.unattributed_dropped[static_cast<size_t>(r)]));
  for (const SubjectStats& s : stats.subjects) {
    const prometheus::Labels subject{{"subject", s.name}};
    received.Add(subject).Increment(static_cast<double>(s.counters.frames_in));
    published.Add(subject).Increment(static_cast<double>(s.counters.frames_published));
    inserted.Add(subject).Increment(static_cast<double>(s.counters.frames_inserted));
    pending.Add(subject).Set(static_cast<double>(s.pending));
    restarts.Add(subject).Increment(static_cast<double>(s.counters.restarts));
    skipped.Add(subject).Increment(static_cast<double>(s.counters.frames_skipped));
    sessions.Add(subject).Increment(static_cast<double>(s.counters.session_changes));
    stalls.Add(subject).Increment(static_cast<double>(s.counters.stalls));
    state.Add(subject).Set(static_cast<double>(s.state));
    unrecoverable.Add(subject).Increment(static_cast<double>(s.cleanup.unrecoverable));
    iterations.Add(subject).Increment(static_cast<double>(s.cleanup.solve_iterations));
    failures.Add(subject).Increment(static_cast<double>(s.cleanup.solve_failures));
    cold.Add(subject).Increment(static_cast<double>(s.cleanup.cold_starts));
    out_of_volume.Add(subject).Increment(static_cast<double>(s.cleanup.samples_out_of_volume));
    glitches.Add(subject).Increment(static_cast<double>(s.cleanup.glitch_frames));
    resyncs.Add(subject).Increment(static_cast<double>(s.cleanup.resyncs));
    for (int r = 0; r < kDropReasonCount; ++r)
      if (ChargeableToSubject(static_cast<DropReason>(r)))
        dropped.Add({{"subject", s.name}, {"reason", to_string(static_cast<DropReason>(r))}})
            .Increment(static_cast<double>(s.counters.dropped[static_cast<size_t>(r)]));
    for (int r = 1; r < kMaskReasonCount; ++r)
      repaired.Add({{"subject", s.name}, {"detector", to_string(static_cast<MaskReason>(r))}})
          .Increment(static_cast<double>(s.cleanup.repaired_by[static_cast<size_t>(r)]));
    std::vector<double> buckets(s.counters.processing.counts.begin(),
                                s.counters.processing.counts.end());
    latency.Add(subject, bounds).ObserveMultiple(buckets, s.counters.processing.sum_s);
    if (s.character)
      character_published.Add({{"subject", s.name}, {"character", s.character->file}})
          .Increment(static_cast<double>(s.counters.character_frames_published));
    if (const auto& c = s.calibration) {
      calibration_state.Add(subject).Set(static_cast<double>(c->state));
      calibration_collected.Add(subject).Set(c->collected_s);
      calibration_ready.Add(subject).Set(static_cast<double>(std::count_if(
          c->joints.begin(), c->joints.end(), [](const auto& j) { return j.ready; })));
      calibration_swaps.Add(subject).Increment(static_cast<double>(c->swaps));
    }
  }
  return prometheus::TextSerializer().Serialize(registry.Collect());
}

namespace {

nlohmann::json SubjectJson(const SubjectStats& s) {
  nlohmann::json dropped = nlohmann::json::object();
  for (int r = 0; r < kDropReasonCount; ++r)
    if (s.counters.dropped[static_cast<size_t>(r)] > 0)
      dropped[to_string(static_cast<DropReason>(r))] = s.counters.dropped[static_cast<size_t>(r)];
  nlohmann::json repaired = nlohmann::json::object();
  for (int r = 1; r < kMaskReasonCount; ++r)
    if (s.cleanup.repaired_by[static_cast<size_t>(r)] > 0)
      repaired[to_string(static_cast<MaskReason>(r))] =
          s.cleanup.repaired_by[static_cast<size_t>(r)];
  const protocol::StreamInfo& stream = s.counters.last_stream;
  const double mean_latency_us =
      s.counters.processing.count > 0
          ? s.counters.processing.sum_s / static_cast<double>(s.counters.processing.count) * 1e6
          : 0.0;
  return {{"name", s.name},
          {"worker", s.worker},
          {"state", protocol::to_string(s.state)},
          {"markers", s.markers},
          {"joints", s.joints},
          {"rate_hz", s.rate_hz},
          {"lookahead_frames", s.lookahead},
          {"marker_set_hash", s.marker_set_hash},
          {"skeleton_hash", s.skeleton_hash},
          {"frames_received", s.counters.frames_in},
          {"frames_published", s.counters.frames_published},
          {"frames_inserted", s.counters.frames_inserted},
          {"frames_pending", s.pending},
          {"frames_dropped", dropped},
          {"frames_skipped", s.counters.frames_skipped},
          {"capture_restarts", s.counters.restarts},
          {"capture_session_changes", s.counters.session_changes},
          {"capture_session_id", stream.session_id},
          {"last_timecode", stream.has_timecode
                                ? nlohmann::json(protocol::FormatTimecode(stream.timecode))
                                : nlohmann::json(nullptr)},
          {"input_stalls", s.counters.stalls},
          {"last_frame_number", s.counters.last_frame_number},
          {"seconds_since_last_input", s.since_last_input_s},
          {"samples_repaired", repaired},
          {"samples_unrecoverable", s.cleanup.unrecoverable},
          {"samples_out_of_volume", s.cleanup.samples_out_of_volume},
          {"rejecting_input", s.rejecting_input},
          {"unstable_input", s.unstable_input},
          {"model_suspect", s.model_suspect},
          {"model_distance_mm", s.model_distance_mm},
          {"glitch_frames", s.cleanup.glitch_frames},
          {"capture_resyncs", s.cleanup.resyncs},
          {"mean_processing_latency_us", mean_latency_us}};
}

// A live calibration's progress: the state, and per joint how ready its centre is.
nlohmann::json CalibrationJson(const LiveCalibrationStatus& c) {
  nlohmann::json joints = nlohmann::json::array();
  for (const JointReadiness& j : c.joints) {
    auto known = [](double v) { return v >= 0.0 ? nlohmann::json(v) : nlohmann::json(nullptr); };
    joints.push_back(
        {{"joint", j.name},
         {"method", j.method.empty() ? nlohmann::json(nullptr) : nlohmann::json(j.method)},
         {"directions_covered", j.directions_covered},
         {"uncertainty_mm", known(j.uncertainty_mm)},
         {"moved_mm", known(j.moved_mm)},
         {"ready", j.ready}});
  }
  return {
      {"state", to_string(c.state)},
      {"height_m", c.height_m},
      {"collected_s", c.collected_s},
      {"refinements", c.refinements},
      {"median_residual_mm",
       c.median_residual_mm >= 0 ? nlohmann::json(c.median_residual_mm) : nlohmann::json(nullptr)},
      {"swapped_in", c.swaps},
      {"written_to", c.written_to.empty() ? nlohmann::json(nullptr) : nlohmann::json(c.written_to)},
      {"message", c.message},
      {"joints", joints}};
}

}  // namespace

std::string FormatSubjectsJson(const DaemonStats& stats) {
  nlohmann::json subjects = nlohmann::json::array();
  for (const SubjectStats& s : stats.subjects) {
    nlohmann::json subject = SubjectJson(s);
    if (s.calibration) subject["calibration"] = CalibrationJson(*s.calibration);
    if (s.character)
      subject["character"] = {{"file", s.character->file},
                              {"joints", s.character->joints},
                              {"bones_matched", s.character->bones_matched},
                              {"scale", s.character->scale},
                              {"stands_on", s.character->stands_on},
                              {"frames_published", s.counters.character_frames_published}};
    subjects.push_back(std::move(subject));
  }
  return subjects.dump(2, ' ', false, nlohmann::json::error_handler_t::replace) + "\n";
}

std::string RejectionDetail(const SubjectStats& s) {
  // Another bridge's marker set, or a hash written wrong (0): which the frames carry, and
  // what the model has, so an integrator can tell which.
  if (s.rejecting_input && s.rejecting_reason == DropReason::kModelMismatch)
    return fmt::format(
        ": the frames carry marker-set hash {} with {} markers, the subject's model {} with {}",
        s.mismatched_model_hash, s.mismatched_marker_count, s.marker_set_hash, s.markers);
  if (!s.rejecting_input || s.rejecting_reason != DropReason::kRateMismatch) return "";
  char detail[160];
  std::snprintf(detail, sizeof(detail),
                ": the frames say %g Hz, the subject is configured for %g Hz (rate_hz)",
                s.mismatched_rate_hz, s.rate_hz);
  return detail;
}

std::string UnstableInputText(const SubjectStats& s) {
  const UnstableCause& cause = s.unstable_cause;
  std::string mostly, likely;
  switch (cause.kind) {
    case UnstableCause::Kind::kResynchronisation:
      mostly = "re-synchronisations";
      likely = "two senders for one subject? a session id that changes every frame?";
      break;
    case UnstableCause::Kind::kRepeatedFrame:
      mostly = fmt::format("frames it had taken already, sent again ({})", to_string(cause.reason));
      likely = "two senders for one subject?";
      break;
    case UnstableCause::Kind::kTakenAndDropped:
      mostly = fmt::format("frames dropped as {} between frames taken", to_string(cause.reason));
      switch (cause.reason) {
        case DropReason::kNonFinite:
          likely = "a sender writing NaN or Inf into some frames?";
          break;
        case DropReason::kModelMismatch:
          likely = "two senders with different marker sets for one subject?";
          break;
        case DropReason::kRateMismatch:
          likely = "two senders at different rates for one subject?";
          break;
        case DropReason::kOversized: likely = "some frames over input.max_message_bytes?"; break;
        default: likely = "a sender writing some frames wrongly?"; break;
      }
      break;
  }
  return fmt::format(
      "input unstable: 5 re-synchronisations, repeated frames or switches between taken and "
      "dropped frames within 2 s, mostly {} ({})",
      mostly, likely);
}

std::string RestartLogLine(const SubjectStats& s, uint64_t restarts_since_last_report) {
  const SubjectCounters& c = s.counters;
  auto session = [](uint64_t id) {
    return id == 0 ? std::string() : fmt::format(" (session {})", id);
  };
  std::string line = fmt::format(
      "subject '{}': capture restart or jump in frame numbers, frame {}{} -> {}{}; pipeline "
      "re-synchronised",
      s.name, c.resync_from_frame, session(c.resync_from_session), c.resync_frame,
      session(c.resync_session));
  if (restarts_since_last_report > 1)
    line += fmt::format(" ({} re-synchronisations since the last report; the last shown)",
                        restarts_since_last_report);
  return line;
}

std::string FormatHealthJson(const DaemonStats& stats, bool data_plane_alive) {
  nlohmann::json subjects = nlohmann::json::object();
  nlohmann::json problems = nlohmann::json::array();
  for (const SubjectStats& s : stats.subjects) {
    subjects[s.name] = protocol::to_string(s.state);
    // Frames arriving, every one dropped: "input stalled" beside the rejection read as a
    // silent sender, which it is not. A rejected sender that then fell silent is stalled.
    const bool frames_arriving = s.since_last_input_s >= 0.0 && s.since_last_input_s < 0.5;
    if (s.state == protocol::SubjectState::kStalled && !(s.rejecting_input && frames_arriving))
      problems.push_back("subject '" + s.name + "': input stalled");
    if (s.rejecting_input)
      problems.push_back("subject '" + s.name + "': every frame dropped (" +
                         to_string(s.rejecting_reason) + ")" + RejectionDetail(s));
    if (s.unstable_input) problems.push_back("subject '" + s.name + "': " + UnstableInputText(s));
    // Half a second, as for the drops: an actor occluded for a few frames is no problem;
    // a bridge whose every marker is flagged invalid, or sits outside the capture volume,
    // left /health ok while the pose was guessed from nothing (or the subject lost).
    if (s.unobserved_for_s >= 0.5)
      problems.push_back(fmt::format(
          "subject '{}': no marker observed for {:.1f} s (none sent, flagged invalid, or "
          "outside the capture volume): the pose is {}",
          s.name, s.unobserved_for_s,
          s.state == protocol::SubjectState::kLost ? "held (lost)" : "guessed"));
    if (s.model_suspect) {
      char line[160];
      std::snprintf(line, sizeof(line),
                    "subject '%s': model suspect (received markers %.0f mm from the model's)",
                    s.name.c_str(), s.model_distance_mm);
      problems.push_back(line);
    }
  }
  // A configured subject that has never received a frame while another has streamed two
  // seconds: most likely its sender names it otherwise ("Actor3" for "actor3"), which a
  // subscribing daemon never even sees. It read "waiting", as a take that ended does, and
  // /health said ok.
  const bool another_streams =
      std::any_of(stats.subjects.begin(), stats.subjects.end(), [](const SubjectStats& s) {
        return s.rate_hz > 0.0 && static_cast<double>(s.counters.frames_in) >= 2.0 * s.rate_hz &&
               s.since_last_input_s >= 0.0 && s.since_last_input_s < 1.0;
      });
  for (const SubjectStats& s : stats.subjects)
    if (another_streams && s.counters.frames_in == 0 && s.since_last_input_s < 0.0)
      problems.push_back(
          "subject '" + s.name +
          "': no frame received while other subjects stream (a sender naming it otherwise? "
          "names match exactly, case included; " +
          (stats.last_unknown_subject.empty()
               ? std::string("with input.subscribe = \"all\", /health names the last unknown "
                             "name received)")
               : "the last unknown name received: '" +
                     protocol::PrintableName(stats.last_unknown_subject) + "')"));
  if (stats.rejecting_unattributed)
    problems.push_back(std::string("every input message dropped for over 0.5 s before a subject "
                                   "could be named (the last: ") +
                       to_string(stats.rejecting_unattributed_reason) + ")");
  // A data plane reading a backlog is busy, not dead; one flushing its lookahead on the
  // way out is stopping.
  const char* status = stats.stopping      ? "stopping"
                       : !data_plane_alive ? "down"
                       : stats.catching_up ? "catching up"
                       : !problems.empty() ? "degraded"
                                           : "ok";
  const nlohmann::json health = {
      {"status", status},
      {"uptime_s", stats.uptime_s},
      {"messages_received", stats.messages_in},
      {"frames_published", stats.published_total()},
      {"frames_dropped", stats.dropped_total()},
      {"frames_pending", stats.pending_total()},
      {"accounted", stats.Balanced()},
      {"catching_up", stats.catching_up},
      {"unknown_subject_dropped",
       stats.unattributed_dropped[static_cast<size_t>(DropReason::kUnknownSubject)]},
      {"last_unknown_subject", stats.last_unknown_subject},
      {"problems", problems},
      {"subjects", subjects}};
  // A sender's bytes (the last unknown subject's name) may be no UTF-8: replaced, not a
  // type_error that made every later /health a 500 until another name came.
  return health.dump(2, ' ', false, nlohmann::json::error_handler_t::replace) + "\n";
}

}  // namespace mocapd
