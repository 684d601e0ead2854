// ZeroMQ CURVE keys for the wire: generating key pairs (`mocapd keygen`), reading and
// writing them as ZeroMQ certificate files (the ZPL format czmq and pyzmq's zmq.auth use:
// NAME.key holds the public key, NAME.key_secret both), reading a directory of clients'
// public keys (an allow-list), and making a socket a CURVE server or client. Keys are
// the 40-character Z85 text form throughout.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace zmq {
class socket_t;
}

namespace mocapd::curve {

constexpr size_t kZ85KeyLength = 40;

struct KeyPair {
  std::string public_key;  ///< Z85
  std::string secret_key;  ///< Z85; empty when only the public half was read.
};

/// True if libzmq was built with CURVE (Debian's is).
bool Available();

/// A fresh key pair from libzmq (zmq_curve_keypair). Throws if CURVE is unavailable.
KeyPair GenerateKeyPair();

/// The public key that belongs to a Z85 secret key (zmq_curve_public).
std::string PublicKeyOf(const std::string& secret_key);

/// True for 40 characters of Z85 that decode to a 32-byte key.
bool IsZ85Key(std::string_view key);

/// Writes BASE.key (public) and BASE.key_secret (both halves, mode 0600), refusing to
/// overwrite either. Throws std::runtime_error naming the file.
void WriteCertificates(const std::string& base_path, const KeyPair& keys);

/// Reads a certificate file. need_secret: it must hold a secret key (and may be read only
/// by its owner, as ssh insists for its keys). Throws "PATH:LINE: problem" or "PATH: problem".
KeyPair ReadCertificate(const std::string& path, bool need_secret);

struct AuthorizedKey {
  std::string public_key;  ///< Z85
  std::string file;        ///< The certificate it came from (for logs).
};

/// Every public certificate (*.key) in a directory, sorted by file name; secret ones
/// (*.key_secret) are ignored. Throws naming the directory or the bad file.
std::vector<AuthorizedKey> ReadAuthorizedKeys(const std::string& directory);

/// The socket authenticates itself with `own` and its clients through ZAP under
/// `zap_domain` (the daemon's authenticator decides who may connect). Before bind/connect.
void MakeServer(zmq::socket_t& socket, const KeyPair& own, const std::string& zap_domain);
/// The socket connects only to a server holding server_public_key's secret half.
void MakeClient(zmq::socket_t& socket, const KeyPair& own, const std::string& server_public_key);

/// What a CURVE client needs: its own key pair and the server's public key.
struct ClientKeys {
  KeyPair own;
  std::string server_public_key;
};
/// Reads both files, or returns nothing when both paths are empty; one without the other
/// is an error. `who` starts the messages ("replay: ...").
std::optional<ClientKeys> ReadClientKeys(const std::string& own_key_file,
                                         const std::string& server_key_file,
                                         const std::string& who);

/// The first characters of a key, enough to tell keys apart in a log line.
std::string ShortKey(const std::string& key);

/// One event from a socket monitor (zmq_socket_monitor): the event, its value (a protocol
/// error code, an errno or, for a refusal, the ZAP status) and the peer's endpoint.
struct MonitorEvent {
  uint16_t event = 0;
  uint32_t value = 0;
  std::string endpoint;
};
/// Reads one event from the PAIR socket connected to a monitor, without waiting; nothing
/// when none is queued or its first frame is too short to be one.
std::optional<MonitorEvent> ReadMonitorEvent(zmq::socket_t& monitor);

}  // namespace mocapd::curve
