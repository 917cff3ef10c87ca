// The terrastride wire protocol (docs/protocol.md): length-prefixed frames carrying a JSON header
// and binary attachments (float32 arrays, little-endian), used by the server, the C++ client and
// the fuzz target. Pure functions, no I/O: everything here is safe on arbitrary bytes.
//
// Frame := u32be body_length | body
// body  := u32be header_length | header (UTF-8 JSON object) | attachment bytes (concatenated)
#pragma once

#include <Eigen/Core>
#include <cstddef>
#include <cstdint>
#include <nlohmann/json.hpp>
#include <optional>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

namespace terrastride::service::protocol {

constexpr int kVersion = 1;
constexpr std::size_t kPrefixBytes = 4;
constexpr std::uint32_t kDefaultMaxFrameBytes = 64u << 20;  // 64 MiB: a 5 M-point cloud
constexpr std::size_t kMaxHeaderBytes = 4u << 20;           // JSON header cap inside a frame
constexpr std::size_t kMaxAttachments = 16;
// A deadline_ms at or above this (about 116 days) means no deadline: the time point it names would
// overflow the clock, and no request runs that long.
constexpr double kNoDeadlineFromMs = 1e10;

// Error codes carried by error replies ({"code", "message"}).
namespace code {
inline constexpr const char* kBadFrame = "bad_frame";             // framing/attachment layout
inline constexpr const char* kFrameTooLarge = "frame_too_large";  // length prefix above the cap
inline constexpr const char* kBadJson = "bad_json";               // header is not a JSON object
inline constexpr const char* kBadRequest = "bad_request";         // wrong types, missing fields
inline constexpr const char* kUnsupportedVersion = "unsupported_version";
inline constexpr const char* kUnknownOp = "unknown_op";
inline constexpr const char* kUnauthorized = "unauthorized";
inline constexpr const char* kBusy = "busy";
inline constexpr const char* kDeadlineExceeded = "deadline_exceeded";
inline constexpr const char* kCancelled = "cancelled";
inline constexpr const char* kShuttingDown = "shutting_down";
inline constexpr const char* kUnavailable = "unavailable";  // backing module not built in
inline constexpr const char* kNoMap = "no_map";
inline constexpr const char* kFailed = "failed";      // the operation ran and failed (solver, I/O)
inline constexpr const char* kInternal = "internal";  // a bug; the message says what
// A frame that did not complete in time, or an idle connection (the connection is closed).
inline constexpr const char* kTimeout = "timeout";
// A request refused up front because it cannot finish within the server's limit for it.
inline constexpr const char* kTooLarge = "too_large";
}  // namespace code

// A protocol-level failure with its reply code.
class ProtocolError : public std::runtime_error {
 public:
  ProtocolError(std::string code, const std::string& message)
      : std::runtime_error(message), code_(std::move(code)) {}
  const std::string& code() const { return code_; }

 private:
  std::string code_;
};

// The element types of attachments: float32 little-endian arrays (points, samples) and uint8
// byte strings (a ROS message as its driver serialised it, map.update's "pointcloud2").
enum class Dtype { kFloat32, kUint8 };
const char* dtype_name(Dtype dtype);
std::size_t dtype_bytes(Dtype dtype);

// A binary array, row-major with the given shape (e.g. [N, 3] for xyz).
struct Attachment {
  std::string name;
  std::vector<std::uint64_t> shape;
  std::string data;  // raw bytes, product(shape) * dtype_bytes(dtype) long
  Dtype dtype = Dtype::kFloat32;
};

struct Message {
  nlohmann::json header = nlohmann::json::object();
  std::vector<Attachment> attachments;
  const Attachment* find(std::string_view name) const;
};

// Encodes a whole frame (length prefix included). Throws ProtocolError(bad_frame) if the
// attachment shapes and byte sizes disagree or the frame exceeds 4 GiB.
std::string encode_frame(const Message& message);
// Same, with `raw_result` (an already serialised JSON value) spliced in as header["result"]; used
// for large replies built without a JSON tree. The caller guarantees `raw_result` is valid JSON.
std::string encode_frame(const Message& message, std::string_view raw_result);

// Big-endian u32 of the first 4 bytes.
std::uint32_t read_u32be(const unsigned char* p);
void write_u32be(std::uint32_t v, unsigned char* p);

// Validates a body length announced by a prefix; throws ProtocolError(frame_too_large or
// bad_frame) naming the announced size and the cap.
void check_body_length(std::uint32_t body_length, std::uint32_t max_frame_bytes);

// Decodes a frame body (without the prefix). Throws ProtocolError with code bad_frame (layout),
// bad_json (header not a JSON object). Attachments are validated against their descriptors.
Message decode_body(std::string_view body);
// The same with a header limit other than kMaxHeaderBytes: the server and the client allow a
// header as large as their frame cap (a plan's JSON samples, sent back as `init`).
Message decode_body(std::string_view body, std::size_t max_header_bytes);

// Incremental splitter for a byte stream (used by the client and the fuzz target).
class FrameReader {
 public:
  explicit FrameReader(std::uint32_t max_frame_bytes = kDefaultMaxFrameBytes)
      : max_(max_frame_bytes) {}
  void feed(const char* data, std::size_t n) { buffer_.append(data, n); }
  // Next complete body, if any. Throws ProtocolError when the prefix is over the cap; the stream
  // cannot be resynchronised after that.
  std::optional<std::string> next();
  std::size_t buffered() const { return buffer_.size(); }

 private:
  std::uint32_t max_;
  std::string buffer_;
  std::size_t pos_ = 0;
};

// ---- the request/reply envelope ----

struct Request {
  nlohmann::json id;  // integer or string, echoed in the reply
  std::string op;
  // Relative to arrival, in [0, kNoDeadlineFromMs); nullopt when absent, null or beyond that.
  std::optional<double> deadline_ms;
};

// Reads {v, id, op, deadline_ms?} from a decoded header. Throws ProtocolError(bad_request or
// unsupported_version). `id_out` receives the id as soon as it is known to be valid so error
// replies can carry it.
Request parse_envelope(const nlohmann::json& header, nlohmann::json* id_out = nullptr);

// Throws ProtocolError(bad_request) naming an attachment name used twice in one message
// (Message::find would silently see only the first).
void check_attachment_names(const Message& message);

// Header keys every request may carry besides its operation's own fields.
inline constexpr const char* kEnvelopeKeys[] = {"v", "id", "op", "deadline_ms", "attachments"};

// Throws ProtocolError(bad_request) naming the first header key that is neither an envelope key
// nor one of `accepted` (the fields operation `op` reads), so a misspelt option is refused rather
// than silently ignored. When a known key is within edit distance 2 the message suggests it:
// unknown field "optimise_timing" for op plan (did you mean "optimize_timing"?).
void check_fields(const nlohmann::json& header, const std::string& op,
                  const std::vector<std::string>& accepted);

// Edit distance (insertions, deletions, substitutions, adjacent transpositions) between a and b,
// or `limit` + 1 when it exceeds `limit` (cheap for long hostile keys).
std::size_t edit_distance(std::string_view a, std::string_view b, std::size_t limit);

// Best-effort id for replies to malformed requests: the id if it is an integer or a string
// (strings capped at 256 bytes), else null.
nlohmann::json salvage_id(const nlohmann::json& header);

Message make_reply(const nlohmann::json& id, nlohmann::json result,
                   std::vector<Attachment> attachments = {});
Message make_error(const nlohmann::json& id, const std::string& code, const std::string& message);

// ---- typed accessors for request fields (throw ProtocolError(bad_request) naming the field) ----

double get_number(const nlohmann::json& header, const char* key, std::optional<double> fallback);
std::string get_string(const nlohmann::json& header, const char* key,
                       std::optional<std::string> fallback);
bool get_bool(const nlohmann::json& header, const char* key, std::optional<bool> fallback);
// A fixed-size array of finite numbers, e.g. "origin": [x, y, z].
Eigen::VectorXd get_vector(const nlohmann::json& header, const char* key, int n);

// ---- point arrays ----

Attachment make_points_attachment(const std::string& name,
                                  const std::vector<Eigen::Vector3f>& points);
Attachment make_float_attachment(const std::string& name, std::vector<std::uint64_t> shape,
                                 const std::vector<float>& values);
// A uint8 attachment of shape [bytes.size()].
Attachment make_bytes_attachment(const std::string& name, std::string bytes);
// Reads an [N, cols] float32 attachment into row-major floats. Throws bad_request naming the
// attachment when the shape differs or (if `require_finite`) a value is NaN or infinite.
std::vector<float> read_floats(const Attachment& a, std::size_t cols, bool require_finite);
std::vector<Eigen::Vector3f> read_points(const Attachment& a);
// The bytes of a uint8 attachment of shape [N]. Throws bad_request naming the attachment when its
// dtype or shape differ.
std::string_view read_bytes(const Attachment& a);

// Appends `v` as JSON: fixed point rounded to 1e-9 for 1e-4 <= |v| < 1e9, otherwise the shortest
// round-trip text; null when not finite.
void append_json_number(std::string& out, double v);

// Constant-time comparison (time depends only on the lengths, not on where they differ).
bool constant_time_equal(std::string_view a, std::string_view b);

}  // namespace terrastride::service::protocol
