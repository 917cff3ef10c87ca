#include "listen.hpp"

#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <unistd.h>

#include <cerrno>
#include <stdexcept>

#include "terrastride/service/server.hpp"

namespace terrastride::service {

ListenAddress parse_listen_address(const std::string& text) {
  ListenAddress a;
  if (text.rfind("unix:", 0) == 0) {
    a.kind = ListenAddress::Kind::kUnix;
    a.path = text.substr(5);
    if (a.path.rfind("//", 0) == 0) a.path = a.path.substr(2);  // unix://PATH
    if (a.path.empty())
      throw std::invalid_argument("listen address '" + text + "': empty socket path");
    if (a.path.size() >= sizeof(sockaddr_un::sun_path))
      throw std::invalid_argument("listen address '" + text + "': socket path longer than " +
                                  std::to_string(sizeof(sockaddr_un::sun_path) - 1) + " bytes");
    return a;
  }
  std::string rest = text;
  if (rest.rfind("tcp://", 0) == 0)
    rest = rest.substr(6);
  else if (rest.find("://") != std::string::npos)
    throw std::invalid_argument("listen address '" + text +
                                "': scheme must be tcp:// or unix: (e.g. tcp://127.0.0.1:7700)");
  std::string port;
  if (!rest.empty() && rest[0] == '[') {  // [::1]:PORT
    const auto close = rest.find(']');
    if (close == std::string::npos || close + 1 >= rest.size() || rest[close + 1] != ':')
      throw std::invalid_argument("listen address '" + text + "': expected [IPv6]:PORT");
    a.host = rest.substr(1, close - 1);
    port = rest.substr(close + 2);
  } else {
    const auto colon = rest.rfind(':');
    if (colon == std::string::npos)
      throw std::invalid_argument("listen address '" + text + "': missing :PORT");
    a.host = rest.substr(0, colon);
    port = rest.substr(colon + 1);
  }
  if (a.host == "localhost") a.host = "127.0.0.1";
  if (a.host.empty() || port.empty() || port.size() > 5 ||
      port.find_first_not_of("0123456789") != std::string::npos || std::stoul(port) > 65535)
    throw std::invalid_argument("listen address '" + text +
                                "': expected HOST:PORT with port 0-65535");
  a.port = static_cast<std::uint16_t>(std::stoul(port));
  asio::error_code ec;
  asio::ip::make_address(a.host, ec);
  if (ec)
    throw std::invalid_argument("listen address '" + text + "': '" + a.host +
                                "' is not an IP address");
  return a;
}

namespace {

// A Unix socket path already in use by a live server is an error; a stale socket file is removed.
void prepare_unix_path(const std::string& path) {
  struct stat st;
  if (::lstat(path.c_str(), &st) != 0) return;
  if (!S_ISSOCK(st.st_mode))
    throw std::runtime_error("unix:" + path +
                             ": exists and is not a socket; refusing to replace it");
  asio::io_context probe_io;
  asio::local::stream_protocol::socket probe(probe_io);
  asio::error_code ec;
  probe.connect(asio::local::stream_protocol::endpoint(path), ec);
  if (!ec) throw std::runtime_error("unix:" + path + ": another server is listening there");
  ::unlink(path.c_str());
}

}  // namespace

void listen_on(asio::io_context& io, const std::string& text, bool have_token, Listeners* out) {
  ListenAddress a;
  try {
    a = parse_listen_address(text);
  } catch (const std::invalid_argument& e) {
    throw std::runtime_error(e.what());
  }
  if (a.kind == ListenAddress::Kind::kTcp) {
    const auto addr = asio::ip::make_address(a.host);
    if (!addr.is_loopback() && !have_token)
      throw std::runtime_error("listen address '" + text +
                               "' is not loopback: --token-file is required to serve on it");
    asio::ip::tcp::acceptor acc(io);
    const asio::ip::tcp::endpoint ep(addr, a.port);
    asio::error_code ec;
    acc.open(ep.protocol(), ec);
    if (!ec) acc.set_option(asio::socket_base::reuse_address(true), ec);
    if (!ec) acc.bind(ep, ec);
    if (!ec) acc.listen(asio::socket_base::max_listen_connections, ec);
    if (ec) throw std::runtime_error("cannot listen on '" + text + "': " + ec.message());
    const auto local = acc.local_endpoint();
    const std::string host = local.address().is_v6() ? "[" + local.address().to_string() + "]"
                                                     : local.address().to_string();
    out->bound.push_back("tcp://" + host + ":" + std::to_string(local.port()));
    out->tcp.push_back(std::move(acc));
  } else {
    prepare_unix_path(a.path);
    asio::local::stream_protocol::acceptor acc(io);
    asio::error_code ec;
    acc.open(asio::local::stream_protocol(), ec);
    // Created 0600: the umask covers the window between bind and chmod.
    const mode_t old = ::umask(0177);
    if (!ec) acc.bind(asio::local::stream_protocol::endpoint(a.path), ec);
    ::umask(old);
    if (!ec && ::chmod(a.path.c_str(), 0600) != 0)
      ec = asio::error_code(errno, asio::system_category());
    if (!ec) acc.listen(asio::socket_base::max_listen_connections, ec);
    if (ec) throw std::runtime_error("cannot listen on '" + text + "': " + ec.message());
    out->unix_paths.push_back(a.path);
    out->bound.push_back("unix:" + a.path);
    out->unix_sockets.push_back(std::move(acc));
  }
}

}  // namespace terrastride::service
