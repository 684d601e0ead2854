// A small HTTP/1.1 server (Boost.Beast) on the control plane's io_context, for the
// daemon's /health, /subjects and /metrics endpoints and the live view's page and
// WebSocket. GET only; one request per connection (or an upgrade to a WebSocket, handed
// over); every read and write has a timeout so a stuck client cannot pin it; a bounded
// number of connections at once (more are closed at once, counted); optionally a bearer
// token every request must carry (others get 401, counted): in the Authorization header,
// or, for a browser, once as "?token=" (answered with a redirect that drops it from the
// address and a cookie that carries it on the page's own requests). A WebSocket upgrade
// must come from a page of this server (its Origin, when sent, names this Host). A server
// bound to loopback answers only requests addressed to a loopback name (127.0.0.1,
// localhost, [::1]): a web page that rebinds its own domain name to 127.0.0.1 (DNS
// rebinding) cannot read it.
#pragma once

#include <boost/asio/io_context.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/beast/http/message.hpp>
#include <boost/beast/http/string_body.hpp>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <string_view>

namespace mocapd {

struct HttpResponse {
  int status = 200;
  std::string content_type = "text/plain; charset=utf-8";
  std::string body;
};

using HttpRequest = boost::beast::http::request<boost::beast::http::string_body>;

struct HttpServerOptions {
  std::string bearer_token;  ///< Empty: no authentication.
  int max_connections = 64;  ///< Open at once; beyond, a connection is closed unanswered.
  /// An authorized WebSocket upgrade for path: take the socket and return nothing, or
  /// return the answer to send instead (nothing taken: 404 for an unknown path, 503 when
  /// full, ...). Empty: upgrades get 404.
  std::function<std::optional<HttpResponse>(
      const std::string& path, boost::asio::ip::tcp::socket& socket, HttpRequest request)>
      upgrade;
};

/// The value of a request target's query parameter, percent-decoded ('+' is a space);
/// empty if it is absent.
std::string QueryParameter(std::string_view target, std::string_view name);

/// What the server turned away (read on the io_context's thread).
struct HttpServerCounters {
  uint64_t unauthorized = 0;      ///< Requests without the bearer token (401).
  uint64_t over_connections = 0;  ///< Connections closed because max_connections were open.
  uint64_t foreign_host = 0;      ///< Loopback server asked under another host name (403).
};

class HttpServer {
 public:
  /// Called with the request's path (without its query; QueryParameter reads it from
  /// the target).
  using Handler = std::function<HttpResponse(const std::string& path)>;
  /// Binds address:port (port 0: any free port). Throws std::runtime_error naming the
  /// address if it cannot bind.
  HttpServer(boost::asio::io_context& io, const std::string& address, int port, Handler handler,
             HttpServerOptions options = {});
  ~HttpServer();
  int port() const { return port_; }
  const HttpServerCounters& counters() const { return shared_->counters; }
  void Stop();

  /// State the sessions share with the server (and may outlive it by a few callbacks).
  struct Shared {
    Handler handler;
    HttpServerOptions options;
    HttpServerCounters counters;
    int open_connections = 0;
    std::string cookie_name;  ///< mocapd_token_<port>: one per daemon on a host.
    bool loopback = false;    ///< Bound to a loopback address: only loopback Host names.
  };

 private:
  void Accept();
  boost::asio::io_context& io_;
  boost::asio::ip::tcp::acceptor acceptor_;
  std::shared_ptr<Shared> shared_;
  int port_ = 0;
};

}  // namespace mocapd
