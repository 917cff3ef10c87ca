// parse_json_input: json::parse with arrays and objects nested at most kMaxJsonNesting levels.
#include <gtest/gtest.h>

#include <sstream>
#include <string>

#include "terrastride/perception/json_input.hpp"

namespace pe = terrastride::perception;
using nlohmann::json;

namespace {

std::string nested(std::size_t levels, char open = '[', char close = ']') {
  return std::string(levels, open) + std::string(levels, close);
}

// The what() of the json::exception parse_json_input(text) throws, "" when it parses.
std::string error_of(const std::string& text) {
  try {
    (void)pe::parse_json_input(text);
  } catch (const json::exception& e) {
    return e.what();
  }
  return "";
}

}  // namespace

TEST(JsonInput, NestingUpToTheCapParsesAsJsonParseDoes) {
  const std::string at_cap = nested(pe::kMaxJsonNesting);
  EXPECT_EQ(pe::parse_json_input(at_cap), json::parse(at_cap));
  std::string objects;
  for (std::size_t i = 0; i < pe::kMaxJsonNesting; ++i) objects += R"({"k":)";
  objects += "1" + std::string(pe::kMaxJsonNesting, '}');
  EXPECT_EQ(pe::parse_json_input(objects), json::parse(objects));
  // Siblings do not add up: depth is nesting, not the number of containers.
  std::string wide = "[";
  for (int i = 0; i < 1000; ++i) wide += (i ? "," : "") + nested(50);
  wide += "]";
  EXPECT_EQ(pe::parse_json_input(wide).size(), 1000u);
  std::istringstream stream(at_cap);
  EXPECT_EQ(pe::parse_json_input(stream), json::parse(at_cap));
  EXPECT_EQ(pe::parse_json_input(at_cap.begin(), at_cap.end()), json::parse(at_cap));
}

TEST(JsonInput, DeeperNestingIsAParseError) {
  for (const std::string& text :
       {nested(pe::kMaxJsonNesting + 1), nested(pe::kMaxJsonNesting + 1, '[', ']') + "x",
        R"({"a":)" + nested(pe::kMaxJsonNesting) + "}", nested(2'000'000)}) {
    try {
      (void)pe::parse_json_input(text);
      ADD_FAILURE() << text.size() << " bytes parsed";
    } catch (const json::parse_error& e) {
      EXPECT_EQ(e.id, 101);
      EXPECT_NE(std::string(e.what()).find("nested more than 100 levels deep"), std::string::npos)
          << e.what();
    }
  }
}

TEST(JsonInput, MalformedJsonFailsAsJsonParseDoes) {
  EXPECT_NE(error_of("{\"a\": 1"), "");
  EXPECT_NE(error_of("[1] x"), "");  // trailing bytes
  EXPECT_NE(error_of("[1e999]"), "");  // beyond double
  EXPECT_NE(error_of(""), "");
  EXPECT_EQ(error_of(R"({"a": [1, {"b": null}], "c": "]]]"})"), "");
}
