// A small HTTP/1.1 server (Boost.Beast) on the control plane's io_context, for the
// daemon's /health, /subjects and /metrics endpoints. GET only; one request per
// connection; every read and write has a timeout so a stuck client cannot pin it; a
// bounded number of connections at once (more are closed at once, counted); optionally a
// bearer token every request must carry (others get 401, counted).
#pragma once

#include <boost/asio/io_context.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <functional>
#include <memory>
#include <string>

namespace mocapd {

struct HttpResponse {
  int status = 200;
  std::string content_type = "text/plain; charset=utf-8";
  std::string body;
};

struct HttpServerOptions {
  std::string bearer_token;  ///< Empty: no authentication.
  int max_connections = 64;  ///< Open at once; beyond, a connection is closed unanswered.
};

/// What the server turned away (read on the io_context's thread).
struct HttpServerCounters {
  uint64_t unauthorized = 0;      ///< Requests without the bearer token (401).
  uint64_t over_connections = 0;  ///< Connections closed because max_connections were open.
};

class HttpServer {
 public:
  using Handler = std::function<HttpResponse(const std::string& target)>;
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
  };

 private:
  void Accept();
  boost::asio::io_context& io_;
  boost::asio::ip::tcp::acceptor acceptor_;
  std::shared_ptr<Shared> shared_;
  int port_ = 0;
};

}  // namespace mocapd
