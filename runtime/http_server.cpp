// The control plane's HTTP endpoint: accept, read one request, answer, close.
#include "runtime/http_server.hpp"

#include <algorithm>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <chrono>
#include <stdexcept>
#include <string_view>

namespace mocapd {
namespace {

namespace beast = boost::beast;
namespace http = beast::http;
using tcp = boost::asio::ip::tcp;

// Compares without stopping at the first difference, so the time a wrong token takes
// says nothing about how much of it was right.
bool SameSecret(std::string_view given, std::string_view secret) {
  unsigned char difference = given.size() == secret.size() ? 0 : 1;
  for (size_t i = 0; i < given.size(); ++i)
    difference |=
        static_cast<unsigned char>(given[i] ^ secret[i % std::max<size_t>(1, secret.size())]);
  return difference == 0;
}

class Session : public std::enable_shared_from_this<Session> {
 public:
  Session(tcp::socket socket, std::shared_ptr<HttpServer::Shared> shared)
      : stream_(std::move(socket)), shared_(std::move(shared)) {
    ++shared_->open_connections;
  }
  ~Session() { --shared_->open_connections; }

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
    const std::string& token = shared_->options.bearer_token;
    if (!token.empty() && !Authorized(token)) {
      ++shared_->counters.unauthorized;
      answer = {401, "text/plain; charset=utf-8",
                "unauthorized: send the header 'Authorization: Bearer TOKEN' "
                "(control.http_token_file)\n"};
      response_.set(http::field::www_authenticate, "Bearer realm=\"mocapd\"");
    } else if (request_.method() != http::verb::get && request_.method() != http::verb::head) {
      answer = {405, "text/plain; charset=utf-8", "only GET is served here\n"};
    } else {
      try {
        answer = shared_->handler(std::string(request_.target()));
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

  bool Authorized(const std::string& token) const {
    const auto header = request_.find(http::field::authorization);
    if (header == request_.end()) return false;
    constexpr std::string_view kScheme = "Bearer ";
    const std::string_view value(header->value().data(), header->value().size());
    return value.starts_with(kScheme) && SameSecret(value.substr(kScheme.size()), token);
  }

  beast::tcp_stream stream_;
  beast::flat_buffer buffer_;
  http::request<http::string_body> request_;
  http::response<http::string_body> response_;
  std::shared_ptr<HttpServer::Shared> shared_;
};

}  // namespace

HttpServer::HttpServer(boost::asio::io_context& io, const std::string& address, int port,
                       Handler handler, HttpServerOptions options)
    : io_(io),
      acceptor_(io),
      shared_(std::make_shared<Shared>(Shared{std::move(handler), std::move(options), {}, 0})) {
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
    if (!ec && shared_->open_connections >= shared_->options.max_connections) {
      // Busy: closing now costs nothing, where reading a request would hold memory.
      ++shared_->counters.over_connections;
      boost::system::error_code ignored;
      socket.close(ignored);
    } else if (!ec) {
      std::make_shared<Session>(std::move(socket), shared_)->Start();
    }
    Accept();
  });
}

}  // namespace mocapd
