// `terrastride bench-service`: load tool for the socket service. Measures map.query throughput and
// latency with many concurrent clients, the overhead a worker operation (plan) adds beyond its own
// compute time, and survival of malformed frames and abrupt disconnects while well-behaved clients
// keep getting exact answers.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <iomanip>
#include <iostream>
#include <memory>
#include <mutex>
#include <random>
#include <thread>

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
};

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

// Hostile traffic while `clients` well-behaved clients query; nothing may be lost for them.
json bench_hostile(const BenchOptions& o, const json& extent) {
  std::atomic<bool> keep_going{true};
  BenchOptions good = o;
  QueryRun background;
  std::thread bg([&] { background = run_queries(good, 4, 0, extent, &keep_going); });
  const auto t0 = Clock::now();
  // Malformed frames with intact framing: every one must get an error reply.
  std::uint64_t malformed_replies = 0;
  const int per_conn = 1000;
  for (int sent = 0; sent < o.malformed; sent += per_conn) {
    Client c = connect(o);
    const int n = std::min(per_conn, o.malformed - sent);
    std::string burst;
    for (int i = 0; i < n; ++i) {
      std::string header;
      switch (i % 5) {
        case 0:
          header = "{not json";
          break;
        case 1:
          header = "[1,2,3]";
          break;
        case 2:
          header = R"({"v":1,"id":1,"op":7})";
          break;
        case 3:
          header = R"({"v":1,"id":2,"op":"no.such.op"})";
          break;
        default:
          header = R"({"v":1,"id":3,"op":"map.query","points":[[1,"x"]]})";
          break;
      }
      std::string f(8, '\0');
      protocol::write_u32be(static_cast<std::uint32_t>(4 + header.size()),
                            reinterpret_cast<unsigned char*>(&f[0]));
      protocol::write_u32be(static_cast<std::uint32_t>(header.size()),
                            reinterpret_cast<unsigned char*>(&f[4]));
      burst += f + header;
    }
    std::thread w([&] { c.send_raw(burst); });
    for (int i = 0; i < n; ++i)
      if (!c.receive().header.value("ok", true)) malformed_replies++;
    w.join();
  }
  const double malformed_s = std::chrono::duration<double>(Clock::now() - t0).count();
  // Abrupt disconnects: mid-prefix, mid-body, after a full request, with a job in flight.
  const auto t1 = Clock::now();
  int disconnects = 0;
  for (int i = 0; i < o.disconnects; ++i) {
    Client c = Client::connect(o.connect);
    const std::string f = protocol::encode_frame(
        {{{"v", 1}, {"id", 1}, {"op", "map.query"}, {"points", {{0.0, 0.0}}}}, {}});
    switch (i % 3) {
      case 0:
        c.send_raw(f.substr(0, 2));
        break;
      case 1:
        c.send_raw(f.substr(0, f.size() - 3));
        break;
      default:
        c.send_raw(f);
        break;
    }
    c.close();
    disconnects++;
  }
  const double disconnect_s = std::chrono::duration<double>(Clock::now() - t1).count();
  keep_going = false;
  bg.join();
  json st = connect(o).call_ok({{"op", "status"}});
  return {{"malformed_sent", o.malformed},
          {"malformed_error_replies", malformed_replies},
          {"malformed_s", malformed_s},
          {"disconnects", disconnects},
          {"disconnect_s", disconnect_s},
          {"background_queries", background.latencies_ms.size()},
          {"background_failures", background.failures},
          {"background_latency", latency_json(background.latencies_ms)},
          {"server_connections_open", st["connections"]["open"]},
          {"server_malformed_frames", st["requests"]["malformed_frames"]}};
}

void print_latency(const std::string& label, const json& j) {
  if (!j.contains("p50_ms")) return;
  std::cout << std::fixed << std::setprecision(3) << label << "p50 " << j["p50_ms"].get<double>()
            << " ms, p90 " << j["p90_ms"].get<double>() << " ms, p99 " << j["p99_ms"].get<double>()
            << " ms, max " << j["max_ms"].get<double>() << " ms (" << j["count"] << " samples)\n";
}

}  // namespace

void add_bench_service_command(CLI::App& app) {
  auto o = std::make_shared<BenchOptions>();
  CLI::App* cmd = app.add_subcommand(
      "bench-service",
      "Load-test the socket service: map.query throughput and p50/p99 latency with many clients, "
      "plan overhead, malformed frames and abrupt disconnects");
  cmd->add_option("--connect", o->connect,
                  "Server address (tcp://HOST:PORT or unix:PATH); default: start one in-process "
                  "on an ephemeral loopback port");
  cmd->add_option("--token", o->token, "Token for hello, when the server requires one");
  cmd->add_option("--mode", o->mode, "query, plan, hostile or all")
      ->capture_default_str()
      ->check(CLI::IsMember({"query", "plan", "hostile", "all"}));
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
  cmd->add_option("--workers", o->workers, "Workers of the in-process server")
      ->capture_default_str()
      ->check(CLI::Range(1, 64));
  cmd->add_option("--scene", o->scene, "Scene loaded as the map before the benchmark")
      ->capture_default_str();
  cmd->add_flag("--json-points", o->json_points,
                "Send query points as JSON [[x, y], ...] instead of a float32 attachment");
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
      OperationRegistry reg;
      BackendOptions bo;
      bo.debug_ops = true;
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
    if (out.contains("hostile")) {
      const json& h = out["hostile"];
      std::cout << std::setprecision(2) << "hostile: " << h["malformed_sent"]
                << " malformed frames -> " << h["malformed_error_replies"] << " error replies in "
                << h["malformed_s"].get<double>() << " s; " << h["disconnects"]
                << " abrupt disconnects in " << h["disconnect_s"].get<double>() << " s\n"
                << "  well-behaved clients meanwhile: " << h["background_queries"]
                << " queries, failures " << h["background_failures"] << "\n";
      print_latency("  their latency: ", h["background_latency"]);
    }
  });
}

}  // namespace terrastride::service
