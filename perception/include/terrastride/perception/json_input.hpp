// Parsing JSON that comes from outside (a plan, a start state, a socket request's header, a
// map's terrain.json, a simulation report) with its nesting capped.
//
// nlohmann's parser is iterative, but copying, comparing and dumping a document recurse once per
// level of nesting: 2 MB of '[' parse fine and then overflow the stack wherever the document is
// first copied (a plan's extra keys) or written back, far from the reader. Refusing the nesting
// at parse time keeps that out of every later use. The documents terrastride reads nest a few
// levels (a plan: top, samples, sample, base, vector); the cap leaves users' extra keys room.
#pragma once

#include <cstddef>
#include <nlohmann/json.hpp>
#include <string>
#include <utility>

namespace terrastride::perception {

constexpr std::size_t kMaxJsonNesting = 100;

namespace json_input_detail {

// nlohmann's own DOM builder (what json::parse uses) with a depth check where an array or an
// object starts. json::parse's callback form could check the depth too, but its builder is
// about 50 times slower on a 30 MB plan.
class NestingCappedBuilder : public nlohmann::detail::json_sax_dom_parser<nlohmann::json> {
 public:
  explicit NestingCappedBuilder(nlohmann::json& result)
      : nlohmann::detail::json_sax_dom_parser<nlohmann::json>(result, true) {}
  bool start_object(std::size_t elements) {
    enter();
    return json_sax_dom_parser::start_object(elements);
  }
  bool end_object() {
    --depth_;
    return json_sax_dom_parser::end_object();
  }
  bool start_array(std::size_t elements) {
    enter();
    return json_sax_dom_parser::start_array(elements);
  }
  bool end_array() {
    --depth_;
    return json_sax_dom_parser::end_array();
  }

 private:
  void enter() {
    if (++depth_ > kMaxJsonNesting)
      throw nlohmann::json::parse_error::create(
          101, 0,
          "arrays and objects nested more than " + std::to_string(kMaxJsonNesting) +
              " levels deep",
          nullptr);
  }
  std::size_t depth_ = 0;
};

}  // namespace json_input_detail

// json::parse of `input` (a stream, a string, or an iterator pair) with arrays and objects
// nested at most kMaxJsonNesting levels deep. Throws json::parse_error (the nesting as id 101)
// like json::parse, so callers' handling of malformed JSON covers it.
template <typename... Input>
nlohmann::json parse_json_input(Input&&... input) {
  nlohmann::json result;
  json_input_detail::NestingCappedBuilder builder(result);
  nlohmann::json::sax_parse(std::forward<Input>(input)..., &builder);
  return result;
}

}  // namespace terrastride::perception
