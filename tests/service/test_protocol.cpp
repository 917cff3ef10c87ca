// The wire protocol: frame encoding/decoding, attachments, the envelope, typed fields, the
// constant-time token compare, and a replay of the fuzz seed corpus.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <sstream>

#include "support/fuzz_replay.hpp"
#include "terrastride/perception/json_input.hpp"
#include "terrastride/service/protocol.hpp"


namespace {

namespace p = terrastride::service::protocol;
using nlohmann::json;

std::string body_of(const std::string& frame) {
  return frame.substr(4);
}

std::string raw_body(const std::string& header_text, const std::string& tail = "") {
  std::string b(4, '\0');
  p::write_u32be(static_cast<std::uint32_t>(header_text.size()),
                 reinterpret_cast<unsigned char*>(&b[0]));
  return b + header_text + tail;
}

std::string code_of(const std::function<void()>& f) {
  try {
    f();
  } catch (const p::ProtocolError& e) {
    return e.code();
  }
  return "";
}

// "code: message" of the ProtocolError `f` throws, "" when it does not throw.
std::string message_of(const std::function<void()>& f) {
  try {
    f();
  } catch (const p::ProtocolError& e) {
    return e.code() + ": " + e.what();
  }
  return "";
}

}  // namespace

TEST(Protocol, RoundTripWithAttachments) {
  p::Message m;
  m.header = {{"v", 1}, {"id", 7}, {"op", "map.update"}, {"origin", {0, 0, 0.8}}};
  std::vector<Eigen::Vector3f> pts = {{1, 2, 3}, {-1.5f, 0.25f, 1e-3f}};
  m.attachments.push_back(p::make_points_attachment("points", pts));
  m.attachments.push_back(p::make_float_attachment("xy", {1, 2}, {0.5f, -0.5f}));
  const std::string frame = p::encode_frame(m);
  ASSERT_GE(frame.size(), 8u);
  EXPECT_EQ(p::read_u32be(reinterpret_cast<const unsigned char*>(frame.data())), frame.size() - 4);
  const p::Message d = p::decode_body(body_of(frame));
  EXPECT_EQ(d.header["op"], "map.update");
  ASSERT_EQ(d.attachments.size(), 2u);
  const auto back = p::read_points(*d.find("points"));
  ASSERT_EQ(back.size(), 2u);
  EXPECT_EQ(back[1], pts[1]);
  EXPECT_EQ(p::read_floats(*d.find("xy"), 2, true), (std::vector<float>{0.5f, -0.5f}));
  EXPECT_EQ(d.find("nope"), nullptr);
  // Little-endian float32 on the wire: 1.0f is 00 00 80 3f.
  const p::Attachment one = p::make_float_attachment("one", {1}, {1.0f});
  EXPECT_EQ(one.data, std::string("\x00\x00\x80\x3f", 4));
}

TEST(Protocol, EncodeRejectsShapeMismatch) {
  p::Message m;
  m.header = {{"v", 1}};
  p::Attachment a;
  a.name = "points";
  a.shape = {2, 3};
  a.data = std::string(12, '\0');
  m.attachments.push_back(a);
  EXPECT_EQ(code_of([&] { p::encode_frame(m); }), "bad_frame");
}

TEST(Protocol, EncodeReplacesNonFiniteNumbers) {
  p::Message m;
  m.header = {{"x", std::numeric_limits<double>::quiet_NaN()}};
  const p::Message d = p::decode_body(body_of(p::encode_frame(m)));
  EXPECT_TRUE(d.header["x"].is_null());
}

TEST(Protocol, MalformedBodies) {
  EXPECT_EQ(code_of([] { p::decode_body("ab"); }), "bad_frame");
  // Header length beyond the body.
  EXPECT_EQ(code_of([] { p::decode_body(std::string("\x00\x00\x10\x00{}", 6)); }), "bad_frame");
  EXPECT_EQ(code_of([] { p::decode_body(raw_body("{\"v\":1,")); }), "bad_json");
  EXPECT_EQ(code_of([] { p::decode_body(raw_body("[1,2]")); }), "bad_json");
  EXPECT_EQ(code_of([] { p::decode_body(raw_body("\"str\"")); }), "bad_json");
  EXPECT_EQ(code_of([] { p::decode_body(raw_body("{}", "x")); }), "bad_frame");  // trailing
  EXPECT_EQ(code_of([] { p::decode_body(raw_body(R"({"attachments":{}})")); }), "bad_frame");
  EXPECT_EQ(code_of([] { p::decode_body(raw_body(R"({"attachments":[{"shape":[1]}]})", "abcd")); }),
            "bad_frame");  // no name
  EXPECT_EQ(code_of([] {
              p::decode_body(raw_body(R"({"attachments":[{"name":"a","shape":[2,3]}]})", "abcd"));
            }),
            "bad_frame");  // too few bytes
  EXPECT_EQ(
      code_of([] {
        p::decode_body(raw_body(
            R"({"attachments":[{"name":"a","shape":[18446744073709551615,4611686018427387904]}]})",
            "abcd"));
      }),
      "bad_frame");  // size overflow
  EXPECT_EQ(code_of([] {
              p::decode_body(raw_body(
                  R"({"attachments":[{"name":"a","dtype":"float64","shape":[1]}]})", "abcd"));
            }),
            "bad_frame");
  EXPECT_EQ(code_of([] {
              p::decode_body(raw_body(R"({"attachments":[{"name":"a","shape":[-1]}]})", "abcd"));
            }),
            "bad_frame");
  EXPECT_EQ(code_of([] { p::decode_body(raw_body(R"({"attachments":[]})")); }), "");
}

// Copying or dumping a JSON value recurses once per level of nesting: a header of 2 MB of '['
// parsed fine, and a plan holding one as an extra key overflowed the server's stack when it was
// copied. Headers nested deeper than the cap are refused as bad JSON; the cap itself is accepted.
TEST(Protocol, HeadersNestedBeyondTheCapAreRefused) {
  const auto nested = [](std::size_t levels) {
    return R"({"v":1,"id":1,"op":"status","x":)" + std::string(levels, '[') +
           std::string(levels, ']') + "}";
  };
  const std::size_t cap = terrastride::perception::kMaxJsonNesting;
  EXPECT_EQ(code_of([&] { p::decode_body(raw_body(nested(cap - 1))); }), "");  // + the object
  const std::string refused = message_of([&] { p::decode_body(raw_body(nested(cap))); });
  EXPECT_EQ(refused.rfind("bad_json: ", 0), 0u) << refused;
  EXPECT_NE(refused.find("nested more than 100 levels deep"), std::string::npos) << refused;
  EXPECT_EQ(code_of([&] { p::decode_body(raw_body(nested(1u << 20))); }), "bad_json");
}

TEST(Protocol, BodyLengthChecks) {
  EXPECT_EQ(code_of([] { p::check_body_length(1000, 100); }), "frame_too_large");
  EXPECT_EQ(code_of([] { p::check_body_length(0xffffffffu, 1u << 20); }), "frame_too_large");
  EXPECT_EQ(code_of([] { p::check_body_length(3, 100); }), "bad_frame");
  EXPECT_EQ(code_of([] { p::check_body_length(100, 100); }), "");
}

TEST(Protocol, FrameReaderSplitsAStreamByteByByte) {
  std::string stream;
  for (int i = 0; i < 5; ++i) {
    p::Message m;
    m.header = {{"v", 1}, {"id", i}, {"op", "status"}};
    stream += p::encode_frame(m);
  }
  p::FrameReader r(1024);
  int seen = 0;
  for (char c : stream) {
    r.feed(&c, 1);
    while (auto b = r.next()) {
      EXPECT_EQ(p::decode_body(*b).header["id"], seen);
      ++seen;
    }
  }
  EXPECT_EQ(seen, 5);
  p::FrameReader small(16);
  small.feed("\x7f\xff\xff\xff", 4);
  EXPECT_EQ(code_of([&] { small.next(); }), "frame_too_large");
}

TEST(Protocol, Envelope) {
  json id;
  const p::Request r =
      p::parse_envelope(json{{"v", 1}, {"id", "abc"}, {"op", "plan"}, {"deadline_ms", 250}}, &id);
  EXPECT_EQ(r.op, "plan");
  EXPECT_EQ(id, "abc");
  ASSERT_TRUE(r.deadline_ms.has_value());
  EXPECT_DOUBLE_EQ(*r.deadline_ms, 250);
  auto code = [](const json& h) { return code_of([&] { p::parse_envelope(h); }); };
  EXPECT_EQ(code({{"v", 1}, {"op", "x"}}), "bad_request");               // no id
  EXPECT_EQ(code({{"v", 1}, {"id", 1.5}, {"op", "x"}}), "bad_request");  // float id
  EXPECT_EQ(code({{"v", 1}, {"id", {1}}, {"op", "x"}}), "bad_request");  // array id
  EXPECT_EQ(code({{"id", 1}, {"op", "x"}}), "bad_request");              // no v
  EXPECT_EQ(code({{"v", "1"}, {"id", 1}, {"op", "x"}}), "bad_request");  // string v
  EXPECT_EQ(code({{"v", 2}, {"id", 1}, {"op", "x"}}), "unsupported_version");
  EXPECT_EQ(code({{"v", 1}, {"id", 1}, {"op", 3}}), "bad_request");
  EXPECT_EQ(code({{"v", 1}, {"id", 1}, {"op", "x"}, {"deadline_ms", -1}}), "bad_request");
  EXPECT_EQ(code({{"v", 1}, {"id", 1}, {"op", "x"}, {"deadline_ms", "5"}}), "bad_request");
  EXPECT_EQ(code({{"v", 1}, {"id", std::string(300, 'x')}, {"op", "x"}}), "bad_request");
  // Huge deadlines mean none (1e13 ms used to overflow the clock); negative or NaN are refused
  // naming the field.
  for (double d : {1e10, 1e13, 1e300, std::numeric_limits<double>::infinity()})
    EXPECT_FALSE(
        p::parse_envelope(json{{"v", 1}, {"id", 1}, {"op", "x"}, {"deadline_ms", d}}).deadline_ms)
        << d;
  EXPECT_DOUBLE_EQ(
      *p::parse_envelope(json{{"v", 1}, {"id", 1}, {"op", "x"}, {"deadline_ms", 9.9e9}})
           .deadline_ms,
      9.9e9);
  for (double d : {-1.0, -1e300, std::numeric_limits<double>::quiet_NaN()}) {
    const std::string m = message_of([&] {
      p::parse_envelope(json{{"v", 1}, {"id", 1}, {"op", "x"}, {"deadline_ms", d}});
    });
    EXPECT_EQ(m.rfind("bad_request: \"deadline_ms\"", 0), 0u) << d << ": " << m;
  }
  // The id is salvaged for the error reply when it is usable.
  EXPECT_EQ(p::salvage_id(json{{"id", 5}, {"v", "bad"}}), 5);
  EXPECT_TRUE(p::salvage_id(json{{"id", {1, 2}}}).is_null());
  EXPECT_TRUE(p::salvage_id(json::array()).is_null());
}

TEST(Protocol, UnknownFieldsAreRefusedWithASuggestion) {
  const std::vector<std::string> plan = {"terrain", "gait", "optimize_timing", "max_time"};
  const json ok = {{"v", 1},           {"id", 1},         {"op", "plan"},
                   {"deadline_ms", 5}, {"gait", "crawl"}, {"optimize_timing", true}};
  EXPECT_EQ(message_of([&] { p::check_fields(ok, "plan", plan); }), "");
  json h = ok;
  h["optimise_timing"] = true;
  EXPECT_EQ(message_of([&] { p::check_fields(h, "plan", plan); }),
            "bad_request: unknown field \"optimise_timing\" for op plan (did you mean "
            "\"optimize_timing\"?)");
  // Envelope keys are suggested too; nothing close: the accepted fields are listed.
  EXPECT_NE(message_of([&] {
              p::check_fields({{"dedline_ms", 5}}, "plan", plan);
            }).find("did you mean \"deadline_ms\"?"),
            std::string::npos);
  EXPECT_EQ(message_of([&] {
              p::check_fields({{"colour", 1}}, "plan", plan);
            }),
            "bad_request: unknown field \"colour\" for op plan (fields: terrain, gait, "
            "optimize_timing, max_time)");
  EXPECT_NE(message_of([&] {
              p::check_fields({{"verbose", 1}}, "status", {});
            }).find("no fields"),
            std::string::npos);
  // A hostile key is shown truncated and costs no quadratic work.
  const std::string huge(1 << 20, 'k');
  const std::string m = message_of([&] { p::check_fields({{huge, 1}}, "plan", plan); });
  EXPECT_LT(m.size(), 300u) << m.substr(0, 300);
  EXPECT_EQ(p::edit_distance("optimise", "optimize", 2), 1u);
  EXPECT_EQ(p::edit_distance("gati", "gait", 2), 1u);  // transposition
  EXPECT_EQ(p::edit_distance("terrain", "t", 2), 3u);  // beyond the limit: limit + 1
  EXPECT_EQ(p::edit_distance("", "", 2), 0u);
}

TEST(Protocol, DuplicateAttachmentNamesAreRefused) {
  p::Message m;
  m.attachments = {p::make_float_attachment("points", {1, 2}, {0, 0}),
                   p::make_float_attachment("origin", {3}, {0, 0, 0}),
                   p::make_float_attachment("points", {1, 2}, {1, 1})};
  // The layout is valid (it decodes); the names are not.
  const p::Message d = p::decode_body(body_of(p::encode_frame(m)));
  EXPECT_EQ(message_of([&] { p::check_attachment_names(d); }),
            "bad_request: attachments[2]: duplicate name \"points\" (also attachments[0]); names "
            "must be unique");
  m.attachments.pop_back();
  EXPECT_EQ(message_of([&] { p::check_attachment_names(m); }), "");
}

TEST(Protocol, TypedFieldsNameTheField) {
  const json h = {{"n", 2.5},   {"s", "x"},       {"b", true},
                  {"bad", "2"}, {"o", {1, 2, 3}}, {"o2", {1, "a", 3}}};
  EXPECT_DOUBLE_EQ(p::get_number(h, "n", std::nullopt), 2.5);
  EXPECT_DOUBLE_EQ(p::get_number(h, "missing", 4.0), 4.0);
  EXPECT_EQ(p::get_string(h, "s", std::nullopt), "x");
  EXPECT_TRUE(p::get_bool(h, "b", std::nullopt));
  EXPECT_EQ(p::get_vector(h, "o", 3), Eigen::Vector3d(1, 2, 3));
  try {
    p::get_number(h, "bad", std::nullopt);
    FAIL();
  } catch (const p::ProtocolError& e) {
    EXPECT_EQ(e.code(), "bad_request");
    EXPECT_NE(std::string(e.what()).find("\"bad\""), std::string::npos) << e.what();
  }
  EXPECT_EQ(code_of([&] { p::get_vector(h, "o2", 3); }), "bad_request");
  EXPECT_EQ(code_of([&] { p::get_vector(h, "o", 2); }), "bad_request");
  EXPECT_EQ(code_of([&] { p::get_string(h, "missing", std::nullopt); }), "bad_request");
}

TEST(Protocol, PointAttachmentsRejectNaNAndWrongShape) {
  const auto nan = std::numeric_limits<float>::quiet_NaN();
  const p::Attachment a = p::make_float_attachment("points", {2, 3}, {0, 0, 0, 1, nan, 2});
  try {
    p::read_points(a);
    FAIL();
  } catch (const p::ProtocolError& e) {
    EXPECT_EQ(e.code(), "bad_request");
    EXPECT_NE(std::string(e.what()).find("row 1"), std::string::npos) << e.what();
  }
  const p::Attachment inf =
      p::make_float_attachment("points", {1, 3}, {0, std::numeric_limits<float>::infinity(), 0});
  EXPECT_EQ(code_of([&] { p::read_points(inf); }), "bad_request");
  const p::Attachment flat = p::make_float_attachment("points", {6}, {0, 0, 0, 1, 1, 1});
  EXPECT_EQ(code_of([&] { p::read_points(flat); }), "bad_request");
  EXPECT_EQ(p::read_floats(a, 3, false).size(), 6u);  // allowed when finiteness is not required
}

TEST(Protocol, ConstantTimeEqual) {
  EXPECT_TRUE(p::constant_time_equal("secret-token-123", "secret-token-123"));
  EXPECT_FALSE(p::constant_time_equal("secret-token-123", "secret-token-124"));
  EXPECT_FALSE(p::constant_time_equal("secret", "secret-token-123"));
  EXPECT_FALSE(p::constant_time_equal("", "x"));
  EXPECT_TRUE(p::constant_time_equal("", ""));
  EXPECT_FALSE(p::constant_time_equal(std::string("a\0b", 3), "a"));
}

// The fuzz target on every seed (and a few mutations of each): it must neither crash nor trap.
TEST(Protocol, FuzzCorpusReplay) {
  const std::filesystem::path corpus =
      std::filesystem::path(TERRASTRIDE_SOURCE_DIR) / "tests" / "fuzz" / "corpus";
  ASSERT_TRUE(std::filesystem::is_directory(corpus)) << corpus;
  EXPECT_GE(terrastride::test_support::replay_fuzz_corpus(corpus), 10);
}

TEST(Protocol, RawResultSplicingAndNumbers) {
  p::Message m = p::make_reply(7, nlohmann::json());
  std::string raw = "{\"a\":";
  p::append_json_number(raw, 0.1);
  raw += ",\"b\":";
  p::append_json_number(raw, std::numeric_limits<double>::quiet_NaN());
  raw += ",\"c\":";
  p::append_json_number(raw, -1e-300);
  raw += "}";
  const p::Message d = p::decode_body(body_of(p::encode_frame(m, raw)));
  EXPECT_EQ(d.header["id"], 7);
  EXPECT_EQ(d.header["ok"], true);
  EXPECT_EQ(d.header["result"]["a"].get<double>(), 0.1);
  EXPECT_TRUE(d.header["result"]["b"].is_null());
  EXPECT_EQ(d.header["result"]["c"].get<double>(), -1e-300);
  for (double v : {1.0, -2.5, 0.123456789, 123456.000000001, 0.0001, -7e-5, 3e12, 0.0, -0.5}) {
    std::string t;
    p::append_json_number(t, v);
    const double back = json::parse(t).get<double>();
    EXPECT_NEAR(back, v, std::max(1e-9, std::abs(v) * 1e-15)) << t;
  }
  std::string t;
  p::append_json_number(t, 0.07000000000000001);
  EXPECT_EQ(t, "0.07");
  // Into an empty header, too.
  p::Message empty;
  EXPECT_EQ(p::decode_body(body_of(p::encode_frame(empty, "[1]"))).header["result"], json({1}));
}
