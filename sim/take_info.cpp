// Take inspection for `mocap-sim info`.
#include "sim/take_info.hpp"

#include <algorithm>
#include <cstdio>
#include <nlohmann/json.hpp>
#include <stdexcept>

#include <boost/algorithm/string/case_conv.hpp>

#include "formats/bvh.hpp"
#include "formats/c3d.hpp"
#include "protocol/messages.hpp"
#include "sim/recording.hpp"

namespace mocapd {

std::string FileExtension(const std::string& path) {
  const size_t dot = path.rfind('.');
  const size_t slash = path.find_last_of('/');
  if (dot == std::string::npos || (slash != std::string::npos && dot < slash)) return "";
  return boost::algorithm::to_lower_copy(path.substr(dot + 1));
}

namespace {

// Follows one subject's frame numbers: a v2 session id that changes, a change of protocol
// version, or v1 numbers that start again behind the session's first begin a new capture
// session; within one, numbers skipped are frames lost before the recorder. Numbers are
// compared as the daemon compares them, modulo 2^64: a counter that wraps goes on.
struct StreamTracker {
  RecordedStreamInfo info;
  uint64_t session_id = 0;
  uint64_t session_first = 0;
  int version = 0;
  int64_t first_ns = 0;

  static bool Behind(uint64_t n, uint64_t than) { return n != than && than - n < (1ull << 63); }

  void Add(const protocol::MarkerFrameMessage& frame, int64_t arrival_ns) {
    const uint64_t n = frame.frame_number;
    const bool new_session = info.frames == 0 || frame.version != version ||
                             (frame.version >= 2 && frame.stream.session_id != session_id) ||
                             (frame.version < 2 && Behind(n, session_first));
    const bool ahead = !new_session && n != info.last_frame && !Behind(n, info.last_frame);
    if (new_session) {
      ++info.sessions;
      session_id = frame.stream.session_id;
      session_first = n;
      version = frame.version;
    } else if (ahead) {
      info.frames_skipped += static_cast<int64_t>(n - info.last_frame - 1);
    } else {
      ++info.frames_out_of_order;
    }
    if (info.frames == 0) {
      info.first_frame = n;
      first_ns = arrival_ns;
      info.min_protocol_version = frame.version;
    }
    if (new_session || ahead) info.last_frame = n;
    ++info.frames;
    info.markers = std::max(info.markers, static_cast<int>(frame.positions.size()));
    info.rate_hz = frame.rate_hz;
    info.protocol_version = std::max(info.protocol_version, static_cast<int>(frame.version));
    info.min_protocol_version =
        std::min(info.min_protocol_version, static_cast<int>(frame.version));
    info.seconds = static_cast<double>(arrival_ns - first_ns) * 1e-9;
  }
};

void InspectRecording(const std::string& path, TakeInfo* info) {
  const Recording recording = ReadRecording(path);
  info->format = "recording";
  info->units = "m";
  info->messages = static_cast<int64_t>(recording.messages.size());
  info->ignored_tail_bytes = recording.ignored_tail_bytes;
  std::vector<StreamTracker> streams;
  auto stream_of = [&](const std::string& subject) -> StreamTracker& {
    for (StreamTracker& s : streams)
      if (s.info.subject == subject) return s;
    streams.emplace_back();
    streams.back().info.subject = subject;
    return streams.back();
  };
  protocol::MarkerFrameMessage frame;
  protocol::EndOfStreamMessage end;
  for (const RecordedMessage& m : recording.messages) {
    if (protocol::DecodeMarkerFrame(m.message, &frame) == protocol::DecodeStatus::kOk) {
      stream_of(frame.subject).Add(frame, m.offset_ns);
      ++info->frames;
    } else if (protocol::DecodeEndOfStream(m.message, &end) == protocol::DecodeStatus::kOk) {
      ++stream_of(end.subject).info.end_of_stream;
    } else if (protocol::MessageType type{};
               protocol::PeekType(m.message, &type) == protocol::DecodeStatus::kOk &&
               type == protocol::MessageType::kMarkerFrame) {
      ++info->undecodable_marker_frames;
    } else {
      ++info->undecodable_messages;
    }
  }
  for (const StreamTracker& s : streams) info->streams.push_back(s.info);
  if (!info->streams.empty()) info->rate_hz = info->streams.front().rate_hz;
  if (!recording.messages.empty())
    info->seconds = static_cast<double>(recording.messages.back().offset_ns -
                                        recording.messages.front().offset_ns) *
                    1e-9;
}

// Text left-aligned in a column of width bytes (a longer text keeps all of itself).
std::string Padded(std::string text, size_t width) {
  if (text.size() < width) text.append(width - text.size(), ' ');
  return text;
}

}  // namespace

TakeInfo InspectTake(const std::string& path) {
  TakeInfo info;
  info.path = path;
  const std::string ext = FileExtension(path);
  if (IsRecordingFile(path)) {
    InspectRecording(path, &info);
  } else if (ext == "c3d") {
    const C3dTake take = ReadC3d(path);
    info.format = "c3d";
    info.frames = take.num_frames;
    info.rate_hz = take.rate_hz;
    info.units = take.units;
    info.processor = take.processor;
    info.analog_channels = take.analog.labels;
    info.analog_samples_per_frame = take.analog.samples_per_frame;
    info.origin_samples_missing = take.origin_samples_missing;
    info.notes = take.notes;
    for (int p = 0; p < take.num_points(); ++p) {
      PointInfo pi;
      pi.label = take.labels[static_cast<size_t>(p)];
      pi.kind = take.is_marker(p) ? "marker" : take.model_output_kind[static_cast<size_t>(p)];
      int missing = 0, run = 0;
      for (int f = 0; f < take.num_frames; ++f) {
        if (!take.valid(f, p)) {
          ++missing;
          if (run == 0) ++pi.gaps;
          ++run;
          pi.longest_gap = std::max(pi.longest_gap, run);
        } else {
          run = 0;
        }
      }
      pi.missing_fraction =
          take.num_frames > 0 ? static_cast<double>(missing) / take.num_frames : 0.0;
      info.points.push_back(pi);
    }
  } else if (ext == "bvh") {
    const BvhTake take = ReadBvh(path);
    info.format = "bvh";
    info.frames = take.num_frames();
    info.rate_hz = take.rate_hz();
    info.units = take.units;
    info.units_guessed = take.units_guessed;
    for (const Joint& j : take.skeleton.joints())
      info.joints.push_back(j.name + " (" + to_string(j.type) + ")");
    info.end_sites = static_cast<int>(take.end_sites.size());
  } else {
    throw std::invalid_argument(path + ": unknown take format '." + ext +
                                "' (expected .c3d, .bvh or a recording made by mocap-sim record)");
  }
  if (info.format != "recording" && info.rate_hz > 0) info.seconds = info.frames / info.rate_hz;
  return info;
}

// Every name a file or a sender chose is printed escaped (protocol::PrintableName): a
// recorded subject name or a C3D label may hold control characters, which would move a
// terminal's cursor or forge a line.
std::string FormatTakeInfo(const TakeInfo& info) {
  char line[256];
  std::string out;
  // Names go in as strings, numbers through snprintf: a long path or an escaped name
  // would be cut by the line buffer, taking its newline with it.
  out += protocol::PrintableName(info.path) + "\n  format  " + info.format + "\n";
  std::snprintf(line, sizeof(line), "  frames  %d\n  rate    %.6g Hz (%.3f s)\n", info.frames,
                info.rate_hz, info.seconds);
  out += line;
  out += "  units   " + info.units + (info.units_guessed ? " (guessed from its bones)" : "") + "\n";
  if (info.format == "c3d") {
    out += "  processor " + protocol::PrintableName(info.processor) + "\n";
    if (!info.analog_channels.empty()) {
      std::snprintf(line, sizeof(line), "  analog  %zu channels x %d samples a frame (%.6g Hz):",
                    info.analog_channels.size(), info.analog_samples_per_frame,
                    info.rate_hz * info.analog_samples_per_frame);
      out += line;
      for (const std::string& label : info.analog_channels)
        out += " " + protocol::PrintableName(label);
      out += "\n";
    }
    for (const std::string& note : info.notes)
      out += "  note    " + protocol::PrintableName(note) + "\n";
    if (info.origin_samples_missing > 0)
      out += "  " + std::to_string(info.origin_samples_missing) +
             " marker samples at exactly (0, 0, 0) read as missing (an exporter's gaps)\n";
    std::snprintf(line, sizeof(line), "  %-24s %-8s %9s %6s %12s\n", "label", "kind", "missing%",
                  "gaps", "longest gap");
    out += line;
    for (const PointInfo& p : info.points) {
      std::snprintf(line, sizeof(line), " %8.2f%% %6d %12d\n", 100.0 * p.missing_fraction, p.gaps,
                    p.longest_gap);
      out += "  " + Padded(protocol::PrintableName(p.label), 24) + " " +
             Padded(protocol::PrintableName(p.kind), 8) + line;
    }
  } else if (info.format == "recording") {
    std::snprintf(line, sizeof(line),
                  "  messages %lld (%lld marker frames that do not decode, %lld neither a marker "
                  "frame nor an end)\n",
                  static_cast<long long>(info.messages),
                  static_cast<long long>(info.undecodable_marker_frames),
                  static_cast<long long>(info.undecodable_messages));
    out += line;
    if (info.ignored_tail_bytes > 0)
      out += "  note    ends in an interrupted record (" + std::to_string(info.ignored_tail_bytes) +
             " bytes ignored)\n";
    std::snprintf(line, sizeof(line), "  %-16s %8s %9s %9s %8s %9s %8s %7s %8s %4s %5s\n",
                  "subject", "frames", "first", "last", "skipped", "reordered", "sessions",
                  "markers", "rate Hz", "ends", "v");
    out += line;
    for (const RecordedStreamInfo& s : info.streams) {
      std::snprintf(
          line, sizeof(line), " %8lld %9llu %9llu %8lld %9lld %8d %7d %8.6g %4d %5s\n",
          static_cast<long long>(s.frames), static_cast<unsigned long long>(s.first_frame),
          static_cast<unsigned long long>(s.last_frame), static_cast<long long>(s.frames_skipped),
          static_cast<long long>(s.frames_out_of_order), s.sessions, s.markers, s.rate_hz,
          s.end_of_stream,
          (s.min_protocol_version == s.protocol_version
               ? std::to_string(s.protocol_version)
               : std::to_string(s.min_protocol_version) + "+" + std::to_string(s.protocol_version))
              .c_str());
      out += "  " + Padded(protocol::PrintableName(s.subject), 16) + line;
    }
  } else {
    out += "  joints  " + std::to_string(info.joints.size()) + " (+" +
           std::to_string(info.end_sites) + " end sites)\n";
    for (const std::string& j : info.joints) out += "    " + protocol::PrintableName(j) + "\n";
  }
  return out;
}

nlohmann::json TakeInfoJson(const TakeInfo& info) {
  nlohmann::json j = {{"path", info.path},       {"format", info.format},   {"frames", info.frames},
                      {"rate_hz", info.rate_hz}, {"seconds", info.seconds}, {"units", info.units}};
  if (info.format == "c3d") {
    j["processor"] = info.processor;
    j["analog"] = {{"channels", info.analog_channels},
                   {"samples_per_frame", info.analog_samples_per_frame}};
    j["origin_samples_missing"] = info.origin_samples_missing;
    j["notes"] = info.notes;
    j["points"] = nlohmann::json::array();
    for (const PointInfo& p : info.points)
      j["points"].push_back({{"label", p.label},
                             {"kind", p.kind},
                             {"missing_fraction", p.missing_fraction},
                             {"gaps", p.gaps},
                             {"longest_gap", p.longest_gap}});
  } else if (info.format == "recording") {
    j["messages"] = info.messages;
    j["undecodable_marker_frames"] = info.undecodable_marker_frames;
    j["undecodable_messages"] = info.undecodable_messages;
    j["ignored_tail_bytes"] = info.ignored_tail_bytes;
    j["streams"] = nlohmann::json::array();
    for (const RecordedStreamInfo& s : info.streams)
      j["streams"].push_back({{"subject", s.subject},
                              {"frames", s.frames},
                              {"first_frame", s.first_frame},
                              {"last_frame", s.last_frame},
                              {"frames_skipped", s.frames_skipped},
                              {"frames_out_of_order", s.frames_out_of_order},
                              {"sessions", s.sessions},
                              {"markers", s.markers},
                              {"rate_hz", s.rate_hz},
                              {"end_of_stream", s.end_of_stream},
                              {"protocol_version", s.protocol_version},
                              {"min_protocol_version", s.min_protocol_version},
                              {"seconds", s.seconds}});
  } else {
    j["joints"] = info.joints;
    j["units_guessed"] = info.units_guessed;
    j["end_sites"] = info.end_sites;
  }
  return j;
}

}  // namespace mocapd
