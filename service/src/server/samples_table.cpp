// Plan samples as one float32 table (samples_table.hpp).
#include "server/samples_table.hpp"

namespace terrastride::service {

protocol::Attachment samples_table(const std::vector<planner::TrajectorySample>& samples,
                                   const std::vector<std::string>& feet, nlohmann::json* result) {
  std::vector<std::string> columns{"t"};
  auto add3 = [&](const std::string& prefix) {
    for (const char* axis : {".x", ".y", ".z"}) columns.push_back(prefix + axis);
  };
  for (const char* field : {"position", "euler_zyx", "linear_velocity", "angular_velocity",
                            "linear_acceleration", "angular_acceleration"})
    add3(std::string("base.") + field);
  for (const auto& foot : feet) {
    for (const char* field : {"position", "velocity", "force"}) add3(foot + "." + field);
    columns.push_back(foot + ".contact");
  }
  protocol::Attachment a;
  a.name = "samples";
  a.shape = {samples.size(), columns.size()};
  std::vector<float> table;
  table.reserve(samples.size() * columns.size());
  auto put3 = [&](const Eigen::Vector3d& v) {
    for (int i = 0; i < 3; ++i) table.push_back(static_cast<float>(v[i]));
  };
  for (const auto& smp : samples) {
    table.push_back(static_cast<float>(smp.t));
    put3(smp.base.position);
    put3(smp.base.euler_zyx);
    put3(smp.base.linear_velocity);
    put3(smp.base.angular_velocity);
    put3(smp.base.linear_acceleration);
    put3(smp.base.angular_acceleration);
    for (std::size_t f = 0; f < feet.size(); ++f) {
      const planner::FootState& fs = smp.feet.at(f);
      put3(fs.position);
      put3(fs.velocity);
      put3(fs.force);
      table.push_back(fs.contact ? 1.0f : 0.0f);
    }
  }
  a.data.assign(reinterpret_cast<const char*>(table.data()), table.size() * sizeof(float));
  (*result)["samples"] = {{"attachment", a.name}, {"columns", columns}, {"rows", samples.size()}};
  return a;
}

}  // namespace terrastride::service
