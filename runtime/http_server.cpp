// The control plane's HTTP endpoint: accept, read one request, answer, close.
#include "runtime/http_server.hpp"

#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <chrono>
#include <stdexcept>

namespace mocapd {
namespace {

namespace beast = boost::beast;
namespace http = beast::http;
using tcp = boost::asio::ip::tcp;

class Session : public std::enable_shared_from_this<Session> {
 public:
  Session(tcp::socket socket, std::shared_ptr<HttpServer::Handler> handler)
      : stream_(std::move(socket)), handler_(std::move(handler)) {}

  void Start() {
    stream_.expires_after(std::chrono::seconds(5));
    http::async_read(
        stream_, buffer_, request_,
        [self = shared_from_this()](beast::error_code ec, size_t) { self->OnRead(ec); });
  }

 private:
  void OnRead(beast::error_code ec) {
    if (ec) return;  // client went away or timed out: nothing to answer
    HttpResponse answer;
    if (request_.method() != http::verb::get && request_.method() != http::verb::head) {
      answer = {405, "text/plain; charset=utf-8", "only GET is served here\n"};
    } else {
      try {
        answer = (*handler_)(std::string(request_.target()));
      } catch (const std::exception& e) {
        answer = {500, "text/plain; charset=utf-8",
                  std::string("internal error: ") + e.what() + "\n"};
      }
    }
    response_.version(request_.version());
    response_.result(static_cast<http::status>(answer.status));
    response_.set(http::field::server, "mocapd");
    response_.set(http::field::content_type, answer.content_type);
    response_.keep_alive(false);
    if (request_.method() != http::verb::head) response_.body() = std::move(answer.body);
    response_.prepare_payload();
    stream_.expires_after(std::chrono::seconds(5));
    http::async_write(stream_, response_, [self = shared_from_this()](beast::error_code, size_t) {
      beast::error_code ignored;
      self->stream_.socket().shutdown(tcp::socket::shutdown_send, ignored);
    });
  }

  beast::tcp_stream stream_;
  beast::flat_buffer buffer_;
  http::request<http::string_body> request_;
  http::response<http::string_body> response_;
  std::shared_ptr<HttpServer::Handler> handler_;
};

}  // namespace

HttpServer::HttpServer(boost::asio::io_context& io, const std::string& address, int port,
                       Handler handler)
    : io_(io), acceptor_(io), handler_(std::make_shared<Handler>(std::move(handler))) {
  boost::system::error_code ec;
  const auto ip = boost::asio::ip::make_address(address == "localhost" ? "127.0.0.1" : address, ec);
  if (ec) throw std::runtime_error("HTTP address '" + address + "': " + ec.message());
  const tcp::endpoint endpoint(ip, static_cast<uint16_t>(port));
  acceptor_.open(endpoint.protocol(), ec);
  if (!ec) acceptor_.set_option(boost::asio::socket_base::reuse_address(true), ec);
  if (!ec) acceptor_.bind(endpoint, ec);
  if (!ec) acceptor_.listen(boost::asio::socket_base::max_listen_connections, ec);
  if (ec)
    throw std::runtime_error("cannot serve HTTP on " + address + ":" + std::to_string(port) + ": " +
                             ec.message());
  port_ = acceptor_.local_endpoint().port();
  Accept();
}

HttpServer::~HttpServer() { Stop(); }

void HttpServer::Stop() {
  boost::system::error_code ignored;
  acceptor_.close(ignored);
}

void HttpServer::Accept() {
  acceptor_.async_accept(io_, [this](boost::system::error_code ec, tcp::socket socket) {
    if (ec == boost::asio::error::operation_aborted || !acceptor_.is_open()) return;
    if (!ec) std::make_shared<Session>(std::move(socket), handler_)->Start();
    Accept();
  });
}

}  // namespace mocapd
