// The control plane's HTTP endpoint: accept, read one request, answer, close.
#include "runtime/http_server.hpp"

#include <algorithm>
#include <boost/algorithm/string/predicate.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <boost/beast/websocket/rfc6455.hpp>
#include <chrono>
#include <stdexcept>
#include <string_view>
#include <utility>
#include <vector>

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
    const std::string_view target(request_.target().data(), request_.target().size());
    const std::string path(target.substr(0, target.find('?')));
    const Credential credential = token.empty() ? Credential::kNone : Authorized(token, target);
    const unsigned version = request_.version();
    const bool head = request_.method() == http::verb::head;
    if (shared_->loopback && !LoopbackHost()) {
      ++shared_->counters.foreign_host;
      answer = {403, "text/plain; charset=utf-8",
                "this server answers only to 127.0.0.1, localhost or [::1] (Host header)\n"};
    } else if (!token.empty() && credential == Credential::kNone) {
      ++shared_->counters.unauthorized;
      answer = {401, "text/plain; charset=utf-8",
                "unauthorized: send the header 'Authorization: Bearer TOKEN' "
                "(control.http_token_file); in a browser, open /?token=TOKEN once\n"};
      response_.set(http::field::www_authenticate, "Bearer realm=\"mocapd\"");
    } else if (request_.method() != http::verb::get && request_.method() != http::verb::head) {
      answer = {405, "text/plain; charset=utf-8", "only GET is served here\n"};
    } else if (credential == Credential::kQuery && !beast::websocket::is_upgrade(request_)) {
      // The token leaves the address bar (and the history) at once; the cookie keeps it.
      const std::string location = WithoutToken(path, target);
      answer = {303, "text/plain; charset=utf-8", "see " + location + "\n"};
      extra_headers_.emplace_back(http::field::location, location);
    } else if (beast::websocket::is_upgrade(request_) && !SameOrigin()) {
      // Any web page may open a WebSocket to localhost: only this server's own page may.
      answer = {403, "text/plain; charset=utf-8", "cross-origin WebSocket refused\n"};
    } else if (beast::websocket::is_upgrade(request_)) {
      const auto& upgrade = shared_->options.upgrade;
      stream_.expires_never();
      // The upgrade takes the socket out of this session's stream only when it accepts.
      if (!upgrade) {
        answer = {404, "text/plain; charset=utf-8", "no WebSocket here\n"};
      } else {
        auto refused = upgrade(path, stream_.socket(), std::move(request_));
        if (!refused) return;
        answer = std::move(*refused);
      }
    } else {
      try {
        answer = shared_->handler(path);
      } catch (const std::exception& e) {
        answer = {500, "text/plain; charset=utf-8",
                  std::string("internal error: ") + e.what() + "\n"};
      }
    }
    response_.version(version);
    response_.result(static_cast<http::status>(answer.status));
    response_.set(http::field::server, "mocapd");
    response_.set(http::field::content_type, answer.content_type);
    // A browser that opened the page with ?token= keeps it for the page's own requests
    // (scripts, the live view's WebSocket), which cannot carry a header.
    if (credential == Credential::kQuery)
      response_.set(http::field::set_cookie,
                    shared_->cookie_name + "=" + token + "; Path=/; HttpOnly; SameSite=Strict");
    response_.set("Referrer-Policy", "no-referrer");
    for (const auto& [name, value] : extra_headers_) response_.set(name, value);
    response_.keep_alive(false);
    if (!head) response_.body() = std::move(answer.body);
    response_.prepare_payload();
    stream_.expires_after(std::chrono::seconds(5));
    http::async_write(stream_, response_, [self = shared_from_this()](beast::error_code, size_t) {
      beast::error_code ignored;
      self->stream_.socket().shutdown(tcp::socket::shutdown_send, ignored);
    });
  }

  enum class Credential { kNone, kHeader, kCookie, kQuery };

  // A browser sends Origin with every WebSocket handshake; a page of this server has
  // Origin http://<Host>. Clients that are not browsers send none.
  bool SameOrigin() const {
    const auto origin = request_.find(http::field::origin);
    if (origin == request_.end()) return true;
    const auto host = request_.find(http::field::host);
    if (host == request_.end()) return false;
    const std::string_view o(origin->value().data(), origin->value().size());
    const std::string_view h(host->value().data(), host->value().size());
    return o == "http://" + std::string(h) || o == "https://" + std::string(h);
  }

  // The Host header names a loopback address or localhost (any port). A request without
  // one is no browser's, so no rebound page's.
  bool LoopbackHost() const {
    const auto host = request_.find(http::field::host);
    if (host == request_.end()) return true;
    std::string_view name(host->value().data(), host->value().size());
    if (name.starts_with('[')) {  // [::1]:port
      const size_t close = name.find(']');
      name = close == std::string_view::npos ? std::string_view{} : name.substr(1, close - 1);
    } else if (const size_t colon = name.rfind(':'); colon != std::string_view::npos) {
      name = name.substr(0, colon);
    }
    if (name.ends_with('.')) name.remove_suffix(1);  // the absolute form, "localhost."
    if (boost::algorithm::iequals(name, "localhost")) return true;
    boost::system::error_code ec;
    const auto address = boost::asio::ip::make_address(std::string(name), ec);
    return !ec && address.is_loopback();
  }

  // Where a valid token came from, or kNone.
  Credential Authorized(const std::string& token, std::string_view target) const {
    if (const auto header = request_.find(http::field::authorization); header != request_.end()) {
      constexpr std::string_view kScheme = "Bearer ";
      const std::string_view value(header->value().data(), header->value().size());
      // The scheme's name is case-insensitive (RFC 7235): "bearer TOKEN" was refused.
      if (value.size() >= kScheme.size() &&
          boost::algorithm::iequals(value.substr(0, kScheme.size()), kScheme) &&
          SameSecret(value.substr(kScheme.size()), token))
        return Credential::kHeader;
    }
    if (const auto cookies = request_.find(http::field::cookie); cookies != request_.end()) {
      const std::string_view list(cookies->value().data(), cookies->value().size());
      if (SameSecret(ParameterValue(list, shared_->cookie_name, ';'), token))
        return Credential::kCookie;
    }
    if (const auto query = target.find('?'); query != std::string_view::npos) {
      if (SameSecret(ParameterValue(target.substr(query + 1), "token", '&'), token))
        return Credential::kQuery;
    }
    return Credential::kNone;
  }

  // The address without its token: the other parameters (a subject to show) stay.
  static std::string WithoutToken(const std::string& path, std::string_view target) {
    const size_t query = target.find('?');
    std::string kept;
    for (std::string_view rest = target.substr(query + 1); !rest.empty();) {
      const size_t end = std::min(rest.find('&'), rest.size());
      const std::string_view item = rest.substr(0, end);
      if (!item.empty() && !item.starts_with("token=") && item != "token")
        kept += (kept.empty() ? "" : "&") + std::string(item);
      rest.remove_prefix(std::min(end + 1, rest.size()));
    }
    return kept.empty() ? path : path + "?" + kept;
  }

  // The value of name in "a=1<sep> name=2<sep>...", or "" (never a valid token).
  static std::string_view ParameterValue(std::string_view list, std::string_view name,
                                         char separator) {
    while (!list.empty()) {
      const size_t end = std::min(list.find(separator), list.size());
      std::string_view item = list.substr(0, end);
      while (!item.empty() && item.front() == ' ') item.remove_prefix(1);
      if (item.size() > name.size() && item.starts_with(name) && item[name.size()] == '=')
        return item.substr(name.size() + 1);
      list.remove_prefix(std::min(end + 1, list.size()));
    }
    return {};
  }

  beast::tcp_stream stream_;
  beast::flat_buffer buffer_;
  http::request<http::string_body> request_;
  http::response<http::string_body> response_;
  std::vector<std::pair<http::field, std::string>> extra_headers_;
  std::shared_ptr<HttpServer::Shared> shared_;
};

}  // namespace

std::string QueryParameter(std::string_view target, std::string_view name) {
  const size_t query = target.find('?');
  if (query == std::string_view::npos) return {};
  for (std::string_view rest = target.substr(query + 1); !rest.empty();) {
    const size_t end = std::min(rest.find('&'), rest.size());
    const std::string_view item = rest.substr(0, end);
    rest.remove_prefix(std::min(end + 1, rest.size()));
    if (item.size() <= name.size() || !item.starts_with(name) || item[name.size()] != '=') continue;
    std::string value;
    const std::string_view encoded = item.substr(name.size() + 1);
    for (size_t i = 0; i < encoded.size(); ++i) {
      const auto hex = [](char c) {
        return c >= '0' && c <= '9'   ? c - '0'
               : c >= 'a' && c <= 'f' ? c - 'a' + 10
               : c >= 'A' && c <= 'F' ? c - 'A' + 10
                                      : -1;
      };
      if (encoded[i] == '%' && i + 2 < encoded.size() && hex(encoded[i + 1]) >= 0 &&
          hex(encoded[i + 2]) >= 0) {
        value += static_cast<char>(hex(encoded[i + 1]) * 16 + hex(encoded[i + 2]));
        i += 2;
      } else {
        value += encoded[i] == '+' ? ' ' : encoded[i];
      }
    }
    return value;
  }
  return {};
}

HttpServer::HttpServer(boost::asio::io_context& io, const std::string& address, int port,
                       Handler handler, HttpServerOptions options)
    : io_(io),
      acceptor_(io),
      shared_(std::make_shared<Shared>(Shared{std::move(handler), std::move(options), {}, 0, {}})) {
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
  shared_->cookie_name = "mocapd_token_" + std::to_string(port_);
  shared_->loopback = ip.is_loopback();
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
