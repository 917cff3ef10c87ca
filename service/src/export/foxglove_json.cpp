// Foxglove messages in their JSON encoding (foxglove_json.hpp).
#include "export/foxglove_json.hpp"

#include <algorithm>
#include <cmath>

#include "terrastride/robot/geometry.hpp"

namespace terrastride::service::foxglove {

namespace {

#define FOXGLOVE_SCHEMA(name, text) {name, text},
const std::map<std::string, std::string> kFoxgloveSchemas = {
#include "export/foxglove_schemas.inc"
};
#undef FOXGLOVE_SCHEMA

double finite(double v) {
  return std::isfinite(v) ? v : 0.0;
}

json time_json(uint64_t ns) {
  return {{"sec", ns / 1000000000ull}, {"nsec", ns % 1000000000ull}};
}

}  // namespace

uint64_t Clock::ns(double t) const {
  const int64_t offset = std::llround(t * 1e9);
  if (offset < 0 && static_cast<uint64_t>(-offset) > epoch_ns) return 0;
  return epoch_ns + static_cast<uint64_t>(offset);  // modular: a negative offset subtracts
}
json Clock::stamp(double t) const {
  return time_json(ns(t));
}

std::string base64(const std::string& bytes) {
  static const char* kAlphabet = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  out.reserve((bytes.size() + 2) / 3 * 4);
  size_t i = 0;
  for (; i + 2 < bytes.size(); i += 3) {
    const uint32_t v =
        (uint8_t(bytes[i]) << 16) | (uint8_t(bytes[i + 1]) << 8) | uint8_t(bytes[i + 2]);
    for (int s : {18, 12, 6, 0}) out += kAlphabet[(v >> s) & 63];
  }
  if (i + 1 == bytes.size()) {
    const uint32_t v = uint8_t(bytes[i]) << 16;
    out += kAlphabet[(v >> 18) & 63];
    out += kAlphabet[(v >> 12) & 63];
    out += "==";
  } else if (i + 2 == bytes.size()) {
    const uint32_t v = (uint8_t(bytes[i]) << 16) | (uint8_t(bytes[i + 1]) << 8);
    out += kAlphabet[(v >> 18) & 63];
    out += kAlphabet[(v >> 12) & 63];
    out += kAlphabet[(v >> 6) & 63];
    out += '=';
  }
  return out;
}

double rounded(double v, double step) {
  // Divided by the inverse step (an integer): 0.3601, not 0.36010000000000003.
  const double inverse = std::round(1.0 / step);
  return std::isfinite(v) ? std::round(v * inverse) / inverse : 0.0;
}
json vec3(const Eigen::Vector3d& v) {
  return {{"x", rounded(v.x())}, {"y", rounded(v.y())}, {"z", rounded(v.z())}};
}
json quat(const Eigen::Quaterniond& q) {
  return {{"x", finite(q.x())}, {"y", finite(q.y())}, {"z", finite(q.z())}, {"w", finite(q.w())}};
}
json pose(const Eigen::Vector3d& p, const Eigen::Quaterniond& q) {
  return {{"position", vec3(p)}, {"orientation", quat(q)}};
}
json color(double r, double g, double b, double a) {
  return {{"r", rounded(r, 1e-3)},
          {"g", rounded(g, 1e-3)},
          {"b", rounded(b, 1e-3)},
          {"a", rounded(a, 1e-3)}};
}
json size3(double x, double y, double z) {
  return vec3(Eigen::Vector3d(x, y, z));
}
json duration(double s) {
  const uint64_t ns = static_cast<uint64_t>(std::llround(std::max(0.0, s) * 1e9));
  return time_json(ns);
}
json margin_color(double margin) {
  if (margin < 0.0) return color(0.9, 0.1, 0.1);    // unsafe
  if (margin < 0.02) return color(1.0, 0.75, 0.0);  // within 2 cm of an unsafe cell
  return color(0.1, 0.75, 0.3);
}
Eigen::Quaterniond orientation_zyx(const Eigen::Vector3d& euler_zyx) {
  return Eigen::Quaterniond(robot::rotation_zyx<double>(euler_zyx)).normalized();
}

json entity(const Clock& clock, double t, const std::string& id, const std::string& frame_id,
            bool frame_locked) {
  return {
      {"timestamp", clock.stamp(t)}, {"frame_id", frame_id},         {"id", id},
      {"lifetime", duration(0)},     {"frame_locked", frame_locked}, {"metadata", json::array()},
      {"arrows", json::array()},     {"cubes", json::array()},       {"spheres", json::array()},
      {"cylinders", json::array()},  {"lines", json::array()},       {"triangles", json::array()},
      {"texts", json::array()},      {"models", json::array()}};
}
json scene_update(json entities) {
  return {{"deletions", json::array()}, {"entities", std::move(entities)}};
}
json line_strip(const std::vector<Eigen::Vector3d>& points, const json& c, double thickness) {
  json pts = json::array();
  for (const auto& p : points) pts.push_back(vec3(p));
  return {{"type", 0},  // LINE_STRIP
          {"pose", pose(Eigen::Vector3d::Zero())},
          {"thickness", thickness},
          {"scale_invariant", false},
          {"points", pts},
          {"color", c},
          {"colors", json::array()},
          {"indices", json::array()}};
}
json sphere(const Eigen::Vector3d& p, double d, const json& c) {
  return {{"pose", pose(p)}, {"size", size3(d, d, d)}, {"color", c}};
}
json cube(const Eigen::Vector3d& p, const Eigen::Vector3d& size, const json& c,
          const Eigen::Quaterniond& q) {
  return {{"pose", pose(p, q)}, {"size", vec3(size)}, {"color", c}};
}
json cylinder_between(const Eigen::Vector3d& a, const Eigen::Vector3d& b, double d, const json& c) {
  const Eigen::Vector3d axis = b - a;
  const double length = axis.norm();
  const Eigen::Quaterniond q =
      length > 1e-9 ? Eigen::Quaterniond::FromTwoVectors(Eigen::Vector3d::UnitZ(), axis)
                    : Eigen::Quaterniond::Identity();
  return {{"pose", pose(0.5 * (a + b), q)},
          {"size", size3(d, d, length)},
          {"bottom_scale", 1.0},
          {"top_scale", 1.0},
          {"color", c}};
}
json force_arrow(const Eigen::Vector3d& from, const Eigen::Vector3d& force, const json& c,
                 double m_per_N) {
  const double n = force.norm();
  const Eigen::Quaterniond q =
      n > 1e-9 ? Eigen::Quaterniond::FromTwoVectors(Eigen::Vector3d::UnitX(), force / n)
               : Eigen::Quaterniond::Identity();
  const double length = n * m_per_N;
  const double head = std::min(0.05, 0.3 * length);
  return {{"pose", pose(from, q)},   {"shaft_length", std::max(0.0, length - head)},
          {"shaft_diameter", 0.012}, {"head_length", head},
          {"head_diameter", 0.03},   {"color", c}};
}
json transform(const Clock& clock, double t, const std::string& parent, const std::string& child,
               const Eigen::Vector3d& translation, const Eigen::Quaterniond& rotation) {
  return {{"timestamp", clock.stamp(t)},
          {"parent_frame_id", parent},
          {"child_frame_id", child},
          {"translation", vec3(translation)},
          {"rotation", quat(rotation.normalized())}};
}
json log_message(const Clock& clock, double t, int level, const std::string& name,
                 const std::string& message) {
  return {{"timestamp", clock.stamp(t)},
          {"level", level},
          {"message", message},
          {"name", name},
          {"file", ""},
          {"line", 0}};
}

Publisher::Publisher(const std::string& compression)
    : writer_([&] {
        mcap::WriterOptions wo;
        wo.compression = compression == "none" ? "" : "zstd";
        return wo;
      }()) {
  for (const auto& [name, text] : kFoxgloveSchemas)
    schema_ids_[name] = writer_.add_schema(name, "jsonschema", text);
}

void Publisher::add_schema(const std::string& name, const json& schema) {
  schema_ids_[name] = writer_.add_schema(name, "jsonschema", schema.dump());
}

uint16_t Publisher::channel(const std::string& topic, const std::string& schema,
                            std::map<std::string, std::string> metadata) {
  for (const auto& [id, name] : topic_of_)
    if (name == topic) return id;  // one channel per topic (/tf has several writers)
  const uint16_t id = writer_.add_channel(schema_ids_.at(schema), topic, "json", metadata);
  topic_of_[id] = topic;
  counts_[topic] = 0;
  return id;
}

void Publisher::publish(uint16_t channel, uint64_t log_time_ns, const json& message) {
  const std::string bytes = message.dump();
  const std::string& topic = topic_of_.at(channel);
  if (bytes.size() > largest_) {
    largest_ = bytes.size();
    largest_topic_ = topic;
  }
  writer_.add_message(channel, log_time_ns, bytes);
  ++counts_[topic];
}

size_t publish_entities(Publisher& pub, uint16_t channel, uint64_t log_time_ns,
                        const std::vector<json>& entities, size_t budget_bytes) {
  size_t messages = 0, bytes = 0;
  json batch = json::array();
  const auto flush = [&] {
    if (batch.empty()) return;
    pub.publish(channel, log_time_ns, scene_update(std::move(batch)));
    batch = json::array();
    bytes = 0;
    ++messages;
  };
  for (const json& e : entities) {
    const size_t n = e.dump().size() + 1;
    if (bytes + n > budget_bytes) flush();
    batch.push_back(e);
    bytes += n;
  }
  flush();
  return messages;
}

}  // namespace terrastride::service::foxglove
