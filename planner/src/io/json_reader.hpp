// Reading JSON documents field by field, with the field's path in every error (the plan file,
// the start-state file): shared by plan_json.cpp and start_state_json.cpp.
#pragma once

#include <cmath>
#include <cstdint>
#include <initializer_list>
#include <limits>
#include <nlohmann/json.hpp>
#include <string>
#include <utility>

#include "terrastride/planner/plan_io.hpp"

namespace terrastride::planner::io {

using nlohmann::json;

// Field access with a path for error messages.
class Reader {
 public:
  Reader(const std::string& source, const json& node, std::string path)
      : source_(source), node_(node), path_(std::move(path)) {}

  [[noreturn]] void fail(const std::string& field, const std::string& problem) const {
    throw PlanFileError(source_ + ": " + join(field) + ": " + problem);
  }
  const json& at(const std::string& field) const {
    if (!node_.is_object()) throw PlanFileError(source_ + ": " + path_ + ": must be an object");
    const auto it = node_.find(field);
    if (it == node_.end()) fail(field, "missing");
    return *it;
  }
  bool has(const std::string& field) const { return node_.is_object() && node_.contains(field); }
  Reader sub(const std::string& field) const { return Reader(source_, at(field), join(field)); }
  Reader element(const std::string& field, size_t i) const {
    return Reader(source_, at(field)[i], join(field) + "[" + std::to_string(i) + "]");
  }
  double number(const std::string& field) const {
    const json& v = at(field);
    if (!v.is_number()) fail(field, "must be a number");
    const double d = v.get<double>();
    if (!std::isfinite(d)) fail(field, "must be finite");
    return d;
  }
  int integer(const std::string& field) const {
    const json& v = at(field);
    if (!v.is_number_integer()) fail(field, "must be an integer");
    // get<int>() of a wider integer wraps (4294967297 would read as 1).
    const bool in_range = v.is_number_unsigned()
                              ? v.get<std::uint64_t>() <= std::numeric_limits<int>::max()
                              : v.get<std::int64_t>() >= std::numeric_limits<int>::min() &&
                                    v.get<std::int64_t>() <= std::numeric_limits<int>::max();
    if (!in_range) fail(field, "is " + v.dump() + ", beyond the range of an int");
    return v.get<int>();
  }
  std::string text(const std::string& field) const {
    const json& v = at(field);
    if (!v.is_string()) fail(field, "must be a string");
    return v.get<std::string>();
  }
  bool boolean(const std::string& field) const {
    const json& v = at(field);
    if (!v.is_boolean()) fail(field, "must be true or false");
    return v.get<bool>();
  }
  Eigen::Vector3d vec3(const std::string& field) const {
    const json& v = at(field);
    if (!v.is_array() || v.size() != 3) fail(field, "must be an array of 3 numbers");
    Eigen::Vector3d out;
    for (int i = 0; i < 3; ++i) {
      // nlohmann writes NaN as null: report it as non-finite.
      if (!v[i].is_number())
        fail(field, "element " + std::to_string(i) + " is not a finite number");
      out[i] = v[i].get<double>();
      if (!std::isfinite(out[i])) fail(field, "element " + std::to_string(i) + " is not finite");
    }
    return out;
  }
  // This node must be a JSON object holding no keys but `known` (a misspelt optional field
  // would otherwise be silently ignored).
  void only(std::initializer_list<const char*> known) const {
    if (!node_.is_object())
      throw PlanFileError(source_ + ": " + (path_.empty() ? "top level" : path_) +
                          ": must be an object");
    for (const auto& [key, value] : node_.items()) {
      bool ok = false;
      std::string list;
      for (const char* k : known) {
        ok = ok || key == k;
        list += (list.empty() ? "" : ", ") + std::string(k);
      }
      if (!ok) fail(key, "unknown field (known: " + list + ")");
    }
  }
  size_t array_size(const std::string& field) const {
    const json& v = at(field);
    if (!v.is_array()) fail(field, "must be an array");
    return v.size();
  }

 private:
  std::string join(const std::string& field) const {
    return path_.empty() ? field : path_ + "." + field;
  }
  const std::string& source_;
  const json& node_;
  std::string path_;
};

// The JSON document in `path`; `what` names the file's role in the error when it cannot be opened.
json read_json_file(const std::string& path, const char* what);

}  // namespace terrastride::planner::io
