// The terrastride socket service (docs/protocol.md): Asio, one I/O thread, a bounded worker pool
// for long operations. Operations are handlers behind a small interface (OperationRegistry), so the
// transport is independent of the terrain and planner modules behind them.
#pragma once

#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "terrastride/service/cancellation.hpp"
#include "terrastride/service/protocol.hpp"

namespace terrastride::service {

// What a handler sees: the decoded request and its cancellation token (cancel, deadline, shutdown).
struct OpContext {
  const protocol::Message& request;
  std::shared_ptr<CancellationToken> token;
  // The connection the request came on (unique for the server's lifetime): state an operation
  // keeps for a client (planning sessions) is tied to it and freed when it closes.
  std::uint64_t connection = 0;
  // Throws ProtocolError(cancelled / deadline_exceeded / shutting_down) once a stop was requested.
  void check_stop() const;
};

struct OpResult {
  nlohmann::json result = nlohmann::json::object();
  // When set: the result, already serialised as a JSON object (replaces `result`); for large
  // replies that would be slow to build as a JSON tree.
  std::string result_text;
  std::vector<protocol::Attachment> attachments;
};

// Handlers report failures by throwing protocol::ProtocolError(code, message); any other exception
// becomes code "failed" with its message.
using OpHandler = std::function<OpResult(OpContext&)>;

enum class OpKind {
  kInline,  // cheap (microseconds): runs on the I/O thread, in order with the connection's frames
  kWorker,  // long: runs on the bounded worker pool; `busy` when the queue is full
};

struct Operation {
  std::string name;
  OpKind kind = OpKind::kInline;
  std::string summary;
  OpHandler handler;
  // The request fields the handler reads, besides the envelope (v, id, op, deadline_ms,
  // attachments). The server refuses any other header key with bad_request naming it (and a close
  // match, "did you mean"), so a misspelt option is an error rather than silently ignored.
  // nullopt: the fields are not checked.
  std::optional<std::vector<std::string>> fields = std::nullopt;
  // The attachment names the handler reads. The server refuses any other with bad_request naming
  // it (an attachment under a misspelt name would otherwise be ignored). Default: none.
  // nullopt: the names are not checked.
  std::optional<std::vector<std::string>> attachments = std::vector<std::string>{};
  // A worker-pool operation whose reply is due by a deadline may raise its worker thread's
  // scheduling priority (plan.session.step, to a real-time one); the worker keeps it while it
  // waits for its next job, so that it wakes at once for the client's next request, and returns
  // to the normal policy before running any other operation. Others run at the normal policy.
  bool keeps_priority = false;
};

class OperationRegistry {
 public:
  void add(Operation op) { ops_[op.name] = std::move(op); }
  const Operation* find(const std::string& name) const {
    const auto it = ops_.find(name);
    return it == ops_.end() ? nullptr : &it->second;
  }
  std::vector<std::string> names() const {
    std::vector<std::string> n;
    for (const auto& [k, v] : ops_) n.push_back(k);
    return n;
  }
  // Called on the I/O thread with a connection's id when it closes (for any reason: the client
  // left, a timeout, shutdown). Must be quick and must not throw.
  void on_disconnect(std::function<void(std::uint64_t)> hook) {
    disconnect_hooks_.push_back(std::move(hook));
  }
  void disconnected(std::uint64_t connection) const {
    for (const auto& hook : disconnect_hooks_) hook(connection);
  }

 private:
  std::map<std::string, Operation> ops_;
  std::vector<std::function<void(std::uint64_t)>> disconnect_hooks_;
};

// min(512 MiB, a quarter of the physical memory): the default request-buffer budget (8 frames of
// the largest default size, --max-frame-bytes 64 MiB, arriving or waiting at once).
std::size_t default_max_buffered_bytes();

struct ServerOptions {
  std::vector<std::string> listen{"tcp://127.0.0.1:0"};  // tcp://HOST:PORT or unix:PATH
  std::optional<std::string> token;  // shared secret; required for non-loopback TCP addresses
  std::uint32_t max_frame_bytes = protocol::kDefaultMaxFrameBytes;
  int workers = 2;
  int queue = 8;  // jobs waiting for a worker before `busy`
  int max_connections = 512;
  int max_inflight_per_connection = 64;  // worker requests in flight (queued, running, waiting)
  // Worker requests one connection may have in the pool (queued or running): a connection cannot
  // take the whole queue and leave every other client `busy`.
  int max_jobs_per_connection = 4;
  // Unsent replies: one connection's before it is dropped (room for the largest plan reply, 120 s
  // at 1 ms in JSON, some 230 MB), and all connections' together (past that the connection
  // holding the most, stalled ones first, is dropped), each with the reason on stderr, so
  // clients that never read cannot make the server hold their replies.
  std::size_t max_write_queue_bytes = std::size_t{256} << 20;
  std::size_t max_unsent_bytes = std::size_t{512} << 20;
  double drain_seconds = 5.0;  // on SIGINT/SIGTERM: time running jobs get before cancellation
  bool handle_signals = true;
  // The I/O thread (reads requests, writes replies, runs map.query inline) at SCHED_FIFO
  // priority 1 where the process may (CAP_SYS_NICE or an rtprio limit), so that on a busy robot
  // computer a planning-session step's reply leaves when it is due rather than when the
  // scheduler next picks the thread (docs/sessions.md). Off by default: a real-time thread
  // preempts every normal one, and the kernel's real-time throttling is what then leaves the
  // rest of the machine its share. status.realtime_io says whether it took effect.
  bool realtime_io = false;

  // Limits that keep clients from holding memory or connection slots without using them
  // (docs/protocol.md, "Limits"). A frame that has started must be complete within
  // frame_timeout_s plus the time its received bytes take at min_receive_rate (bytes/s), or the
  // connection gets a `timeout` error and is closed; replies the client does not take within the
  // same allowance close it too. On token servers, hello must arrive within frame_timeout_s of
  // connecting. 0 = off.
  double frame_timeout_s = 10.0;
  double min_receive_rate = 128.0 * 1024;  // 1 Mbit/s
  // A connection with nothing in flight (no partial frame, no worker job, no unsent reply) is
  // closed after this long. 0 = off.
  double idle_timeout_s = 300.0;
  // Largest frame before a successful hello on a token server: an unauthenticated peer cannot
  // make the server buffer more than this per connection.
  std::uint32_t max_frame_bytes_before_hello = 64u << 10;
  // Request bytes held across all connections: frames larger than a connection's 64 KiB buffer
  // while they arrive, and the decoded requests of queued and running worker jobs. A frame that
  // would exceed it gets `busy` (id null) and its connection is closed.
  std::size_t max_buffered_bytes = default_max_buffered_bytes();
  // The same, per connection (its frame arriving and its queued and running requests): one
  // client cannot take the whole budget.
  std::size_t max_buffered_bytes_per_connection = std::size_t{128} << 20;
};

// The size of the hello frame carrying `token` (with an id of up to 20 characters): a token server
// must accept it before hello, so this may not exceed max_frame_bytes_before_hello.
std::size_t hello_frame_bytes(const std::string& token);

// Parsed listen address.
struct ListenAddress {
  enum class Kind { kTcp, kUnix } kind = Kind::kTcp;
  std::string host;  // tcp
  std::uint16_t port = 0;
  std::string path;  // unix
};
// Throws std::invalid_argument naming the address when it is malformed.
ListenAddress parse_listen_address(const std::string& text);

class Server {
 public:
  Server(ServerOptions options, OperationRegistry operations,
         std::function<nlohmann::json()> status_extra = {},
         std::function<nlohmann::json()> hello_extra = {});
  ~Server();
  Server(const Server&) = delete;
  Server& operator=(const Server&) = delete;

  // Binds every listen address; returns the bound addresses ("tcp://127.0.0.1:40123",
  // "unix:/run/ts.sock"). Throws std::runtime_error naming the address on failure, and refuses a
  // non-loopback TCP address without a token.
  std::vector<std::string> bind();
  // Serves until shutdown() or SIGINT/SIGTERM (when handle_signals); returns after draining.
  void run();
  // Graceful shutdown, callable from any thread.
  void shutdown();
  // The counters reported by `status` (thread-safe snapshot).
  nlohmann::json status() const;

  struct Impl;  // defined in server.cpp

 private:
  std::unique_ptr<Impl> impl_;
};

// The terrain/planner operations (map.update, map.clear, map.query, plan, check, and with
// `debug_ops` the test operation debug.sleep), registered on `registry`.
struct BackendOptions {
  std::string robot = "hyq";
  bool debug_ops = false;
  // Each plan runs in a forked child process (Debian's MUMPS is not re-entrant; processes run at
  // once). Off: plans run in the worker thread, one solve at a time per process.
  bool plan_in_child_process = true;
  // Address space a plan process may add to the server's (0 = unlimited).
  std::size_t plan_memory_bytes = std::size_t{4} << 30;
  // Directories whose terrain directories (`terrastride map` outputs) clients may name in
  // map.update's "terrain_dir" and plan's "terrain"; empty: clients name none (the server opens
  // no path a client gives, so its errors reveal nothing of the file system).
  std::vector<std::string> terrain_roots;
  // Planning sessions (plan.session.*): at once per server and per connection, and the idle time
  // after which a session is closed. When the server holds max_sessions, opening one closes the
  // longest idle session (not one in the middle of a step).
  int max_sessions = 64;
  int max_sessions_per_connection = 8;
  double session_idle_timeout_s = 300.0;
};
class Backend;
std::shared_ptr<Backend> make_backend(const BackendOptions& options, OperationRegistry& registry);
nlohmann::json backend_status(const Backend& backend);
nlohmann::json backend_hello(const Backend& backend);

}  // namespace terrastride::service
