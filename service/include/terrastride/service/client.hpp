// A small blocking client for the terrastride socket service (docs/protocol.md), used by the tests
// and `terrastride bench-service`. One Client per thread; requests may be pipelined.
#pragma once

#include <chrono>
#include <deque>
#include <nlohmann/json.hpp>
#include <stdexcept>
#include <string>
#include <string_view>
#include <unordered_map>
#include <vector>

#include "terrastride/service/protocol.hpp"

namespace terrastride::service {

// Connection failures, timeouts, a closed connection or an unparsable reply.
class ClientError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

class Client {
 public:
  // `address`: tcp://HOST:PORT or unix:PATH. Throws ClientError naming the address.
  // `timeout_s` bounds the connection only; each reply then waits set_timeout's seconds (30 s
  // unless set).
  static Client connect(const std::string& address, double timeout_s = 10.0);
  Client(Client&& other) noexcept;
  Client& operator=(Client&& other) noexcept;
  Client(const Client&) = delete;
  Client& operator=(const Client&) = delete;
  ~Client();

  // Sends one request. Fills "v" and, when absent, a fresh integer "id"; returns the id.
  nlohmann::json send(nlohmann::json header, std::vector<protocol::Attachment> attachments = {});
  // The next reply in arrival order (or one buffered by wait_for).
  protocol::Message receive();
  // The reply carrying `id`; replies to other ids that arrive first are kept for later.
  protocol::Message wait_for(const nlohmann::json& id);
  // send + wait_for.
  protocol::Message call(nlohmann::json header, std::vector<protocol::Attachment> attachments = {});
  // `call`, then the "result" object; throws ClientError("code: message") on an error reply.
  nlohmann::json call_ok(nlohmann::json header, std::vector<protocol::Attachment> attachments = {});

  // The next frame body as bytes, undecoded (for latency measurements; bypasses wait_for's
  // buffer).
  std::string receive_body() { return read_body(); }
  // Raw bytes, for hostile-input tests.
  void send_raw(std::string_view bytes);
  // Half-closes or closes the socket.
  void close();
  bool is_open() const { return fd_ >= 0; }
  void set_timeout(double seconds) { timeout_s_ = seconds; }
  std::uint32_t max_frame_bytes = 0xffffffffu;

 private:
  explicit Client(int fd) : fd_(fd) {}
  std::string read_body();
  int fd_ = -1;
  double timeout_s_ = 30.0;
  long long next_id_ = 1ll << 32;  // automatic ids stay clear of small ids chosen by callers
  std::string in_;
  std::size_t in_pos_ = 0;
  std::deque<protocol::Message> pending_;  // received but not yet asked for
};

// "code: message" of an error reply, or "" for a success reply.
std::string error_text(const protocol::Message& reply);

// A planning session on a client's connection (docs/protocol.md, "Planning sessions"): opened by
// `open`, closed by the destructor (or `close`). Errors are ClientError("plan.session.OP: code:
// message"), the code first: `failed` for a step without a budget whose solve failed and
// `deadline_exceeded` past its deadline leave the session usable for the next step.
//   PlanningSession s = PlanningSession::open(client, {{"terrain", "pallet_15"}, {"horizon", 1}});
//   json plan = s.step(0.1, measured_state);
class PlanningSession {
 public:
  // plan.session.open with `fields` (terrain, constraints, horizon, init, ... as the op takes).
  // The client must outlive the session.
  static PlanningSession open(Client& client, nlohmann::json fields);
  PlanningSession(PlanningSession&& other) noexcept;
  PlanningSession& operator=(PlanningSession&& other) noexcept;
  PlanningSession(const PlanningSession&) = delete;
  PlanningSession& operator=(const PlanningSession&) = delete;
  // Closes the session if it is still open; errors are dropped (the connection may be gone, and
  // the server frees a connection's sessions when it closes).
  ~PlanningSession();

  // plan.session.step: the plan from session time `time` (s) and the measured state (plan.json's
  // terms; null: the session's current plan at `time`). deadline_ms > 0 bounds the request;
  // budget_ms >= 0 is the step's budget (0: wait for the solve; < 0: the server's default), by
  // which it answers with its plan or the fallback ("fallback": true in the reply).
  nlohmann::json step(double time, const nlohmann::json& start_state = nullptr,
                      int deadline_ms = 0, double budget_ms = -1);
  // plan.session.close; idempotent.
  void close();

  const std::string& id() const { return id_; }
  // The open's reply: the reference plan (samples as JSON), session, horizon, memory_bytes.
  const nlohmann::json& reference() const { return reference_; }
  bool is_open() const { return client_ != nullptr; }

 private:
  PlanningSession(Client* client, nlohmann::json reference);
  Client* client_ = nullptr;
  std::string id_;
  nlohmann::json reference_;
};

}  // namespace terrastride::service
