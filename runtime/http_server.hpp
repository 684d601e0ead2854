// A small HTTP/1.1 server (Boost.Beast) on the control plane's io_context, for the
// daemon's /health, /subjects and /metrics endpoints. GET only; one request per
// connection; every read and write has a timeout so a stuck client cannot pin it.
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

class HttpServer {
 public:
  using Handler = std::function<HttpResponse(const std::string& target)>;
  /// Binds address:port (port 0: any free port). Throws std::runtime_error naming the
  /// address if it cannot bind.
  HttpServer(boost::asio::io_context& io, const std::string& address, int port, Handler handler);
  ~HttpServer();
  int port() const { return port_; }
  void Stop();

 private:
  void Accept();
  boost::asio::io_context& io_;
  boost::asio::ip::tcp::acceptor acceptor_;
  std::shared_ptr<Handler> handler_;
  int port_ = 0;
};

}  // namespace mocapd
