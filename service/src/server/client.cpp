// Blocking client over POSIX sockets (TCP or Unix), with poll() timeouts.
#include "terrastride/service/client.hpp"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <utility>

#include "terrastride/service/server.hpp"

namespace terrastride::service {

using nlohmann::json;
using protocol::Message;

namespace {

int wait_fd(int fd, short events, double timeout_s) {
  pollfd p{fd, events, 0};
  const int ms = timeout_s < 0 ? -1 : static_cast<int>(timeout_s * 1000);
  for (;;) {
    const int r = ::poll(&p, 1, ms);
    if (r < 0 && errno == EINTR) continue;
    return r;
  }
}

}  // namespace

Client Client::connect(const std::string& address, double timeout_s) {
  ListenAddress a;
  try {
    a = parse_listen_address(address);
  } catch (const std::invalid_argument& e) {
    throw ClientError(e.what());
  }
  int fd = -1;
  sockaddr_storage ss{};
  socklen_t len = 0;
  if (a.kind == ListenAddress::Kind::kUnix) {
    auto* un = reinterpret_cast<sockaddr_un*>(&ss);
    un->sun_family = AF_UNIX;
    std::strncpy(un->sun_path, a.path.c_str(), sizeof(un->sun_path) - 1);
    len = sizeof(sockaddr_un);
    fd = ::socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
  } else {
    auto* in4 = reinterpret_cast<sockaddr_in*>(&ss);
    auto* in6 = reinterpret_cast<sockaddr_in6*>(&ss);
    if (::inet_pton(AF_INET, a.host.c_str(), &in4->sin_addr) == 1) {
      in4->sin_family = AF_INET;
      in4->sin_port = htons(a.port);
      len = sizeof(sockaddr_in);
    } else if (::inet_pton(AF_INET6, a.host.c_str(), &in6->sin6_addr) == 1) {
      in6->sin6_family = AF_INET6;
      in6->sin6_port = htons(a.port);
      len = sizeof(sockaddr_in6);
    } else {
      throw ClientError("'" + address + "': not an IP address");
    }
    fd = ::socket(ss.ss_family, SOCK_STREAM | SOCK_CLOEXEC, 0);
  }
  if (fd < 0) throw ClientError("'" + address + "': socket: " + std::strerror(errno));
  const int flags = ::fcntl(fd, F_GETFL, 0);
  ::fcntl(fd, F_SETFL, flags | O_NONBLOCK);
  int r = ::connect(fd, reinterpret_cast<sockaddr*>(&ss), len);
  if (r != 0 && errno == EINPROGRESS) {
    if (wait_fd(fd, POLLOUT, timeout_s) <= 0) {
      ::close(fd);
      throw ClientError("'" + address + "': connect timed out");
    }
    int err = 0;
    socklen_t el = sizeof(err);
    ::getsockopt(fd, SOL_SOCKET, SO_ERROR, &err, &el);
    r = err == 0 ? 0 : -1;
    errno = err;
  }
  if (r != 0) {
    const std::string why = std::strerror(errno);
    ::close(fd);
    throw ClientError("cannot connect to '" + address + "': " + why);
  }
  if (a.kind == ListenAddress::Kind::kTcp) {
    int one = 1;
    ::setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof(one));
  }
  Client c(fd);
  return c;
}

Client::Client(Client&& o) noexcept {
  *this = std::move(o);
}

Client& Client::operator=(Client&& o) noexcept {
  if (this != &o) {
    close();
    fd_ = o.fd_;
    o.fd_ = -1;
    timeout_s_ = o.timeout_s_;
    next_id_ = o.next_id_;
    in_ = std::move(o.in_);
    in_pos_ = o.in_pos_;
    pending_ = std::move(o.pending_);
    max_frame_bytes = o.max_frame_bytes;
  }
  return *this;
}

Client::~Client() {
  close();
}

void Client::close() {
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
}

void Client::send_raw(std::string_view bytes) {
  if (fd_ < 0) throw ClientError("send on a closed connection");
  std::size_t done = 0;
  while (done < bytes.size()) {
    const ssize_t n = ::send(fd_, bytes.data() + done, bytes.size() - done, MSG_NOSIGNAL);
    if (n > 0) {
      done += static_cast<std::size_t>(n);
    } else if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) {
      if (wait_fd(fd_, POLLOUT, timeout_s_) <= 0) throw ClientError("send timed out");
    } else if (n < 0 && errno == EINTR) {
      continue;
    } else {
      throw ClientError(std::string("send failed: ") + std::strerror(errno));
    }
  }
}

json Client::send(json header, std::vector<protocol::Attachment> attachments) {
  if (!header.is_object()) throw ClientError("request header must be a JSON object");
  header["v"] = protocol::kVersion;
  if (!header.contains("id")) header["id"] = next_id_++;
  Message m;
  m.header = std::move(header);
  m.attachments = std::move(attachments);
  send_raw(protocol::encode_frame(m));
  return m.header["id"];
}

std::string Client::read_body() {
  for (;;) {
    const std::size_t avail = in_.size() - in_pos_;
    if (avail >= 4) {
      const auto len = protocol::read_u32be(reinterpret_cast<const unsigned char*>(&in_[in_pos_]));
      if (len > max_frame_bytes) throw ClientError("reply frame too large");
      if (avail >= 4 + std::size_t(len)) {
        std::string body = in_.substr(in_pos_ + 4, len);
        in_pos_ += 4 + len;
        if (in_pos_ == in_.size()) {
          in_.clear();
          in_pos_ = 0;
        }
        return body;
      }
    }
    if (fd_ < 0) throw ClientError("connection closed");
    if (wait_fd(fd_, POLLIN, timeout_s_) <= 0) throw ClientError("timed out waiting for a reply");
    char buf[65536];
    const ssize_t n = ::recv(fd_, buf, sizeof(buf), 0);
    if (n == 0) throw ClientError("connection closed by the server");
    if (n < 0) {
      if (errno == EINTR || errno == EAGAIN || errno == EWOULDBLOCK) continue;
      throw ClientError(std::string("receive failed: ") + std::strerror(errno));
    }
    if (in_pos_ > 0 && in_pos_ == in_.size()) {
      in_.clear();
      in_pos_ = 0;
    }
    in_.append(buf, static_cast<std::size_t>(n));
  }
}

Message Client::receive() {
  if (!pending_.empty()) {
    Message m = std::move(pending_.front());
    pending_.pop_front();
    return m;
  }
  try {
    return protocol::decode_body(read_body(), max_frame_bytes);
  } catch (const protocol::ProtocolError& e) {
    throw ClientError(std::string("malformed reply: ") + e.what());
  }
}

Message Client::wait_for(const json& id) {
  for (auto it = pending_.begin(); it != pending_.end(); ++it)
    if (it->header.value("id", json()) == id) {
      Message m = std::move(*it);
      pending_.erase(it);
      return m;
    }
  for (;;) {
    Message m;
    try {
      m = protocol::decode_body(read_body(), max_frame_bytes);
    } catch (const protocol::ProtocolError& e) {
      throw ClientError(std::string("malformed reply: ") + e.what());
    }
    if (m.header.value("id", json()) == id) return m;
    pending_.push_back(std::move(m));
  }
}

Message Client::call(json header, std::vector<protocol::Attachment> attachments) {
  return wait_for(send(std::move(header), std::move(attachments)));
}

json Client::call_ok(json header, std::vector<protocol::Attachment> attachments) {
  const std::string op = header.value("op", "");
  Message m = call(std::move(header), std::move(attachments));
  if (!m.header.value("ok", false)) throw ClientError(op + ": " + error_text(m));
  return m.header.value("result", json::object());
}

std::string error_text(const Message& reply) {
  if (reply.header.value("ok", false)) return "";
  const json e = reply.header.value("error", json::object());
  return e.value("code", std::string("?")) + ": " + e.value("message", std::string("?"));
}

PlanningSession PlanningSession::open(Client& client, json fields) {
  fields["op"] = "plan.session.open";
  json reply = client.call_ok(std::move(fields));
  if (!reply.contains("session") || !reply["session"].is_string())
    throw ClientError("plan.session.open: reply without a session id");
  return PlanningSession(&client, std::move(reply));
}

PlanningSession::PlanningSession(Client* client, json reference)
    : client_(client), id_(reference["session"].get<std::string>()),
      reference_(std::move(reference)) {}

PlanningSession::PlanningSession(PlanningSession&& other) noexcept
    : client_(std::exchange(other.client_, nullptr)),
      id_(std::move(other.id_)),
      reference_(std::move(other.reference_)) {}

PlanningSession& PlanningSession::operator=(PlanningSession&& other) noexcept {
  if (this != &other) {
    try {
      close();
    } catch (const std::exception&) {
    }
    client_ = std::exchange(other.client_, nullptr);
    id_ = std::move(other.id_);
    reference_ = std::move(other.reference_);
  }
  return *this;
}

PlanningSession::~PlanningSession() {
  try {
    close();
  } catch (const std::exception&) {
  }
}

json PlanningSession::step(double time, const json& start_state, int deadline_ms,
                          double budget_ms) {
  if (!client_) throw ClientError("plan.session.step: the session " + id_ + " is closed");
  json h = {{"op", "plan.session.step"}, {"session", id_}, {"time", time}};
  if (!start_state.is_null()) h["start_state"] = start_state;
  if (deadline_ms > 0) h["deadline_ms"] = deadline_ms;
  if (budget_ms >= 0) h["budget_ms"] = budget_ms;
  return client_->call_ok(std::move(h));
}

void PlanningSession::close() {
  Client* c = std::exchange(client_, nullptr);
  if (c && c->is_open()) c->call_ok({{"op", "plan.session.close"}, {"session", id_}});
}

}  // namespace terrastride::service
