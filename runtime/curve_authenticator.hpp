// The daemon's ZAP handler (ZeroMQ RFC 27) for CURVE: every client that connects to one
// of the daemon's CURVE sockets (a consumer of the output, a capture bridge pushing into a
// PULL input) is admitted only if its public key is in the allow-list
// (security.authorized_keys), and every refusal is counted and logged. It also watches
// the sockets' handshakes (socket monitors), so a peer that fails one for another reason
// (no CURVE at all, the wrong server key) is counted too. One thread, off the data plane:
// handshakes happen at connection time, never per frame.
#pragma once

#include <atomic>
#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "protocol/curve.hpp"

namespace zmq {
class context_t;
}

namespace mocapd {

/// Which of the daemon's sockets a handshake was on (ZAP domain and metric label).
enum class CurveSocket { kInput = 0, kOutput = 1 };
constexpr int kCurveSocketCount = 2;
const char* CurveSocketName(CurveSocket socket);

struct CurveCounts {
  uint64_t accepted[kCurveSocketCount] = {};            ///< Clients admitted by key.
  uint64_t refused[kCurveSocketCount] = {};             ///< Clients whose key is not allowed.
  uint64_t handshake_failures[kCurveSocketCount] = {};  ///< Other failed handshakes.
};

class CurveAuthenticator {
 public:
  /// Binds the context's ZAP endpoint, so it must exist before any CURVE server socket
  /// binds (libzmq admits everyone when no handler is bound). Throws if another handler
  /// already holds the endpoint in this context.
  CurveAuthenticator(zmq::context_t& context, std::vector<curve::AuthorizedKey> keys,
                     double log_interval_s);
  ~CurveAuthenticator();
  CurveAuthenticator(const CurveAuthenticator&) = delete;
  CurveAuthenticator& operator=(const CurveAuthenticator&) = delete;

  /// Watches a socket's handshakes. Call on the thread that owns the socket, before it
  /// binds or connects and before Start. client: the daemon is this socket's CURVE
  /// client, so a server that refuses it is a failure to count here (refusals of the
  /// daemon's own clients are counted by ZAP).
  void Monitor(void* socket_handle, CurveSocket which, bool client);
  /// Starts answering (requests that arrived before are answered then).
  void Start();
  void Stop();
  /// Thread-safe: a reload's allow-list applies to every later handshake.
  void SetAuthorizedKeys(std::vector<curve::AuthorizedKey> keys);
  CurveCounts Counts() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace mocapd
