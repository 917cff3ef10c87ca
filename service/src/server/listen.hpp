// The server's listen addresses: parsing (parse_listen_address, server.hpp) and binding a TCP or
// Unix-socket acceptor for each.
#pragma once

#include <asio.hpp>
#include <string>
#include <vector>

namespace terrastride::service {

struct Listeners {
  std::vector<asio::ip::tcp::acceptor> tcp;
  std::vector<asio::local::stream_protocol::acceptor> unix_sockets;
  std::vector<std::string> unix_paths;  // removed when the server stops
  std::vector<std::string> bound;       // "tcp://127.0.0.1:40123", "unix:/run/ts.sock"
};

// Binds and listens on `address` (tcp://HOST:PORT or unix:PATH), adding the acceptor and its
// bound address to `out`. A non-loopback TCP address needs a token (`have_token`). A Unix socket
// is created 0600; a stale socket file is replaced, anything else at the path (or a live server)
// is an error. Throws std::runtime_error naming the address.
void listen_on(asio::io_context& io, const std::string& address, bool have_token, Listeners* out);

}  // namespace terrastride::service
