// The socket server: Asio acceptors and connections on one I/O thread, long operations on a
// bounded worker pool. All connection state is touched only on the I/O thread; workers hand their
// encoded replies back through asio::post. The parts: listen addresses (listen.hpp), connections
// (connection.hpp), the worker pool (worker_pool.hpp), request memory (request_memory.hpp); this
// file holds the server's life cycle (bind, accept, run, drain), its jobs and its status.
#include "terrastride/service/server.hpp"

#include <malloc.h>
#include <unistd.h>

#include <algorithm>
#include <asio.hpp>
#include <chrono>
#include <cstdio>

#include "connection.hpp"
#include "server_impl.hpp"
#include "thread_priority.hpp"

namespace terrastride::service {

namespace pc = protocol::code;
using nlohmann::json;
using protocol::Message;
using protocol::ProtocolError;

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

void Server::Impl::run_job(std::shared_ptr<Job> job) {
  // Worker thread: run the handler, encode the reply here (off the I/O thread), post it back.
  asio::post(io, [job] { job->running = true; });
  // A worker left at a raised priority by an operation that keeps it (Operation::keeps_priority)
  // returns to the normal policy before any other operation.
  if (!job->op->keeps_priority) return_to_normal_policy();
  bool ok = false;
  std::string code;
  std::string frame;
  try {
    OpContext ctx{job->request, job->token, job->connection};
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
  job->connection_bytes.release();
  pool->finished();
  asio::post(io, [this, job, frame = std::move(frame), ok, code]() mutable {
    heap_used = true;
    last_job_end = Clock::now();
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
    // Full: the connection idle longest makes room, so connections that only keep themselves
    // alive (a status every few minutes) cannot keep new clients out.
    if (const auto victim = longest_idle_connection()) {
      victim->evict(std::chrono::duration<double>(Clock::now() - victim->last_active).count());
    }
  }
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

std::shared_ptr<Connection> Server::Impl::longest_idle_connection() const {
  std::shared_ptr<Connection> victim;
  for (const auto& c : connections) {
    if (!c->counted || c->closed || c->close_after_flush || !c->idle()) continue;
    if (!victim || c->last_active < victim->last_active) victim = c;
  }
  return victim;
}

void Server::Impl::enforce_unsent_budget() {
  const auto now = Clock::now();
  while (unsent_bytes > options.max_unsent_bytes) {
    // A client stalled in taking its replies (more than kStalledSeconds behind
    // --min-receive-rate: one that does not read at all falls behind by the second) goes before
    // one that reads; among them, the one holding the most unsent bytes. Milliseconds behind
    // mean nothing (a small reply whose write just began), so a reader with a status reply in
    // flight is never dropped for a silent client's 12 MB.
    constexpr double kStalledSeconds = 1.0;
    std::shared_ptr<Connection> victim;
    double victim_behind = 0.0;
    auto ranks_above = [&](const Connection& c, double behind) {
      const bool stalled = behind > kStalledSeconds;
      if (stalled != (victim_behind > kStalledSeconds)) return stalled;
      return c.out_bytes > victim->out_bytes ||
             (c.out_bytes == victim->out_bytes && behind > victim_behind);
    };
    for (const auto& c : connections) {
      if (c->closed || c->out_bytes == 0) continue;
      const double behind = c->seconds_behind(now);
      if (!victim || ranks_above(*c, behind)) victim = c, victim_behind = behind;
    }
    if (!victim) return;
    counters.unsent_drops++;
    char text[64];
    std::snprintf(text, sizeof(text), "%.3g s", victim_behind);
    victim->drop_unread(std::to_string(victim->out_bytes) +
                        " bytes of replies unsent, the most of any client (stalled clients "
                        "first; it is " + text + " behind --min-receive-rate), while all "
                        "connections' unsent replies (" + std::to_string(unsent_bytes) +
                        " bytes) exceed " +
                        std::to_string(options.max_unsent_bytes) + " (--max-unsent-bytes)");
  }
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

// What the allocator holds (glibc's mallinfo2 over every arena): in use by the server (heap
// blocks and their own mappings), and freed but kept. Resident memory alone cannot tell a leak
// from what glibc keeps at the top of a worker thread's arena, which malloc_trim does not return
// (up to twice the largest block that thread freed).
struct HeapBytes {
  std::size_t in_use = 0, free_kept = 0;
};
HeapBytes heap_bytes() {
  const struct mallinfo2 mi = ::mallinfo2();
  return {mi.uordblks + mi.hblkhd, mi.fordblks};
}

}  // namespace

std::size_t default_max_buffered_bytes() {
  const std::size_t cap = std::size_t{512} << 20;
  const long pages = ::sysconf(_SC_PHYS_PAGES), page = ::sysconf(_SC_PAGESIZE);
  if (pages <= 0 || page <= 0) return cap;
  return std::min(cap, static_cast<std::size_t>(pages) * static_cast<std::size_t>(page) / 4);
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
            {"realtime_io", realtime_io.load()},
            {"listen", listeners.bound},
            {"connections",
             {{"open", counters.connections_open.load()},
              {"total", counters.connections_total.load()},
              {"rejected", counters.connections_rejected.load()},
              {"slow_client_drops", counters.slow_client_drops.load()},
              {"disconnects_mid_request", counters.disconnects_mid_request.load()},
              {"frame_timeouts", counters.frame_timeouts.load()},
              {"idle_timeouts", counters.idle_timeouts.load()},
              {"write_timeouts", counters.write_timeouts.load()},
              {"evicted", counters.evicted_connections.load()},
              {"unsent_drops", counters.unsent_drops.load()}}},
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
              {"max_buffered_bytes_per_connection", options.max_buffered_bytes_per_connection},
              {"refused_frames", budget->refused.load()},
              {"unsent_reply_bytes", unsent_bytes},
              {"max_unsent_bytes", options.max_unsent_bytes},
              {"max_unsent_bytes_per_connection", options.max_write_queue_bytes},
              // Whether the heap's free pages went back to the system since the last work.
              {"free_heap_returned", !heap_used && !trim_pending},
              {"heap_trims", heap_trims}}}};
  if (const long rss = resident_bytes(); rss >= 0) s["memory"]["rss_bytes"] = rss;
  const HeapBytes heap = heap_bytes();
  s["memory"]["heap_in_use_bytes"] = heap.in_use;
  s["memory"]["heap_free_kept_bytes"] = heap.free_kept;
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
  if (unsent_bytes == 0) {
    const bool rested = heap_used && pool && pool->running() == 0 && pool->queued() == 0 &&
                        now - last_job_end >= std::chrono::duration<double>(kIdleTrimSeconds);
    if (trim_pending || rested) trim_heap();
  }
  sweep_timer->expires_after(
      std::chrono::microseconds(static_cast<long long>(sweep_period_s() * 1e6)));
  sweep_timer->async_wait([this](const asio::error_code& ec) {
    if (!ec) sweep();
  });
}

void Server::Impl::trim_heap() {
  trim_pending = heap_used = false;
  heap_trims++;
  ::malloc_trim(0);
}

void Server::Impl::begin_shutdown() {
  if (draining) return;
  draining = true;
  drain_started = Clock::now();
  asio::error_code ec;
  for (auto& a : listeners.tcp) a.close(ec);
  for (auto& a : listeners.unix_sockets) a.close(ec);
  for (const auto& p : listeners.unix_paths) ::unlink(p.c_str());
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
  for (const auto& p : impl_->listeners.unix_paths) ::unlink(p.c_str());
}

std::size_t hello_frame_bytes(const std::string& token) {
  const json hello = {{"v", 1}, {"id", std::string(20, '9')}, {"op", "hello"}, {"token", token}};
  return protocol::encode_frame(Message{hello, {}}).size() - protocol::kPrefixBytes;
}

std::vector<std::string> Server::bind() {
  auto& im = *impl_;
  if (im.options.listen.empty()) throw std::runtime_error("no listen address given");
  if (im.options.token) {
    // A token whose hello the server would refuse as too large: nobody could authenticate.
    const std::size_t hello = hello_frame_bytes(*im.options.token);
    const std::size_t cap =
        std::min(im.options.max_frame_bytes, im.options.max_frame_bytes_before_hello);
    if (hello > cap)
      throw std::runtime_error("the token's hello frame is " + std::to_string(hello) +
                               " bytes, more than the " + std::to_string(cap) +
                               " a token server accepts before hello "
                               "(--max-frame-bytes-before-hello); use a shorter token");
  }
  for (const auto& text : im.options.listen)
    listen_on(im.io, text, im.options.token.has_value(), &im.listeners);
  return im.listeners.bound;
}

void Server::run() {
  auto& im = *impl_;
  for (auto& a : im.listeners.tcp) im.accept_tcp(a);
  for (auto& a : im.listeners.unix_sockets) im.accept_unix(a);
  if (im.options.handle_signals) {
    im.signals = std::make_unique<asio::signal_set>(im.io, SIGINT, SIGTERM);
    im.signals->async_wait([&im](const asio::error_code& ec, int) {
      if (!ec) im.begin_shutdown();
    });
  }
  im.sweep_timer = std::make_unique<asio::steady_timer>(im.io);
  im.sweep();
  if (im.stopped) im.begin_shutdown();
  if (im.options.realtime_io) {
    im.realtime_io = raise_to_realtime();
    if (!im.realtime_io)
      std::fprintf(stderr,
                   "terrastride serve: --realtime-io: this process may not use SCHED_FIFO (it "
                   "needs CAP_SYS_NICE or an rtprio limit); the I/O thread runs at the normal "
                   "policy\n");
  }
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
