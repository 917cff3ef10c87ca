// One client connection of the socket server: framing and reading requests under the memory and
// time limits, dispatching them (inline, or as a Job on the worker pool), writing replies with
// backpressure, timeouts, and closing gracefully. Runs on the I/O thread only.
#pragma once

#include <asio.hpp>
#include <cstddef>
#include <cstdint>
#include <deque>
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
  BudgetHold request_bytes;  // the request's attachments, until the worker frees them
  std::shared_ptr<CancellationToken> token = std::make_shared<CancellationToken>();
  std::weak_ptr<Connection> conn;
  std::uint64_t connection = 0;  // the connection's id (OpContext::connection)
  bool replied = false;
  bool running = false;
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
  std::deque<std::string> out;
  std::vector<std::string> writing;  // buffers of the write in progress
  std::size_t out_bytes = 0;
  std::unordered_map<std::string, std::shared_ptr<Job>> inflight;

  // Timeouts (checked by Server::Impl::sweep). A frame counts from its first byte; its allowance
  // grows with the bytes received, so a large frame arriving steadily is never cut off.
  Clock::time_point last_active = Clock::now();
  bool frame_started = false;
  Clock::time_point frame_start;
  Clock::time_point write_start;
  std::size_t write_bytes = 0;
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

  void refuse_for_budget(std::size_t frame_bytes);

  void send(std::string frame);

  void send_message(const protocol::Message& m);

  void send_error(const nlohmann::json& id, const std::string& code, const std::string& message);

  void do_write();

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

  void dispatch(std::string_view body);
  OpResult builtin_cancel(const protocol::Message& m);
};

}  // namespace terrastride::service
