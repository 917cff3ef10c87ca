#include "report/terrain_input.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <sstream>
#include <limits>
#include <map>
#include <random>

#include "terrastride/collision/octree_terrain.hpp"
#include "terrastride/perception/point_cloud.hpp"
#include "terrastride/service/cli.hpp"
#include "terrastride/terrain/scenes.hpp"
#include "terrastride/terrain/terrain_map.hpp"

namespace terrastride::service {
// The subcommands built into this binary (generated from service/src/cmd_*.cpp).
#define TERRASTRIDE_COMMAND(name) void add_##name##_command(CLI::App& app);
#include "terrastride_commands.inc"
#undef TERRASTRIDE_COMMAND
}  // namespace terrastride::service

namespace terrastride::service::report {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

const std::map<std::string, void (*)(CLI::App&)>& command_registry() {
  static const std::map<std::string, void (*)(CLI::App&)> registry = {
#define TERRASTRIDE_COMMAND(name) {#name, &add_##name##_command},
#include "terrastride_commands.inc"
#undef TERRASTRIDE_COMMAND
  };
  return registry;
}

void fill_from_map(TerrainView& view, std::shared_ptr<const terrain::TerrainMap> map,
                   const std::vector<double>& radii) {
  const terrain::HeightGrid& grid = map->grid();
  view.origin = grid.geometry.origin;
  view.resolution = grid.geometry.resolution;
  view.nx = grid.geometry.nx;
  view.ny = grid.geometry.ny;
  const size_t cells = grid.geometry.size();
  view.height.assign(cells, std::numeric_limits<float>::quiet_NaN());
  view.observed = grid.observed;
  // Unobserved cells hold conservatively filled heights in the map; the report shows them as
  // unknown (a gap), not as ground that was seen.
  for (size_t k = 0; k < cells; ++k)
    if (grid.observed[k]) view.height[k] = grid.elevation[k];
  view.radii = radii;
  view.margin.clear();
  for (double r : radii) view.margin.push_back(map->layer(r).margin);
  view.field = map;
}

}  // namespace

bool has_subcommand(const std::string& name) { return command_registry().count(name) > 0; }

void run_subcommand(const std::string& name, const std::vector<std::string>& args) {
  const auto it = command_registry().find(name);
  if (it == command_registry().end())
    throw CommandError("the '" + name + "' stage is not available: `terrastride " + name +
                       "` is not built into this binary yet");
  CLI::App app;
  app.name("terrastride");
  app.require_subcommand(1, 1);
  it->second(app);
  // CLI11 takes the arguments in reverse order, without the program name.
  std::vector<std::string> reversed(args.rbegin(), args.rend());
  reversed.push_back(name);
  try {
    app.parse(reversed);
  } catch (const CLI::ParseError& e) {
    std::string line = "terrastride " + name;
    for (const auto& a : args) line += " " + a;
    throw CommandError("`" + line + "`: " + e.what());
  }
}

bool is_terrain_dir(const std::string& path) {
  std::error_code ec;
  return fs::is_directory(path, ec) && fs::exists(fs::path(path) / "terrain.json", ec);
}

bool is_scene_name(const std::string& name) {
  const auto names = terrain::scene_names();
  return std::find(names.begin(), names.end(), name) != names.end();
}

std::vector<double> safety_radii(const std::vector<double>& requested,
                                 const std::vector<double>& terrain_radii, double foot_radius) {
  std::vector<double> radii = requested;
  if (radii.empty()) radii = terrain_radii;
  if (radii.empty()) radii = {0.02, 0.04, 0.06};
  radii.push_back(foot_radius);
  for (double r : radii)
    if (!(r > 0.0) || r > 1.0 || !std::isfinite(r))
      throw CommandError("--foot-radius: " + std::to_string(r) + " is not a radius in (0, 1] m");
  std::sort(radii.begin(), radii.end());
  std::vector<double> out;
  for (double r : radii)
    if (out.empty() || std::abs(out.back() - r) > 1e-9) out.push_back(r);
  return out;
}

TerrainView load_terrain_view(const std::vector<std::string>& inputs,
                              const TerrainInputOptions& options) {
  if (inputs.empty()) throw CommandError("--terrain: no terrain given");
  const auto t0 = Clock::now();
  TerrainView view;
  if (inputs.size() == 1 && is_scene_name(inputs[0])) {
    std::shared_ptr<terrain::Scene> scene(terrain::make_scene(inputs[0]));
    view.kind = "scene";
    view.source = inputs[0];
    view.resolution = options.resolution;
    view.origin = scene->min_corner();
    const Eigen::Vector2d size = scene->max_corner() - scene->min_corner();
    view.nx = std::max(1, static_cast<int>(std::ceil(size.x() / options.resolution - 1e-9)));
    view.ny = std::max(1, static_cast<int>(std::ceil(size.y() / options.resolution - 1e-9)));
    rasterize_field(view, *scene, safety_radii(options.radii, {}, options.foot_radius));
    view.field = scene;
    view.info = {{"scene", scene->name()}, {"description", scene->describe()},
                 {"note", "exact analytic terrain: heights and safety margins are exact, sharp edges"}};
    if (options.voxelise_scene && (options.voxel_hi - options.voxel_lo).minCoeff() > 0) {
      view.octree = collision::voxelise_scene(*scene, options.voxel_lo, options.voxel_hi);
      view.info["octomap"] = "voxelised from the scene's boxes (no scan)";
    }
  } else if (inputs.size() == 1 && is_terrain_dir(inputs[0])) {
    std::shared_ptr<const terrain::TerrainMap> map;
    try {
      map = terrain::load_terrain_dir(inputs[0]);
    } catch (const std::exception& e) {
      throw CommandError(std::string("--terrain ") + inputs[0] + ": " + e.what());
    }
    view.kind = "map";
    view.source = inputs[0];
    fill_from_map(view, map, safety_radii(options.radii, map->radii(), options.foot_radius));
    std::ifstream meta{(fs::path(inputs[0]) / "terrain.json").string()};
    try {
      view.info = nlohmann::json::parse(meta);
    } catch (const std::exception&) {
      view.info = nlohmann::json::object();
    }
    const fs::path bt = fs::path(inputs[0]) / "octomap.bt";
    if (fs::exists(bt)) {
      try {
        view.octree = collision::read_octomap(bt.string());
      } catch (const std::exception& e) {
        throw CommandError(std::string("--terrain ") + inputs[0] + ": " + e.what());
      }
    }
  } else {
    // Point clouds: map them with the same code path as `terrastride map`, into a temporary folder.
    for (const auto& in : inputs) {
      std::error_code ec;
      if (fs::is_directory(in, ec))
        throw CommandError("--terrain " + in +
                           ": a folder without terrain.json (not written by `terrastride map`)");
      if (!fs::exists(in, ec))
        throw CommandError("--terrain " + in + ": no such file, folder or scene (scenes: flat, "
                           "pallet_10, pallet_15, eur_pallet, stairs, gap)");
    }
    std::mt19937_64 rng(std::random_device{}());
    const fs::path tmp = fs::temp_directory_path() /
                         ("terrastride-report-map-" + std::to_string(rng() % 1000000007ULL));
    struct Cleanup {
      fs::path p;
      ~Cleanup() {
        std::error_code ec;
        fs::remove_all(p, ec);
      }
    } cleanup{tmp};
    std::vector<std::string> args = inputs;
    args.insert(args.end(), options.map_args.begin(), options.map_args.end());
    args.push_back("--resolution");
    args.push_back(std::to_string(options.resolution));
    args.push_back("--out");
    args.push_back(tmp.string());
    // The map command's own summary is not part of the report's output.
    std::ostringstream captured;
    std::streambuf* old = std::cout.rdbuf(captured.rdbuf());
    try {
      run_subcommand("map", args);
    } catch (...) {
      std::cout.rdbuf(old);
      throw;
    }
    std::cout.rdbuf(old);
    TerrainInputOptions sub = options;
    TerrainView mapped = load_terrain_view({tmp.string()}, sub);
    mapped.kind = "clouds";
    mapped.source.clear();
    for (const auto& in : inputs) mapped.source += (mapped.source.empty() ? "" : ", ") + in;
    view = std::move(mapped);
  }
  view.build_s = std::chrono::duration<double>(Clock::now() - t0).count();
  return view;
}

}  // namespace terrastride::service::report
