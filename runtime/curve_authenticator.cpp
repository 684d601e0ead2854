// ZAP handler and handshake monitors for the daemon's CURVE sockets (see the header).
#include "runtime/curve_authenticator.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <stdexcept>
#include <zmq.hpp>
#include <zmq_addon.hpp>

namespace mocapd {
namespace {

constexpr char kZapEndpoint[] = "inproc://zeromq.zap.01";

int64_t SteadyNowNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

}  // namespace

const char* CurveSocketName(CurveSocket socket) {
  return socket == CurveSocket::kInput ? "input" : "output";
}

struct CurveAuthenticator::Impl {
  Impl(zmq::context_t& ctx, double log_interval)
      : context(ctx),
        zap(ctx, zmq::socket_type::rep),
        control_in(ctx, zmq::socket_type::pair),
        control_out(ctx, zmq::socket_type::pair),
        log_interval_ns(static_cast<int64_t>(log_interval * 1e9)) {}

  struct Watched {
    zmq::socket_t events;
    CurveSocket which;
  };

  void Loop() {
    std::vector<zmq::pollitem_t> items = {{zap.handle(), 0, ZMQ_POLLIN, 0},
                                          {control_in.handle(), 0, ZMQ_POLLIN, 0}};
    for (Watched& w : watched)
      items.push_back(zmq::pollitem_t{w.events.handle(), 0, ZMQ_POLLIN, 0});
    for (;;) {
      try {
        if (zmq::poll(items.data(), items.size(), std::chrono::milliseconds(-1)) <= 0) continue;
      } catch (const zmq::error_t& e) {
        if (e.num() == EINTR) continue;
        spdlog::error("CURVE authenticator: {}", e.what());
        return;
      }
      if ((items[1].revents & ZMQ_POLLIN) != 0) return;
      if ((items[0].revents & ZMQ_POLLIN) != 0) AnswerZap();
      for (size_t i = 0; i < watched.size(); ++i)
        if ((items[2 + i].revents & ZMQ_POLLIN) != 0) ReadEvent(watched[i]);
    }
  }

  void AnswerZap() {
    std::vector<zmq::message_t> request;
    if (!zmq::recv_multipart(zap, std::back_inserter(request), zmq::recv_flags::dontwait)) return;
    // RFC 27: version, request id, domain, address, routing id, mechanism, credentials...
    const auto text = [&](size_t i) {
      return i < request.size() ? request[i].to_string() : std::string();
    };
    const std::string request_id = text(1), domain = text(2), address = text(3);
    const CurveSocket which = domain == "input" ? CurveSocket::kInput : CurveSocket::kOutput;
    std::string key;
    if (request.size() >= 7 && text(5) == "CURVE" && request[6].size() == 32) {
      std::array<char, curve::kZ85KeyLength + 1> z85{};
      if (zmq_z85_encode(z85.data(), request[6].data<uint8_t>(), 32) != nullptr) key = z85.data();
    }
    bool allowed = false;
    if (text(0) == "1.0" && !key.empty()) {
      std::lock_guard lock(keys_mutex);
      allowed = std::binary_search(allowed_keys.begin(), allowed_keys.end(), key);
    }
    const int slot = static_cast<int>(which);
    (allowed ? accepted : refused)[slot].fetch_add(1, std::memory_order_relaxed);
    if (!allowed) LogRefusal(which, key, address);
    std::array<std::string, 6> reply = {
        "1.0",
        request_id,
        allowed ? "200" : "400",
        allowed ? "OK" : "client key not in security.authorized_keys",
        key,
        ""};
    for (size_t i = 0; i < reply.size(); ++i)
      (void)zap.send(zmq::buffer(reply[i]),
                     i + 1 < reply.size() ? zmq::send_flags::sndmore : zmq::send_flags::none);
  }

  void LogRefusal(CurveSocket which, const std::string& key, const std::string& address) {
    // A refused client retries every reconnect interval: one line per log interval.
    const int64_t now = SteadyNowNs();
    if (last_log_ns >= 0 && now - last_log_ns < log_interval_ns) {
      ++unlogged_refusals;
      return;
    }
    spdlog::warn(
        "CURVE: refused a client on the {} from {} (key {}: not in security.authorized_keys){}",
        CurveSocketName(which), address.empty() ? "?" : address,
        key.empty() ? "none" : curve::ShortKey(key),
        unlogged_refusals > 0
            ? fmt::format("; {} more refusals since the last report", unlogged_refusals)
            : "");
    unlogged_refusals = 0;
    last_log_ns = now;
  }

  void ReadEvent(Watched& w) {
    const std::optional<curve::MonitorEvent> event = curve::ReadMonitorEvent(w.events);
    if (!event) return;
    handshake_failures[static_cast<size_t>(w.which)].fetch_add(1, std::memory_order_relaxed);
    const int64_t now = SteadyNowNs();
    if (last_failure_log_ns < 0 || now - last_failure_log_ns >= log_interval_ns) {
      const std::string peer = event->endpoint.empty() ? "?" : event->endpoint;
      if (event->event == ZMQ_EVENT_HANDSHAKE_FAILED_AUTH)
        spdlog::warn(
            "CURVE: {} refused this daemon (ZAP status {}): is its key in that peer's allow-list?",
            peer, event->value);
      else
        spdlog::warn(
            "CURVE: a handshake on the {} ({}) failed (code {:#x}): a peer without CURVE or with "
            "other keys",
            CurveSocketName(w.which), peer, event->value);
      last_failure_log_ns = now;
    }
  }

  zmq::context_t& context;
  zmq::socket_t zap, control_in, control_out;
  std::vector<Watched> watched;
  std::thread thread;
  int64_t log_interval_ns;
  int64_t last_log_ns = -1, last_failure_log_ns = -1;
  uint64_t unlogged_refusals = 0;
  std::mutex keys_mutex;
  std::vector<std::string> allowed_keys;  // sorted Z85
  std::array<std::atomic<uint64_t>, kCurveSocketCount> accepted{}, refused{}, handshake_failures{};
};

CurveAuthenticator::CurveAuthenticator(zmq::context_t& context,
                                       std::vector<curve::AuthorizedKey> keys,
                                       double log_interval_s)
    : impl_(std::make_unique<Impl>(context, log_interval_s)) {
  SetAuthorizedKeys(std::move(keys));
  static std::atomic<uint64_t> made{0};
  const std::string control = "inproc://mocapd-curve-control-" + std::to_string(++made);
  try {
    impl_->zap.set(zmq::sockopt::linger, 0);
    impl_->zap.bind(kZapEndpoint);
    impl_->control_in.bind(control);
    impl_->control_out.connect(control);
  } catch (const zmq::error_t& e) {
    throw std::runtime_error(std::string("CURVE authenticator: cannot bind ") + kZapEndpoint +
                             " (another ZAP handler in this context?): " + e.what());
  }
}

CurveAuthenticator::~CurveAuthenticator() { Stop(); }

void CurveAuthenticator::Monitor(void* socket_handle, CurveSocket which, bool client) {
  static std::atomic<uint64_t> monitors{0};
  const std::string endpoint = "inproc://mocapd-curve-monitor-" + std::to_string(++monitors);
  int events = ZMQ_EVENT_HANDSHAKE_FAILED_NO_DETAIL | ZMQ_EVENT_HANDSHAKE_FAILED_PROTOCOL;
  if (client) events |= ZMQ_EVENT_HANDSHAKE_FAILED_AUTH;
  if (zmq_socket_monitor(socket_handle, endpoint.c_str(), events) != 0)
    throw std::runtime_error("CURVE authenticator: cannot monitor the " +
                             std::string(CurveSocketName(which)) + ": " +
                             zmq_strerror(zmq_errno()));
  Impl::Watched w{zmq::socket_t(impl_->context, zmq::socket_type::pair), which};
  w.events.connect(endpoint);
  impl_->watched.push_back(std::move(w));
}

void CurveAuthenticator::Start() {
  if (!impl_->thread.joinable()) impl_->thread = std::thread([this] { impl_->Loop(); });
}

void CurveAuthenticator::Stop() {
  if (!impl_->thread.joinable()) return;
  (void)impl_->control_out.send(zmq::str_buffer("stop"), zmq::send_flags::none);
  impl_->thread.join();
}

void CurveAuthenticator::SetAuthorizedKeys(std::vector<curve::AuthorizedKey> keys) {
  std::vector<std::string> sorted;
  for (auto& k : keys) sorted.push_back(std::move(k.public_key));
  std::sort(sorted.begin(), sorted.end());
  std::lock_guard lock(impl_->keys_mutex);
  impl_->allowed_keys = std::move(sorted);
}

CurveCounts CurveAuthenticator::Counts() const {
  CurveCounts c;
  for (int i = 0; i < kCurveSocketCount; ++i) {
    c.accepted[i] = impl_->accepted[static_cast<size_t>(i)].load(std::memory_order_relaxed);
    c.refused[i] = impl_->refused[static_cast<size_t>(i)].load(std::memory_order_relaxed);
    c.handshake_failures[i] =
        impl_->handshake_failures[static_cast<size_t>(i)].load(std::memory_order_relaxed);
  }
  return c;
}

}  // namespace mocapd
