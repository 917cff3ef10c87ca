// bench_service (build/tests/bench/bench_service): load tool for the socket service, a tool of its
// own beside the benchmarks rather than a command of the product binary. Measures map.query throughput and
// latency with many concurrent clients, the overhead a worker operation (plan) adds beyond its own
// compute time, and, in hostile mode, what attacks on the transport do (malformed frames, abrupt
// disconnects, slowloris, half-sent frames, idle sockets at the connection limit, oversized
// length claims, the request-byte budget, deadline overflow, duplicate attachments, unknown
// fields) to the server's memory and to well-behaved clients querying meanwhile.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstring>
#include <fstream>
#include <functional>
#include <iomanip>
#include <iostream>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <random>
#include <thread>

#include <pthread.h>
#include <sched.h>
#include <time.h>

#include "blas_kernel.hpp"
#include "terrastride/service/cli.hpp"
#include "terrastride/service/client.hpp"
#include "terrastride/service/server.hpp"

namespace terrastride::service {
namespace {

using nlohmann::json;
using Clock = std::chrono::steady_clock;

struct BenchOptions {
  std::string connect;
  std::string token;
  std::string mode = "all";
  int clients = 50;
  int requests = 200;
  int points = 100;
  int plans = 5;
  int malformed = 10000;
  int disconnects = 1000;
  int workers = 2;
  std::string scene = "pallet_10";
  bool json = false;
  bool json_points = false;
  double rate = 0;  // requests per second per client; 0 = back to back (saturation)
  // Replan mode: a planning session on pallet_15 with every constraint set.
  int replan_steps = 50;
  double replan_budget_ms = 50.0;  // plan.session.step "budget_ms"
  // Steps are sent this far apart in wall time (s), as a control loop at 10 Hz sends them (the
  // session's time advances 0.1 s per step); 0: each as soon as the previous reply arrived.
  double replan_period = 0.1;
  double horizon = 1.0;
  std::string replan_scene = "pallet_15";
  std::string replan_constraints = "all";
  // A step reply's samples: "attachment" (the float32 table a client stepping at 10-20 Hz uses:
  // 130-220 KB of JSON samples per reply cost 20-30 ms of a loaded machine outside the step) or
  // "json".
  std::string replan_samples = "attachment";
  // The client's thread and the in-process server's I/O thread at a real-time priority, as a
  // robot's control loop and a deployed server's I/O thread would run (the step's own thread is
  // raised by the server's session op): what is then left of the round trip is the machine's.
  bool realtime_loop = false;
  // Hostile mode.
  int slowloris = 32;      // connections per slow-frame case
  double max_wait_s = 15;  // longest wait for the server to close a hostile connection
  int server_pid = 0;      // for the RSS of a server given with --connect
  // The in-process server's limits (hostile mode), short so the cases finish in seconds.
  double server_frame_timeout_s = 2;
  double server_idle_timeout_s = 3;
  double server_min_receive_rate = 1 << 20;
  int server_max_connections = 128;
  std::size_t server_max_buffered_bytes = std::size_t{256} << 20;
  // Replan mode, in-process server: a session's idle timeout (under valgrind the cold solve
  // outlasts the server's default 300 s, and the session was gone before its first step).
  double server_session_idle_timeout_s = 300;
};

// CPU time of this whole process (all threads), in ms: with the in-process server, a step's CPU
// is the server's work on it (the client thread only waits for the reply and parses it).
double process_cpu_ms() {
  timespec ts{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return 1e3 * static_cast<double>(ts.tv_sec) + 1e-6 * static_cast<double>(ts.tv_nsec);
}

double ms_since(Clock::time_point t) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t).count();
}

json latency_json(std::vector<double> v) {
  if (v.empty()) return json::object();
  std::sort(v.begin(), v.end());
  auto q = [&](double p) {
    const std::size_t i =
        std::min(v.size() - 1, static_cast<std::size_t>(p * (v.size() - 1) + 0.5));
    return v[i];
  };
  double sum = 0;
  for (double x : v) sum += x;
  return {{"count", v.size()}, {"mean_ms", sum / v.size()}, {"p50_ms", q(0.50)},
          {"p90_ms", q(0.90)}, {"p99_ms", q(0.99)},         {"max_ms", v.back()}};
}

Client connect(const BenchOptions& o) {
  Client c = Client::connect(o.connect);
  if (!o.token.empty()) c.call_ok({{"op", "hello"}, {"token", o.token}});
  return c;
}

// Well-behaved query clients; every reply is checked against the expected point count and ids.
struct QueryRun {
  std::vector<double> latencies_ms;
  double wall_s = 0;
  std::uint64_t failures = 0;
};

QueryRun run_queries(const BenchOptions& o, int clients, int requests, const json& extent,
                     const std::atomic<bool>* keep_going = nullptr) {
  QueryRun run;
  std::mutex mu;
  std::atomic<std::uint64_t> failures{0};
  std::vector<std::thread> threads;
  const double x0 = extent[0][0], y0 = extent[0][1], x1 = extent[1][0], y1 = extent[1][1];
  const auto t0 = Clock::now();
  for (int t = 0; t < clients; ++t) {
    threads.emplace_back([&, t] {
      std::vector<double> lat;
      try {
        Client c = connect(o);
        std::mt19937 rng(1234 + t);
        std::uniform_real_distribution<double> ux(x0, x1), uy(y0, y1);
        const auto period = std::chrono::duration_cast<Clock::duration>(
            std::chrono::duration<double>(o.rate > 0 ? 1.0 / o.rate : 0.0));
        // Paced clients start at random phases so they do not fire in lockstep.
        auto next = Clock::now() + std::chrono::duration_cast<Clock::duration>(
                                       period * std::uniform_real_distribution<double>(0, 1)(rng));
        for (int i = 0; keep_going ? keep_going->load() : i < requests; ++i) {
          if (o.rate > 0) {
            std::this_thread::sleep_until(next);
            next += period;
          }
          json request = {{"op", "map.query"}};
          std::vector<protocol::Attachment> atts;
          if (o.json_points) {
            json pts = json::array();
            for (int k = 0; k < o.points; ++k) pts.push_back({ux(rng), uy(rng)});
            request["points"] = std::move(pts);
          } else {
            std::vector<float> xy;
            for (int k = 0; k < o.points; ++k)
              xy.insert(xy.end(), {static_cast<float>(ux(rng)), static_cast<float>(uy(rng))});
            atts.push_back(protocol::make_float_attachment(
                "points", {static_cast<std::uint64_t>(o.points), 2}, xy));
          }
          // Latency: from the send to the whole reply frame received (the client's JSON decoding
          // of the reply is not the server's time and is done after the clock stops).
          const auto start = Clock::now();
          c.send(std::move(request), std::move(atts));
          const std::string body = c.receive_body();
          const double ms = ms_since(start);
          const auto reply = protocol::decode_body(body);
          if (!reply.header.value("ok", false) ||
              reply.header["result"]["results"].size() != static_cast<std::size_t>(o.points)) {
            failures++;
            continue;
          }
          if (i >= 3 || keep_going) lat.push_back(ms);  // the first requests warm up
        }
      } catch (const std::exception& e) {
        failures++;
      }
      std::lock_guard<std::mutex> lock(mu);
      run.latencies_ms.insert(run.latencies_ms.end(), lat.begin(), lat.end());
    });
  }
  for (auto& th : threads) th.join();
  run.wall_s = std::chrono::duration<double>(Clock::now() - t0).count();
  run.failures = failures;
  return run;
}

json bench_query(const BenchOptions& o, const json& extent) {
  const QueryRun r = run_queries(o, o.clients, o.requests, extent);
  json j = latency_json(r.latencies_ms);
  j["clients"] = o.clients;
  j["points_per_request"] = o.points;
  j["rate_per_client"] = o.rate;
  j["points_encoding"] = o.json_points ? "json" : "float32 attachment";
  j["requests"] = r.latencies_ms.size();
  j["failures"] = r.failures;
  j["wall_s"] = r.wall_s;
  j["requests_per_s"] = r.latencies_ms.size() / r.wall_s;
  j["points_per_s"] = r.latencies_ms.size() * o.points / r.wall_s;
  return j;
}

// Worker-operation overhead: round trip minus the compute time the operation reports itself
// (plan: the planner's total, timings.total_s = problem build + solve + sampling + dense checks;
// so the overhead is what the service adds: framing, parsing, queueing, terrain lookup, JSON
// encoding and transport; without a planner: debug.sleep's slept_ms). The planner's own time
// outside the Ipopt solve is reported next to it as planner_outside_solve.
// `samples` is the plan's sample encoding: "attachment" (a float32 table) or "json".
json bench_overhead(const BenchOptions& o, const std::string& samples) {
  Client c = connect(o);
  json probe_plan = {{"op", "plan"},
                     {"terrain", "flat"},
                     {"gait", "crawl"},
                     {"duration", 2.4},
                     {"goal", {0.3, 0.0, 0.0}},
                     {"samples", samples}};
  const auto first = c.call(probe_plan);
  const bool have_plan = first.header.value("ok", false);
  std::vector<double> overhead, compute, outside_solve;
  std::string op = have_plan ? "plan" : "debug.sleep";
  if (!have_plan) {
    const auto probe = c.call({{"op", "debug.sleep"}, {"ms", 0}});
    if (!probe.header.value("ok", false))
      return {{"op", "none"},
              {"note", "plan unavailable (" + error_text(first) +
                           ") and debug.sleep disabled (serve --debug-ops)"}};
  }
  for (int i = 0; i < (have_plan ? o.plans : 50); ++i) {
    const auto start = Clock::now();
    const auto reply = have_plan ? c.call(probe_plan) : c.call({{"op", "debug.sleep"}, {"ms", 2}});
    const double rtt = ms_since(start);
    if (!reply.header.value("ok", false)) continue;
    const json& r = reply.header["result"];
    double own = r.value("slept_ms", 0.0);
    if (have_plan) {
      const json timings = r.contains("timings") ? r["timings"] : json::object();
      const double solve_ms = r["solver"].value("wall_s", 0.0) * 1000.0;
      own = timings.value("total_s", r["solver"].value("wall_s", 0.0)) * 1000.0;
      outside_solve.push_back(own - solve_ms);
    }
    compute.push_back(own);
    overhead.push_back(rtt - own);
  }
  json j = latency_json(overhead);
  j["op"] = op;
  if (have_plan) j["samples"] = samples;
  j["compute"] = latency_json(compute);
  if (!outside_solve.empty()) j["planner_outside_solve"] = latency_json(outside_solve);
  if (!have_plan) j["note"] = "plan unavailable: " + error_text(first) + "; measured debug.sleep";
  return j;
}

// ---- hostile mode ----

// Well-behaved clients querying throughout the hostile cases; their latencies are kept with the
// time they were measured, so each case reports what a good client saw while it ran.
class Bystanders {
 public:
  Bystanders(const BenchOptions& o, const json& extent, int clients) : o_(o) {
    for (int t = 0; t < clients; ++t) threads_.emplace_back([this, extent, t] { loop(extent, t); });
  }
  ~Bystanders() { stop(); }
  void stop() {
    stop_ = true;
    for (auto& t : threads_)
      if (t.joinable()) t.join();
  }
  // Latency figures for samples taken within [t0, t1], plus failures in that window.
  json window(Clock::time_point t0, Clock::time_point t1) {
    std::vector<double> v;
    std::uint64_t failures = 0;
    std::lock_guard<std::mutex> lock(mu_);
    for (const auto& [t, ms] : samples_)
      if (t >= t0 && t <= t1) {
        if (ms < 0)
          failures++;
        else
          v.push_back(ms);
      }
    json j = latency_json(v);
    j["failures"] = failures;
    return j;
  }

 private:
  void loop(const json& extent, int t) {
    std::mt19937 rng(99 + t);
    const double x0 = extent[0][0], y0 = extent[0][1], x1 = extent[1][0], y1 = extent[1][1];
    std::uniform_real_distribution<double> ux(x0, x1), uy(y0, y1);
    std::optional<Client> c;
    while (!stop_) {
      const auto start = Clock::now();
      double ms = -1;
      try {
        if (!c) c.emplace(connect(o_));
        std::vector<float> xy;
        for (int k = 0; k < o_.points; ++k)
          xy.insert(xy.end(), {static_cast<float>(ux(rng)), static_cast<float>(uy(rng))});
        const auto reply =
            c->call({{"op", "map.query"}},
                    {protocol::make_float_attachment("points", {std::uint64_t(o_.points), 2}, xy)});
        if (reply.header.value("ok", false) &&
            reply.header["result"]["results"].size() == static_cast<std::size_t>(o_.points))
          ms = ms_since(start);
      } catch (const std::exception&) {
        c.reset();  // reconnect next time
      }
      {
        std::lock_guard<std::mutex> lock(mu_);
        samples_.emplace_back(Clock::now(), ms);
      }
      // Paced (not saturating): the figure is the latency a control loop would see.
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
  }

  const BenchOptions& o_;
  std::atomic<bool> stop_{false};
  std::vector<std::thread> threads_;
  std::mutex mu_;
  std::vector<std::pair<Clock::time_point, double>> samples_;
};

// What the server says about itself (a fresh connection, so an idle timeout cannot have closed
// it); null when it cannot be reached (e.g. while every connection slot is taken).
json server_status(const BenchOptions& o) {
  try {
    Client c = connect(o);
    c.set_timeout(5);
    return c.call_ok({{"op", "status"}});
  } catch (const std::exception&) {
    return nullptr;
  }
}

// Resident memory of the server in kB: /proc/PID/status with --server-pid, else the status op's
// memory.rss_bytes (servers from before that field: -1).
long server_rss_kb(const BenchOptions& o) {
  if (o.server_pid > 0) {
    std::ifstream in("/proc/" + std::to_string(o.server_pid) + "/status");
    std::string line;
    while (std::getline(in, line))
      if (line.rfind("VmRSS:", 0) == 0) return std::stol(line.substr(6));
    return -1;
  }
  const json st = server_status(o);
  if (st.is_object() && st.contains("memory") && st["memory"].contains("rss_bytes"))
    return st["memory"]["rss_bytes"].get<long>() / 1024;
  return -1;
}

std::string frame_prefix(std::uint32_t body_length) {
  std::string f(4, '\0');
  protocol::write_u32be(body_length, reinterpret_cast<unsigned char*>(&f[0]));
  return f;
}

std::string raw_frame(const std::string& header) {
  std::string f = frame_prefix(static_cast<std::uint32_t>(4 + header.size())) + "    ";
  protocol::write_u32be(static_cast<std::uint32_t>(header.size()),
                        reinterpret_cast<unsigned char*>(&f[4]));
  return f + header;
}

// One hostile connection's fate: the error replies it got, and whether the server closed it
// cleanly (FIN), reset it, or left it open.
struct Fate {
  std::map<std::string, int> errors;
  int ok = 0, closed = 0, reset = 0, open = 0;
  void add(const Fate& f) {
    for (const auto& [k, v] : f.errors) errors[k] += v;
    ok += f.ok, closed += f.closed, reset += f.reset, open += f.open;
  }
  json to_json() const {
    json e = json::object();
    for (const auto& [k, v] : errors) e[k] = v;
    return {{"error_replies", e},
            {"ok_replies", ok},
            {"closed_by_server", closed},
            {"reset", reset},
            {"still_open", open}};
  }
};

// Reads replies until the server closes the connection or `wait_s` pass.
Fate await_fate(Client& c, double wait_s) {
  Fate f;
  c.set_timeout(wait_s);
  for (;;) {
    try {
      const auto m = c.receive();
      if (m.header.value("ok", false))
        f.ok++;
      else
        f.errors[m.header["error"].value("code", "?")]++;
    } catch (const ClientError& e) {
      const std::string what = e.what();
      if (what.find("timed out") != std::string::npos)
        f.open++;
      else if (what.find("closed by the server") != std::string::npos)
        f.closed++;
      else
        f.reset++;
      return f;
    }
  }
}

// await_fate for every connection, all within one shared wait.
Fate await_fates(std::vector<Client>& cs, double wait_s) {
  Fate f;
  const auto until = Clock::now() + std::chrono::duration_cast<Clock::duration>(
                                        std::chrono::duration<double>(wait_s));
  for (auto& c : cs)
    f.add(
        await_fate(c, std::max(0.05, std::chrono::duration<double>(until - Clock::now()).count())));
  return f;
}

// The server's limits as it reports them in hello (older servers: the documented defaults).
struct Limits {
  double frame_timeout_s = 10, idle_timeout_s = 300;
  int max_connections = 512;
  std::uint64_t max_frame_bytes = 64u << 20;
};

json bench_hostile(const BenchOptions& o, const json& extent) {
  Limits lim;
  {
    Client c = Client::connect(o.connect);
    json hello = {{"op", "hello"}};
    if (!o.token.empty()) hello["token"] = o.token;
    const json caps = c.call_ok(hello)["capabilities"];
    lim.frame_timeout_s = caps.value("frame_timeout_s", lim.frame_timeout_s);
    lim.idle_timeout_s = caps.value("idle_timeout_s", lim.idle_timeout_s);
    lim.max_connections = caps.value("max_connections", lim.max_connections);
    lim.max_frame_bytes = caps.value("max_frame_bytes", lim.max_frame_bytes);
  }
  // How long a case waits for the server to close its hostile connections: the limit plus
  // slack, capped so that a server without the limit shows up as "still_open" in bounded time.
  const double settle_s = std::min(lim.frame_timeout_s, o.max_wait_s) + 2.0;
  Bystanders bystanders(o, extent, 4);
  std::this_thread::sleep_for(std::chrono::milliseconds(200));
  json cases = json::array();

  auto run_case = [&](const std::string& name, const std::string& what,
                      const std::function<json()>& attack) {
    const long rss_before = server_rss_kb(o);
    const auto t0 = Clock::now();
    json r;
    try {
      r = attack();
    } catch (const std::exception& e) {
      r = {{"bench_error", e.what()}};
    }
    const auto t1 = Clock::now();
    const json st = server_status(o);
    r["name"] = name;
    r["attack"] = what;
    r["seconds"] = std::chrono::duration<double>(t1 - t0).count();
    r["survived"] = st.is_object();
    r["rss_before_kb"] = rss_before;
    r["rss_after_kb"] = server_rss_kb(o);
    r["bystanders"] = bystanders.window(t0, t1);
    cases.push_back(r);
    std::cerr << "bench-service: hostile case " << name << " done\n";
  };

  run_case("malformed", std::to_string(o.malformed) + " malformed frames, 1000 per connection",
           [&] {
             Fate fate;
             const int per_conn = 1000;
             for (int sent = 0; sent < o.malformed; sent += per_conn) {
               Client c = connect(o);
               const int n = std::min(per_conn, o.malformed - sent);
               std::string burst;
               for (int i = 0; i < n; ++i) {
                 static const char* headers[] = {
                     "{not json", "[1,2,3]", R"({"v":1,"id":1,"op":7})",
                     R"({"v":1,"id":2,"op":"no.such.op"})",
                     R"({"v":1,"id":3,"op":"map.query","points":[[1,"x"]]})"};
                 burst += raw_frame(headers[i % 5]);
               }
               std::thread w([&] { c.send_raw(burst); });
               for (int i = 0; i < n; ++i) {
                 const auto m = c.receive();
                 if (m.header.value("ok", false))
                   fate.ok++;
                 else
                   fate.errors[m.header["error"].value("code", "?")]++;
               }
               w.join();
             }
             return fate.to_json();
           });

  run_case("disconnects",
           std::to_string(o.disconnects) +
               " abrupt disconnects: mid-prefix, mid-body, after a whole request",
           [&] {
             const std::string f = protocol::encode_frame(
                 {{{"v", 1}, {"id", 1}, {"op", "map.query"}, {"points", {{0.0, 0.0}}}}, {}});
             for (int i = 0; i < o.disconnects; ++i) {
               Client c = Client::connect(o.connect);
               c.send_raw(i % 3 == 0 ? f.substr(0, 2) : i % 3 == 1 ? f.substr(0, f.size() - 3) : f);
             }
             return json{{"connections", o.disconnects}};
           });

  run_case("slow_headers",
           std::to_string(o.slowloris) +
               " connections sending a small request one byte every 200 ms (slowloris)",
           [&] {
             std::vector<Client> cs;
             for (int i = 0; i < o.slowloris; ++i) cs.push_back(Client::connect(o.connect));
             const std::string f = raw_frame(R"({"v":1,"id":1,"op":"hello","padding":")" +
                                             std::string(200, 'x') + "\"}");
             // Each connection gets one byte per round until the server answers or closes it.
             std::vector<bool> done(cs.size(), false);
             Fate fate;
             const auto until = Clock::now() + std::chrono::duration<double>(settle_s);
             for (std::size_t k = 0; k < f.size() && Clock::now() < until; ++k) {
               for (std::size_t i = 0; i < cs.size(); ++i) {
                 if (done[i]) continue;
                 cs[i].set_timeout(0);
                 try {
                   const auto m = cs[i].receive();  // the server spoke: the case is decided
                   if (m.header.value("ok", false))
                     fate.ok++;
                   else
                     fate.errors[m.header["error"].value("code", "?")]++;
                   fate.add(await_fate(cs[i], 1.0));
                   done[i] = true;
                   continue;
                 } catch (const ClientError& e) {
                   if (std::string(e.what()).find("timed out") == std::string::npos) {
                     fate.reset++;
                     done[i] = true;
                     continue;
                   }
                 }
                 try {
                   cs[i].send_raw(f.substr(k, 1));
                 } catch (const ClientError&) {
                   fate.reset++;
                   done[i] = true;
                 }
               }
               std::this_thread::sleep_for(std::chrono::milliseconds(200));
             }
             std::vector<Client> rest;
             for (std::size_t i = 0; i < cs.size(); ++i)
               if (!done[i]) rest.push_back(std::move(cs[i]));
             fate.add(await_fates(rest, 0.5));
             return fate.to_json();
           });

  run_case("half_sent_frames",
           std::to_string(o.slowloris) + " connections announcing " +
               std::to_string(lim.max_frame_bytes) + "-byte frames, sending 4 MiB, then stalling",
           [&] {
             std::vector<Client> cs;
             long peak = -1;
             for (int i = 0; i < o.slowloris; ++i) {
               cs.push_back(connect(o));  // after hello: the full frame cap applies
               cs.back().send_raw(frame_prefix(static_cast<std::uint32_t>(lim.max_frame_bytes)) +
                                  std::string((4u << 20) - 4, 'x'));
             }
             std::this_thread::sleep_for(std::chrono::milliseconds(300));
             peak = server_rss_kb(o);
             // Allowance: frame timeout + 4 MiB at the minimum rate (the server's business); the
             // bench waits up to --max-wait.
             json j = await_fates(cs, o.max_wait_s + 2.0).to_json();
             j["rss_while_held_kb"] = peak;
             return j;
           });

  run_case("buffer_budget",
           std::to_string(o.slowloris) +
               " connections announcing maximal frames and sending 16 MiB at once; closed by the "
               "bench after 1 s",
           [&] {
             std::vector<Client> cs;
             for (int i = 0; i < o.slowloris; ++i) {
               cs.push_back(connect(o));
               try {
                 cs.back().set_timeout(2);
                 cs.back().send_raw(frame_prefix(static_cast<std::uint32_t>(lim.max_frame_bytes)) +
                                    std::string((16u << 20) - 4, 'x'));
               } catch (const ClientError&) {
               }
             }
             std::this_thread::sleep_for(std::chrono::seconds(1));
             const long peak = server_rss_kb(o);
             const Fate fate = await_fates(cs, 0.5);
             cs.clear();  // the bench lets go: what the server held goes back
             std::this_thread::sleep_for(std::chrono::milliseconds(500));
             json j = fate.to_json();
             j["rss_while_held_kb"] = peak;
             return j;
           });

  run_case("idle_sockets",
           "idle connections up to the connection limit, then a new client; then wait for the "
           "idle timeout",
           [&] {
             std::vector<Client> idle;
             json j;
             bool refused = false;
             // Fill every slot: each idle client asks one status (so it is adopted) and then
             // stays silent; the first one refused marks the limit.
             for (int i = 0; i < lim.max_connections + 1 && !refused; ++i) {
               Client c = Client::connect(o.connect);
               c.set_timeout(5);
               json hello = {{"op", "hello"}};
               if (!o.token.empty()) hello["token"] = o.token;
               try {
                 c.send(hello);
                 const auto m = c.receive();  // the refusal carries id null: not wait_for
                 if (!m.header.value("ok", false)) {
                   refused = true;
                   j["refused_after"] = i;
                   j["refusal"] = error_text(m);
                 } else {
                   idle.push_back(std::move(c));
                 }
               } catch (const ClientError& e) {
                 refused = true;
                 j["refused_after"] = i;
                 j["refusal"] = std::string("no reply: ") + e.what();
               }
             }
             j["idle_connections"] = idle.size();
             // A new client, waiting (up to the idle timeout, capped) for a slot.
             const auto t0 = Clock::now();
             double got_in_s = -1;
             const double wait = std::min(lim.idle_timeout_s, o.max_wait_s) + 3.0;
             while (ms_since(t0) < wait * 1000) {
               try {
                 Client c = connect(o);
                 c.call_ok({{"op", "status"}});
                 got_in_s = ms_since(t0) / 1000;
                 break;
               } catch (const std::exception&) {
                 std::this_thread::sleep_for(std::chrono::milliseconds(100));
               }
             }
             j["new_client_got_in_after_s"] = got_in_s;
             j["idle_fates"] = await_fates(idle, 1.0).to_json();
             return j;
           });

  run_case(
      "oversized_claims",
      "length prefixes of 1 MiB, the frame cap and 4 GiB-1 before hello (token servers), "
      "and of 4 GiB-1 and the cap (nothing sent after) after hello",
      [&] {
        std::vector<Client> before, after;
        for (std::uint32_t claim :
             {1u << 20, static_cast<std::uint32_t>(lim.max_frame_bytes), 0xffffffffu}) {
          before.push_back(Client::connect(o.connect));
          before.back().send_raw(frame_prefix(claim) + "{\"v\":1");
        }
        for (std::uint32_t claim : {0xffffffffu, static_cast<std::uint32_t>(lim.max_frame_bytes)}) {
          after.push_back(connect(o));
          after.back().send_raw(frame_prefix(claim) + "{\"v\":1");
        }
        const json b = await_fates(before, settle_s).to_json();
        return json{{"before_hello", b}, {"after_hello", await_fates(after, settle_s).to_json()}};
      });

  run_case("deadline_overflow",
           "status, map.query and debug.sleep with deadline_ms 1e13, 1e15 and 1e300 (should run "
           "as if without a deadline)",
           [&] {
             Fate fate;
             Client c = connect(o);
             for (double d : {1e13, 1e15, 1e300})
               for (const json& req :
                    {json{{"op", "status"}}, json{{"op", "map.query"}, {"points", {{0.0, 0.0}}}},
                     json{{"op", "debug.sleep"}, {"ms", 1}}}) {
                 json r = req;
                 r["deadline_ms"] = d;
                 const auto m = c.call(r);
                 if (m.header.value("ok", false))
                   fate.ok++;
                 else
                   fate.errors[m.header["error"].value("code", "?")]++;
               }
             return fate.to_json();
           });

  run_case("duplicate_attachments",
           "map.query carrying two attachments named points (should be bad_request)", [&] {
             Fate fate;
             Client c = connect(o);
             for (int i = 0; i < 10; ++i) {
               const auto m = c.call({{"op", "map.query"}},
                                     {protocol::make_float_attachment("points", {1, 2}, {0, 0}),
                                      protocol::make_float_attachment("points", {1, 2}, {1, 1})});
               if (m.header.value("ok", false))
                 fate.ok++;
               else
                 fate.errors[m.header["error"].value("code", "?")]++;
             }
             return fate.to_json();
           });

  run_case("unknown_fields",
           "status with \"verbose\", cancel with \"targte\", hello with \"tokn\" (should be "
           "bad_request with a suggestion)",
           [&] {
             Fate fate;
             Client c = connect(o);
             json messages = json::array();
             for (const json& req :
                  {json{{"op", "status"}, {"verbose", true}}, json{{"op", "cancel"}, {"targte", 1}},
                   json{{"op", "hello"}, {"tokn", "x"}}}) {
               const auto m = c.call(req);
               if (m.header.value("ok", false)) {
                 fate.ok++;
               } else {
                 fate.errors[m.header["error"].value("code", "?")]++;
                 messages.push_back(m.header["error"].value("message", ""));
               }
             }
             json j = fate.to_json();
             j["messages"] = messages;
             return j;
           });

  bystanders.stop();
  const json st = server_status(o);
  return {{"server_limits",
           {{"frame_timeout_s", lim.frame_timeout_s},
            {"idle_timeout_s", lim.idle_timeout_s},
            {"max_connections", lim.max_connections},
            {"max_frame_bytes", lim.max_frame_bytes}}},
          {"cases", cases},
          {"server_status_after", st.is_object() ? json{{"connections", st["connections"]},
                                                        {"memory", st.value("memory", json())}}
                                                 : json()}};
}

// ---- replan mode ----
// A step reply with its samples as a float32 table (plan.session.step "samples": "attachment"),
// its samples turned back into the {t, base: {position, linear_velocity}} objects the next step's
// measured state is taken from.
json samples_from_table(const protocol::Message& reply) {
  json r = reply.header["result"];
  const json& desc = r["samples"];
  const auto columns = desc["columns"].get<std::vector<std::string>>();
  const std::size_t rows = desc["rows"], nc = columns.size();
  const protocol::Attachment* a = nullptr;
  for (const auto& att : reply.attachments)
    if (att.name == desc["attachment"].get<std::string>()) a = &att;
  if (!a || a->data.size() != rows * nc * sizeof(float))
    throw ClientError("plan.session.step: the samples attachment is missing or of the wrong size");
  std::vector<float> v(rows * nc);
  std::memcpy(v.data(), a->data.data(), a->data.size());
  auto col = [&](const std::string& name) {
    const auto it = std::find(columns.begin(), columns.end(), name);
    if (it == columns.end()) throw ClientError("plan.session.step: no samples column " + name);
    return static_cast<std::size_t>(it - columns.begin());
  };
  const std::size_t ct = col("t"), cp = col("base.position.x"), cv = col("base.linear_velocity.x");
  json samples = json::array();
  for (std::size_t i = 0; i < rows; ++i) {
    const float* row = v.data() + i * nc;
    samples.push_back({{"t", row[ct]},
                       {"base",
                        {{"position", {row[cp], row[cp + 1], row[cp + 2]}},
                         {"linear_velocity", {row[cv], row[cv + 1], row[cv + 2]}}}}});
  }
  r["samples"] = samples;
  return r;
}

// What the replan mode measures, step by step.
struct ReplanTally {
  std::vector<double> latencies, solves;
  // Where a step's time goes, from the reply's "timings" (server side): building the problem and
  // its warm start, the solve, sampling and dense checks, and the step in all.
  std::vector<double> builds, checks, server_totals;
  // Per-iteration cost beside the iteration counts (a faster Jacobian or linear solve shows in
  // the first, a better warm start in the second), the process CPU of a step when the server is
  // in-process (load-independent, unlike the wall times), and one record per step for the tail.
  std::vector<double> per_iteration, cpu, outside_server;
  // Where a step's round trip goes past its work (the reply's "timing_ms"): how late the step
  // returned after its answer was due (the scheduler's wake-up), the op before the step and the
  // reply's building, and what is outside the op (the server's queue and I/O thread, the socket,
  // the client).
  std::vector<double> answer_late, op_overhead, outside_op;
  int realtime_steps = 0;
  json records = json::array();
  int failures = 0, iterations = 0, fallbacks = 0, deadline_fallbacks = 0, misses = 0;
  int late_warm = 0, sessions = 1;

  // A step's reply (ok) into the figures and its record.
  void add_reply(const protocol::Message& reply, double latency, json* rec) {
    const json& r = reply.header["result"];
    if (r.value("fallback", false)) {
      ++fallbacks;
      const std::string why = r.value("fallback_reason", std::string());
      deadline_fallbacks += why == "deadline";
      (*rec)["fallback"] = why;
    }
    late_warm += r.value("warm_from_late_solve", false);
    const double solve_ms = 1e3 * r["solver"]["wall_s"].get<double>();
    const int its = r["solver"]["iterations"].get<int>();
    // A fallback's solver figures are those of no solve (or of a failed one).
    if (!rec->contains("fallback")) {
      solves.push_back(solve_ms);
      if (its > 0) per_iteration.push_back(solve_ms / its);
      iterations += its;
    }
    (*rec)["iterations"] = its;
    (*rec)["solve_ms"] = solve_ms;
    (*rec)["step_ms"] = r.value("step_ms", 0.0);
    (*rec)["variables"] = r["solver"].value("n_variables", 0);
    (*rec)["constraints"] = r["solver"].value("n_constraints", 0);
    (*rec)["end_time"] = r.value("end_time", 0.0);
    if (r.contains("timing_ms")) {
      const json& tm = r["timing_ms"];
      const double before = tm.value("before_step", 0.0), step = tm.value("step", 0.0),
                   built = tm.value("reply", 0.0);
      answer_late.push_back(tm.value("answer_late", 0.0));
      op_overhead.push_back(before + built);
      outside_op.push_back(latency - before - step - built);
      realtime_steps += tm.value("realtime", false);
      (*rec)["answer_late_ms"] = answer_late.back();
      (*rec)["op_overhead_ms"] = op_overhead.back();
      (*rec)["outside_op_ms"] = outside_op.back();
    }
    std::size_t reply_bytes = reply.header.dump().size();
    for (const auto& a : reply.attachments) reply_bytes += a.data.size();
    (*rec)["reply_bytes"] = reply_bytes;
    if (r.contains("timings")) {
      const json& tm = r["timings"];
      builds.push_back(1e3 * tm.value("build_s", 0.0));
      checks.push_back(1e3 * tm.value("sample_and_checks_s", 0.0));
      server_totals.push_back(1e3 * tm.value("total_s", 0.0));
      // The reply's JSON, the socket and the client's parsing: the client's latency minus the
      // step in the server.
      outside_server.push_back(latency - server_totals.back());
      (*rec)["build_ms"] = builds.back();
      (*rec)["server_ms"] = server_totals.back();
    }
  }
  json to_json(const BenchOptions& o, const json& ref, double cold_ms) const {
    json j = {{"scene", o.replan_scene},
              {"constraints", o.replan_constraints},
              {"horizon_s", o.horizon},
              {"samples", o.replan_samples},
              {"blas_kernel", bench::blas_kernel_name()},
              {"cold_ms", cold_ms},
              {"cold_solve_ms", 1e3 * ref["solver"]["wall_s"].get<double>()},
              {"cold_iterations", ref["solver"]["iterations"]},
              {"steps", o.replan_steps},
              {"sessions", sessions},
              {"budget_ms", o.replan_budget_ms},
              {"period_s", o.replan_period},
              {"failures", failures},
              {"fallbacks", fallbacks},
              {"deadline_fallbacks", deadline_fallbacks},
              {"deadline_misses", misses},
              {"warm_from_late_solve", late_warm},
              // Steps answered with their own solve's plan (neither a fallback nor failed).
              {"own_solutions", static_cast<int>(latencies.size()) - failures - fallbacks},
              {"own_fraction", latencies.empty() ? 0.0
                                                 : static_cast<double>(static_cast<int>(
                                                       latencies.size()) - failures - fallbacks) /
                                                       latencies.size()},
              {"iterations_per_step", static_cast<double>(iterations) /
                                          std::max<std::size_t>(1, solves.size())},
              {"latency", latency_json(latencies)},
              {"solve", latency_json(solves)},
              {"build", latency_json(builds)},
              {"sample_and_checks", latency_json(checks)},
              {"server_total", latency_json(server_totals)},
              {"solve_per_iteration", latency_json(per_iteration)},
              {"outside_server", latency_json(outside_server)},
              {"answer_late", latency_json(answer_late)},
              {"op_overhead", latency_json(op_overhead)},
              {"outside_op", latency_json(outside_op)},
              {"realtime_steps", realtime_steps},
              {"step_records", records}};
    if (!cpu.empty()) j["cpu"] = latency_json(cpu);
    if (j["latency"].contains("p50_ms")) {
      j["median_over_cold"] = j["latency"]["p50_ms"].get<double>() / cold_ms;
      j["targets"] = {{"median_over_cold_max", 0.05}, {"p99_ms_max", 50.0}, {"max_ms_max", 60.0}};
    }
    return j;
  }
};

// The measured base a step sends: the current plan's at session time t, 1 cm to the side and
// 0.05 m/s faster.
json measured_base(const json& current, double current_start, double t) {
  const json* at = nullptr;
  for (const json& s : current["samples"])
    if (s["t"].get<double>() + current_start >= t - 1e-6) {  // float32 times in tables
      at = &s;
      break;
    }
  if (!at) at = &current["samples"].back();
  json base = {{"position", (*at)["base"]["position"]},
               {"linear_velocity", (*at)["base"]["linear_velocity"]}};
  base["position"][1] = base["position"][1].get<double>() + 0.01;
  base["linear_velocity"][0] = base["linear_velocity"][0].get<double>() + 0.05;
  return base;
}

// A planning session (plan.session.open: the cold solve), then steps 0.1 s apart, each from the
// current plan's state at that time 1 cm to the side and 0.05 m/s faster (a robot's measured
// state), timed as the client sees them (send to reply), each with budget_ms. The cold figure is
// the open's round trip: the reference plan's solve and everything around it, as a `plan`
// would be. A motion holds about duration / 0.1 steps; the next session (the same motion as its
// reference, "init": no solve) begins where the previous one ended, as a robot's next motion would.
// The calling thread (or `thread`) at SCHED_FIFO priority 1, where the process may; false if not.
bool try_realtime(pthread_t thread) {
  sched_param rt{};
  rt.sched_priority = 1;
  return pthread_setschedparam(thread, SCHED_FIFO, &rt) == 0;
}

json bench_replan(const BenchOptions& o, bool in_process) {
  const bool realtime_client = o.realtime_loop && try_realtime(pthread_self());
  Client c = connect(o);
  c.set_timeout(600);
  // As the server reports it (serve --realtime-io; the in-process server's --realtime-loop).
  const bool realtime_server_io = c.call_ok({{"op", "status"}}).value("realtime_io", false);
  const auto t_open = Clock::now();
  const json ref = c.call_ok({{"op", "plan.session.open"},
                              {"terrain", o.replan_scene},
                              {"constraints", o.replan_constraints},
                              {"horizon", o.horizon}});
  const double cold_ms = ms_since(t_open);
  std::string id = ref["session"];
  json init = ref;
  for (const char* k : {"session", "horizon", "memory_bytes", "success"}) init.erase(k);
  json current = ref;
  double current_start = 0.0, session_origin = 0.0;
  const double duration = ref["duration"];
  ReplanTally tally;
  const auto loop_start = Clock::now();
  for (int k = 1; k <= o.replan_steps; ++k) {
    double t = 0.1 * k - session_origin;
    if (t >= duration - 0.2) {
      c.call_ok({{"op", "plan.session.close"}, {"session", id}});
      id = c.call_ok({{"op", "plan.session.open"},
                      {"terrain", o.replan_scene},
                      {"init", init},
                      {"horizon", o.horizon}})["session"];
      ++tally.sessions;
      session_origin = 0.1 * (k - 1);
      t = 0.1 * k - session_origin;
      current = ref;
      current_start = 0.0;
    }
    if (o.replan_period > 0 && k > 1)
      std::this_thread::sleep_until(loop_start + std::chrono::duration_cast<Clock::duration>(
                                                     std::chrono::duration<double>(
                                                         o.replan_period * (k - 1))));
    const double cpu0 = process_cpu_ms();
    const auto t0 = Clock::now();
    const auto reply = c.call({{"op", "plan.session.step"},
                               {"session", id},
                               {"time", t},
                               {"start_state", {{"base", measured_base(current, current_start, t)}}},
                               {"budget_ms", o.replan_budget_ms},
                               {"samples", o.replan_samples}});
    const double latency = ms_since(t0);
    const double step_cpu = process_cpu_ms() - cpu0;
    if (o.replan_budget_ms > 0 && latency > o.replan_budget_ms) ++tally.misses;
    tally.latencies.push_back(latency);
    json rec = {{"t", t}, {"session_t0", session_origin}, {"latency_ms", latency}};
    if (in_process) {
      tally.cpu.push_back(step_cpu);
      rec["cpu_ms"] = step_cpu;
    }
    if (!reply.header.value("ok", false)) {
      ++tally.failures;
      const json error = reply.header.value("error", json::object());
      rec["failed"] = error.value("message", std::string());
      tally.records.push_back(rec);
      continue;
    }
    tally.add_reply(reply, latency, &rec);
    tally.records.push_back(rec);
    current = o.replan_samples == "attachment" ? samples_from_table(reply)
                                               : reply.header["result"];
    current_start = t;
  }
  c.call_ok({{"op", "plan.session.close"}, {"session", id}});
  json out = tally.to_json(o, ref, cold_ms);
  out["realtime_loop"] = {{"client", realtime_client}, {"server_io", realtime_server_io}};
  return out;
}

void print_latency(const std::string& label, const json& j) {
  if (!j.contains("p50_ms")) return;
  std::cout << std::fixed << std::setprecision(3) << label << "p50 " << j["p50_ms"].get<double>()
            << " ms, p90 " << j["p90_ms"].get<double>() << " ms, p99 " << j["p99_ms"].get<double>()
            << " ms, max " << j["max_ms"].get<double>() << " ms (" << j["count"] << " samples)\n";
}

void print_replan(const json& r) {
  std::cout << std::fixed << std::setprecision(1) << "replan (" << r["scene"].get<std::string>()
            << ", " << r["constraints"].get<std::string>() << ", horizon "
            << r["horizon_s"].get<double>() << " s, 1 cm and 0.05 m/s off the plan; BLAS kernel "
            << r.value("blas_kernel", "unknown") << "):\n"
            << "  cold: session open " << r["cold_ms"].get<double>() << " ms (solve "
            << r["cold_solve_ms"].get<double>() << " ms, " << r["cold_iterations"]
            << " iterations)\n";
  print_latency("  step, client-observed: ", r["latency"]);
  print_latency("  step solve: ", r["solve"]);
  print_latency("  step build (problem, warm start): ", r["build"]);
  print_latency("  step sampling and dense checks: ", r["sample_and_checks"]);
  print_latency("  step in the server: ", r["server_total"]);
  print_latency("  step outside the server (reply JSON, socket, client parsing): ",
                r["outside_server"]);
  print_latency("  step answered after it was due (scheduler wake-up): ", r["answer_late"]);
  print_latency("  step op before and after the step (lock, state, reply): ", r["op_overhead"]);
  print_latency("  outside the op (server queue and I/O thread, socket, client): ",
                r["outside_op"]);
  std::cout << "  steps at a real-time priority: " << r.value("realtime_steps", 0)
            << "; client and server I/O thread at one: "
            << r["realtime_loop"].value("client", false) << ", "
            << r["realtime_loop"].value("server_io", false) << "\n";
  print_latency("  step solve per iteration: ", r["solve_per_iteration"]);
  if (r.contains("cpu")) print_latency("  step process CPU (in-process server): ", r["cpu"]);
  std::cout << std::setprecision(3) << "  median / cold = "
            << r.value("median_over_cold", -1.0) << " (target <= 0.05), p99 "
            << r["latency"].value("p99_ms", -1.0) << " ms (target <= 50 ms), max "
            << r["latency"].value("max_ms", -1.0) << " ms (target <= 60 ms); "
            << std::setprecision(2) << r["iterations_per_step"].get<double>()
            << " iterations per solved step, " << r["failures"] << " failed steps\n"
            << std::setprecision(0) << "  budget " << r["budget_ms"].get<double>()
            << " ms: " << r["deadline_misses"] << " replies after it, " << r["fallbacks"]
            << " fallbacks (" << r["deadline_fallbacks"] << " at the deadline), "
            << r["warm_from_late_solve"] << " steps warm-started from a late solve, "
            << r["sessions"] << " sessions\n"
            << "  own solutions (not fallbacks): " << r["own_solutions"] << " of "
            << r["latency"].value("count", 0) << std::setprecision(2) << " ("
            << r["own_fraction"].get<double>() << ")\n";
}

}  // namespace

// The tool's options and its run on `cmd` (the executable's own app).
void configure_bench_service(CLI::App* cmd) {
  auto o = std::make_shared<BenchOptions>();
  cmd->description(
      "Load-test the socket service: map.query throughput and p50/p99 latency with many clients, "
      "plan overhead, and (--mode hostile) attacks on the transport with the server's memory and "
      "well-behaved clients' latency meanwhile");
  cmd->add_option("--connect", o->connect,
                  "Server address (tcp://HOST:PORT or unix:PATH); default: start one in-process "
                  "on an ephemeral loopback port");
  cmd->add_option("--token", o->token, "Token for hello, when the server requires one");
  cmd->add_option("--mode", o->mode,
                  "query, plan, hostile, all, or replan (planning-session re-plan latency; not "
                  "part of all)")
      ->capture_default_str()
      ->check(CLI::IsMember({"query", "plan", "hostile", "all", "replan"}));
  cmd->add_option("--steps", o->replan_steps, "Replan mode: session steps, 0.1 s apart")
      ->capture_default_str()
      ->check(CLI::Range(1, 100000));
  cmd->add_option("--budget-ms", o->replan_budget_ms,
                  "Replan mode: each step's budget_ms (0 = wait for every solve)")
      ->capture_default_str();
  cmd->add_option("--replan-period", o->replan_period,
                  "Replan mode: seconds between steps sent (a 10 Hz loop: 0.1, the session time "
                  "per step); 0 = each as soon as the previous reply arrived")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 10.0));
  cmd->add_option("--horizon", o->horizon, "Replan mode: the session's horizon in s (0 = to the goal)")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 60.0));
  cmd->add_option("--replan-scene", o->replan_scene, "Replan mode: the scene")
      ->capture_default_str();
  cmd->add_option("--replan-samples", o->replan_samples,
                  "Replan mode: step replies' samples as json or attachment (a float32 table)")
      ->capture_default_str()
      ->check(CLI::IsMember({"json", "attachment"}));
  cmd->add_option("--replan-constraints", o->replan_constraints, "Replan mode: constraint sets")
      ->capture_default_str();
  cmd->add_option("--clients", o->clients, "Concurrent query clients")
      ->capture_default_str()
      ->check(CLI::Range(1, 1000));
  cmd->add_option("--requests", o->requests, "map.query requests per client")
      ->capture_default_str()
      ->check(CLI::Range(4, 1000000));
  cmd->add_option("--rate", o->rate,
                  "map.query requests per second per client (0 = back to back, i.e. saturation)")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 100000.0));
  cmd->add_option("--points", o->points, "Points per map.query")
      ->capture_default_str()
      ->check(CLI::Range(1, 10000));
  cmd->add_option("--plans", o->plans, "Plan (or worker) requests for the overhead figure")
      ->capture_default_str()
      ->check(CLI::Range(1, 100000));
  cmd->add_option("--malformed", o->malformed, "Malformed frames to send")
      ->capture_default_str()
      ->check(CLI::Range(0, 10000000));
  cmd->add_option("--disconnects", o->disconnects, "Abrupt disconnects")
      ->capture_default_str()
      ->check(CLI::Range(0, 1000000));
  cmd->add_option("--slowloris", o->slowloris, "Hostile connections per slow-frame case")
      ->capture_default_str()
      ->check(CLI::Range(1, 10000));
  cmd->add_option("--max-wait", o->max_wait_s,
                  "Hostile mode: longest wait (s) for the server to close a hostile connection")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 3600.0));
  cmd->add_option("--server-pid", o->server_pid,
                  "PID of the server given with --connect, for its resident memory "
                  "(/proc/PID/status); default: the status op's memory.rss_bytes");
  cmd->add_option("--server-frame-timeout", o->server_frame_timeout_s,
                  "Hostile mode, in-process server: --frame-timeout")
      ->capture_default_str();
  cmd->add_option("--server-idle-timeout", o->server_idle_timeout_s,
                  "Hostile mode, in-process server: --idle-timeout")
      ->capture_default_str();
  cmd->add_option("--server-session-idle-timeout", o->server_session_idle_timeout_s,
                  "Replan mode, in-process server: --session-idle-timeout (s)")
      ->capture_default_str();
  cmd->add_option("--server-min-receive-rate", o->server_min_receive_rate,
                  "Hostile mode, in-process server: --min-receive-rate")
      ->capture_default_str();
  cmd->add_option("--server-max-connections", o->server_max_connections,
                  "Hostile mode, in-process server: --max-connections")
      ->capture_default_str();
  cmd->add_option("--server-max-buffered-bytes", o->server_max_buffered_bytes,
                  "Hostile mode, in-process server: --max-buffered-bytes")
      ->capture_default_str();
  cmd->add_option("--workers", o->workers, "Workers of the in-process server")
      ->capture_default_str()
      ->check(CLI::Range(1, 64));
  cmd->add_option("--scene", o->scene, "Scene loaded as the map before the benchmark")
      ->capture_default_str();
  cmd->add_flag("--json-points", o->json_points,
                "Send query points as JSON [[x, y], ...] instead of a float32 attachment");
  cmd->add_flag("--realtime-loop", o->realtime_loop,
                "Replan mode: the client's thread and the in-process server's I/O thread at "
                "SCHED_FIFO priority 1 where permitted (a robot's control loop, a deployed "
                "server's I/O thread)");
  cmd->add_flag("--json", o->json, "Print the figures as one JSON object");
  cmd->callback([o] {
    std::unique_ptr<Server> server;
    std::thread server_thread;
    std::shared_ptr<Backend> backend;
    if (o->connect.empty()) {
      ServerOptions so;
      so.listen = {"tcp://127.0.0.1:0"};
      so.workers = o->workers;
      so.queue = 64;
      so.handle_signals = false;
      so.realtime_io = o->realtime_loop && o->mode == "replan";
      if (o->mode == "hostile" || o->mode == "all") {
        // Short limits so each case ends in seconds, and a token so the cases before hello run.
        so.frame_timeout_s = o->server_frame_timeout_s;
        so.idle_timeout_s = o->server_idle_timeout_s;
        so.min_receive_rate = o->server_min_receive_rate;
        so.max_connections = std::max(o->server_max_connections, o->clients + 16);
        so.max_buffered_bytes = o->server_max_buffered_bytes;
        if (o->token.empty()) o->token = "bench-service-hostile-token";
        so.token = o->token;
      }
      OperationRegistry reg;
      BackendOptions bo;
      bo.debug_ops = true;
      bo.session_idle_timeout_s = o->server_session_idle_timeout_s;
      backend = make_backend(bo, reg);
      server = std::make_unique<Server>(
          so, std::move(reg), [backend] { return backend_status(*backend); },
          [backend] { return backend_hello(*backend); });
      o->connect = server->bind().front();
      server_thread = std::thread([&server] { server->run(); });
    }
    json out = {{"address", o->connect}};
    try {
      Client c = connect(*o);
      const json up = c.call_ok({{"op", "map.update"}, {"scene", o->scene}});
      const json st = c.call_ok({{"op", "status"}});
      const json extent = {st["map"]["min_corner"], st["map"]["max_corner"]};
      if (o->mode == "query" || o->mode == "all") out["query"] = bench_query(*o, extent);
      if (o->mode == "plan" || o->mode == "all") {
        out["plan_overhead"] = bench_overhead(*o, "attachment");
        out["plan_overhead_json_samples"] = bench_overhead(*o, "json");
      }
      if (o->mode == "hostile" || o->mode == "all") out["hostile"] = bench_hostile(*o, extent);
      if (o->mode == "replan") out["replan"] = bench_replan(*o, server != nullptr);
    } catch (const ClientError& e) {
      if (server) {
        server->shutdown();
        server_thread.join();
      }
      throw CommandError(std::string("bench-service: ") + e.what());
    }
    if (server) {
      server->shutdown();
      server_thread.join();
    }
    if (o->json) {
      std::cout << out.dump() << "\n";
      return;
    }
    std::cout << "server " << o->connect << "\n";
    if (out.contains("query")) {
      const json& q = out["query"];
      std::cout << std::fixed << std::setprecision(0) << "map.query: " << q["clients"]
                << " clients x " << q["points_per_request"] << " points"
                << (o->rate > 0 ? " at " + std::to_string(int(o->rate)) + " Hz each" : "") << ": "
                << q["requests_per_s"].get<double>() << " requests/s, "
                << q["points_per_s"].get<double>() << " points/s ("
                << q["points_encoding"].get<std::string>() << "), failures " << q["failures"]
                << "\n";
      print_latency("  latency: ", q);
    }
    for (const char* key : {"plan_overhead", "plan_overhead_json_samples"}) {
      if (!out.contains(key)) continue;
      const json& p = out[key];
      std::cout << "worker overhead (" << p["op"].get<std::string>()
                << (p.contains("samples") ? ", samples as " + p["samples"].get<std::string>() : "")
                << ", round trip minus own compute time):\n";
      print_latency("  overhead: ", p);
      if (p.contains("planner_outside_solve"))
        print_latency("  planner outside the solve (build, sampling, dense checks): ",
                      p["planner_outside_solve"]);
      if (p.contains("note")) std::cout << "  note: " << p["note"].get<std::string>() << "\n";
    }
    if (out.contains("replan")) print_replan(out["replan"]);
    if (out.contains("hostile")) {
      const json& h = out["hostile"];
      std::cout << "hostile (server limits " << h["server_limits"].dump() << "):\n";
      for (const json& c : h["cases"]) {
        std::cout << std::fixed << std::setprecision(1) << "  " << c["name"].get<std::string>()
                  << " (" << c["seconds"].get<double>() << " s): " << c["attack"].get<std::string>()
                  << "\n    survived " << (c["survived"].get<bool>() ? "yes" : "NO")
                  << ", server RSS " << c["rss_before_kb"].get<long>() / 1024 << " -> "
                  << c["rss_after_kb"].get<long>() / 1024 << " MiB";
        if (c.contains("rss_while_held_kb"))
          std::cout << " (" << c["rss_while_held_kb"].get<long>() / 1024 << " MiB while held)";
        json rest = c;
        for (const char* k : {"name", "attack", "seconds", "survived", "rss_before_kb",
                              "rss_after_kb", "rss_while_held_kb", "bystanders"})
          rest.erase(k);
        std::cout << "\n    " << rest.dump() << "\n";
        const json& b = c["bystanders"];
        std::cout << std::setprecision(2) << "    well-behaved clients: ";
        if (b.contains("p50_ms"))
          std::cout << b["count"] << " queries, p50 " << b["p50_ms"].get<double>() << " ms, p99 "
                    << b["p99_ms"].get<double>() << " ms, max " << b["max_ms"].get<double>()
                    << " ms, ";
        std::cout << "failures " << b["failures"] << "\n";
      }
    }
  });
}

}  // namespace terrastride::service

int main(int argc, char** argv) {
  terrastride::bench::pin_blas_kernel(argv);
  CLI::App app;
  app.name("bench_service");
  terrastride::service::configure_bench_service(&app);
  return terrastride::service::run_command_line(app, argc, argv);
}
