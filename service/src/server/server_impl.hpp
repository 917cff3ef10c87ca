// The server's state (Server::Impl): options, operations, listeners, the worker pool, the open
// connections, the counters `status` reports, and the drain on shutdown. Touched only on the I/O
// thread, except the atomics and what the worker pool locks.
#pragma once

#include <asio.hpp>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <set>
#include <string>

#include "listen.hpp"
#include "request_memory.hpp"
#include "terrastride/service/server.hpp"
#include "worker_pool.hpp"

namespace terrastride::service {

struct Connection;  // connection.hpp
struct Job;

struct Counters {
  std::atomic<std::uint64_t> connections_total{0}, connections_open{0}, connections_rejected{0},
      requests{0}, replies_ok{0}, replies_error{0}, malformed_frames{0}, busy{0}, bytes_in{0},
      bytes_out{0}, slow_client_drops{0}, disconnects_mid_request{0}, cancelled{0},
      deadline_exceeded{0}, auth_failures{0}, frame_timeouts{0}, idle_timeouts{0},
      write_timeouts{0}, evicted_connections{0}, unsent_drops{0};
  std::mutex mu;
  std::map<std::string, std::uint64_t> errors_by_code;
  std::map<std::string, std::uint64_t> ops;
};

using Clock = std::chrono::steady_clock;

struct Server::Impl {
  ServerOptions options;
  OperationRegistry registry;
  std::function<nlohmann::json()> status_extra, hello_extra;
  asio::io_context io;
  Listeners listeners;
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
  std::atomic<bool> realtime_io{false};  // the I/O thread runs at SCHED_FIFO (ServerOptions::realtime_io)
  std::shared_ptr<ByteBudget> budget;
  // Connections counted against max_connections (not the ones closing or refused).
  int active_connections = 0;
  // Connections that sent their last reply and wait briefly for the peer's end (see linger()).
  int lingering = 0;
  std::unique_ptr<asio::steady_timer> sweep_timer;
  // Unsent reply bytes across all connections (ServerOptions::max_unsent_bytes).
  std::size_t unsent_bytes = 0;
  // Large replies were freed since the last sweep: the sweep hands the freed heap back to the
  // system once nothing is unsent (glibc keeps freed blocks of a few MiB in its heap, so the
  // memory a burst of large replies took would otherwise stay resident).
  bool trim_pending = false;
  // A job ended since the heap was last trimmed, and when the last one did: once the server has
  // been idle for kIdleTrimSeconds, the sweep returns the heap's free pages (a burst of solves or
  // replies otherwise stays resident in glibc's arenas until the next burst). Not while work is
  // steady: a session's steps reuse their pages.
  static constexpr double kIdleTrimSeconds = 1.0;
  bool heap_used = false;
  Clock::time_point last_job_end = Clock::now();
  std::uint64_t heap_trims = 0;
  void trim_heap();
  // When the server holds max_connections: the connection idle longest (nothing in flight), to
  // close for a new one; null when every connection is busy.
  std::shared_ptr<Connection> longest_idle_connection() const;
  // After a send pushed unsent_bytes over max_unsent_bytes: drops the connections holding the
  // most until it fits again.
  void enforce_unsent_budget();

  void accept_tcp(asio::ip::tcp::acceptor& acc);
  void accept_unix(asio::local::stream_protocol::acceptor& acc);
  void adopt(asio::generic::stream_protocol::socket sock, bool tcp);
  void run_job(std::shared_ptr<Job> job);  // worker thread
  void begin_shutdown();
  void drain_tick();
  void sweep();  // timeouts: slow frames, stalled writes, idle connections, lingering closes
  double sweep_period_s() const;
  nlohmann::json status_json();
  void count_error(const std::string& code) {
    counters.replies_error++;
    std::lock_guard<std::mutex> lock(counters.mu);
    counters.errors_by_code[code]++;
  }
};

}  // namespace terrastride::service
