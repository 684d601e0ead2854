// Recorded capture streams (`mocap-sim record`, replayed by `mocap-sim replay FILE.mcr`):
// every message a capture publisher sent, with its topic and the time it arrived, so a
// session can be played back later with its original timing, gaps and glitches.
//
// File (little-endian): a 16-byte header ("MCPDREC1", then the recording's start as u64
// wall-clock ns), then one record per message: u64 arrival offset from the start (ns),
// u32 topic length, u32 message length, u32 CRC-32 of those 16 bytes, the topic, the
// message, u32 CRC-32 of topic and message. Each record is appended with a single write(2), so a
// recorder that is killed leaves at most one partial record at the end; the reader stops at the
// first record that is incomplete or fails its CRC, and says so, keeping everything before it.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

namespace mocapd {

struct RecordedMessage {
  int64_t offset_ns = 0;  ///< Arrival time since the recording started.
  std::string topic;
  std::vector<uint8_t> message;
};

struct Recording {
  uint64_t start_wall_ns = 0;
  std::vector<RecordedMessage> messages;
  /// Bytes after the last good record (an interrupted write); 0 for a clean file.
  size_t ignored_tail_bytes = 0;
};

class RecordingWriter {
 public:
  /// Creates (truncates) path. Throws std::runtime_error naming it on failure.
  explicit RecordingWriter(const std::string& path);
  ~RecordingWriter();
  RecordingWriter(const RecordingWriter&) = delete;
  RecordingWriter& operator=(const RecordingWriter&) = delete;
  /// Appends one record (one write(2)); throws std::runtime_error on a write error.
  void Append(int64_t offset_ns, std::string_view topic, std::span<const uint8_t> message);
  /// Forces the data to the disk (called about once a second by the recorder).
  void Sync();
  uint64_t records() const { return records_; }

 private:
  std::string path_;
  int fd_ = -1;
  uint64_t records_ = 0;
  std::vector<uint8_t> buffer_;
};

/// Reads a recording. Throws std::runtime_error naming the file if it cannot be read or
/// is not a recording; a damaged or partial tail is reported in ignored_tail_bytes.
Recording ReadRecording(const std::string& path);

struct RecordOptions {
  std::string from = "tcp://127.0.0.1:5555";  ///< The capture publisher to subscribe to.
  std::string out;
  std::vector<std::string> subjects;  ///< Topics markers/<name>/; empty: every markers/ topic.
  double seconds = 0.0;               ///< Stop after this long (0: until stop is set).
  /// CURVE (both or neither): the recorder's key pair and the publisher's public key.
  std::string curve_key_file;
  std::string curve_server_key_file;
  const std::atomic<bool>* stop = nullptr;
};

/// Subscribes to a capture publisher and records what arrives until seconds pass or
/// stop is set. Returns the number of messages recorded. The file is valid at every
/// moment: a recorder killed mid-way leaves a readable recording.
uint64_t RecordStream(const RecordOptions& options,
                      const std::function<void(const std::string&)>& on_status);

/// True if the file starts like a recording.
bool IsRecordingFile(const std::string& path);

}  // namespace mocapd
