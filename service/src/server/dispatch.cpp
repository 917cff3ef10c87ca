// A connection's requests: the envelope, authentication, the built-in operations (hello, status,
// cancel), the field check, and the run of a registered operation inline or as a worker Job
// (deadline, per-connection and pool limits).
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
                    {"attachment_dtypes", {"float32", "uint8"}},
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
      OpContext ctx{m, token, cid};
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
  job->connection = cid;
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

}  // namespace terrastride::service
