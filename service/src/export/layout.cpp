// The Foxglove layout of an export (layout.hpp), in the format Foxglove's "Export layout" writes.
#include "export/layout.hpp"

#include <string>
#include <vector>

namespace terrastride::service::foxglove {

using nlohmann::json;

namespace {

json plot(const std::string& title,
          const std::vector<std::pair<std::string, std::string>>& series) {
  json paths = json::array();
  for (const auto& [path, label] : series)
    paths.push_back(
        {{"value", path}, {"enabled", true}, {"timestampMethod", "receiveTime"}, {"label", label}});
  return {{"title", title},          {"paths", paths},
          {"showLegend", true},      {"legendDisplay", "floating"},
          {"showXAxisLabels", true}, {"showYAxisLabels", true},
          {"isSynced", true},        {"xAxisVal", "timestamp"}};
}

// Panels stacked in a column, evenly.
json stack(const std::vector<std::string>& ids) {
  if (ids.size() == 1) return ids[0];
  const std::vector<std::string> rest(ids.begin() + 1, ids.end());
  return {{"first", ids[0]},
          {"second", stack(rest)},
          {"direction", "column"},
          {"splitPercentage", 100.0 / static_cast<double>(ids.size())}};
}

}  // namespace

json foxglove_layout(const robot::RobotModel& model, bool has_plan, bool has_sim) {
  json topics = json::object();
  for (const char* t :
       {"/terrain/relief", "/terrain/voxels", "/terrain/points", "/terrain/overhangs",
        "/plan/robot", "/plan/contact_forces", "/plan/footholds", "/plan/base_path",
        "/plan/shin_contacts", "/sim/robot", "/sim/contact_forces"})
    topics[t] = {{"visible", true}};
  topics["/terrain/grid"] = {
      {"visible", false}, {"colorField", "height"}, {"colorMode", "colormap"}};
  topics["/terrain/overhead"] = {{"visible", false}};
  json config = {
      {"3D!scene",
       {{"followTf", has_plan ? "base" : "map"},
        {"followMode", "follow-position"},
        {"scene", {{"transforms", {{"showLabel", false}, {"axisScale", 0.3}}}}},
        {"cameraState",
         {{"distance", 4.0},
          {"perspective", true},
          {"phi", 60.0},
          {"thetaOffset", 45.0},
          {"target", {0, 0, 0}},
          {"targetOffset", {0, 0, 0}},
          {"targetOrientation", {0, 0, 0, 1}},
          {"fovy", 45.0},
          {"near", 0.01},
          {"far", 5000.0}}},
        {"topics", topics}}},
      {"Log!log", {{"topicToRender", "/log"}, {"minLogLevel", 1}, {"searchTerms", json::array()}}}};
  std::vector<std::string> column;
  if (has_plan) {
    for (const char* joint : {"kfe", "hfe"}) {
      std::vector<std::pair<std::string, std::string>> series;
      for (const auto& leg : model.legs) {
        series.push_back({"/plan/joints." + leg.name + "." + joint + ".torque",
                          leg.name + " " + joint + " torque"});
        if (has_sim)
          series.push_back({"/sim/joints." + leg.name + "." + joint + ".torque",
                            leg.name + " " + joint + " sim"});
      }
      series.push_back(
          {"/plan/joints." + model.legs[0].name + "." + joint + ".torque_limit", "limit"});
      const std::string id = std::string("Plot!torque_") + joint;
      config[id] = plot(std::string(joint) + " torque vs limit (N m)", series);
      column.push_back(id);
    }
    std::vector<std::pair<std::string, std::string>> forces, margins;
    for (const auto& leg : model.legs) {
      forces.push_back({"/plan/feet." + leg.name + ".normal_force", leg.name + " plan"});
      if (has_sim) forces.push_back({"/sim/feet." + leg.name + ".normal_force", leg.name + " sim"});
      margins.push_back(
          {"/plan/feet." + leg.name + ".friction_margin", leg.name + " friction (N)"});
    }
    config["Plot!forces"] = plot("foot normal forces (N)", forces);
    config["Plot!margins"] = plot("friction-cone margins (N, < 0 slips)", margins);
    column.push_back("Plot!forces");
    column.push_back("Plot!margins");
  }
  if (has_sim) {
    config["Plot!tracking"] =
        plot("base tracking error (m)", {{"/sim/tracking.position_error_norm", "|sim - plan|"}});
    column.push_back("Plot!tracking");
  }
  column.push_back("Log!log");
  return {{"configById", config},
          {"globalVariables", json::object()},
          {"userNodes", json::object()},
          {"playbackConfig", {{"speed", 1.0}}},
          {"layout",
           {{"first", "3D!scene"},
            {"second", stack(column)},
            {"direction", "row"},
            {"splitPercentage", 55}}}};
}

}  // namespace terrastride::service::foxglove
