// One client connection of the socket server: framing and reading requests under the memory and
// time limits, dispatching them (inline, or as a Job on the worker pool), writing replies with
// backpressure, timeouts, and closing gracefully. Runs on the I/O thread only.
#pragma once

#include <asio.hpp>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <functional>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <string_view>
#include <unordered_map>
#include <vector>

#include "request_memory.hpp"
#include "server_impl.hpp"
#include "terrastride/service/protocol.hpp"

namespace terrastride::service {

// A long operation travelling through the worker pool. `replied` and `conn` are I/O-thread state.
struct Job {
  std::uint64_t seq = 0;
  nlohmann::json id;
  std::string key;  // id.dump(): the connection's in-flight map key
  const Operation* op = nullptr;
  protocol::Message request;
  // The request's bytes (its frame: header and attachments), against the server's and the
  // connection's budgets, until the worker frees them.
  BudgetHold request_bytes, connection_bytes;
  std::shared_ptr<CancellationToken> token = std::make_shared<CancellationToken>();
  std::weak_ptr<Connection> conn;
  std::uint64_t connection = 0;  // the connection's id (OpContext::connection)
  bool replied = false;
  bool running = false;
  bool in_pool = false;  // counted in the connection's pool_jobs (queued or running on a worker)
  // The planning session the request names (plan.session.step / close): requests of one session
  // are answered in the order they arrived, so each waits in the session's lane for the one
  // before it. Empty: not in a lane.
  std::string lane;
  bool waiting = false;  // in a lane behind another request, not started
  std::unique_ptr<asio::steady_timer> deadline_timer;
};

struct Connection : std::enable_shared_from_this<Connection> {
  Connection(Server::Impl& s, asio::generic::stream_protocol::socket sock, std::uint64_t id)
      : server(s), socket(std::move(sock)), cid(id) {
    authenticated = !server.options.token.has_value();
    asio::error_code ignored;
    socket.non_blocking(true, ignored);  // reads happen once readable (see read_more)
  }

  Server::Impl& server;
  asio::generic::stream_protocol::socket socket;
  std::uint64_t cid;
  bool authenticated;
  bool closed = false;
  bool close_after_flush = false;
  bool counted = false;  // counted in active_connections / connections_open
  // Input buffer: bytes [in_start, in_end) are received and not yet consumed. Reads go into the
  // free tail, so several pipelined frames arrive with one system call. Its size is fixed: a
  // frame that does not fit is received into `large` instead.
  static constexpr std::size_t kBufferBytes = 64u << 10;
  static constexpr std::size_t kReadChunk = 1u << 20;  // largest read into `large`
  std::string inbuf = std::string(kBufferBytes, '\0');
  std::size_t in_start = 0, in_end = 0;
  FrameBuffer large;
  std::size_t large_have = 0;  // bytes of `large` received (prefix included)
  BudgetHold large_bytes;      // large_have, counted against max_buffered_bytes
  BudgetHold large_own_bytes;  // the same against this connection's budget
  // Request bytes this connection holds (its large frame, its requests' frames until a worker
  // frees them), under max_buffered_bytes_per_connection.
  std::shared_ptr<ByteBudget> own_budget =
      std::make_shared<ByteBudget>(server.options.max_buffered_bytes_per_connection);
  std::deque<std::string> out;
  std::vector<std::string> writing;  // buffers of the write in progress
  std::size_t out_bytes = 0;
  std::unordered_map<std::string, std::shared_ptr<Job>> inflight;
  int pool_jobs = 0;  // jobs of this connection queued or running in the pool
  // Requests of one planning session in arrival order; the front one has started.
  std::unordered_map<std::string, std::deque<std::shared_ptr<Job>>> lanes;

  // Timeouts (checked by Server::Impl::sweep). A frame counts from its first byte; its allowance
  // grows with the bytes received, so a large frame arriving steadily is never cut off.
  Clock::time_point last_active = Clock::now();
  // The last bytes of a request received: a frame that stops arriving is cut off after
  // frame_timeout_s, however many bytes came before (they would earn it minutes otherwise).
  Clock::time_point last_received = Clock::now();
  bool frame_started = false;
  Clock::time_point frame_start;
  Clock::time_point write_start;
  std::size_t write_bytes = 0;  // the batch being written
  std::size_t write_done = 0;   // of it, written
  Clock::time_point write_progress;  // the last bytes the client took
  bool lingering = false;
  Clock::time_point linger_until;
  static constexpr double kLingerSeconds = 1.0;

  // Backpressure: a client whose replies pile up unsent is not read from until they drain, so it
  // slows only itself (its own sends block in TCP).
  static constexpr std::size_t kPauseReadBytes = 4u << 20;
  bool read_paused = false;
  bool read_pending = false;

  void start() { read_more(); }

  bool partial_frame() const { return large.data() != nullptr || in_end > in_start; }
  // Nothing in flight: no partial frame, no request, no unsent reply (what idle timeouts and
  // eviction look at).
  bool idle() const {
    return !frame_started && inflight.empty() && out.empty() && writing.empty();
  }

  // Waits until the socket is readable, then reads into whatever buffer is current at that time.
  // No buffer is handed to a pending operation, so the large-frame buffer can be freed at any
  // moment (a timeout, a refusal) without waiting for the peer to send or close.
  void read_more();

  void on_readable(asio::error_code ec);

  void free_large();

  // The cap on a frame's body: smaller until a token server has seen hello.
  std::uint32_t frame_cap() const;

  // Dispatches every complete frame in the buffer, then reads on (unless paused or closing).
  void process_frames();

  // Moves the partial frame at in_start into its own buffer of `total` bytes. False (after a
  // `busy` reply) when the frame cannot fit in what the request-byte budget has left.
  bool start_large(std::size_t total);

  // `busy` (id null) and close for a frame beyond the server's request-byte budget, or beyond
  // this connection's (`own`).
  void refuse_for_budget(std::size_t frame_bytes, bool own);

  // Closed to make room when the server holds max_connections: told why, then closed.
  void evict(double idle_s);

  void send(std::string frame);

  void send_message(const protocol::Message& m);

  void send_error(const nlohmann::json& id, const std::string& code, const std::string& message);

  void do_write();
  void write_some();
  void end_write(const asio::error_code& ec);
  // How far behind --min-receive-rate the client is in taking its replies (s; the larger, the
  // less it reads): whom the unsent-reply budget drops first.
  double seconds_behind(Clock::time_point now) const;

  // After the last reply (an error that ends the connection): stop reading requests, close once
  // it is written.
  void finish_and_close();

  // Half-closes (FIN after the last reply) and reads until the peer closes or kLingerSeconds
  // pass: closing with unread input would send a reset, which can destroy the reply in flight.
  void linger();

  void uncount();

  // Nobody is left to read these replies: stop the work.
  void abandon_jobs();

  void close();

  // Called by the sweep: closes a connection whose frame, write or silence outlasted its limit.
  void check_timeouts(Clock::time_point now);

  void finish_job(const std::shared_ptr<Job>& job, std::string frame, bool ok,
                  const std::string& code);

  // Answers a job now with an error and forgets it; the worker's later result is dropped.
  void abort_job(const std::shared_ptr<Job>& job, const char* code, const std::string& message);

  // Drops this connection's unsent replies and closes it, naming the reason on stderr (nobody
  // reads them; the server's unsent-reply budget is needed for clients that do).
  void drop_unread(const std::string& reason);

  void dispatch(std::string_view body);
  // The first request on a token server: a hello with the token; false after refusing it.
  bool authenticate(const protocol::Message& m, const protocol::Request& req,
                    const nlohmann::json& id);
  // The operation (`*op` null for hello, status, cancel), its fields and attachment names; false
  // after an error reply.
  bool check_request(const protocol::Message& m, const protocol::Request& req,
                     const nlohmann::json& id, const Operation** op);
  OpResult hello_result() const;
  // A registered operation: inline now, or as a Job (the pool, or its session's lane).
  void run_operation(protocol::Message m, const protocol::Request& req, const nlohmann::json& id,
                     const Operation* op, std::size_t frame_bytes, Clock::time_point arrival);
  void watch_deadline(const std::shared_ptr<Job>& job);
  OpResult builtin_cancel(const protocol::Message& m);
  // Runs an inline operation now and sends its reply (or its error).
  void answer_inline(const nlohmann::json& id, const std::string& op,
                     const std::function<OpResult()>& fn);
  // Submits a worker job to the pool under the connection's and the pool's limits; false after a
  // `busy` reply.
  bool submit_job(const std::shared_ptr<Job>& job);
  // Starts a job that reached the front of its lane (or has none).
  void start_job(const std::shared_ptr<Job>& job);
  // A job was answered: the pool place it held, and the next request of its lane.
  void job_answered(const std::shared_ptr<Job>& job);
  void leave_pool(const std::shared_ptr<Job>& job);
};

}  // namespace terrastride::service
