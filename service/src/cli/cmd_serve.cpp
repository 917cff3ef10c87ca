// `terrastride serve`: the socket service (docs/protocol.md).
#include <algorithm>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <limits>
#include <memory>
#include <sstream>

#include "terrastride/robot/robot_model.hpp"
#include "terrastride/service/cli.hpp"
#include "terrastride/service/server.hpp"

namespace terrastride::service {
namespace {

struct ServeOptions {
  std::vector<std::string> listen;
  std::string token_file;
  std::uint32_t max_frame_bytes = protocol::kDefaultMaxFrameBytes;
  int workers = 2;
  int queue = 8;
  int max_connections = 512;
  double drain_seconds = 5.0;
  bool realtime_io = false;
  double frame_timeout_s = 10.0;
  double min_receive_rate = 128.0 * 1024;
  double idle_timeout_s = 300.0;
  std::uint32_t max_frame_bytes_before_hello = 64u << 10;
  std::size_t max_buffered_bytes = default_max_buffered_bytes();
  // Quotas and budgets (docs/protocol.md, "Limits"); defaults as ServerOptions/BackendOptions.
  ServerOptions quotas;
  BackendOptions sessions;
  std::string robot = "hyq";
  bool debug_ops = false;
  std::vector<std::string> terrain_roots;
  double plan_memory_mb = 4096;
  bool plans_in_process = false;
};

std::string read_token(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw CommandError("--token-file: cannot read '" + path + "'");
  std::stringstream ss;
  ss << in.rdbuf();
  std::string token = ss.str();
  // Surrounding whitespace (an editor's newline, indentation) is not part of the secret, and must
  // not count toward its length.
  auto space = [](char c) { return std::isspace(static_cast<unsigned char>(c)) != 0; };
  while (!token.empty() && space(token.back())) token.pop_back();
  std::size_t lead = 0;
  while (lead < token.size() && space(token[lead])) ++lead;
  token.erase(0, lead);
  if (token.empty()) throw CommandError("--token-file: '" + path + "' is empty");
  if (token.size() < 16)
    throw CommandError("--token-file: the token in '" + path +
                       "' is shorter than 16 characters; use a long random secret");
  return token;
}

// A token whose hello the server would refuse before hello: nobody could authenticate.
void check_token_fits(const std::string& token, const std::string& path,
                      std::uint32_t max_frame_bytes, std::uint32_t max_before_hello) {
  const std::size_t hello = hello_frame_bytes(token);
  const std::size_t cap = std::min(max_frame_bytes, max_before_hello);
  if (hello > cap)
    throw CommandError("--token-file: the token in '" + path + "' (" +
                       std::to_string(token.size()) + " characters) makes a hello frame of " +
                       std::to_string(hello) + " bytes, more than the " + std::to_string(cap) +
                       " accepted before hello (--max-frame-bytes-before-hello); use a shorter "
                       "token or raise the cap");
}

// Starts the server with the parsed options and serves until SIGINT/SIGTERM.
void serve(const ServeOptions& o) {
  ServerOptions so;
  so.listen = o.listen.empty() ? std::vector<std::string>{"tcp://127.0.0.1:7700"} : o.listen;
  if (!o.token_file.empty()) {
    so.token = read_token(o.token_file);
    check_token_fits(*so.token, o.token_file, o.max_frame_bytes,
                     o.max_frame_bytes_before_hello);
  }
  so.max_frame_bytes = o.max_frame_bytes;
  so.workers = o.workers;
  so.queue = o.queue;
  so.max_connections = o.max_connections;
  so.drain_seconds = o.drain_seconds;
  so.realtime_io = o.realtime_io;
  so.frame_timeout_s = o.frame_timeout_s;
  so.min_receive_rate = o.min_receive_rate;
  so.idle_timeout_s = o.idle_timeout_s;
  so.max_frame_bytes_before_hello = o.max_frame_bytes_before_hello;
  so.max_buffered_bytes = o.max_buffered_bytes;
  so.max_jobs_per_connection = o.quotas.max_jobs_per_connection;
  so.max_buffered_bytes_per_connection = o.quotas.max_buffered_bytes_per_connection;
  so.max_unsent_bytes = o.quotas.max_unsent_bytes;
  so.max_write_queue_bytes = o.quotas.max_write_queue_bytes;
  OperationRegistry registry;
  std::shared_ptr<Backend> backend;
  try {
    BackendOptions bo = o.sessions;
    bo.robot = o.robot;
    bo.debug_ops = o.debug_ops;
    bo.terrain_roots = o.terrain_roots;
    bo.plan_memory_bytes = static_cast<std::size_t>(o.plan_memory_mb * 1048576.0);
    bo.plan_in_child_process = !o.plans_in_process;
    backend = make_backend(bo, registry);
  } catch (const robot::RobotFileError& e) {
    throw CommandError(std::string("--robot: ") + e.what());
  }
  Server server(
      so, std::move(registry), [backend] { return backend_status(*backend); },
      [backend] { return backend_hello(*backend); });
  std::vector<std::string> bound;
  try {
    bound = server.bind();
  } catch (const std::runtime_error& e) {
    throw CommandError(e.what());
  }
  for (const auto& b : bound) std::cout << "listening " << b << "\n";
  std::cout.flush();
  server.run();
  std::cerr << "terrastride serve: stopped\n";
}

void add_quota_options(CLI::App* cmd, ServeOptions* o) {
  ServerOptions& q = o->quotas;
  cmd->add_option("--max-jobs-per-connection", q.max_jobs_per_connection,
                  "Worker requests one connection may have queued or running; beyond: busy")
      ->capture_default_str()
      ->check(CLI::Range(1, 100000));
  cmd->add_option("--max-buffered-bytes-per-connection", q.max_buffered_bytes_per_connection,
                  "Request bytes one connection may hold (its large frame arriving, its queued "
                  "and running requests); a frame beyond gets busy and its connection is closed")
      ->capture_default_str()
      ->check(CLI::Range(std::size_t{1} << 16, std::numeric_limits<std::size_t>::max()));
  cmd->add_option("--max-unsent-bytes", q.max_unsent_bytes,
                  "Unsent replies across all connections; beyond, the connection furthest "
                  "behind in taking its replies is dropped (logged on stderr)")
      ->capture_default_str()
      ->check(CLI::Range(std::size_t{1} << 20, std::numeric_limits<std::size_t>::max()));
  cmd->add_option("--max-unsent-bytes-per-connection", q.max_write_queue_bytes,
                  "Unsent replies of one connection; beyond, it is dropped (logged on stderr)")
      ->capture_default_str()
      ->check(CLI::Range(std::size_t{1} << 20, std::numeric_limits<std::size_t>::max()));
  BackendOptions& b = o->sessions;
  cmd->add_option("--max-sessions", b.max_sessions,
                  "Planning sessions at once; when full, opening one closes the longest idle")
      ->capture_default_str()
      ->check(CLI::Range(1, 100000));
  cmd->add_option("--max-sessions-per-connection", b.max_sessions_per_connection,
                  "Planning sessions one connection may hold; beyond: busy")
      ->capture_default_str()
      ->check(CLI::Range(1, 100000));
  cmd->add_option("--session-idle-timeout", b.session_idle_timeout_s,
                  "Seconds a planning session lives without a step. 0 = off")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 1e7));
}

}  // namespace

void add_serve_command(CLI::App& app) {
  auto o = std::make_shared<ServeOptions>();
  CLI::App* cmd = app.add_subcommand(
      "serve",
      "Run the socket service: terrain map updates and queries, plans and checks "
      "(protocol: docs/protocol.md)");
  cmd->add_option("--listen", o->listen,
                  "tcp://HOST:PORT or unix:PATH, repeatable; port 0 picks a free port. Default "
                  "tcp://127.0.0.1:7700");
  cmd->add_option("--token-file", o->token_file,
                  "File holding a shared secret every client must present in hello; required for "
                  "non-loopback addresses");
  cmd->add_option("--max-frame-bytes", o->max_frame_bytes, "Largest accepted frame")
      ->capture_default_str()
      ->check(CLI::Range(64u, 0xffffffffu));
  cmd->add_flag("--realtime-io", o->realtime_io,
                "Run the I/O thread (requests, replies, map.query) at SCHED_FIFO priority 1 where "
                "permitted, so a planning-session step's reply leaves when due on a busy computer "
                "(budgeted steps raise their worker likewise); status.realtime_io says whether it "
                "took effect");
  cmd->add_option("--workers", o->workers, "Threads for plans, checks and map updates")
      ->capture_default_str()
      ->check(CLI::Range(1, 64));
  cmd->add_option("--queue", o->queue, "Jobs that may wait for a worker before replies are busy")
      ->capture_default_str()
      ->check(CLI::Range(0, 100000));
  cmd->add_option("--max-connections", o->max_connections, "Concurrent connections")
      ->capture_default_str()
      ->check(CLI::Range(1, 100000));
  cmd->add_option("--drain-seconds", o->drain_seconds,
                  "On SIGINT/SIGTERM: time running jobs get to finish before they are cancelled")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 3600.0));
  cmd->add_option("--frame-timeout", o->frame_timeout_s,
                  "Seconds a started frame may take, plus its received bytes at "
                  "--min-receive-rate; also the time a token server waits for hello, and for a "
                  "client to take its replies. 0 = off")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 86400.0));
  cmd->add_option("--min-receive-rate", o->min_receive_rate,
                  "Bytes per second a large frame (or reply) must move at to keep extending "
                  "--frame-timeout")
      ->capture_default_str()
      ->check(CLI::Range(1.0, 1e12));
  cmd->add_option("--idle-timeout", o->idle_timeout_s,
                  "Seconds a connection with nothing in flight stays open. 0 = off")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 1e7));
  cmd->add_option("--max-frame-bytes-before-hello", o->max_frame_bytes_before_hello,
                  "Largest frame accepted before hello on a token server")
      ->capture_default_str()
      ->check(CLI::Range(64u, 0xffffffffu));
  cmd->add_option("--max-buffered-bytes", o->max_buffered_bytes,
                  "Request bytes the server buffers across all connections (large frames "
                  "arriving, queued worker requests); a frame beyond it gets busy and its "
                  "connection is closed. Default: 512 MiB or a quarter of the memory if less")
      ->capture_default_str()
      ->check(CLI::Range(std::size_t{1} << 16, std::numeric_limits<std::size_t>::max()));
  add_quota_options(cmd, o.get());
  cmd->add_option("--robot", o->robot, "Robot name or file")->capture_default_str();
  cmd->add_flag("--debug-ops", o->debug_ops, "Enable test operations (debug.sleep)");
  cmd->add_option("--terrain-root", o->terrain_roots,
                  "Folder whose terrain directories (terrastride map outputs) clients may name in "
                  "map.update's terrain_dir and plan's terrain, repeatable; without it the server "
                  "opens no path a client names")
      ->check(CLI::ExistingDirectory);
  cmd->add_option("--plan-memory-mb", o->plan_memory_mb,
                  "Memory a plan process may use beyond the server's, MiB (0 = unlimited)")
      ->capture_default_str()
      ->check([](const std::string& text) -> std::string {
        // Below 256 MiB a plan cannot even map OpenBLAS's buffer (128 MiB), and OpenBLAS retries
        // a failed allocation forever instead of failing.
        const double mb = std::atof(text.c_str());
        return mb == 0.0 || (mb >= 256.0 && mb <= 1048576.0)
                   ? ""
                   : "must be 0 (unlimited) or within [256, 1048576] MiB";
      });
  cmd->add_flag("--plans-in-process", o->plans_in_process,
                "Solve plans in the worker threads, one at a time (default: each plan in its own "
                "child process, so plans run at once)");
  cmd->callback([o] { serve(*o); });
}

}  // namespace terrastride::service
