// Turning the report's --terrain argument into a TerrainView: a folder written by `terrastride map`,
// point-cloud files (mapped in-process with the same code path as `terrastride map`), or a scene
// name (the exact analytic terrain).
#pragma once

#include <functional>
#include <string>
#include <vector>

#include "report/report.hpp"

namespace terrastride::service::report {

struct TerrainInputOptions {
  std::vector<double> radii;   // safety radii asked for (empty: the terrain's own, or 2/4/6 cm)
  double foot_radius = 0.02;   // the robot's, always drawn
  double resolution = 0.02;    // for scenes and clouds
  std::vector<std::string> map_args;  // extra `terrastride map` options for clouds (e.g. --origin)
  // Region a scene is voxelised over for the leg-capsule check (plans' extent); empty = none.
  bool voxelise_scene = true;
  Eigen::Vector2d voxel_lo = Eigen::Vector2d::Zero();
  Eigen::Vector2d voxel_hi = Eigen::Vector2d::Zero();
};

// Runs a registered subcommand in-process, exactly as the command line would ("map", args...).
// Throws CommandError naming the command when it is not built into this binary.
void run_subcommand(const std::string& name, const std::vector<std::string>& args);
bool has_subcommand(const std::string& name);

// True when `path` is a folder written by `terrastride map` (holds terrain.json).
bool is_terrain_dir(const std::string& path);
// True when the name is one of the DESIGN.md scenes.
bool is_scene_name(const std::string& name);

TerrainView load_terrain_view(const std::vector<std::string>& inputs,
                              const TerrainInputOptions& options);

// The radii to draw: the requested ones (or the terrain's own, or 2/4/6 cm), plus the robot's foot
// radius, sorted and without duplicates.
std::vector<double> safety_radii(const std::vector<double>& requested,
                                 const std::vector<double>& terrain_radii, double foot_radius);

// Reads the plans, builds the terrain view (a scene is voxelised over the plans' extent for the
// leg-capsule check), writes OUT.html and OUT.json; returns the report (cmd_report.cpp).
nlohmann::json make_report_file(const std::vector<std::string>& terrain_inputs,
                                const std::vector<std::string>& plan_paths,
                                TerrainInputOptions terrain_options, ReportOptions options,
                                const std::string& out_html);

}  // namespace terrastride::service::report
