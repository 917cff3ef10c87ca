// The JSON encoding of Foxglove messages (@foxglove/schemas' JSON schemas): times, poses,
// colours, scene entities and primitives, and the MCAP channel/publish bookkeeping of one export.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cstdint>
#include <map>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "export/mcap_writer.hpp"

namespace terrastride::service::foxglove {

using nlohmann::json;

constexpr const char* kMapFrame = "map";

// Export time: a time t in seconds of the export's clock (the plan's t = 0 is `plan_offset_s`
// after the epoch) as nanoseconds since the Unix epoch.
struct Clock {
  uint64_t epoch_ns = 0;  // what t = 0 of the terrain is (a recording's first stamp, or stated)
  double plan_offset_s = 0.0;  // the plan's t = 0 on that clock
  uint64_t ns(double t) const;
  json stamp(double t) const;  // {sec, nsec}
  double plan(double t_plan) const { return plan_offset_s + t_plan; }
};

std::string base64(const std::string& bytes);
double rounded(double v, double step = 1e-4);  // shorter JSON; 0.1 mm is below any map's cell
json vec3(const Eigen::Vector3d& v);
json quat(const Eigen::Quaterniond& q);
json pose(const Eigen::Vector3d& p, const Eigen::Quaterniond& q = Eigen::Quaterniond::Identity());
json color(double r, double g, double b, double a = 1.0);
json size3(double x, double y, double z);
json duration(double s);
json margin_color(double margin);  // red < 0, amber < 2 cm, green
Eigen::Quaterniond orientation_zyx(const Eigen::Vector3d& euler_zyx);

// An empty SceneEntity (every array the schema requires present).
json entity(const Clock& clock, double t, const std::string& id,
            const std::string& frame_id = kMapFrame, bool frame_locked = false);
json scene_update(json entities);
json line_strip(const std::vector<Eigen::Vector3d>& points, const json& c, double thickness);
json sphere(const Eigen::Vector3d& p, double d, const json& c);
json cube(const Eigen::Vector3d& p, const Eigen::Vector3d& size, const json& c,
          const Eigen::Quaterniond& q = Eigen::Quaterniond::Identity());
// A cylinder of diameter d from a to b (a link between two joints).
json cylinder_between(const Eigen::Vector3d& a, const Eigen::Vector3d& b, double d, const json& c);
// An arrow from `from` along `force`, `m_per_N` metres per newton.
json force_arrow(const Eigen::Vector3d& from, const Eigen::Vector3d& force, const json& c,
                 double m_per_N);
json transform(const Clock& clock, double t, const std::string& parent, const std::string& child,
               const Eigen::Vector3d& translation, const Eigen::Quaterniond& rotation);
// A foxglove.Log message; level 2 info, 3 warning, 4 error.
json log_message(const Clock& clock, double t, int level, const std::string& name,
                 const std::string& message);

// The channels and messages of one export, on one MCAP writer; every published Foxglove schema
// (foxglove_schemas.inc) and the export's own (add_schema) are available by name.
class Publisher {
 public:
  explicit Publisher(const std::string& compression);
  void add_schema(const std::string& name, const json& schema);
  uint16_t channel(const std::string& topic, const std::string& schema,
                   std::map<std::string, std::string> metadata = {});
  void publish(uint16_t channel, uint64_t log_time_ns, const json& message);

  mcap::Writer& writer() { return writer_; }
  const std::map<std::string, size_t>& messages_per_topic() const { return counts_; }
  size_t largest_message() const { return largest_; }
  const std::string& largest_topic() const { return largest_topic_; }

 private:
  mcap::Writer writer_;
  std::map<std::string, uint16_t> schema_ids_;
  std::map<uint16_t, std::string> topic_of_;
  std::map<std::string, size_t> counts_;
  size_t largest_ = 0;
  std::string largest_topic_;
};

// Entities packed into SceneUpdate messages of at most `budget_bytes` of JSON each, in order (an
// entity larger than the budget goes alone). Returns the number of messages.
size_t publish_entities(Publisher& pub, uint16_t channel, uint64_t log_time_ns,
                        const std::vector<json>& entities, size_t budget_bytes);

}  // namespace terrastride::service::foxglove
