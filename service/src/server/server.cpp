// The socket server: Asio acceptors and connections on one I/O thread, long operations on a
// bounded worker pool. All connection state is touched only on the I/O thread; workers hand their
// encoded replies back through asio::post.
#include "terrastride/service/server.hpp"

#include <sys/mman.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <unistd.h>

#include <algorithm>
#include <asio.hpp>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <cstring>
#include <deque>
#include <mutex>
#include <set>
#include <thread>
#include <unordered_map>

namespace terrastride::service {

namespace pc = protocol::code;
using nlohmann::json;
using protocol::Message;
using protocol::ProtocolError;
using Clock = std::chrono::steady_clock;

void OpContext::check_stop() const {
  if (!token->stop_requested()) return;
  switch (token->reason()) {
    case CancellationToken::Reason::kDeadline:
      throw ProtocolError(pc::kDeadlineExceeded, "deadline exceeded while running");
    case CancellationToken::Reason::kShutdown:
      throw ProtocolError(pc::kShuttingDown, "server shutting down; operation cancelled");
    default:
      throw ProtocolError(pc::kCancelled, "cancelled by request");
  }
}

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

struct Connection;

// The server-wide count of buffered request bytes (ServerOptions::max_buffered_bytes). Shared with
// jobs, which give their bytes back on worker threads, possibly after the server is gone.
struct ByteBudget {
  explicit ByteBudget(std::size_t l) : limit(l) {}
  const std::size_t limit;
  std::atomic<std::size_t> used{0};
  std::atomic<std::uint64_t> refused{0};
  bool fits(std::size_t more) const { return used.load() + more <= limit; }
};

// Bytes counted against a ByteBudget until released (or destroyed).
class BudgetHold {
 public:
  BudgetHold() = default;
  BudgetHold(BudgetHold&& o) noexcept { *this = std::move(o); }
  BudgetHold& operator=(BudgetHold&& o) noexcept {
    if (this != &o) {
      release();
      budget_ = std::move(o.budget_);
      bytes_ = o.bytes_;
      o.bytes_ = 0;
    }
    return *this;
  }
  ~BudgetHold() { release(); }
  void add(const std::shared_ptr<ByteBudget>& budget, std::size_t n) {
    budget_ = budget;
    bytes_ += n;
    budget_->used += n;
  }
  void release() {
    if (budget_ && bytes_ > 0) budget_->used -= bytes_;
    bytes_ = 0;
  }

 private:
  std::shared_ptr<ByteBudget> budget_;
  std::size_t bytes_ = 0;
};

// A frame too large for a connection's fixed buffer, received into its own anonymous mapping:
// pages are committed only as bytes arrive, and munmap returns them to the system at once (a
// malloc'ed block of this size could stay in the heap after it is freed).
class FrameBuffer {
 public:
  FrameBuffer() = default;
  FrameBuffer(FrameBuffer&& o) noexcept { *this = std::move(o); }
  FrameBuffer& operator=(FrameBuffer&& o) noexcept {
    if (this != &o) {
      reset();
      std::swap(data_, o.data_);
      std::swap(size_, o.size_);
    }
    return *this;
  }
  ~FrameBuffer() { reset(); }
  bool allocate(std::size_t n) {
    reset();
    void* p = ::mmap(nullptr, n, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
    if (p == MAP_FAILED) return false;
    data_ = static_cast<char*>(p);
    size_ = n;
    return true;
  }
  void reset() {
    if (data_) ::munmap(data_, size_);
    data_ = nullptr;
    size_ = 0;
  }
  char* data() const { return data_; }
  std::size_t size() const { return size_; }

 private:
  char* data_ = nullptr;
  std::size_t size_ = 0;
};

// A long operation travelling through the worker pool. `replied` and `conn` are I/O-thread state.
struct Job {
  std::uint64_t seq = 0;
  json id;
  std::string key;  // id.dump(): the connection's in-flight map key
  const Operation* op = nullptr;
  Message request;
  BudgetHold request_bytes;  // the request's attachments, until the worker frees them
  std::shared_ptr<CancellationToken> token = std::make_shared<CancellationToken>();
  std::weak_ptr<Connection> conn;
  bool replied = false;
  bool running = false;
  std::unique_ptr<asio::steady_timer> deadline_timer;
};

// Bounded FIFO of jobs served by a fixed set of threads.
class WorkerPool {
 public:
  WorkerPool(int workers, int capacity, std::function<void(std::shared_ptr<Job>)> run)
      : capacity_(static_cast<std::size_t>(std::max(0, capacity))), run_(std::move(run)) {
    for (int i = 0; i < std::max(1, workers); ++i) threads_.emplace_back([this] { loop(); });
  }
  ~WorkerPool() { stop(); }

  // False when every worker is taken and `capacity` jobs already wait (the caller replies
  // `busy`).
  bool try_submit(std::shared_ptr<Job> job) {
    std::lock_guard<std::mutex> lock(mu_);
    if (stopping_) return false;
    if (queue_.size() + running_ >= threads_.size() + capacity_) return false;
    queue_.push_back(std::move(job));
    cv_.notify_one();
    return true;
  }
  // Removes a job that has not started; false when it is running or done.
  bool try_remove(const std::shared_ptr<Job>& job) {
    std::lock_guard<std::mutex> lock(mu_);
    for (auto it = queue_.begin(); it != queue_.end(); ++it)
      if (*it == job) {
        queue_.erase(it);
        return true;
      }
    return false;
  }
  std::vector<std::shared_ptr<Job>> take_all_queued() {
    std::lock_guard<std::mutex> lock(mu_);
    std::vector<std::shared_ptr<Job>> out(queue_.begin(), queue_.end());
    queue_.clear();
    return out;
  }
  std::size_t queued() const {
    std::lock_guard<std::mutex> lock(mu_);
    return queue_.size();
  }
  std::size_t running() const {
    std::lock_guard<std::mutex> lock(mu_);
    return running_;
  }
  std::size_t workers() const { return threads_.size(); }
  std::size_t capacity() const { return capacity_; }
  void stop() {
    {
      std::lock_guard<std::mutex> lock(mu_);
      if (stopping_ && threads_.empty()) return;
      stopping_ = true;
      queue_.clear();
    }
    cv_.notify_all();
    for (auto& t : threads_)
      if (t.joinable()) t.join();
    threads_.clear();
  }

 private:
  void loop() {
    for (;;) {
      std::shared_ptr<Job> job;
      {
        std::unique_lock<std::mutex> lock(mu_);
        cv_.wait(lock, [this] { return stopping_ || !queue_.empty(); });
        if (stopping_) return;
        job = std::move(queue_.front());
        queue_.pop_front();
        ++running_;
      }
      run_(job);
      std::lock_guard<std::mutex> lock(mu_);
      --running_;
    }
  }

  std::size_t capacity_;
  std::function<void(std::shared_ptr<Job>)> run_;
  mutable std::mutex mu_;
  std::condition_variable cv_;
  std::deque<std::shared_ptr<Job>> queue_;
  std::size_t running_ = 0;
  bool stopping_ = false;
  std::vector<std::thread> threads_;
};

struct Counters {
  std::atomic<std::uint64_t> connections_total{0}, connections_open{0}, connections_rejected{0},
      requests{0}, replies_ok{0}, replies_error{0}, malformed_frames{0}, busy{0}, bytes_in{0},
      bytes_out{0}, slow_client_drops{0}, disconnects_mid_request{0}, cancelled{0},
      deadline_exceeded{0}, auth_failures{0}, frame_timeouts{0}, idle_timeouts{0},
      write_timeouts{0};
  std::mutex mu;
  std::map<std::string, std::uint64_t> errors_by_code;
  std::map<std::string, std::uint64_t> ops;
};

}  // namespace

struct Server::Impl {
  ServerOptions options;
  OperationRegistry registry;
  std::function<json()> status_extra, hello_extra;
  asio::io_context io;
  std::vector<asio::ip::tcp::acceptor> tcp_acceptors;
  std::vector<asio::local::stream_protocol::acceptor> unix_acceptors;
  std::vector<std::string> unix_paths;
  std::vector<std::string> bound;
  std::unique_ptr<WorkerPool> pool;
  std::set<std::shared_ptr<Connection>> connections;
  Counters counters;
  Clock::time_point started = Clock::now();
  std::uint64_t next_conn_id = 1;
  std::uint64_t next_job_seq = 1;
  std::atomic<bool> draining{false};
  Clock::time_point drain_started;
  bool drain_cancelled = false;
  std::unique_ptr<asio::signal_set> signals;
  std::unique_ptr<asio::steady_timer> drain_timer;
  std::atomic<bool> stopped{false};
  std::shared_ptr<ByteBudget> budget;
  // Connections counted against max_connections (not the ones closing or refused).
  int active_connections = 0;
  // Connections that sent their last reply and wait briefly for the peer's end (see linger()).
  int lingering = 0;
  std::unique_ptr<asio::steady_timer> sweep_timer;

  void accept_tcp(asio::ip::tcp::acceptor& acc);
  void accept_unix(asio::local::stream_protocol::acceptor& acc);
  void adopt(asio::generic::stream_protocol::socket sock, bool tcp);
  void run_job(std::shared_ptr<Job> job);  // worker thread
  void begin_shutdown();
  void drain_tick();
  void sweep();  // timeouts: slow frames, stalled writes, idle connections, lingering closes
  double sweep_period_s() const;
  json status_json();
  void count_error(const std::string& code) {
    counters.replies_error++;
    std::lock_guard<std::mutex> lock(counters.mu);
    counters.errors_by_code[code]++;
  }
};

namespace {

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
  void read_more() {
    if (closed || read_pending || (close_after_flush && !lingering)) return;
    read_pending = true;
    auto self = shared_from_this();
    socket.async_wait(asio::socket_base::wait_read,
                      [self](const asio::error_code& ec) { self->on_readable(ec); });
  }

  void on_readable(asio::error_code ec) {
    read_pending = false;
    if (closed) return;
    char* dst;
    std::size_t room;
    if (lingering || close_after_flush) {  // the peer's last bytes, read only to be discarded
      dst = &inbuf[0];
      room = inbuf.size();
    } else if (large.data()) {
      dst = large.data() + large_have;
      room = std::min(large.size() - large_have, kReadChunk);
    } else {
      if (in_end == inbuf.size() && in_start > 0) {
        std::memmove(&inbuf[0], &inbuf[in_start], in_end - in_start);
        in_end -= in_start;
        in_start = 0;
      }
      dst = &inbuf[in_end];
      room = inbuf.size() - in_end;
    }
    std::size_t n = 0;
    if (!ec) n = socket.read_some(asio::buffer(dst, room), ec);
    if (ec == asio::error::would_block || ec == asio::error::try_again) return read_more();
    server.counters.bytes_in += n;
    if (ec) {
      if (!lingering && !close_after_flush && partial_frame())
        server.counters.disconnects_mid_request++;
      return close();
    }
    if (lingering || close_after_flush) return read_more();
    last_active = Clock::now();
    if (large.data()) {
      large_have += n;
      large_bytes.add(server.budget, n);
      if (server.budget->used.load() > server.budget->limit) return refuse_for_budget(large.size());
    } else {
      in_end += n;
    }
    process_frames();
  }

  void free_large() {
    large.reset();
    large_have = 0;
    large_bytes.release();
  }

  // The cap on a frame's body: smaller until a token server has seen hello.
  std::uint32_t frame_cap() const {
    return authenticated ? server.options.max_frame_bytes
                         : std::min(server.options.max_frame_bytes,
                                    server.options.max_frame_bytes_before_hello);
  }

  // Dispatches every complete frame in the buffer, then reads on (unless paused or closing).
  void process_frames() {
    while (!closed && !close_after_flush) {
      if (out_bytes > kPauseReadBytes) {
        read_paused = true;
        return;
      }
      if (large.data()) {
        if (large_have < large.size()) break;
        // Moved out first: whatever dispatch does (even closing), the body stays valid.
        FrameBuffer frame = std::move(large);
        BudgetHold held = std::move(large_bytes);
        large_have = 0;
        frame_started = false;
        dispatch(std::string_view(frame.data() + 4, frame.size() - 4));
        continue;
      }
      const std::size_t avail = in_end - in_start;
      if (avail < 4) break;
      const std::uint32_t len =
          protocol::read_u32be(reinterpret_cast<const unsigned char*>(&inbuf[in_start]));
      const std::uint32_t cap = frame_cap();
      try {
        protocol::check_body_length(len, cap);
      } catch (const ProtocolError& e) {
        // The stream cannot be resynchronised: reply, then close once the reply is out.
        server.counters.malformed_frames++;
        std::string message = e.what();
        if (len > cap && cap < server.options.max_frame_bytes)
          message = "frame of " + std::to_string(len) + " bytes exceeds the limit of " +
                    std::to_string(cap) +
                    " bytes before hello (--max-frame-bytes-before-hello); authenticate first";
        send_error(nullptr, e.code(), message);
        finish_and_close();
        return;
      }
      const std::size_t total = 4 + std::size_t(len);
      if (avail >= total) {
        const std::string_view body(&inbuf[in_start + 4], len);
        in_start += total;
        frame_started = false;
        dispatch(body);
        continue;
      }
      if (total > inbuf.size() && !start_large(total)) return;
      break;
    }
    if (closed || close_after_flush) return;
    if (in_start == in_end) in_start = in_end = 0;
    if (!partial_frame()) {
      frame_started = false;
    } else if (!frame_started) {
      frame_started = true;
      frame_start = Clock::now();
    }
    read_more();
  }

  // Moves the partial frame at in_start into its own buffer of `total` bytes. False (after a
  // `busy` reply) when the frame cannot fit in what the request-byte budget has left.
  bool start_large(std::size_t total) {
    const std::size_t have = in_end - in_start;
    if (!server.budget->fits(total)) {
      refuse_for_budget(total);
      return false;
    }
    if (!large.allocate(total)) {
      send_error(nullptr, pc::kBusy,
                 "cannot allocate " + std::to_string(total) + " bytes for a frame; retry later");
      finish_and_close();
      return false;
    }
    std::memcpy(large.data(), &inbuf[in_start], have);
    large_have = have;
    large_bytes.add(server.budget, have);
    in_start = in_end = 0;
    return true;
  }

  void refuse_for_budget(std::size_t frame_bytes) {
    server.budget->refused++;
    server.counters.busy++;
    send_error(nullptr, pc::kBusy,
               "frame of " + std::to_string(frame_bytes) + " bytes refused: the server holds " +
                   std::to_string(server.budget->used.load()) +
                   " bytes of requests and its budget is " + std::to_string(server.budget->limit) +
                   " (--max-buffered-bytes); connection closed, retry later");
    finish_and_close();
  }

  void send(std::string frame) {
    if (closed || lingering) return;
    server.counters.bytes_out += frame.size();
    out_bytes += frame.size();
    if (out_bytes > server.options.max_write_queue_bytes) {
      // A client that does not read its replies: drop it rather than grow without bound.
      server.counters.slow_client_drops++;
      close();
      return;
    }
    last_active = Clock::now();
    out.push_back(std::move(frame));
    if (writing.empty()) do_write();
  }

  void send_message(const Message& m) {
    try {
      send(protocol::encode_frame(m));
    } catch (const ProtocolError& e) {
      send(protocol::encode_frame(
          protocol::make_error(m.header.value("id", json()), pc::kInternal, e.what())));
    }
  }

  void send_error(const json& id, const std::string& code, const std::string& message) {
    server.count_error(code);
    send(protocol::encode_frame(protocol::make_error(id, code, message)));
  }

  void do_write() {
    if (closed) return;
    if (out.empty()) {
      if (close_after_flush) linger();
      return;
    }
    std::vector<asio::const_buffer> bufs;
    while (!out.empty() && writing.size() < 64) {
      writing.push_back(std::move(out.front()));
      out.pop_front();
    }
    write_bytes = 0;
    for (const auto& w : writing) {
      bufs.emplace_back(asio::buffer(w));
      write_bytes += w.size();
    }
    write_start = Clock::now();
    auto self = shared_from_this();
    asio::async_write(socket, bufs, [self](const asio::error_code& ec, std::size_t) {
      for (const auto& w : self->writing) self->out_bytes -= w.size();
      self->writing.clear();
      if (ec) return self->close();
      self->last_active = Clock::now();
      if (self->read_paused && self->out_bytes <= kPauseReadBytes / 2) {
        self->read_paused = false;
        // The frame clock stopped while the server did not read.
        if (self->frame_started) self->frame_start = Clock::now();
        self->process_frames();
      }
      self->do_write();
    });
  }

  // After the last reply (an error that ends the connection): stop reading requests, close once
  // it is written.
  void finish_and_close() {
    close_after_flush = true;
    free_large();
    abandon_jobs();
    if (out.empty() && writing.empty()) linger();
  }

  // Half-closes (FIN after the last reply) and reads until the peer closes or kLingerSeconds
  // pass: closing with unread input would send a reset, which can destroy the reply in flight.
  void linger() {
    if (closed || lingering) return;
    uncount();
    if (server.lingering >= std::max(64, server.options.max_connections)) return close();
    lingering = true;
    server.lingering++;
    asio::error_code ignored;
    socket.shutdown(asio::socket_base::shutdown_send, ignored);
    linger_until = Clock::now() + std::chrono::milliseconds(static_cast<int>(kLingerSeconds * 1e3));
    in_start = in_end = 0;
    read_more();
  }

  void uncount() {
    if (!counted) return;
    counted = false;
    server.active_connections--;
    server.counters.connections_open--;
  }

  // Nobody is left to read these replies: stop the work.
  void abandon_jobs() {
    for (auto& [key, job] : inflight) {
      job->replied = true;
      job->token->cancel(CancellationToken::Reason::kCancelled);
      if (job->deadline_timer) job->deadline_timer->cancel();
      server.pool->try_remove(job);
    }
    inflight.clear();
  }

  void close() {
    if (closed) return;
    closed = true;
    uncount();
    if (lingering) server.lingering--;
    asio::error_code ignored;
    socket.shutdown(asio::socket_base::shutdown_both, ignored);
    socket.close(ignored);
    free_large();
    abandon_jobs();
    server.connections.erase(shared_from_this());
  }

  // Called by the sweep: closes a connection whose frame, write or silence outlasted its limit.
  void check_timeouts(Clock::time_point now) {
    if (closed) return;
    const auto since = [&](Clock::time_point t) {
      return std::chrono::duration<double>(now - t).count();
    };
    if (lingering) {
      if (now >= linger_until) close();
      return;
    }
    const ServerOptions& o = server.options;
    if (o.frame_timeout_s <= 0 && o.idle_timeout_s <= 0) return;
    if (o.frame_timeout_s > 0 && !writing.empty() &&
        since(write_start) > o.frame_timeout_s + double(write_bytes) / o.min_receive_rate) {
      // The client does not take its replies: nothing more can reach it, so no error reply.
      server.counters.write_timeouts++;
      return close();
    }
    if (close_after_flush) return;
    if (o.frame_timeout_s > 0 && frame_started && !read_paused) {
      const std::size_t have = large.data() ? large_have : in_end - in_start;
      const double allowed = o.frame_timeout_s + double(have) / o.min_receive_rate;
      if (since(frame_start) > allowed) {
        server.counters.frame_timeouts++;
        char text[64];
        std::snprintf(text, sizeof(text), "%.3g s", allowed);
        const std::size_t announced =
            large.data() ? large.size()
            : have >= 4  ? 4 + std::size_t(protocol::read_u32be(
                                   reinterpret_cast<const unsigned char*>(&inbuf[in_start])))
                         : 0;
        send_error(nullptr, pc::kTimeout,
                   "frame incomplete after " + std::string(text) + ": " + std::to_string(have) +
                       (announced ? " of " + std::to_string(announced) : std::string()) +
                       " bytes received (a frame must arrive within --frame-timeout plus its "
                       "bytes at --min-receive-rate); connection closed");
        return finish_and_close();
      }
    }
    const bool busy = frame_started || !inflight.empty() || !out.empty() || !writing.empty();
    if (busy) return;
    // Before hello on a token server, silence is bounded by the frame timeout too.
    double limit = o.idle_timeout_s;
    const bool waiting_for_hello = !authenticated && o.frame_timeout_s > 0;
    if (waiting_for_hello)
      limit = limit > 0 ? std::min(limit, o.frame_timeout_s) : o.frame_timeout_s;
    if (limit > 0 && since(last_active) > limit) {
      server.counters.idle_timeouts++;
      char text[64];
      std::snprintf(text, sizeof(text), "%.3g s", limit);
      send_error(nullptr, pc::kTimeout,
                 waiting_for_hello ? "no hello within " + std::string(text) +
                                         " (--frame-timeout); connection closed"
                                   : "connection idle for " + std::string(text) +
                                         " (--idle-timeout); connection closed");
      finish_and_close();
    }
  }

  void finish_job(const std::shared_ptr<Job>& job, std::string frame, bool ok,
                  const std::string& code) {
    if (job->deadline_timer) job->deadline_timer->cancel();
    const auto it = inflight.find(job->key);
    if (it != inflight.end() && it->second == job) inflight.erase(it);
    if (job->replied) return;  // already answered (cancel, deadline, shutdown) or gone
    job->replied = true;
    if (ok)
      server.counters.replies_ok++;
    else
      server.count_error(code);
    send(std::move(frame));
  }

  // Answers a job now with an error and forgets it; the worker's later result is dropped.
  void abort_job(const std::shared_ptr<Job>& job, const char* code, const std::string& message) {
    if (job->replied) return;
    if (job->deadline_timer) job->deadline_timer->cancel();
    inflight.erase(job->key);
    job->replied = true;
    send_error(job->id, code, message);
  }

  void dispatch(std::string_view body);
  OpResult builtin_cancel(const Message& m);
};

void Connection::dispatch(std::string_view body) {
  server.counters.requests++;
  const auto arrival = Clock::now();
  Message m;
  json id = nullptr;
  protocol::Request req;
  try {
    m = protocol::decode_body(body);
    id = protocol::salvage_id(m.header);
    req = protocol::parse_envelope(m.header, &id);
    protocol::check_attachment_names(m);
  } catch (const ProtocolError& e) {
    server.counters.malformed_frames++;
    send_error(id, e.code(), e.what());
    // Before hello on a token server every refusal ends the connection, as `unauthorized` does:
    // a peer without the token gets no second try on the same connection.
    if (!authenticated) finish_and_close();
    return;
  }
  {
    // Per-op counters for known ops only, so hostile op names cannot grow the map.
    const bool known = req.op == "hello" || req.op == "status" || req.op == "cancel" ||
                       server.registry.find(req.op) != nullptr;
    std::lock_guard<std::mutex> lock(server.counters.mu);
    server.counters.ops[known ? req.op : "(unknown)"]++;
  }

  if (!authenticated) {
    // The first request must be a hello carrying the shared token.
    const auto tok = m.header.find("token");
    const bool ok =
        req.op == "hello" && tok != m.header.end() && tok->is_string() &&
        protocol::constant_time_equal(tok->get_ref<const std::string&>(), *server.options.token);
    if (!ok) {
      server.counters.auth_failures++;
      send_error(id, pc::kUnauthorized,
                 req.op == "hello" ? "wrong or missing token"
                                   : "authenticate first: send hello with \"token\"");
      finish_and_close();
      return;
    }
    authenticated = true;
  }
  // While draining, status still answers (it is how a client sees "draining": true).
  if (server.draining && req.op != "status") {
    send_error(id, pc::kShuttingDown, "server is shutting down; request '" + req.op + "' refused");
    return;
  }
  if (req.deadline_ms && *req.deadline_ms <= 0) {
    server.counters.deadline_exceeded++;
    send_error(id, pc::kDeadlineExceeded, "deadline of 0 ms expired before '" + req.op + "' ran");
    return;
  }

  auto run_inline = [&](const std::function<OpResult()>& fn) {
    try {
      OpResult r = fn();
      server.counters.replies_ok++;
      const Message reply = protocol::make_reply(
          id, r.result_text.empty() ? std::move(r.result) : json(), std::move(r.attachments));
      send(protocol::encode_frame(reply, r.result_text));
    } catch (const ProtocolError& e) {
      send_error(id, e.code(), e.what());
    } catch (const std::exception& e) {
      send_error(id, pc::kFailed, req.op + ": " + e.what());
    }
  };

  // The built-in operations' fields (registered operations carry theirs in Operation::fields).
  static const std::vector<std::string> kHelloFields{"token"}, kStatusFields{},
      kCancelFields{"target"};
  const Operation* op = nullptr;
  const std::vector<std::string>* fields = nullptr;
  if (req.op == "hello") {
    fields = &kHelloFields;
  } else if (req.op == "status") {
    fields = &kStatusFields;
  } else if (req.op == "cancel") {
    fields = &kCancelFields;
  } else {
    op = server.registry.find(req.op);
    if (!op) {
      std::string known = "hello, status, cancel";
      for (const auto& n : server.registry.names()) known += ", " + n;
      const std::string shown = req.op.size() > 64 ? req.op.substr(0, 64) + "..." : req.op;
      send_error(id, pc::kUnknownOp, "unknown op '" + shown + "' (known: " + known + ")");
      return;
    }
    if (op->fields) fields = &*op->fields;
  }
  if (fields) {
    try {
      protocol::check_fields(m.header, req.op, *fields);
    } catch (const ProtocolError& e) {
      send_error(id, e.code(), e.what());
      return;
    }
  }

  if (req.op == "hello") {
    return run_inline([&] {
      OpResult r;
      r.result = {{"server", "terrastride"},
                  {"version", "0.1.0"},
                  {"protocol", protocol::kVersion},
                  {"connection", cid},
                  {"ops", json::array()},
                  {"capabilities",
                   {{"max_frame_bytes", server.options.max_frame_bytes},
                    {"attachment_dtypes", {"float32"}},
                    {"pipelining", true},
                    {"deadlines", true},
                    {"cancel", true},
                    {"workers", server.pool->workers()},
                    {"queue", server.pool->capacity()},
                    {"token_required", server.options.token.has_value()},
                    {"max_connections", server.options.max_connections},
                    {"frame_timeout_s", server.options.frame_timeout_s},
                    {"min_receive_rate", server.options.min_receive_rate},
                    {"idle_timeout_s", server.options.idle_timeout_s}}}};
      r.result["ops"] = {"hello", "status", "cancel"};
      for (const auto& n : server.registry.names()) r.result["ops"].push_back(n);
      if (server.hello_extra) r.result.update(server.hello_extra());
      return r;
    });
  }
  if (req.op == "status") {
    return run_inline([&] {
      OpResult r;
      r.result = server.status_json();
      return r;
    });
  }
  if (req.op == "cancel") return run_inline([&] { return builtin_cancel(m); });

  if (op->kind == OpKind::kInline) {
    auto token = std::make_shared<CancellationToken>();
    if (req.deadline_ms)
      token->set_deadline(
          arrival + std::chrono::microseconds(static_cast<long long>(*req.deadline_ms * 1000)));
    return run_inline([&] {
      OpContext ctx{m, token};
      return op->handler(ctx);
    });
  }

  // A worker job.
  auto job = std::make_shared<Job>();
  job->seq = server.next_job_seq++;
  job->id = id;
  job->key = id.dump();
  if (inflight.count(job->key)) {
    send_error(id, pc::kBadRequest,
               "id " + job->key + " is already in flight on this connection; ids must be unique");
    return;
  }
  if (static_cast<int>(inflight.size()) >= server.options.max_inflight_per_connection) {
    server.counters.busy++;
    send_error(id, pc::kBusy,
               "too many requests in flight on this connection (limit " +
                   std::to_string(server.options.max_inflight_per_connection) + ")");
    return;
  }
  job->op = op;
  job->request = std::move(m);
  // The attachments stay in memory until a worker runs the job: count them as buffered request
  // bytes (already received, so counted rather than refused; the next large frame sees them).
  std::size_t request_bytes = 0;
  for (const auto& a : job->request.attachments) request_bytes += a.data.size();
  job->request_bytes.add(server.budget, request_bytes);
  job->conn = weak_from_this();
  if (req.deadline_ms) {
    const auto deadline =
        arrival + std::chrono::microseconds(static_cast<long long>(*req.deadline_ms * 1000));
    job->token->set_deadline(deadline);
    job->deadline_timer = std::make_unique<asio::steady_timer>(server.io, deadline);
  }
  if (!server.pool->try_submit(job)) {
    server.counters.busy++;
    send_error(id, pc::kBusy,
               "all " + std::to_string(server.pool->workers()) + " workers busy and the queue of " +
                   std::to_string(server.pool->capacity()) + " is full; retry later");
    return;
  }
  inflight[job->key] = job;
  if (job->deadline_timer) {
    std::weak_ptr<Connection> wc = weak_from_this();
    job->deadline_timer->async_wait([wc, job](const asio::error_code& ec) {
      auto c = wc.lock();
      if (ec || !c || job->replied) return;
      job->token->cancel(CancellationToken::Reason::kDeadline);
      c->server.pool->try_remove(job);
      c->server.counters.deadline_exceeded++;
      c->abort_job(job, pc::kDeadlineExceeded,
                   std::string("deadline exceeded ") +
                       (job->running ? "while running" : "in queue") + " ('" + job->op->name +
                       "')");
    });
  }
}

OpResult Connection::builtin_cancel(const Message& m) {
  const auto t = m.header.find("target");
  if (t == m.header.end() || !(t->is_number_integer() || t->is_string()))
    throw ProtocolError(pc::kBadRequest,
                        "cancel needs \"target\": the id of the request to cancel");
  OpResult r;
  const auto it = inflight.find(t->dump());
  if (it == inflight.end()) {
    r.result = {{"target", *t}, {"cancelled", false}, {"state", "unknown"}};
    return r;
  }
  auto job = it->second;
  const bool queued = server.pool->try_remove(job);
  job->token->cancel(CancellationToken::Reason::kCancelled);
  server.counters.cancelled++;
  r.result = {{"target", *t}, {"cancelled", true}, {"state", queued ? "queued" : "running"}};
  abort_job(job, pc::kCancelled, "request cancelled by cancel (id " + job->key + ")");
  return r;
}

}  // namespace

void Server::Impl::run_job(std::shared_ptr<Job> job) {
  // Worker thread: run the handler, encode the reply here (off the I/O thread), post it back.
  asio::post(io, [job] { job->running = true; });
  bool ok = false;
  std::string code;
  std::string frame;
  try {
    OpContext ctx{job->request, job->token};
    ctx.check_stop();
    OpResult r = job->op->handler(ctx);
    frame = protocol::encode_frame(
        protocol::make_reply(job->id, r.result_text.empty() ? std::move(r.result) : json(),
                             std::move(r.attachments)),
        r.result_text);
    ok = true;
  } catch (const ProtocolError& e) {
    code = e.code();
    frame = protocol::encode_frame(protocol::make_error(job->id, code, e.what()));
  } catch (const std::exception& e) {
    code = pc::kFailed;
    frame = protocol::encode_frame(
        protocol::make_error(job->id, code, job->op->name + ": " + e.what()));
  }
  job->request = Message{};  // free the attachments now
  job->request_bytes.release();
  asio::post(io, [job, frame = std::move(frame), ok, code]() mutable {
    auto c = job->conn.lock();
    if (job->deadline_timer) job->deadline_timer->cancel();
    if (!c) return;
    c->finish_job(job, std::move(frame), ok, code);
  });
}

void Server::Impl::adopt(asio::generic::stream_protocol::socket sock, bool tcp) {
  counters.connections_total++;
  if (draining) return;
  auto c = std::make_shared<Connection>(*this, std::move(sock), next_conn_id++);
  if (active_connections >= options.max_connections) {
    counters.connections_rejected++;
    const std::string message = "connection limit of " + std::to_string(options.max_connections) +
                                " reached (--max-connections); retry later";
    if (lingering >= std::max(64, options.max_connections)) {
      // Too many closes in progress already: a best-effort reply, then close at once.
      const std::string frame =
          protocol::encode_frame(protocol::make_error(nullptr, pc::kBusy, message));
      asio::error_code ec;
      c->socket.non_blocking(true, ec);
      asio::write(c->socket, asio::buffer(frame), ec);
      c->socket.close(ec);
      return;
    }
    // Told why (`busy`, id null), then closed gracefully, so the client reads the reply instead
    // of a reset; it never counts against the limit.
    connections.insert(c);
    c->send_error(nullptr, pc::kBusy, message);
    c->finish_and_close();
    return;
  }
  active_connections++;
  counters.connections_open++;
  c->counted = true;
  connections.insert(c);
  c->start();
}

void Server::Impl::accept_tcp(asio::ip::tcp::acceptor& acc) {
  acc.async_accept([this, &acc](const asio::error_code& ec, asio::ip::tcp::socket s) {
    if (!acc.is_open() || draining) return;
    if (!ec) {
      asio::error_code ignored;
      s.set_option(asio::ip::tcp::no_delay(true), ignored);
      adopt(asio::generic::stream_protocol::socket(std::move(s)), true);
    } else if (ec == asio::error::no_descriptors || ec == asio::error::no_buffer_space) {
      // Out of file descriptors: back off briefly rather than spin.
      auto t = std::make_shared<asio::steady_timer>(io, std::chrono::milliseconds(50));
      t->async_wait([this, &acc, t](const asio::error_code&) { accept_tcp(acc); });
      return;
    }
    accept_tcp(acc);
  });
}

void Server::Impl::accept_unix(asio::local::stream_protocol::acceptor& acc) {
  acc.async_accept(
      [this, &acc](const asio::error_code& ec, asio::local::stream_protocol::socket s) {
        if (!acc.is_open() || draining) return;
        if (!ec)
          adopt(asio::generic::stream_protocol::socket(std::move(s)), false);
        else if (ec == asio::error::no_descriptors || ec == asio::error::no_buffer_space) {
          auto t = std::make_shared<asio::steady_timer>(io, std::chrono::milliseconds(50));
          t->async_wait([this, &acc, t](const asio::error_code&) { accept_unix(acc); });
          return;
        }
        accept_unix(acc);
      });
}

namespace {

// Resident memory of this process from /proc (Linux), -1 elsewhere.
long resident_bytes() {
  std::FILE* f = std::fopen("/proc/self/statm", "r");
  if (!f) return -1;
  long pages_total = 0, pages_resident = -1;
  if (std::fscanf(f, "%ld %ld", &pages_total, &pages_resident) != 2) pages_resident = -1;
  std::fclose(f);
  return pages_resident < 0 ? -1 : pages_resident * ::sysconf(_SC_PAGESIZE);
}

}  // namespace

std::size_t default_max_buffered_bytes() {
  const std::size_t gib = std::size_t{1} << 30;
  const long pages = ::sysconf(_SC_PHYS_PAGES), page = ::sysconf(_SC_PAGESIZE);
  if (pages <= 0 || page <= 0) return gib;
  return std::min(gib, static_cast<std::size_t>(pages) * static_cast<std::size_t>(page) / 4);
}

json Server::Impl::status_json() {
  json errors = json::object();
  json ops = json::object();
  {
    std::lock_guard<std::mutex> lock(counters.mu);
    for (const auto& [k, v] : counters.errors_by_code) errors[k] = v;
    for (const auto& [k, v] : counters.ops) ops[k] = v;
  }
  json s = {{"uptime_s", std::chrono::duration<double>(Clock::now() - started).count()},
            {"draining", draining.load()},
            {"listen", bound},
            {"connections",
             {{"open", counters.connections_open.load()},
              {"total", counters.connections_total.load()},
              {"rejected", counters.connections_rejected.load()},
              {"slow_client_drops", counters.slow_client_drops.load()},
              {"disconnects_mid_request", counters.disconnects_mid_request.load()},
              {"frame_timeouts", counters.frame_timeouts.load()},
              {"idle_timeouts", counters.idle_timeouts.load()},
              {"write_timeouts", counters.write_timeouts.load()}}},
            {"requests",
             {{"total", counters.requests.load()},
              {"ok", counters.replies_ok.load()},
              {"errors", counters.replies_error.load()},
              {"malformed_frames", counters.malformed_frames.load()},
              {"busy", counters.busy.load()},
              {"cancelled", counters.cancelled.load()},
              {"deadline_exceeded", counters.deadline_exceeded.load()},
              {"auth_failures", counters.auth_failures.load()},
              {"errors_by_code", errors},
              {"by_op", ops}}},
            {"bytes", {{"in", counters.bytes_in.load()}, {"out", counters.bytes_out.load()}}},
            {"queue",
             {{"length", pool ? pool->queued() : std::size_t{0}},
              {"capacity", pool ? pool->capacity() : std::size_t{0}},
              {"running", pool ? pool->running() : std::size_t{0}},
              {"workers", pool ? pool->workers() : std::size_t{0}}}},
            {"memory",
             {{"buffered_request_bytes", budget->used.load()},
              {"max_buffered_bytes", budget->limit},
              {"refused_frames", budget->refused.load()}}}};
  if (const long rss = resident_bytes(); rss >= 0) s["memory"]["rss_bytes"] = rss;
  if (status_extra) s.update(status_extra());
  return s;
}

double Server::Impl::sweep_period_s() const {
  // A quarter of the shortest limit, so a limit is enforced within 25 % of its value.
  double shortest = Connection::kLingerSeconds;
  if (options.frame_timeout_s > 0) shortest = std::min(shortest, options.frame_timeout_s);
  if (options.idle_timeout_s > 0) shortest = std::min(shortest, options.idle_timeout_s);
  return std::clamp(shortest / 4, 0.005, 1.0);
}

void Server::Impl::sweep() {
  const auto now = Clock::now();
  const auto conns = connections;  // check_timeouts may close (erase) connections
  for (const auto& c : conns) c->check_timeouts(now);
  sweep_timer->expires_after(
      std::chrono::microseconds(static_cast<long long>(sweep_period_s() * 1e6)));
  sweep_timer->async_wait([this](const asio::error_code& ec) {
    if (!ec) sweep();
  });
}

void Server::Impl::begin_shutdown() {
  if (draining) return;
  draining = true;
  drain_started = Clock::now();
  asio::error_code ec;
  for (auto& a : tcp_acceptors) a.close(ec);
  for (auto& a : unix_acceptors) a.close(ec);
  for (const auto& p : unix_paths) ::unlink(p.c_str());
  if (signals) signals->cancel(ec);
  // Jobs that have not started are answered now; running ones get drain_seconds to finish.
  for (auto& job : pool->take_all_queued()) {
    job->token->cancel(CancellationToken::Reason::kShutdown);
    if (auto c = job->conn.lock())
      c->abort_job(job, pc::kShuttingDown, "server shutting down; queued request not started");
  }
  drain_timer = std::make_unique<asio::steady_timer>(io);
  drain_tick();
}

void Server::Impl::drain_tick() {
  const double waited = std::chrono::duration<double>(Clock::now() - drain_started).count();
  std::size_t pending_jobs = 0, pending_bytes = 0;
  for (const auto& c : connections) {
    pending_jobs += c->inflight.size();
    pending_bytes += c->out.size() + c->writing.size();
  }
  if (pending_jobs > 0 && waited >= options.drain_seconds && !drain_cancelled) {
    drain_cancelled = true;
    auto conns = connections;  // abort_job may not erase connections, but copy to be safe
    for (const auto& c : conns) {
      auto jobs = c->inflight;
      for (auto& [k, job] : jobs) {
        job->token->cancel(CancellationToken::Reason::kShutdown);
        c->abort_job(job, pc::kShuttingDown,
                     "server shutting down; running request cancelled after the drain period");
      }
    }
  }
  // Done when every job is answered and every reply written (bounded by 2 s after the drain).
  if ((pending_jobs == 0 && pending_bytes == 0) || waited > options.drain_seconds + 2.0) {
    auto conns = connections;
    for (const auto& c : conns) c->close();
    io.stop();
    return;
  }
  drain_timer->expires_after(std::chrono::milliseconds(10));
  drain_timer->async_wait([this](const asio::error_code& ec) {
    if (!ec) drain_tick();
  });
}

Server::Server(ServerOptions options, OperationRegistry operations,
               std::function<json()> status_extra, std::function<json()> hello_extra)
    : impl_(std::make_unique<Impl>()) {
  impl_->options = std::move(options);
  impl_->registry = std::move(operations);
  impl_->status_extra = std::move(status_extra);
  impl_->hello_extra = std::move(hello_extra);
  impl_->budget = std::make_shared<ByteBudget>(impl_->options.max_buffered_bytes);
  Impl* impl = impl_.get();
  impl_->pool = std::make_unique<WorkerPool>(impl_->options.workers, impl_->options.queue,
                                             [impl](std::shared_ptr<Job> j) { impl->run_job(j); });
}

Server::~Server() {
  impl_->pool->stop();
  for (const auto& p : impl_->unix_paths) ::unlink(p.c_str());
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

std::vector<std::string> Server::bind() {
  auto& im = *impl_;
  if (im.options.listen.empty()) throw std::runtime_error("no listen address given");
  for (const auto& text : im.options.listen) {
    ListenAddress a;
    try {
      a = parse_listen_address(text);
    } catch (const std::invalid_argument& e) {
      throw std::runtime_error(e.what());
    }
    if (a.kind == ListenAddress::Kind::kTcp) {
      const auto addr = asio::ip::make_address(a.host);
      if (!addr.is_loopback() && !im.options.token)
        throw std::runtime_error("listen address '" + text +
                                 "' is not loopback: --token-file is required to serve on it");
      asio::ip::tcp::acceptor acc(im.io);
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
      im.bound.push_back("tcp://" + host + ":" + std::to_string(local.port()));
      im.tcp_acceptors.push_back(std::move(acc));
    } else {
      prepare_unix_path(a.path);
      asio::local::stream_protocol::acceptor acc(im.io);
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
      im.unix_paths.push_back(a.path);
      im.bound.push_back("unix:" + a.path);
      im.unix_acceptors.push_back(std::move(acc));
    }
  }
  return im.bound;
}

void Server::run() {
  auto& im = *impl_;
  for (auto& a : im.tcp_acceptors) im.accept_tcp(a);
  for (auto& a : im.unix_acceptors) im.accept_unix(a);
  if (im.options.handle_signals) {
    im.signals = std::make_unique<asio::signal_set>(im.io, SIGINT, SIGTERM);
    im.signals->async_wait([&im](const asio::error_code& ec, int) {
      if (!ec) im.begin_shutdown();
    });
  }
  im.sweep_timer = std::make_unique<asio::steady_timer>(im.io);
  im.sweep();
  if (im.stopped) im.begin_shutdown();
  im.io.run();
  im.pool->stop();
}

void Server::shutdown() {
  impl_->stopped = true;
  Impl* im = impl_.get();
  asio::post(im->io, [im] { im->begin_shutdown(); });
}

json Server::status() const {
  return impl_->status_json();
}

}  // namespace terrastride::service
