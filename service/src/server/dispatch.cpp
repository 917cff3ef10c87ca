// A connection's requests: the envelope, authentication, the built-in operations (hello, status,
// cancel), the field check, and the run of a registered operation inline or as a worker Job
// (deadline, per-connection and pool limits).
#include <algorithm>
#include <chrono>
#include <functional>
#include <string>
#include <vector>

#include "connection.hpp"

namespace terrastride::service {

namespace pc = protocol::code;
using nlohmann::json;
using protocol::Message;
using protocol::ProtocolError;

void Connection::dispatch(std::string_view body) {
  server.counters.requests++;
  const auto arrival = Clock::now();
  Message m;
  json id = nullptr;
  protocol::Request req;
  try {
    // A header may fill the frame: a plan the server wrote (16 MB of JSON for 120 s at 10 ms) is
    // accepted back as `init` or `plan`; the frame cap bounds it, and a worker request's bytes
    // count against the request-byte budgets while it waits.
    m = protocol::decode_body(body, frame_cap());
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
  if (!authenticated && !authenticate(m, req, id)) return;
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
  const Operation* op = nullptr;
  if (!check_request(m, req, id, &op)) return;
  if (req.op == "hello") return answer_inline(id, req.op, [&] { return hello_result(); });
  if (req.op == "status") {
    return answer_inline(id, req.op, [&] {
      OpResult r;
      r.result = server.status_json();
      return r;
    });
  }
  if (req.op == "cancel") return answer_inline(id, req.op, [&] { return builtin_cancel(m); });
  run_operation(std::move(m), req, id, op, body.size(), arrival);
}

bool Connection::authenticate(const Message& m, const protocol::Request& req, const json& id) {
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
    return false;
  }
  authenticated = true;
  return true;
}

bool Connection::check_request(const Message& m, const protocol::Request& req, const json& id,
                               const Operation** op_out) {
  // The built-in operations' fields (registered operations carry theirs in Operation::fields).
  static const std::vector<std::string> kHelloFields{"token"}, kStatusFields{},
      kCancelFields{"target"}, kNoAttachments;
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
      return false;
    }
    if (op->fields) fields = &*op->fields;
  }
  *op_out = op;
  try {
    if (fields) protocol::check_fields(m.header, req.op, *fields);
  } catch (const ProtocolError& e) {
    send_error(id, e.code(), e.what());
    return false;
  }
  // The attachments the operation reads: another name would be silently ignored.
  const std::vector<std::string>* names =
      !op ? &kNoAttachments : op->attachments ? &*op->attachments : nullptr;
  for (std::size_t i = 0; names && i < m.attachments.size(); ++i) {
    const std::string& name = m.attachments[i].name;
    if (std::find(names->begin(), names->end(), name) != names->end()) continue;
    std::string takes;
    for (const auto& n : *names) takes += (takes.empty() ? "" : ", ") + n;
    const std::string shown = name.size() > 64 ? name.substr(0, 64) + "..." : name;
    send_error(id, pc::kBadRequest,
               "attachments[" + std::to_string(i) + "]: unknown attachment \"" + shown +
                   "\" for op " + req.op +
                   (takes.empty() ? " (it takes none)" : " (it takes: " + takes + ")"));
    return false;
  }
  return true;
}

OpResult Connection::hello_result() const {
  OpResult r;
  const ServerOptions& o = server.options;
  r.result = {{"server", "terrastride"},
              {"version", "0.1.0"},
              {"protocol", protocol::kVersion},
              {"connection", cid},
              {"ops", json::array()},
              {"capabilities",
               {{"max_frame_bytes", o.max_frame_bytes},
                {"attachment_dtypes", {"float32", "uint8"}},
                {"pipelining", true},
                {"deadlines", true},
                {"cancel", true},
                {"workers", server.pool->workers()},
                {"queue", server.pool->capacity()},
                {"token_required", o.token.has_value()},
                {"max_connections", o.max_connections},
                {"frame_timeout_s", o.frame_timeout_s},
                {"min_receive_rate", o.min_receive_rate},
                {"idle_timeout_s", o.idle_timeout_s},
                {"max_jobs_per_connection", o.max_jobs_per_connection},
                {"max_buffered_bytes_per_connection", o.max_buffered_bytes_per_connection},
                {"max_unsent_bytes_per_connection", o.max_write_queue_bytes}}}};
  r.result["ops"] = {"hello", "status", "cancel"};
  for (const auto& n : server.registry.names()) r.result["ops"].push_back(n);
  if (server.hello_extra) r.result.update(server.hello_extra());
  return r;
}

void Connection::run_operation(Message m, const protocol::Request& req, const json& id,
                               const Operation* op, std::size_t frame_bytes,
                               Clock::time_point arrival) {
  // Requests naming a planning session are answered in their order (a close never overtakes
  // the step before it): each waits in the session's lane for the one before it.
  std::string lane;
  if (req.op.rfind("plan.session.", 0) == 0) {
    const auto it = m.header.find("session");
    if (it != m.header.end() && it->is_string()) lane = it->get<std::string>();
  }
  const bool behind = !lane.empty() && lanes.count(lane) && !lanes[lane].empty();
  if (op->kind == OpKind::kInline && !behind) {
    auto token = std::make_shared<CancellationToken>();
    if (req.deadline_ms)
      token->set_deadline(
          arrival + std::chrono::microseconds(static_cast<long long>(*req.deadline_ms * 1000)));
    return answer_inline(id, req.op, [&] {
      OpContext ctx{m, token, cid};
      return op->handler(ctx);
    });
  }

  // A worker job, or an inline request waiting in its session's lane.
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
  job->lane = lane;
  // The request stays in memory until a worker runs it: its frame's bytes count as buffered
  // request bytes (already received, so counted rather than refused; the next large frame sees
  // them).
  job->request_bytes.add(server.budget, frame_bytes);
  job->connection_bytes.add(own_budget, frame_bytes);
  job->conn = weak_from_this();
  job->connection = cid;
  if (req.deadline_ms) {
    const auto deadline =
        arrival + std::chrono::microseconds(static_cast<long long>(*req.deadline_ms * 1000));
    job->token->set_deadline(deadline);
    job->deadline_timer = std::make_unique<asio::steady_timer>(server.io, deadline);
  }
  if (behind) {
    job->waiting = true;
  } else if (!submit_job(job)) {
    return;
  }
  inflight[job->key] = job;
  if (!lane.empty()) lanes[lane].push_back(job);
  if (job->deadline_timer) watch_deadline(job);
}

void Connection::watch_deadline(const std::shared_ptr<Job>& job) {
  std::weak_ptr<Connection> wc = weak_from_this();
  job->deadline_timer->async_wait([wc, job](const asio::error_code& ec) {
    auto c = wc.lock();
    if (ec || !c || job->replied) return;
    job->token->cancel(CancellationToken::Reason::kDeadline);
    if (c->server.pool->try_remove(job)) c->leave_pool(job);
    c->server.counters.deadline_exceeded++;
    c->abort_job(job, pc::kDeadlineExceeded,
                 std::string("deadline exceeded ") + (job->running ? "while running" : "in queue") +
                     " ('" + job->op->name + "')");
  });
}

void Connection::answer_inline(const json& id, const std::string& op,
                               const std::function<OpResult()>& fn) {
  try {
    OpResult r = fn();
    server.counters.replies_ok++;
    const Message reply = protocol::make_reply(
        id, r.result_text.empty() ? std::move(r.result) : json(), std::move(r.attachments));
    send(protocol::encode_frame(reply, r.result_text));
  } catch (const ProtocolError& e) {
    send_error(id, e.code(), e.what());
  } catch (const std::exception& e) {
    send_error(id, pc::kFailed, op + ": " + e.what());
  }
}

bool Connection::submit_job(const std::shared_ptr<Job>& job) {
  if (pool_jobs >= server.options.max_jobs_per_connection) {
    server.counters.busy++;
    send_error(job->id, pc::kBusy,
               "this connection has " + std::to_string(pool_jobs) +
                   " requests queued or running, its quota (--max-jobs-per-connection); retry "
                   "when one is answered");
    return false;
  }
  if (!server.pool->try_submit(job)) {
    server.counters.busy++;
    send_error(job->id, pc::kBusy,
               "all " + std::to_string(server.pool->workers()) + " workers busy and the queue of " +
                   std::to_string(server.pool->capacity()) + " is full; retry later");
    return false;
  }
  job->in_pool = true;
  pool_jobs++;
  return true;
}

void Connection::start_job(const std::shared_ptr<Job>& job) {
  job->waiting = false;
  if (server.draining) {
    abort_job(job, pc::kShuttingDown, "server is shutting down; request '" + job->op->name +
                                          "' refused");
    return;
  }
  if (job->op->kind == OpKind::kInline) {
    inflight.erase(job->key);
    job->replied = true;
    if (job->deadline_timer) job->deadline_timer->cancel();
    answer_inline(job->id, job->op->name, [&] {
      OpContext ctx{job->request, job->token, cid};
      return job->op->handler(ctx);
    });
    job_answered(job);
    return;
  }
  if (submit_job(job)) return;
  // Answered busy: it leaves its lane for the next request.
  if (job->deadline_timer) job->deadline_timer->cancel();
  inflight.erase(job->key);
  job->replied = true;
  job_answered(job);
}

void Connection::job_answered(const std::shared_ptr<Job>& job) {
  if (job->lane.empty() || closed) return;
  const auto it = lanes.find(job->lane);
  if (it == lanes.end()) return;
  auto& lane = it->second;
  const bool was_front = !lane.empty() && lane.front() == job;
  lane.erase(std::remove(lane.begin(), lane.end(), job), lane.end());
  if (lane.empty()) {
    lanes.erase(it);
    return;
  }
  // The next request of the session starts once the one before it is answered (it may answer
  // at once, and start the one after it).
  if (was_front) start_job(std::shared_ptr<Job>(lane.front()));
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
  bool queued = job->waiting;
  if (server.pool->try_remove(job)) {
    leave_pool(job);
    queued = true;
  }
  job->token->cancel(CancellationToken::Reason::kCancelled);
  server.counters.cancelled++;
  r.result = {{"target", *t}, {"cancelled", true}, {"state", queued ? "queued" : "running"}};
  abort_job(job, pc::kCancelled, "request cancelled by cancel (id " + job->key + ")");
  return r;
}

}  // namespace terrastride::service
