// The offline foothold-safety report (`terrastride report`, `terrastride demo`): terrain and plans
// turned into one JSON document (report.json: every number the page shows) and one self-contained
// HTML page (the JSON, the page's script and the plotting library inlined; no network at all).
#pragma once

#include <Eigen/Core>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "terrastride/planner/trajectory.hpp"
#include "terrastride/terrain/height_field.hpp"

namespace octomap {
class OcTree;
}
namespace terrastride::collision {
struct CheckReport;
}  // namespace terrastride::collision
namespace terrastride::simulation {
struct SimulationReport;
}  // namespace terrastride::simulation

namespace terrastride::service::report {

// A regular grid of the terrain as the report draws it. Cell (i, j) has its centre at
// origin + resolution * (i + 0.5, j + 0.5); arrays use index k = i * ny + j (the terrain module's
// layout, x index major).
struct TerrainView {
  std::string source;  // what it was built from (a folder, files, a scene name)
  std::string kind;    // "map" (terrastride map folder), "clouds", "octomap" (a .bt/.ot file), "scene"
  Eigen::Vector2d origin = Eigen::Vector2d::Zero();
  double resolution = 0.02;
  int nx = 0;
  int ny = 0;
  std::vector<float> height;               // NaN where nothing is known at all
  std::vector<uint8_t> observed;           // 1 = measured (always 1 for a scene)
  std::vector<double> radii;               // foot radii of the safety layers
  std::vector<std::vector<float>> margin;  // per radius: signed safety margin (m), k-indexed
  // Per radius, a map's SafetyLayer::safe_fraction() (`map`'s figure: safe over observed cells);
  // empty for a scene, whose fraction the report counts on its own grid the same way.
  std::vector<double> safe_fraction;
  // Per cell, the underside of the lowest overhang above the ground (world z; a ceiling, a table
  // top, a shelf), +infinity where none; empty when nothing is overhead anywhere.
  std::vector<float> overhead;
  // A map's observed cells on levels unreachable from its floor (SafetyLayer::unreachable_cells:
  // out of the safe fraction); 0 for a scene.
  size_t unreachable_cells = 0;
  // The terrain as the planner and the checks see it (heights and margins at any point); footholds
  // and profiles are queried here rather than on the coarser display grid.
  std::shared_ptr<const terrain::HeightField> field;
  std::shared_ptr<const octomap::OcTree> octree;   // null when the terrain has none (scenes)
  nlohmann::json info = nlohmann::json::object();  // terrain.json or the scene's description
  double build_s = 0.0;                            // time spent making this view

  size_t index(int i, int j) const { return static_cast<size_t>(i) * ny + j; }
  Eigen::Vector2d center(int i, int j) const {
    return origin + resolution * Eigen::Vector2d(i + 0.5, j + 0.5);
  }
};

// Fills height/observed/margin on the grid from a height field (scenes, loaded maps).
void rasterize_field(TerrainView& view, const terrain::HeightField& field,
                     const std::vector<double>& radii);

struct PlanInput {
  std::string name;  // shown in the page (file name)
  std::string path;
  planner::Trajectory trajectory;
  // The post-hoc checks (collision module) when the caller has just run them on this terrain
  // (demo); null: the report runs them itself.
  std::shared_ptr<const collision::CheckReport> checks;
  // The plan's execution in MuJoCo on this terrain (demo, `report --simulate`); null: the
  // "Simulated execution" section shows the verdict plan.json recorded (`plan --simulate`), if any.
  std::shared_ptr<const terrastride::simulation::SimulationReport> simulation;
};

struct ReportOptions {
  std::string title = "terrastride foothold-safety report";
  std::vector<double> radii;  // safety layers; empty: the terrain's own or {0.02, 0.04, 0.06}
  std::string robot = "hyq";  // for terrain-only reports (foot radius) and plans without one
  size_t max_display_cells = 160'000;  // larger grids are shown decimated (noted in the page)
  // Run every plan without a simulation in MuJoCo on the terrain (`report --simulate`).
  bool simulate = false;
  // Wall-clock fields (generated_utc, report_build_s, the terrain's build_s and map timings,
  // checks_wall_s). Off: the report is a function of its inputs alone, byte for byte (`report
  // --batch` without --timestamp), so reruns and resumed batches can be compared with cmp.
  bool clock_fields = true;
};

// Everything the page shows, as numbers: terrain layers and statistics, per plan the path, feet,
// footholds with margins, elevation profile, torque series, leg clearance series, and the list of
// problems (each with the figure and the limit it breaks). Deterministic for given inputs except
// the "generated_utc" and timing fields (left out when options.clock_fields is false).
nlohmann::json build_report(const TerrainView& terrain, const std::vector<PlanInput>& plans,
                            const ReportOptions& options);

// The page: template + plotting library + data, all inline. Throws CommandError when the assets
// (service/report/template.html, the npm-installed plotly.js) cannot be found, naming the path
// and the set-up step that provides them.
std::string render_html(const nlohmann::json& report);

// Where the assets are looked for: $TERRASTRIDE_REPORT_ASSETS_DIR, else the source tree's
// service/report folder.
std::string assets_dir();

// Writes OUT.html and OUT.json (same stem) atomically. Returns the JSON path.
std::string write_report(const nlohmann::json& report, const std::string& html_path);

// Current time as 2026-11-22T05:00:00Z.
std::string utc_now();

// Ranking page for batch mode: one row per report (relative links), best safe fraction first.
std::string render_index_html(const nlohmann::json& index);

}  // namespace terrastride::service::report
