// The wire protocol: frames, attachments, envelope (docs/protocol.md).
#include "terrastride/service/protocol.hpp"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstring>
#include <limits>

#include "terrastride/perception/json_input.hpp"

namespace terrastride::service::protocol {

using nlohmann::json;

const char* dtype_name(Dtype dtype) { return dtype == Dtype::kUint8 ? "uint8" : "float32"; }
std::size_t dtype_bytes(Dtype dtype) { return dtype == Dtype::kUint8 ? 1 : 4; }

namespace {

[[noreturn]] void fail(const char* code, const std::string& message) {
  throw ProtocolError(code, message);
}

std::string shape_text(const std::vector<std::uint64_t>& shape) {
  std::string s = "[";
  for (std::size_t i = 0; i < shape.size(); ++i) s += (i ? "," : "") + std::to_string(shape[i]);
  return s + "]";
}

// Number of bytes for an array of this shape and type; nullopt on overflow past `limit`.
std::optional<std::uint64_t> byte_size(const std::vector<std::uint64_t>& shape, Dtype dtype,
                                       std::uint64_t limit) {
  std::uint64_t n = dtype_bytes(dtype);
  for (std::uint64_t d : shape) {
    if (d != 0 && n > limit / d) return std::nullopt;
    n *= d;
  }
  if (n > limit) return std::nullopt;
  return n;
}

bool little_endian() {
  const std::uint16_t one = 1;
  unsigned char b;
  std::memcpy(&b, &one, 1);
  return b == 1;
}

float load_f32le(const char* p) {
  unsigned char b[4];
  std::memcpy(b, p, 4);
  if (!little_endian()) std::swap(b[0], b[3]), std::swap(b[1], b[2]);
  float f;
  std::memcpy(&f, b, 4);
  return f;
}

void store_f32le(float f, char* p) {
  unsigned char b[4];
  std::memcpy(b, &f, 4);
  if (!little_endian()) std::swap(b[0], b[3]), std::swap(b[1], b[2]);
  std::memcpy(p, b, 4);
}

}  // namespace

const Attachment* Message::find(std::string_view name) const {
  for (const auto& a : attachments)
    if (a.name == name) return &a;
  return nullptr;
}

std::uint32_t read_u32be(const unsigned char* p) {
  return (std::uint32_t(p[0]) << 24) | (std::uint32_t(p[1]) << 16) | (std::uint32_t(p[2]) << 8) |
         std::uint32_t(p[3]);
}

void write_u32be(std::uint32_t v, unsigned char* p) {
  p[0] = static_cast<unsigned char>(v >> 24);
  p[1] = static_cast<unsigned char>(v >> 16);
  p[2] = static_cast<unsigned char>(v >> 8);
  p[3] = static_cast<unsigned char>(v);
}

void check_body_length(std::uint32_t body_length, std::uint32_t max_frame_bytes) {
  if (body_length > max_frame_bytes)
    fail(code::kFrameTooLarge, "frame of " + std::to_string(body_length) +
                                   " bytes exceeds the limit of " +
                                   std::to_string(max_frame_bytes) + " bytes (--max-frame-bytes)");
  if (body_length < 4)
    fail(code::kBadFrame, "frame body of " + std::to_string(body_length) +
                              " bytes is shorter than its 4-byte header length");
}

std::string encode_frame(const Message& message) {
  return encode_frame(message, {});
}

void append_json_number(std::string& out, double v) {
  if (!std::isfinite(v)) {
    out += "null";
    return;
  }
  const double a = std::fabs(v);
  if (a == 0.0) {
    out += '0';
    return;
  }
  char buf[40];
  if (a < 1e-4 || a >= 1e9) {  // rare magnitudes: shortest round-trip text
    const auto r = std::to_chars(buf, buf + sizeof(buf), v);
    out.append(buf, r.ptr);
    return;
  }
  // Fixed point with 9 decimals (1 nm for metres), integer arithmetic only: several times faster
  // than shortest round-trip formatting, which dominated large query replies.
  const auto scaled = static_cast<unsigned long long>(std::llround(a * 1e9));
  unsigned long long ip = scaled / 1000000000ull, fp = scaled % 1000000000ull;
  char* end = buf + sizeof(buf);
  char* p = end;
  if (fp != 0) {
    int digits = 9;
    while (fp % 10 == 0) {
      fp /= 10;
      --digits;
    }
    for (int i = 0; i < digits; ++i) {
      *--p = static_cast<char>('0' + fp % 10);
      fp /= 10;
    }
    *--p = '.';
  }
  do {
    *--p = static_cast<char>('0' + ip % 10);
    ip /= 10;
  } while (ip != 0);
  if (v < 0) *--p = '-';
  out.append(p, end);
}

std::string encode_frame(const Message& message, std::string_view raw_result) {
  json header = message.header;
  if (!header.is_object()) fail(code::kBadFrame, "message header must be a JSON object");
  if (!message.attachments.empty()) {
    json list = json::array();
    for (const auto& a : message.attachments) {
      const auto n = byte_size(a.shape, a.dtype, std::numeric_limits<std::uint32_t>::max());
      if (!n || *n != a.data.size())
        fail(code::kBadFrame, "attachment '" + a.name + "' has shape " + shape_text(a.shape) +
                                  " but " + std::to_string(a.data.size()) + " bytes");
      list.push_back({{"name", a.name}, {"dtype", dtype_name(a.dtype)}, {"shape", a.shape}});
    }
    header["attachments"] = std::move(list);
  } else {
    header.erase("attachments");
  }
  // NaN/inf are not JSON: they become null rather than failing the whole reply. A raw result is
  // spliced in between the header's other keys and its closing brace, written straight into the
  // frame: a copy of it in between would double the memory of a large reply (a plan's samples).
  if (!raw_result.empty()) header.erase("result");
  std::string text = header.dump(-1, ' ', false, json::error_handler_t::replace);
  std::string_view splice_before;
  if (!raw_result.empty()) {
    text.pop_back();  // the closing brace of the object
    splice_before = text.size() > 1 ? ",\"result\":" : "\"result\":";
  }
  const std::uint64_t header_bytes =
      text.size() + (raw_result.empty() ? 0 : splice_before.size() + raw_result.size() + 1);
  std::uint64_t body = 4 + header_bytes;
  for (const auto& a : message.attachments) body += a.data.size();
  if (body > std::numeric_limits<std::uint32_t>::max())
    fail(code::kBadFrame, "frame of " + std::to_string(body) + " bytes exceeds 4 GiB");
  std::string out;
  out.reserve(4 + body);
  out.resize(8);
  write_u32be(static_cast<std::uint32_t>(body), reinterpret_cast<unsigned char*>(&out[0]));
  write_u32be(static_cast<std::uint32_t>(header_bytes), reinterpret_cast<unsigned char*>(&out[4]));
  out += text;
  if (!raw_result.empty()) {
    out += splice_before;
    out += raw_result;
    out += '}';
  }
  for (const auto& a : message.attachments) out += a.data;
  return out;
}

Message decode_body(std::string_view body) { return decode_body(body, kMaxHeaderBytes); }

Message decode_body(std::string_view body, std::size_t max_header_bytes) {
  if (body.size() < 4)
    fail(code::kBadFrame, "frame body of " + std::to_string(body.size()) +
                              " bytes is shorter than its 4-byte header length");
  const std::uint32_t header_length =
      read_u32be(reinterpret_cast<const unsigned char*>(body.data()));
  if (header_length > body.size() - 4)
    fail(code::kBadFrame, "header length " + std::to_string(header_length) +
                              " exceeds the frame body (" + std::to_string(body.size() - 4) +
                              " bytes after the header length)");
  if (header_length > max_header_bytes)
    fail(code::kBadFrame, "JSON header of " + std::to_string(header_length) +
                              " bytes exceeds the limit of " + std::to_string(max_header_bytes));
  Message m;
  const std::string_view text = body.substr(4, header_length);
  // Nesting is capped: the server copies and dumps parts of a header (a plan's extra keys), which
  // recurse once per level.
  try {
    m.header = perception::parse_json_input(text.begin(), text.end());
  } catch (const json::exception& e) {
    fail(code::kBadJson, "header is not valid JSON (" + std::to_string(header_length) +
                             " bytes): " + e.what());
  }
  if (!m.header.is_object()) fail(code::kBadJson, "header must be a JSON object");

  std::string_view rest = body.substr(4 + header_length);
  const auto it = m.header.find("attachments");
  if (it != m.header.end()) {
    if (!it->is_array()) fail(code::kBadFrame, "\"attachments\" must be an array");
    if (it->size() > kMaxAttachments)
      fail(code::kBadFrame, "too many attachments (" + std::to_string(it->size()) + ", limit " +
                                std::to_string(kMaxAttachments) + ")");
    for (std::size_t i = 0; i < it->size(); ++i) {
      const json& d = (*it)[i];
      const std::string where = "attachments[" + std::to_string(i) + "]";
      if (!d.is_object()) fail(code::kBadFrame, where + " must be an object");
      Attachment a;
      const auto name = d.find("name");
      if (name == d.end() || !name->is_string())
        fail(code::kBadFrame, where + ".name must be a string");
      a.name = name->get<std::string>();
      const auto dtype = d.find("dtype");
      if (dtype != d.end()) {
        if (dtype->is_string() && dtype->get_ref<const std::string&>() == "float32")
          a.dtype = Dtype::kFloat32;
        else if (dtype->is_string() && dtype->get_ref<const std::string&>() == "uint8")
          a.dtype = Dtype::kUint8;
        else
          fail(code::kBadFrame, where + ".dtype: only \"float32\" and \"uint8\" are supported");
      }
      const auto shape = d.find("shape");
      if (shape == d.end() || !shape->is_array() || shape->empty() || shape->size() > 4)
        fail(code::kBadFrame, where + ".shape must be an array of 1 to 4 sizes");
      for (const json& s : *shape) {
        if (!s.is_number_unsigned())
          fail(code::kBadFrame, where + ".shape must hold integers >= 0");
        a.shape.push_back(s.get<std::uint64_t>());
      }
      const auto n = byte_size(a.shape, a.dtype, rest.size());
      if (!n)
        fail(code::kBadFrame, where + " ('" + a.name + "') with shape " + shape_text(a.shape) +
                                  " needs more bytes than the frame holds (" +
                                  std::to_string(rest.size()) + " left)");
      a.data.assign(rest.data(), *n);
      rest.remove_prefix(*n);
      m.attachments.push_back(std::move(a));
    }
  }
  if (!rest.empty())
    fail(code::kBadFrame,
         std::to_string(rest.size()) + " trailing bytes after the header and attachments");
  return m;
}

std::optional<std::string> FrameReader::next() {
  if (buffer_.size() - pos_ < kPrefixBytes) return std::nullopt;
  const auto len = read_u32be(reinterpret_cast<const unsigned char*>(buffer_.data() + pos_));
  if (len > max_) check_body_length(len, max_);  // throws frame_too_large
  if (buffer_.size() - pos_ - kPrefixBytes < len) return std::nullopt;
  std::string body = buffer_.substr(pos_ + kPrefixBytes, len);
  pos_ += kPrefixBytes + len;
  if (pos_ > 65536 && pos_ * 2 > buffer_.size()) {
    buffer_.erase(0, pos_);
    pos_ = 0;
  }
  return body;
}

json salvage_id(const json& header) {
  if (!header.is_object()) return nullptr;
  const auto it = header.find("id");
  if (it == header.end()) return nullptr;
  if (it->is_number_integer()) return *it;
  if (it->is_string() && it->get_ref<const std::string&>().size() <= 256) return *it;
  return nullptr;
}

Request parse_envelope(const json& header, json* id_out) {
  Request r;
  const auto id = header.find("id");
  if (id == header.end()) fail(code::kBadRequest, "missing \"id\" (an integer or a string)");
  if (!id->is_number_integer() && !id->is_string())
    fail(code::kBadRequest, "\"id\" must be an integer or a string");
  if (id->is_string() && id->get_ref<const std::string&>().size() > 256)
    fail(code::kBadRequest, "\"id\" string longer than 256 bytes");
  r.id = *id;
  if (id_out) *id_out = r.id;
  const auto v = header.find("v");
  if (v == header.end()) fail(code::kBadRequest, "missing \"v\" (protocol version, 1)");
  if (!v->is_number_integer()) fail(code::kBadRequest, "\"v\" must be an integer");
  if (v->get<long long>() != kVersion)
    fail(code::kUnsupportedVersion, "protocol version " + v->dump() + " is not supported (" +
                                        std::to_string(kVersion) + " is)");
  const auto op = header.find("op");
  if (op == header.end() || !op->is_string())
    fail(code::kBadRequest, "missing or non-string \"op\"");
  r.op = op->get<std::string>();
  const auto dl = header.find("deadline_ms");
  if (dl != header.end() && !dl->is_null()) {
    if (!dl->is_number())
      fail(code::kBadRequest, "\"deadline_ms\" must be a number of milliseconds >= 0");
    const double d = dl->get<double>();
    if (std::isnan(d) || d < 0)
      fail(code::kBadRequest,
           "\"deadline_ms\" must be a number of milliseconds >= 0, got " + dl->dump());
    // Huge budgets (1e13, 1e300) mean "no deadline" rather than a time point past the clock's
    // range, which would wrap into the past and expire at once.
    if (d < kNoDeadlineFromMs) r.deadline_ms = d;
  }
  return r;
}

void check_attachment_names(const Message& message) {
  const auto& a = message.attachments;
  for (std::size_t i = 1; i < a.size(); ++i)
    for (std::size_t j = 0; j < i; ++j)
      if (a[i].name == a[j].name) {
        const std::string shown =
            a[i].name.size() > 64 ? a[i].name.substr(0, 64) + "..." : a[i].name;
        fail(code::kBadRequest, "attachments[" + std::to_string(i) + "]: duplicate name \"" +
                                    shown + "\" (also attachments[" + std::to_string(j) +
                                    "]); names must be unique");
      }
}

std::size_t edit_distance(std::string_view a, std::string_view b, std::size_t limit) {
  const std::size_t n = a.size(), m = b.size();
  if ((n > m ? n - m : m - n) > limit) return limit + 1;
  // Optimal string alignment over three rows; keys here are short once the length test passed.
  std::vector<std::size_t> prev2(m + 1), prev(m + 1), cur(m + 1);
  for (std::size_t j = 0; j <= m; ++j) prev[j] = j;
  for (std::size_t i = 1; i <= n; ++i) {
    cur[0] = i;
    std::size_t row_min = cur[0];
    for (std::size_t j = 1; j <= m; ++j) {
      const std::size_t cost = a[i - 1] == b[j - 1] ? 0 : 1;
      cur[j] = std::min({prev[j] + 1, cur[j - 1] + 1, prev[j - 1] + cost});
      if (i > 1 && j > 1 && a[i - 1] == b[j - 2] && a[i - 2] == b[j - 1])
        cur[j] = std::min(cur[j], prev2[j - 2] + 1);
      row_min = std::min(row_min, cur[j]);
    }
    if (row_min > limit) return limit + 1;
    std::swap(prev2, prev);
    std::swap(prev, cur);
  }
  return std::min(prev[m], limit + 1);
}

void check_fields(const json& header, const std::string& op,
                  const std::vector<std::string>& accepted) {
  if (!header.is_object()) return;
  auto known = [&](const std::string& key) {
    for (const char* e : kEnvelopeKeys)
      if (key == e) return true;
    return std::find(accepted.begin(), accepted.end(), key) != accepted.end();
  };
  for (const auto& item : header.items()) {
    // A named reference, not a structured binding: lambdas may not capture those in C++17.
    const std::string& key = item.key();
    if (known(key)) continue;
    // Hostile keys can be megabytes long: show at most 64 bytes of them.
    const std::string shown = key.size() > 64 ? key.substr(0, 64) + "..." : key;
    std::string message = "unknown field \"" + shown + "\" for op " + op;
    std::string best;
    std::size_t best_d = 3;
    auto consider = [&](const std::string& candidate) {
      const std::size_t d = edit_distance(key, candidate, 2);
      if (d < best_d) best_d = d, best = candidate;
    };
    for (const auto& f : accepted) consider(f);
    for (const char* e : kEnvelopeKeys) consider(e);
    if (!best.empty()) {
      message += " (did you mean \"" + best + "\"?)";
    } else if (accepted.empty()) {
      message += " (it takes no fields besides v, id, op, deadline_ms, attachments)";
    } else {
      message += " (fields: ";
      for (std::size_t i = 0; i < accepted.size(); ++i) message += (i ? ", " : "") + accepted[i];
      message += ")";
    }
    fail(code::kBadRequest, message);
  }
}

Message make_reply(const json& id, json result, std::vector<Attachment> attachments) {
  Message m;
  m.header = {{"v", kVersion}, {"id", id}, {"ok", true}, {"result", std::move(result)}};
  m.attachments = std::move(attachments);
  return m;
}

Message make_error(const json& id, const std::string& code, const std::string& message) {
  Message m;
  m.header = {{"v", kVersion},
              {"id", id},
              {"ok", false},
              {"error", {{"code", code}, {"message", message}}}};
  return m;
}

double get_number(const json& header, const char* key, std::optional<double> fallback) {
  const auto it = header.find(key);
  if (it == header.end() || it->is_null()) {
    if (fallback) return *fallback;
    fail(code::kBadRequest, std::string("missing \"") + key + "\" (a number)");
  }
  if (!it->is_number()) fail(code::kBadRequest, std::string("\"") + key + "\" must be a number");
  const double v = it->get<double>();
  if (!std::isfinite(v)) fail(code::kBadRequest, std::string("\"") + key + "\" must be finite");
  return v;
}

std::string get_string(const json& header, const char* key, std::optional<std::string> fallback) {
  const auto it = header.find(key);
  if (it == header.end() || it->is_null()) {
    if (fallback) return *fallback;
    fail(code::kBadRequest, std::string("missing \"") + key + "\" (a string)");
  }
  if (!it->is_string()) fail(code::kBadRequest, std::string("\"") + key + "\" must be a string");
  return it->get<std::string>();
}

bool get_bool(const json& header, const char* key, std::optional<bool> fallback) {
  const auto it = header.find(key);
  if (it == header.end() || it->is_null()) {
    if (fallback) return *fallback;
    fail(code::kBadRequest, std::string("missing \"") + key + "\" (true or false)");
  }
  if (!it->is_boolean()) fail(code::kBadRequest, std::string("\"") + key + "\" must be a boolean");
  return it->get<bool>();
}

Eigen::VectorXd get_vector(const json& header, const char* key, int n) {
  const auto it = header.find(key);
  const std::string what =
      std::string("\"") + key + "\" must be an array of " + std::to_string(n) + " finite numbers";
  if (it == header.end() || !it->is_array() || it->size() != static_cast<std::size_t>(n))
    fail(code::kBadRequest, what);
  Eigen::VectorXd v(n);
  for (int i = 0; i < n; ++i) {
    const json& e = (*it)[i];
    if (!e.is_number()) fail(code::kBadRequest, what);
    v[i] = e.get<double>();
    if (!std::isfinite(v[i])) fail(code::kBadRequest, what);
  }
  return v;
}

Attachment make_float_attachment(const std::string& name, std::vector<std::uint64_t> shape,
                                 const std::vector<float>& values) {
  Attachment a;
  a.name = name;
  a.shape = std::move(shape);
  a.data.resize(values.size() * 4);
  for (std::size_t i = 0; i < values.size(); ++i) store_f32le(values[i], &a.data[4 * i]);
  return a;
}

Attachment make_points_attachment(const std::string& name,
                                  const std::vector<Eigen::Vector3f>& points) {
  std::vector<float> v;
  v.reserve(points.size() * 3);
  for (const auto& p : points) v.insert(v.end(), {p.x(), p.y(), p.z()});
  return make_float_attachment(name, {points.size(), 3}, v);
}

Attachment make_bytes_attachment(const std::string& name, std::string bytes) {
  Attachment a;
  a.name = name;
  a.shape = {bytes.size()};
  a.data = std::move(bytes);
  a.dtype = Dtype::kUint8;
  return a;
}

std::string_view read_bytes(const Attachment& a) {
  if (a.dtype != Dtype::kUint8 || a.shape.size() != 1)
    fail(code::kBadRequest, "attachment '" + a.name + "' must be uint8 of shape [bytes], got " +
                                dtype_name(a.dtype) + " " + shape_text(a.shape));
  return a.data;
}

std::vector<float> read_floats(const Attachment& a, std::size_t cols, bool require_finite) {
  if (a.dtype != Dtype::kFloat32)
    fail(code::kBadRequest, "attachment '" + a.name + "' must be float32, got " +
                                dtype_name(a.dtype));
  if (a.shape.size() != 2 || a.shape[1] != cols)
    fail(code::kBadRequest, "attachment '" + a.name + "' must have shape [N, " +
                                std::to_string(cols) + "], got " + shape_text(a.shape));
  const std::size_t n = a.data.size() / 4;
  std::vector<float> out(n);
  for (std::size_t i = 0; i < n; ++i) {
    out[i] = load_f32le(&a.data[4 * i]);
    if (require_finite && !std::isfinite(out[i]))
      fail(code::kBadRequest, "attachment '" + a.name + "': row " + std::to_string(i / cols) +
                                  " holds a non-finite value (NaN or infinity)");
  }
  return out;
}

std::vector<Eigen::Vector3f> read_points(const Attachment& a) {
  const std::vector<float> f = read_floats(a, 3, /*require_finite=*/true);
  std::vector<Eigen::Vector3f> pts(f.size() / 3);
  for (std::size_t i = 0; i < pts.size(); ++i) pts[i] = {f[3 * i], f[3 * i + 1], f[3 * i + 2]};
  return pts;
}

bool constant_time_equal(std::string_view a, std::string_view b) {
  // Compare over the longer length so the time does not reveal a matching prefix.
  const std::size_t n = std::max(a.size(), b.size());
  unsigned char diff = a.size() == b.size() ? 0 : 1;
  for (std::size_t i = 0; i < n; ++i) {
    const unsigned char x = i < a.size() ? static_cast<unsigned char>(a[i]) : 0;
    const unsigned char y = i < b.size() ? static_cast<unsigned char>(b[i]) : 0;
    diff |= static_cast<unsigned char>(x ^ y);
  }
  return diff == 0;
}

}  // namespace terrastride::service::protocol
