// plan.session.open / plan.session.step / plan.session.close: planning sessions over the socket
// (docs/protocol.md, "Planning sessions"). A session is a planner::PlanningSession (the reference
// plan, the terrain, the previous step's solution) owned by the connection that opened it: it
// ends on close, when that connection closes, after BackendOptions::session_idle_timeout_s
// without a step, or when the server is full and it is the longest idle. Steps run in
// the server process (one solve at a time per process: Debian's MUMPS is not re-entrant), so they
// pay no process start; a session's steps run one at a time.

#include <algorithm>
#include <chrono>
#include <cmath>
#include <deque>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "common/plan_request.hpp"
#include "server/backend.hpp"
#include "server/samples_table.hpp"
#include "server/thread_priority.hpp"
#include "common/terrain_source.hpp"
#include "terrastride/planner/plan_io.hpp"
#include "terrastride/planner/planning_session.hpp"
#include "terrastride/planner/request_limits.hpp"

namespace terrastride::service {

namespace pc = protocol::code;
using nlohmann::json;
using protocol::ProtocolError;

namespace {

using Clock = std::chrono::steady_clock;

struct Session {
  std::string id;
  std::uint64_t connection = 0;
  // What the planner session reads, kept alive with it.
  std::shared_ptr<const MapSnapshot> snapshot;
  std::shared_ptr<const SceneRaster> raster;
  std::unique_ptr<terrain::TerrainMap> owned_terrain;
  std::string terrain;
  double sample_dt = 0.01;
  std::unique_ptr<planner::PlanningSession> planner;
  std::timed_mutex step_mu;  // one step at a time
  Clock::time_point last_used = Clock::now();
  // How long a step's reply took to be ready after the step returned (a decaying maximum): kept
  // from the next step's budget so that the reply, not only the plan, is ready by it (the
  // session keeps its own lateness out of the budget too).
  double reply_s = 0.002;
};

// A step's default budget (plan.session.step "budget_ms"): a control loop at 10-20 Hz.
constexpr double kDefaultStepBudgetMs = 50.0;

// A budgeted step's thread at a real-time priority (SCHED_FIFO) for the step and its reply, where
// the process may (root, CAP_SYS_NICE, an rtprio limit); a step without a budget, which solves on
// this thread, at the normal policy. The server's worker keeps the priority while it waits for
// its next job (Operation::keeps_priority): restored at the op's end, the thread was preempted
// before its reply left, and woken at the normal policy it started the next step late (together
// 10-45 ms of the round trip at load 13). The
// step sleeps until its solve finishes or its answer is due, and at that moment has to win a
// core from its own solve and any other process: at the normal policy a loaded machine's
// scheduler woke it 5-35 ms late (the answer is a few milliseconds of work: the fallback is
// made while the solve runs). The work under it is bounded (no solve runs on this thread), and
// the kernel's real-time throttling leaves the rest of the machine its share regardless.
class RealtimeForStep {
 public:
  explicit RealtimeForStep(bool wanted) {
    if (wanted)
      active_ = raise_to_realtime();
    else
      return_to_normal_policy();
  }
  RealtimeForStep(const RealtimeForStep&) = delete;
  RealtimeForStep& operator=(const RealtimeForStep&) = delete;
  bool active() const { return active_; }

 private:
  bool active_ = false;
};

double ms_between(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double, std::milli>(b - a).count();
}

// The memory one session may hold (its reference and previous plans).
constexpr std::size_t kMaxSessionBytes = std::size_t{16} << 20;
// Ids of evicted sessions remembered, so a step on one says why it is gone.
constexpr std::size_t kEvictedIdsKept = 256;

// The open sessions under the limits of BackendOptions: max_sessions per server (when full, the
// longest idle session not in a step is closed for a new one: an idle session cannot keep every
// other client out), max_sessions_per_connection, session_idle_timeout_s.
class SessionTable {
  // Sessions taken out of the table, destroyed after its lock is released: a session's
  // destructor joins its solver thread, which may be within one long iteration.
  using Graveyard = std::vector<std::shared_ptr<Session>>;

 public:
  explicit SessionTable(const BackendOptions& o)
      : limit_(static_cast<std::size_t>(o.max_sessions)),
        per_connection_(static_cast<std::size_t>(o.max_sessions_per_connection)),
        idle_timeout_s_(o.session_idle_timeout_s) {}

  // Throws busy when `connection` holds its quota already (checked before a reference solve, and
  // again when the session is added).
  void check_quota(std::uint64_t connection) {
    Graveyard closed;
    std::lock_guard<std::mutex> lock(mu_);
    expire_locked(&closed);
    check_quota_locked(connection);
  }
  void add(std::shared_ptr<Session> s) {
    Graveyard closed;
    std::lock_guard<std::mutex> lock(mu_);
    expire_locked(&closed);
    check_quota_locked(s->connection);
    if (sessions_.size() >= limit_ && !evict_longest_idle_locked(&closed))
      throw ProtocolError(pc::kBusy, "the server holds " + std::to_string(limit_) +
                                         " planning sessions (--max-sessions), every one in a "
                                         "step; retry later");
    sessions_[s->id] = std::move(s);
  }
  // The session `id` of `connection`; bad_request naming why it is not there otherwise.
  std::shared_ptr<Session> get(const std::string& id, std::uint64_t connection) {
    Graveyard closed;
    std::lock_guard<std::mutex> lock(mu_);
    expire_locked(&closed);
    const auto it = sessions_.find(id);
    if (it == sessions_.end() || it->second->connection != connection) {
      if (std::find(evicted_ids_.begin(), evicted_ids_.end(), id) != evicted_ids_.end())
        throw ProtocolError(pc::kBadRequest,
                            "session: \"" + id +
                                "\" was closed to make room for another client's session (the "
                                "server held --max-sessions and it was the longest idle); open a "
                                "new one");
      throw ProtocolError(pc::kBadRequest,
                          "session: no open session \"" + id +
                              "\" on this connection (closed, expired after " +
                              std::to_string(static_cast<int>(idle_timeout_s_)) +
                              " s idle, or opened on another connection)");
    }
    it->second->last_used = Clock::now();
    return it->second;
  }
  bool close(const std::string& id, std::uint64_t connection) {
    Graveyard closed;
    std::lock_guard<std::mutex> lock(mu_);
    const auto it = sessions_.find(id);
    if (it == sessions_.end() || it->second->connection != connection) return false;
    closed.push_back(std::move(it->second));
    sessions_.erase(it);
    return true;
  }
  void close_connection(std::uint64_t connection) {
    Graveyard closed;
    std::lock_guard<std::mutex> lock(mu_);
    for (auto it = sessions_.begin(); it != sessions_.end();) {
      if (it->second->connection != connection) {
        ++it;
        continue;
      }
      closed.push_back(std::move(it->second));
      it = sessions_.erase(it);
    }
  }
  std::string next_id() {
    std::lock_guard<std::mutex> lock(mu_);
    return "s" + std::to_string(++counter_);
  }
  json status() {
    Graveyard closed;
    std::lock_guard<std::mutex> lock(mu_);
    expire_locked(&closed);
    return {{"open", sessions_.size()},          {"limit", limit_},
            {"per_connection", per_connection_}, {"opened", counter_},
            {"evicted", evicted_},               {"idle_timeout_s", idle_timeout_s_}};
  }

 private:
  void check_quota_locked(std::uint64_t connection) const {
    const auto held = std::count_if(sessions_.begin(), sessions_.end(), [&](const auto& entry) {
      return entry.second->connection == connection;
    });
    if (static_cast<std::size_t>(held) >= per_connection_)
      throw ProtocolError(pc::kBusy, "this connection holds " + std::to_string(held) +
                                         " planning sessions, its quota "
                                         "(--max-sessions-per-connection); close one first");
  }
  // Closes the session idle longest among those not in a step; false when every one is.
  bool evict_longest_idle_locked(Graveyard* closed) {
    auto victim = sessions_.end();
    for (auto it = sessions_.begin(); it != sessions_.end(); ++it) {
      std::unique_lock<std::timed_mutex> stepping(it->second->step_mu, std::try_to_lock);
      if (!stepping.owns_lock()) continue;
      if (victim == sessions_.end() || it->second->last_used < victim->second->last_used)
        victim = it;
    }
    if (victim == sessions_.end()) return false;
    evicted_ids_.push_back(victim->first);
    if (evicted_ids_.size() > kEvictedIdsKept) evicted_ids_.pop_front();
    evicted_++;
    closed->push_back(std::move(victim->second));
    sessions_.erase(victim);
    return true;
  }
  void expire_locked(Graveyard* closed) {
    if (idle_timeout_s_ <= 0) return;
    const auto now = Clock::now();
    for (auto it = sessions_.begin(); it != sessions_.end();) {
      const double idle = std::chrono::duration<double>(now - it->second->last_used).count();
      if (!(idle > idle_timeout_s_)) {
        ++it;
        continue;
      }
      closed->push_back(std::move(it->second));
      it = sessions_.erase(it);
    }
  }
  const std::size_t limit_, per_connection_;
  const double idle_timeout_s_;
  std::mutex mu_;
  std::map<std::string, std::shared_ptr<Session>> sessions_;
  std::deque<std::string> evicted_ids_;
  std::uint64_t counter_ = 0, evicted_ = 0;
};

double number_field(const json& h, const char* key, double fallback) {
  if (!h.contains(key)) return fallback;
  if (!h[key].is_number() || !std::isfinite(h[key].get<double>()))
    throw ProtocolError(pc::kBadRequest, std::string(key) + ": must be a finite number");
  return h[key].get<double>();
}

std::string session_field(const json& h) {
  if (!h.contains("session") || !h["session"].is_string())
    throw ProtocolError(pc::kBadRequest, "session: the id plan.session.open returned (a string)");
  return h["session"].get<std::string>();
}

// The deadline of a request as the solver's budget (as `plan` does).
void apply_deadline(OpContext& ctx, planner::PlannerOptions* po) {
  po->should_stop = CancellationToken::as_callback(ctx.token);
  if (ctx.token->has_deadline()) {
    const double left =
        std::chrono::duration<double>(ctx.token->deadline() - Clock::now()).count();
    if (left <= 0) ctx.check_stop();
    po->max_time = po->max_time > 0 ? std::min(po->max_time, left) : left;
  }
}

json plan_reply(const planner::Trajectory& t, const Session& s, const planner::SessionStep* step) {
  json r = planner::plan_to_json(t);
  r["session"] = s.id;
  if (step) {
    r["start_time"] = step->start_time;
    r["end_time"] = step->end_time;
    r["to_goal"] = step->to_goal;
  }
  r["memory_bytes"] = s.planner->memory_bytes();
  return r;
}

OpResult open_session(Backend& backend, SessionTable& table, OpContext& ctx) {
  table.check_quota(ctx.connection);  // before the reference solve it would waste
  json fields = ctx.request.header;
  const double horizon = number_field(fields, "horizon", 0.0);
  if (!(horizon >= 0.0) || horizon > planner::PlanLimits::kMaxDuration)
    throw ProtocolError(pc::kBadRequest, "horizon: must be within [0, " +
                                             std::to_string(planner::PlanLimits::kMaxDuration) +
                                             "] s (0 = every step plans to the goal)");
  for (const char* envelope : protocol::kEnvelopeKeys) fields.erase(envelope);
  fields.erase("horizon");
  gait_name(fields);
  PlanRequest req;
  try {
    req = read_plan_request(fields, backend.robot());
  } catch (const RequestFieldError& e) {
    throw ProtocolError(pc::kBadRequest, e.what());
  }
  auto s = std::make_shared<Session>();
  s->terrain = req.terrain;
  s->sample_dt = req.sample_dt;
  s->connection = ctx.connection;
  const terrain::HeightField* plan_field = nullptr;
  const terrain::HeightField* check_field = nullptr;
  try {
    if (req.terrain == "current") {
      s->snapshot = backend.map();
      if (!s->snapshot) throw ProtocolError(pc::kNoMap, "plan.session.open on \"current\": no map");
      if (const auto* sc = dynamic_cast<const terrain::Scene*>(s->snapshot->field.get())) {
        s->raster =
            backend.scene_raster(s->snapshot->source.substr(s->snapshot->source.find(':') + 1));
        plan_field = s->raster->smooth.get();
        check_field = sc;
      } else {
        plan_field = check_field = s->snapshot->field.get();
      }
    } else {
      if (terrain::is_scene_name(req.terrain)) {
        s->raster = backend.scene_raster(req.terrain);
        plan_field = s->raster->smooth.get();
        check_field = s->raster->scene.get();
      } else {
        s->owned_terrain =
            terrain::load_terrain_dir(backend.terrain_dir_path(req.terrain, "terrain"));
        plan_field = check_field = s->owned_terrain.get();
      }
    }
    check_stances_on_terrain(req, backend.robot(), *check_field);
  } catch (const perception::InputError& e) {
    throw ProtocolError(pc::kBadRequest, "\"terrain\" " + req.terrain + ": " + e.what());
  } catch (const RequestFieldError& e) {
    throw ProtocolError(pc::kBadRequest, e.what());
  }
  planner::PlannerOptions po = req.options;
  apply_deadline(ctx, &po);
  // The reference plan: the client's ("init": a plan.json, e.g. the plan a simulator or robot
  // executes, with its options), else a cold solve from rest, as `plan` makes it.
  planner::PlanOutcome cold;
  if (req.replan) {
    if (req.start_time != 0.0 || req.has_start_state)
      throw ProtocolError(pc::kBadRequest,
                          "init: a session's reference is followed from its start (no start_time "
                          "or start_state at open; send the state with plan.session.step)");
    cold.trajectory = req.previous;
  } else {
    try {
      cold = planner::plan_motion(backend.robot(), *plan_field, *check_field, po, req.sample_dt);
    } catch (const planner::GaitError& e) {
      throw ProtocolError(pc::kBadRequest, std::string("\"gait\": ") + e.what());
    } catch (const std::invalid_argument& e) {
      throw ProtocolError(pc::kBadRequest, e.what());
    }
    ctx.check_stop();
    if (!cold.success)
      throw ProtocolError(pc::kFailed, "plan.session.open: the reference plan failed: " +
                                           cold.message);
  }
  po.should_stop = nullptr;
  po.max_time = req.options.max_time;
  try {
    s->planner = std::make_unique<planner::PlanningSession>(
        backend.robot(), *plan_field, *check_field, po, cold.trajectory, horizon, req.sample_dt);
  } catch (const std::invalid_argument& e) {
    throw ProtocolError(pc::kBadRequest, e.what());
  }
  if (s->planner->memory_bytes() > kMaxSessionBytes)
    throw ProtocolError(pc::kBadRequest,
                        "the session would hold " + std::to_string(s->planner->memory_bytes()) +
                            " bytes, more than the " + std::to_string(kMaxSessionBytes) +
                            " a session may (a larger sample_dt or a shorter plan)");
  s->id = table.next_id();
  table.add(s);
  OpResult r;
  r.result = plan_reply(s->planner->reference(), *s, nullptr);
  r.result["horizon"] = horizon;
  r.result["success"] = true;
  return r;
}

OpResult step_session(Backend& backend, SessionTable& table, OpContext& ctx) {
  const auto op_start = Clock::now();
  const json& h = ctx.request.header;
  const auto s = table.get(session_field(h), ctx.connection);
  // A step waits for the one before it (which may still be stopping after its deadline's reply
  // went out), within its own deadline.
  std::unique_lock<std::timed_mutex> lock(s->step_mu, std::defer_lock);
  while (!lock.try_lock_for(std::chrono::milliseconds(2))) ctx.check_stop();
  if (!h.contains("time"))
    throw ProtocolError(pc::kBadRequest, "time: the session time (s) of the measured state");
  const double t = number_field(h, "time", 0.0);
  const bool samples_ok = !h.contains("samples") || h["samples"].is_string();
  const std::string samples = samples_ok ? h.value("samples", std::string("json")) : "";
  if (samples != "json" && samples != "attachment")
    throw ProtocolError(pc::kBadRequest, "samples: must be \"json\" or \"attachment\"");
  planner::PlanningSession& ps = *s->planner;
  // Fields the client leaves out of its state are the session's current plan's at t.
  planner::SrbdProblem::StartState measured;
  try {
    const bool on_previous =
        t >= ps.previous_start_time() && t <= ps.previous_start_time() + ps.previous().duration;
    const planner::Trajectory& from = on_previous ? ps.previous() : ps.reference();
    const double at = on_previous ? t - ps.previous_start_time() : t;
    if (!(t >= 0.0 && t < ps.reference().duration))
      throw RequestFieldError("time", "must be within the session's plan [0, " +
                                          std::to_string(ps.reference().duration) + ") s");
    measured = h.contains("start_state")
                   ? planner::start_state_from_json(h["start_state"], "start_state", from, at)
                   : ps.planned_state(t);
  } catch (const std::invalid_argument& e) {
    throw ProtocolError(pc::kBadRequest, e.what());
  } catch (const planner::PlanFileError& e) {
    // A malformed start_state ("start_state: feet.LF.position: must be ..."): the client's
    // mistake, answered bad_request as `plan` answers the same field.
    throw ProtocolError(pc::kBadRequest, e.what());
  }
  // The step's budget: it answers by then with its solve's plan or the fallback. The request's
  // deadline, when shorter, bounds it too (and past it the reply is deadline_exceeded).
  const double budget_ms = number_field(h, "budget_ms", kDefaultStepBudgetMs);
  if (!(budget_ms >= 0.0 && budget_ms <= 60000.0))
    throw ProtocolError(pc::kBadRequest,
                        "budget_ms: must be within [0, 60000] (0 = no budget: wait for the solve)");
  planner::PlannerOptions po;
  apply_deadline(ctx, &po);
  // "budget_iterations": the deadline counted in solver iterations instead (budget_ms 0 then;
  // a simulation's closed loop, whose answers must not depend on the machine's load).
  const double budget_iterations = number_field(h, "budget_iterations", 0.0);
  if (!(budget_iterations >= 0.0 && budget_iterations <= 1000.0 &&
        budget_iterations == std::floor(budget_iterations)))
    throw ProtocolError(pc::kBadRequest,
                        "budget_iterations: must be a whole number within [0, 1000] (0 = none)");
  if (budget_iterations > 0.0 && h.contains("budget_ms") && budget_ms > 0.0)
    throw ProtocolError(pc::kBadRequest,
                        "budget_ms and budget_iterations: give one of them (budget_iterations "
                        "counts the step's deadline in solver iterations, budget_ms in time)");
  planner::StepLimits limits{po.should_stop, po.max_time,
                             budget_iterations > 0.0 ? 0.0 : 1e-3 * budget_ms, 0.0,
                             static_cast<int>(budget_iterations)};
  if (limits.budget > 0.0 && po.max_time > 0.0) limits.budget = std::min(limits.budget, po.max_time);
  // That time, plus 5 ms for the socket and the client's parsing, and the time this request has
  // spent here already (the previous step's lock, the state's parsing) come out of the budget.
  const auto step_called = Clock::now();
  if (limits.budget > 0.0)
    limits.reserve = std::min(s->reply_s + 0.005 + 1e-3 * ms_between(op_start, step_called),
                              0.6 * limits.budget);
  const RealtimeForStep realtime(limits.budget > 0.0);
  planner::SessionStep step;
  try {
    step = ps.step(measured, t, limits);
  } catch (const std::invalid_argument& e) {
    throw ProtocolError(pc::kBadRequest, e.what());
  }
  const auto step_returned = Clock::now();
  ctx.check_stop();
  if (!step.outcome.success) {
    if (step.outcome.solve.status == "time_limit")
      throw ProtocolError(pc::kDeadlineExceeded,
                          "session " + s->id + ": " + step.outcome.message);
    throw ProtocolError(pc::kFailed, "session " + s->id + ": " + step.outcome.message);
  }
  s->last_used = Clock::now();
  OpResult r;
  // "attachment": a float32 table instead of ~200 KB of JSON samples (a 1 s horizon on pallet_15
  // at sample_dt 0.01): the reply's JSON was ~5 ms of a ~60 ms step, client-observed.
  r.result = plan_result(step.outcome.trajectory, samples, &r.attachments,
                         [&](const planner::Trajectory& t) { return plan_reply(t, *s, &step); });
  r.result["success"] = true;
  r.result["fallback"] = step.fallback;
  if (step.fallback) {
    r.result["fallback_reason"] = step.fallback_reason;
    r.result["message"] = step.outcome.message;
  }
  r.result["budget_ms"] = limits.budget > 0.0 ? budget_ms : 0.0;
  if (limits.iterations > 0) r.result["budget_iterations"] = limits.iterations;
  r.result["step_ms"] = 1e3 * step.wall_s;
  r.result["warm_from_late_solve"] = step.warm_from_late_solve;
  const auto reply_built = Clock::now();
  // Where the step's time went in this process (the client sees the socket's on top): before
  // the step (the session's lock, the state), the step, how late it returned after its answer
  // was due, the reply's building; and whether the step ran at a real-time priority.
  r.result["timing_ms"] = {{"before_step", ms_between(op_start, step_called)},
                           {"step", 1e3 * step.wall_s},
                           {"answer_late", 1e3 * step.answer_late_s},
                           {"reply", ms_between(step_returned, reply_built)},
                           {"realtime", realtime.active()}};
  s->reply_s = std::max(0.9 * s->reply_s,
                        std::chrono::duration<double>(reply_built - step_returned).count());
  // The reply's JSON text made here, at the step's priority, rather than by the worker after.
  r.result_text = r.result.dump();
  (void)backend;
  return r;
}

}  // namespace

void add_plan_session_operation(Backend& backend, OperationRegistry& registry) {
  Backend* b = &backend;
  auto table = std::make_shared<SessionTable>(backend.options());
  registry.on_disconnect([table](std::uint64_t connection) { table->close_connection(connection); });
  registry.add({"plan.session.open", OpKind::kWorker,
                "open a planning session: plan the reference motion, keep it for re-plans",
                [b, table](OpContext& c) { return open_session(*b, *table, c); },
                std::vector<std::string>{"terrain", "gait", "cycles", "duration", "goal",
                                         "constraints", "feasibility", "sample_dt", "max_time",
                                         "horizon", "init"}});
  registry.add({"plan.session.step", OpKind::kWorker,
                "re-plan a session from a measured state at a session time",
                [b, table](OpContext& c) { return step_session(*b, *table, c); },
                std::vector<std::string>{"session", "time", "start_state", "samples", "budget_ms",
                                         "budget_iterations"},
                std::vector<std::string>{}, /*keeps_priority=*/true});
  registry.add({"plan.session.close", OpKind::kInline, "close a planning session",
                [table](OpContext& c) {
                  OpResult r;
                  r.result["closed"] = table->close(session_field(c.request.header), c.connection);
                  return r;
                },
                std::vector<std::string>{"session"}});
  registry.add({"plan.session.status", OpKind::kInline, "planning sessions open on this server",
                [table](OpContext&) {
                  OpResult r;
                  r.result = table->status();
                  return r;
                },
                std::vector<std::string>{}});
}

}  // namespace terrastride::service
