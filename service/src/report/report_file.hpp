// The report of a terrain and plans named by files (`terrastride report`, once per scan in batch
// mode): the plans read, the terrain viewed, the report built and written as OUT.html and OUT.json.
#pragma once

#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "report/report.hpp"
#include "report/terrain_input.hpp"

namespace terrastride::service::report {

// Reads the plans, builds the terrain view (a scene is voxelised over the plans' extent for the
// leg-capsule check; the first plan's robot sets the foot radius drawn), writes OUT.html and
// OUT.json; returns the report. Throws CommandError naming the file or option at fault.
nlohmann::json make_report_file(const std::vector<std::string>& terrain_inputs,
                                const std::vector<std::string>& plan_paths,
                                TerrainInputOptions terrain_options, ReportOptions options,
                                const std::string& out_html);

// The foot radius of the robot `name`; CommandError naming --robot when it cannot be loaded.
double robot_foot_radius(const std::string& name);

}  // namespace terrastride::service::report
