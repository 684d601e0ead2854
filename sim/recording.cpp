// Crash-safe recording of capture streams.
#include "sim/recording.hpp"

#include <fcntl.h>
#include <unistd.h>

#include <boost/crc.hpp>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <fstream>
#include <iterator>
#include <stdexcept>

#include <zmq.hpp>

#include "protocol/byte_io.hpp"
#include "protocol/curve.hpp"

namespace mocapd {
namespace {

constexpr char kMagic[8] = {'M', 'C', 'P', 'D', 'R', 'E', 'C', '1'};
constexpr size_t kHeaderBytes = 16;
constexpr size_t kRecordHeaderBytes = 20;  // offset u64, topic u32, message u32, crc u32

uint32_t Crc(std::span<const uint8_t> bytes) {
  boost::crc_32_type crc;
  crc.process_bytes(bytes.data(), bytes.size());
  return crc.checksum();
}

void WriteAll(int fd, const std::vector<uint8_t>& bytes, const std::string& path) {
  size_t done = 0;
  while (done < bytes.size()) {
    const ssize_t n = ::write(fd, bytes.data() + done, bytes.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) throw std::runtime_error(path + ": write failed: " + std::strerror(errno));
    done += static_cast<size_t>(n);
  }
}

}  // namespace

RecordingWriter::RecordingWriter(const std::string& path) : path_(path) {
  fd_ = ::open(path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd_ < 0) throw std::runtime_error(path + ": cannot create: " + std::strerror(errno));
  std::vector<uint8_t> header(kMagic, kMagic + sizeof(kMagic));
  ByteWriter w(&header);
  w.WriteU64(static_cast<uint64_t>(std::chrono::duration_cast<std::chrono::nanoseconds>(
                                       std::chrono::system_clock::now().time_since_epoch())
                                       .count()));
  WriteAll(fd_, header, path_);
}

RecordingWriter::~RecordingWriter() {
  if (fd_ >= 0) {
    ::fsync(fd_);
    ::close(fd_);
  }
}

void RecordingWriter::Append(int64_t offset_ns, std::string_view topic,
                             std::span<const uint8_t> message) {
  buffer_.clear();
  ByteWriter w(&buffer_);
  w.WriteU64(static_cast<uint64_t>(offset_ns));
  w.WriteU32(static_cast<uint32_t>(topic.size()));
  w.WriteU32(static_cast<uint32_t>(message.size()));
  // Two CRCs: the header's (so a damaged length is never trusted) and the payload's (so a
  // torn write is always detected).
  w.WriteU32(Crc(buffer_));
  const size_t payload_start = buffer_.size();
  buffer_.insert(buffer_.end(), topic.begin(), topic.end());
  buffer_.insert(buffer_.end(), message.begin(), message.end());
  const uint32_t payload_crc =
      Crc({buffer_.data() + payload_start, buffer_.size() - payload_start});
  w.WriteU32(payload_crc);
  WriteAll(fd_, buffer_, path_);
  ++records_;
}

void RecordingWriter::Sync() {
  if (::fsync(fd_) != 0)
    throw std::runtime_error(path_ + ": fsync failed: " + std::strerror(errno));
}

uint64_t RecordStream(const RecordOptions& o,
                      const std::function<void(const std::string&)>& on_status) {
  zmq::context_t context;
  zmq::socket_t in(context, zmq::socket_type::sub);
  in.set(zmq::sockopt::rcvhwm, 0);
  if (const auto keys = curve::ReadClientKeys(o.curve_key_file, o.curve_server_key_file, "record"))
    curve::MakeClient(in, keys->own, keys->server_public_key);
  if (o.subjects.empty()) {
    in.set(zmq::sockopt::subscribe, "markers/");
  } else {
    for (const std::string& s : o.subjects) in.set(zmq::sockopt::subscribe, "markers/" + s + "/");
  }
  try {
    in.connect(o.from);
  } catch (const zmq::error_t& e) {
    throw std::runtime_error("record: cannot connect to " + o.from + ": " + e.what());
  }
  RecordingWriter writer(o.out);
  const auto start = std::chrono::steady_clock::now();
  auto last_sync = start;
  zmq::pollitem_t item = {in.handle(), 0, ZMQ_POLLIN, 0};
  zmq::message_t topic, body;
  for (;;) {
    const auto now = std::chrono::steady_clock::now();
    if (o.stop != nullptr && o.stop->load()) break;
    if (o.seconds > 0 && now - start >= std::chrono::duration<double>(o.seconds)) break;
    // Ctrl-C, the way a recording is stopped, interrupts the wait: the loop's check of
    // stop ends it (it was "error: Interrupted system call", exit 1, no summary).
    try {
      zmq::poll(&item, 1, std::chrono::milliseconds(20));
    } catch (const zmq::error_t& e) {
      if (e.num() != EINTR) throw;
      continue;
    }
    while (in.recv(topic, zmq::recv_flags::dontwait)) {
      const auto arrived = std::chrono::steady_clock::now();
      if (!topic.more()) continue;  // capture topics always carry a message part
      (void)in.recv(body);
      while (body.more()) (void)in.recv(body);  // keep the last part, like the daemon
      writer.Append(std::chrono::duration_cast<std::chrono::nanoseconds>(arrived - start).count(),
                    topic.to_string_view(),
                    {static_cast<const uint8_t*>(body.data()), body.size()});
    }
    if (now - last_sync >= std::chrono::seconds(1)) {
      writer.Sync();
      last_sync = now;
      if (on_status)
        on_status(
            "t=" +
            std::to_string(static_cast<int>(std::chrono::duration<double>(now - start).count())) +
            "s  recorded " + std::to_string(writer.records()) + " messages");
    }
  }
  writer.Sync();
  return writer.records();
}

bool IsRecordingFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  char magic[8] = {};
  in.read(magic, sizeof(magic));
  return in && std::memcmp(magic, kMagic, sizeof(magic)) == 0;
}

Recording ReadRecording(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error(path + ": cannot open for reading");
  const std::vector<uint8_t> bytes((std::istreambuf_iterator<char>(in)),
                                   std::istreambuf_iterator<char>());
  if (bytes.size() < kHeaderBytes || std::memcmp(bytes.data(), kMagic, sizeof(kMagic)) != 0)
    throw std::runtime_error(path + ": not a mocap-sim recording (no MCPDREC1 header)");
  Recording r;
  ByteReader reader(bytes);
  if (!reader.Seek(8) || !reader.ReadU64(&r.start_wall_ns))
    throw std::runtime_error(path + ": truncated header");
  for (;;) {
    const size_t start = reader.offset();
    uint64_t offset = 0;
    uint32_t topic_len = 0, message_len = 0, header_crc = 0, payload_crc = 0;
    if (!reader.ReadU64(&offset) || !reader.ReadU32(&topic_len) || !reader.ReadU32(&message_len))
      break;
    if (!reader.ReadU32(&header_crc) ||
        header_crc != Crc({bytes.data() + start, kRecordHeaderBytes - 4}))
      break;
    if (reader.remaining() < static_cast<size_t>(topic_len) + message_len + 4) break;
    RecordedMessage m;
    m.offset_ns = static_cast<int64_t>(offset);
    const uint8_t* payload = bytes.data() + reader.offset();
    m.topic.assign(reinterpret_cast<const char*>(payload), topic_len);
    m.message.assign(payload + topic_len, payload + topic_len + message_len);
    if (!reader.Skip(topic_len + message_len) || !reader.ReadU32(&payload_crc)) break;
    if (payload_crc != Crc({payload, static_cast<size_t>(topic_len) + message_len})) break;
    r.messages.push_back(std::move(m));
    if (reader.remaining() == 0) break;
  }
  const size_t good_end = kHeaderBytes + [&] {
    size_t n = 0;
    for (const RecordedMessage& m : r.messages)
      n += kRecordHeaderBytes + m.topic.size() + m.message.size() + 4;
    return n;
  }();
  r.ignored_tail_bytes = bytes.size() - good_end;
  return r;
}

}  // namespace mocapd
