// The browser live view (`/` on the HTTP port): each subject's newest frame — raw and
// cleaned markers with their status, the solved joints, the character's — handed from its
// data-plane worker to the control plane, and served over a WebSocket to every open page.
//
// The data plane is never slowed or blocked by a browser: a worker copies a frame into its
// subject's slot only while someone watches, at most `rate` times a second, and only if
// the control plane is not reading the slot at that instant (try_lock; otherwise the next
// frame will do). The control plane builds one message per tick for all viewers (and one
// per subject that a viewer asked for alone); a viewer
// still writing the last one skips this one (newest wins), and a viewer that has not
// taken a message for a few seconds is closed. Memory per viewer: one message.
#pragma once

#include <atomic>
#include <boost/asio/io_context.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/steady_timer.hpp>
#include <boost/beast/http/message.hpp>
#include <boost/beast/http/string_body.hpp>
#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "filters/marker_model.hpp"
#include "filters/skeleton.hpp"
#include "protocol/messages.hpp"
#include "runtime/http_server.hpp"

namespace mocapd {

struct DaemonStats;

/// One subject's frame as the view shows it (sized once from the model; copying it into
/// a slot allocates nothing).
struct LiveViewFrame {
  uint64_t frame_number = 0;
  int64_t published_ns = 0;  ///< Wall clock when published; 0: no frame yet.
  protocol::StreamInfo stream;
  protocol::SubjectState state = protocol::SubjectState::kWaiting;
  float residual_m = 0.0f;
  std::vector<Vec3> raw;  ///< As received; NaN where missing.
  std::vector<Vec3> cleaned;
  std::vector<uint8_t> status, reason;  ///< As in the cleaned-markers message.
  std::vector<Vec3> joints;             ///< World positions of the solved joints.
  std::vector<Vec3> character_joints;   ///< The retargeted character's, if any.
};

/// The views' demand, shared by every slot: how many are watching, how often to copy.
struct LiveViewDemand {
  std::atomic<int> viewers{0};
  int64_t period_ns = 33'333'333;
};

/// One subject's newest frame. Written by its worker, read by the control plane.
class LiveViewSlot {
 public:
  LiveViewSlot(std::string subject, const Skeleton& skeleton, const MarkerSet& markers,
               const Skeleton* character, std::shared_ptr<const LiveViewDemand> demand);

  /// Worker: is anyone watching (one relaxed load; check before reading a clock).
  bool Watched() const { return demand_->viewers.load(std::memory_order_relaxed) > 0; }
  /// Worker: the frame to fill now (now_ns: steady clock), or nullptr when nobody
  /// watches, the last copy is recent, or the control plane holds the slot. Fill it, then
  /// call EndWrite.
  LiveViewFrame* BeginWrite(int64_t now_ns);
  void EndWrite();

  /// Control plane: copies the newest frame if one arrived since the last Take.
  bool Take(LiveViewFrame* out);

  const std::string& subject() const { return subject_; }
  const std::vector<std::string>& marker_names() const { return marker_names_; }
  const std::vector<std::string>& joint_names() const { return joint_names_; }
  const std::vector<int>& parents() const { return parents_; }
  const std::vector<int>& character_parents() const { return character_parents_; }
  /// Which subject's runner this slot belongs to (a reload makes a new one).
  uint64_t generation() const { return generation_; }

 private:
  std::string subject_;
  std::vector<std::string> marker_names_, joint_names_;
  std::vector<int> parents_, character_parents_;
  std::shared_ptr<const LiveViewDemand> demand_;
  uint64_t generation_ = 0;
  int64_t next_write_ns_ = 0;  // worker only
  std::mutex mutex_;
  bool fresh_ = false;
  LiveViewFrame frame_;
};

/// Every subject's slot, registered when its runner is built (control plane), looked up
/// by the view's tick. Slots die with their runners; the board only watches them.
class LiveViewBoard {
 public:
  explicit LiveViewBoard(double rate_hz);
  std::shared_ptr<LiveViewSlot> Register(const std::string& subject, const Skeleton& skeleton,
                                         const MarkerSet& markers, const Skeleton* character);
  /// The live slots, newest registration per subject, in registration order.
  std::vector<std::shared_ptr<LiveViewSlot>> Slots();
  LiveViewDemand& demand() { return *demand_; }

 private:
  std::shared_ptr<LiveViewDemand> demand_;
  std::mutex mutex_;
  std::vector<std::weak_ptr<LiveViewSlot>> slots_;
};

struct LiveViewCounters {
  uint64_t viewers_opened = 0;
  uint64_t messages_sent = 0;
  uint64_t messages_skipped = 0;  ///< Not sent: the viewer was still taking the last one.
  uint64_t viewers_closed_slow = 0;
  uint64_t viewers_refused = 0;  ///< Over the viewer limit.
  uint64_t unknown_subject = 0;  ///< Asked for a subject this daemon does not solve (404).
  /// Closed for what they sent: a malformed WebSocket frame, a message over 4 kB, ...
  uint64_t viewers_closed_bad_input = 0;
};

/// The WebSocket side, on the control plane's io_context.
class LiveViewHub {
 public:
  using Request = boost::beast::http::request<boost::beast::http::string_body>;
  /// A page that has taken no message for close_stalled_after_s is closed.
  LiveViewHub(boost::asio::io_context& io, std::shared_ptr<LiveViewBoard> board, int max_viewers,
              double close_stalled_after_s);
  ~LiveViewHub();
  /// Takes over an upgraded connection (nothing returned), or answers instead (nothing
  /// taken, counted): 503 when the viewer limit is reached, 404 for a `?subject=` this
  /// daemon does not solve. A viewer with a subject gets only that subject's frames.
  std::optional<HttpResponse> Accept(boost::asio::ip::tcp::socket& socket, Request request);
  /// Every stats tick: counters and latency for the page's panels.
  void OnStats(const DaemonStats& stats);
  void Stop();
  int viewers() const;
  const LiveViewCounters& counters() const;

  struct Impl;

 private:
  std::shared_ptr<Impl> impl_;
};

/// The page's files, built into the binary (runtime/live_view/), and Debian's three.js
/// (libjs-three) read from /usr/share/javascript/three. nullopt: not one of them.
struct StaticFile {
  int status = 200;
  std::string content_type;
  std::string body;
};
std::optional<StaticFile> LiveViewFile(const std::string& path);

}  // namespace mocapd
