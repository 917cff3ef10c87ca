// libFuzzer target for the wire protocol: stream splitting, frame bodies, attachment layout, the
// request envelope (deadline range, unique attachment names, known fields) and typed field
// access — everything the server runs on untrusted bytes before an operation sees them. Build:
// tests/fuzz/run.sh (Debian clang with libclang-rt-14-dev).
#include <cstddef>
#include <cstdint>
#include <string>

#include "terrastride/service/protocol.hpp"

namespace {

namespace p = terrastride::service::protocol;

void exercise_body(std::string_view body) {
  p::Message m;
  try {
    m = p::decode_body(body);
  } catch (const p::ProtocolError&) {
    return;
  }
  (void)p::salvage_id(m.header);
  try {
    nlohmann::json id;
    const p::Request r = p::parse_envelope(m.header, &id);
    if (r.deadline_ms && !(*r.deadline_ms >= 0 && *r.deadline_ms < p::kNoDeadlineFromMs))
      __builtin_trap();  // the server turns it into a time point: it must stay in range
    p::check_attachment_names(m);
    p::check_fields(m.header, r.op, {"token", "target", "ms", "points", "origin"});
    (void)p::get_number(m.header, "ms", 0.0);
    (void)p::get_string(m.header, "scene", std::string());
    (void)p::get_bool(m.header, "flag", false);
    if (m.header.contains("origin")) (void)p::get_vector(m.header, "origin", 3);
  } catch (const p::ProtocolError&) {
  }
  for (const auto& a : m.attachments) {
    try {
      (void)p::read_points(a);
    } catch (const p::ProtocolError&) {
    }
    try {
      (void)p::read_floats(a, 2, false);
    } catch (const p::ProtocolError&) {
    }
    try {
      (void)p::read_bytes(a);
    } catch (const p::ProtocolError&) {
    }
  }
  // Re-encoding a decoded message must succeed and decode to the same header.
  const std::string frame = p::encode_frame(m);
  const p::Message again = p::decode_body(std::string_view(frame).substr(4));
  if (again.attachments.size() != m.attachments.size()) __builtin_trap();
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view bytes(reinterpret_cast<const char*>(data), size);
  // 1. The bytes as one frame body.
  exercise_body(bytes);
  // 2. The bytes as a stream of frames (cap 1 MiB), fed in two pieces.
  p::FrameReader reader(1u << 20);
  try {
    reader.feed(bytes.data(), size / 2);
    while (auto body = reader.next()) exercise_body(*body);
    reader.feed(bytes.data() + size / 2, size - size / 2);
    while (auto body = reader.next()) exercise_body(*body);
  } catch (const p::ProtocolError&) {
  }
  return 0;
}
