// A connection's transport: reading frames into its buffer or a large-frame buffer under the
// request-byte budget, writing replies with backpressure, timeouts, and the graceful close.
// Requests are dispatched in dispatch.cpp.
#include "connection.hpp"

#include <algorithm>
#include <cstdio>
#include <cstring>
#include <functional>

namespace terrastride::service {

namespace pc = protocol::code;
using nlohmann::json;
using protocol::Message;
using protocol::ProtocolError;

void Connection::read_more() {
  if (closed || read_pending || (close_after_flush && !lingering)) return;
  read_pending = true;
  auto self = shared_from_this();
  socket.async_wait(asio::socket_base::wait_read,
                    [self](const asio::error_code& ec) { self->on_readable(ec); });
}

void Connection::on_readable(asio::error_code ec) {
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
  last_active = last_received = Clock::now();
  if (large.data()) {
    large_have += n;
    large_bytes.add(server.budget, n);
    large_own_bytes.add(own_budget, n);
    if (server.budget->used.load() > server.budget->limit)
      return refuse_for_budget(large.size(), false);
    if (own_budget->used.load() > own_budget->limit) return refuse_for_budget(large.size(), true);
  } else {
    in_end += n;
  }
  process_frames();
}

void Connection::free_large() {
  large.reset();
  large_have = 0;
  large_bytes.release();
  large_own_bytes.release();
}

std::uint32_t Connection::frame_cap() const {
  return authenticated ? server.options.max_frame_bytes
                       : std::min(server.options.max_frame_bytes,
                                  server.options.max_frame_bytes_before_hello);
}

void Connection::process_frames() {
  while (!closed && !close_after_flush) {
    if (out_bytes > kPauseReadBytes) {
      read_paused = true;
      return;
    }
    if (large.data()) {
      if (large_have < large.size()) break;
      // Moved out first: whatever dispatch does (even closing), the body stays valid.
      FrameBuffer frame = std::move(large);
      BudgetHold held = std::move(large_bytes), held_own = std::move(large_own_bytes);
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

bool Connection::start_large(std::size_t total) {
  const std::size_t have = in_end - in_start;
  if (!server.budget->fits(total) || !own_budget->fits(total)) {
    refuse_for_budget(total, server.budget->fits(total));
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
  large_own_bytes.add(own_budget, have);
  in_start = in_end = 0;
  return true;
}

void Connection::refuse_for_budget(std::size_t frame_bytes, bool own) {
  server.budget->refused++;
  server.counters.busy++;
  const std::string holder = own ? "this connection holds " : "the server holds ";
  const ByteBudget& b = own ? *own_budget : *server.budget;
  send_error(nullptr, pc::kBusy,
             "frame of " + std::to_string(frame_bytes) + " bytes refused: " + holder +
                 std::to_string(b.used.load()) + " bytes of requests and its budget is " +
                 std::to_string(b.limit) +
                 (own ? " (--max-buffered-bytes-per-connection)" : " (--max-buffered-bytes)") +
                 "; connection closed, retry later");
  finish_and_close();
}

void Connection::evict(double idle_s) {
  server.counters.evicted_connections++;
  char text[64];
  std::snprintf(text, sizeof(text), "%.3g s", idle_s);
  send_error(nullptr, pc::kBusy,
             "connection closed for a new client: the server holds " +
                 std::to_string(server.options.max_connections) +
                 " connections (--max-connections) and this one was idle longest (" + text + ")");
  finish_and_close();
  uncount();  // its slot is the new client's now, while the reply goes out
}

double Connection::seconds_behind(Clock::time_point now) const {
  if (writing.empty()) return 0.0;
  const double elapsed = std::chrono::duration<double>(now - write_start).count();
  return elapsed - double(write_done) / server.options.min_receive_rate;
}

void Connection::drop_unread(const std::string& reason) {
  std::fprintf(stderr, "terrastride serve: connection %llu dropped: %s\n",
               static_cast<unsigned long long>(cid), reason.c_str());
  close();
}

void Connection::send(std::string frame) {
  if (closed || lingering) return;
  server.counters.bytes_out += frame.size();
  out_bytes += frame.size();
  server.unsent_bytes += frame.size();
  last_active = Clock::now();
  out.push_back(std::move(frame));
  if (out_bytes > server.options.max_write_queue_bytes) {
    // A client that does not read its replies: drop it rather than grow without bound.
    server.counters.slow_client_drops++;
    return drop_unread(std::to_string(out_bytes) + " bytes of replies unsent, beyond " +
                       std::to_string(server.options.max_write_queue_bytes) +
                       " (--max-unsent-bytes-per-connection)");
  }
  if (server.unsent_bytes > server.options.max_unsent_bytes) {
    auto self = shared_from_this();  // the budget may drop this connection
    server.enforce_unsent_budget();
    if (closed) return;
  }
  if (writing.empty()) do_write();
}

void Connection::send_message(const Message& m) {
  try {
    send(protocol::encode_frame(m));
  } catch (const ProtocolError& e) {
    send(protocol::encode_frame(
        protocol::make_error(m.header.value("id", json()), pc::kInternal, e.what())));
  }
}

void Connection::send_error(const json& id, const std::string& code, const std::string& message) {
  server.count_error(code);
  send(protocol::encode_frame(protocol::make_error(id, code, message)));
}

void Connection::do_write() {
  if (closed) return;
  if (out.empty()) {
    if (close_after_flush) linger();
    return;
  }
  while (!out.empty() && writing.size() < 64) {
    writing.push_back(std::move(out.front()));
    out.pop_front();
  }
  write_bytes = write_done = 0;
  for (const auto& w : writing) write_bytes += w.size();
  write_start = write_progress = Clock::now();
  write_some();
}

void Connection::write_some() {
  // The rest of the batch; written piece by piece so the sweep sees whether the client takes
  // its replies at all (write_progress), not only whether a whole batch is done.
  std::vector<asio::const_buffer> bufs;
  std::size_t skip = write_done;
  for (const auto& w : writing) {
    if (skip >= w.size()) {
      skip -= w.size();
      continue;
    }
    bufs.emplace_back(asio::buffer(w.data() + skip, w.size() - skip));
    skip = 0;
  }
  auto self = shared_from_this();
  socket.async_write_some(bufs, [self](const asio::error_code& ec, std::size_t n) {
    if (!ec) {
      if (n > 0) {
        self->write_done += n;
        self->write_progress = self->last_active = Clock::now();
      }
      if (self->write_done < self->write_bytes) return self->write_some();
    }
    self->end_write(ec);
  });
}

void Connection::end_write(const asio::error_code& ec) {
  if (write_bytes >= kPauseReadBytes) server.trim_pending = true;
  for (const auto& w : writing) {
    out_bytes -= w.size();
    // close() took a closed connection's bytes off the server's count already.
    if (!closed) server.unsent_bytes -= w.size();
  }
  writing.clear();
  write_bytes = write_done = 0;
  if (ec) return close();
  if (read_paused && out_bytes <= kPauseReadBytes / 2) {
    read_paused = false;
    // The frame clock stopped while the server did not read.
    if (frame_started) frame_start = last_received = Clock::now();
    process_frames();
  }
  do_write();
}

void Connection::finish_and_close() {
  close_after_flush = true;
  free_large();
  abandon_jobs();
  if (out.empty() && writing.empty()) linger();
}

void Connection::linger() {
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

void Connection::uncount() {
  if (!counted) return;
  counted = false;
  server.active_connections--;
  server.counters.connections_open--;
}

void Connection::abandon_jobs() {
  for (auto& [key, job] : inflight) {
    job->replied = true;
    job->token->cancel(CancellationToken::Reason::kCancelled);
    if (job->deadline_timer) job->deadline_timer->cancel();
    if (server.pool->try_remove(job)) leave_pool(job);
  }
  inflight.clear();
  lanes.clear();
}

void Connection::close() {
  if (closed) return;
  closed = true;
  uncount();
  if (lingering) server.lingering--;
  asio::error_code ignored;
  socket.shutdown(asio::socket_base::shutdown_both, ignored);
  socket.close(ignored);
  // Unsent replies leave the server's count now; those not yet handed to the socket are freed
  // now, those being written when the aborted write ends.
  server.unsent_bytes -= out_bytes;
  if (out_bytes > 0) server.trim_pending = true;
  for (const auto& frame : out) out_bytes -= frame.size();
  out.clear();
  free_large();
  abandon_jobs();
  server.registry.disconnected(cid);
  server.connections.erase(shared_from_this());
}

void Connection::check_timeouts(Clock::time_point now) {
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
  if (o.frame_timeout_s > 0 && !writing.empty()) {
    // The client does not take its replies (none of them for --frame-timeout, or not at
    // --min-receive-rate): nothing more can reach it, so no error reply; the reason on stderr.
    const bool stalled = since(write_progress) > o.frame_timeout_s;
    if (stalled ||
        since(write_start) > o.frame_timeout_s + double(write_bytes) / o.min_receive_rate) {
      server.counters.write_timeouts++;
      char text[64];
      std::snprintf(text, sizeof(text), "%.3g s", since(stalled ? write_progress : write_start));
      return drop_unread(std::to_string(write_bytes - write_done) + " of " +
                         std::to_string(out_bytes) + " bytes of replies unsent, " +
                         (stalled ? "none taken for " : "not taken at --min-receive-rate in ") +
                         text + " (--frame-timeout)");
    }
  }
  if (close_after_flush) return;
  if (o.frame_timeout_s > 0 && frame_started && !read_paused) {
    const std::size_t have = large.data() ? large_have : in_end - in_start;
    double allowed = o.frame_timeout_s + double(have) / o.min_receive_rate;
    // A frame that stopped arriving: its earlier bytes earn it no more time.
    const bool stalled = since(last_received) > o.frame_timeout_s;
    if (stalled) allowed = std::min(allowed, since(frame_start));
    if (stalled || since(frame_start) > allowed) {
      server.counters.frame_timeouts++;
      char text[64];
      std::snprintf(text, sizeof(text), "%.3g s", allowed);
      const std::size_t announced =
          large.data() ? large.size()
          : have >= 4  ? 4 + std::size_t(protocol::read_u32be(
                                 reinterpret_cast<const unsigned char*>(&inbuf[in_start])))
                       : 0;
      char silent[64];
      std::snprintf(silent, sizeof(silent), "%.3g s", since(last_received));
      send_error(nullptr, pc::kTimeout,
                 "frame incomplete after " + std::string(text) + ": " + std::to_string(have) +
                     (announced ? " of " + std::to_string(announced) : std::string()) +
                     " bytes received" +
                     (stalled ? ", none for the last " + std::string(silent) +
                                    " (--frame-timeout)"
                              : std::string(" (a frame must arrive within --frame-timeout plus "
                                            "its bytes at --min-receive-rate)")) +
                     "; connection closed");
      return finish_and_close();
    }
  }
  if (!idle()) return;
  // Before hello on a token server, silence is bounded by the frame timeout too.
  double limit = o.idle_timeout_s;
  const bool waiting_for_hello = !authenticated && o.frame_timeout_s > 0;
  if (waiting_for_hello) limit = limit > 0 ? std::min(limit, o.frame_timeout_s) : o.frame_timeout_s;
  if (limit > 0 && since(last_active) > limit) {
    server.counters.idle_timeouts++;
    char text[64];
    std::snprintf(text, sizeof(text), "%.3g s", limit);
    send_error(
        nullptr, pc::kTimeout,
        waiting_for_hello
            ? "no hello within " + std::string(text) + " (--frame-timeout); connection closed"
            : "connection idle for " + std::string(text) + " (--idle-timeout); connection closed");
    finish_and_close();
  }
}

void Connection::finish_job(const std::shared_ptr<Job>& job, std::string frame, bool ok,
                            const std::string& code) {
  if (job->deadline_timer) job->deadline_timer->cancel();
  leave_pool(job);  // the worker is done with it
  const auto it = inflight.find(job->key);
  if (it != inflight.end() && it->second == job) inflight.erase(it);
  if (job->replied) return;  // already answered (cancel, deadline, shutdown) or gone
  job->replied = true;
  if (ok)
    server.counters.replies_ok++;
  else
    server.count_error(code);
  send(std::move(frame));
  job_answered(job);
}

void Connection::abort_job(const std::shared_ptr<Job>& job, const char* code,
                           const std::string& message) {
  if (job->replied) return;
  if (job->deadline_timer) job->deadline_timer->cancel();
  inflight.erase(job->key);
  job->replied = true;
  send_error(job->id, code, message);
  job_answered(job);
}

void Connection::leave_pool(const std::shared_ptr<Job>& job) {
  if (!job->in_pool) return;
  job->in_pool = false;
  pool_jobs--;
}

}  // namespace terrastride::service
