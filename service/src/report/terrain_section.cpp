// The terrain section of the report: the grid as drawn (heights, observed cells, safety margins
// per foot radius) and its statistics (sections.hpp).
#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include "report/sections.hpp"

namespace terrastride::service::report {
namespace {

using nlohmann::json;

// Margins beyond this are drawn as "far from anything unsafe" (flat scenes report 1e9).
constexpr double kMarginDisplayCap = 1.0;

// Index of the radius closest to r (the robot's foot radius) in the safety layers.
int closest_radius(const std::vector<double>& radii, double r) {
  int best = 0;
  for (size_t i = 1; i < radii.size(); ++i)
    if (std::abs(radii[i] - r) < std::abs(radii[best] - r)) best = static_cast<int>(i);
  return best;
}

// How the input's up direction was found, in one word: "pose" (the rotation given), "check" (the
// dominant plane checked against the given or assumed z), "auto" (levelled by the dominant plane),
// "z" (z taken as up unchecked).
std::string up_method(const std::string& from) {
  if (from == "pose") return "pose";
  if (from.find("--up auto") != std::string::npos) return "auto";
  if (from.find("checked") != std::string::npos) return "check";
  return "z";
}

// Per cloud input of a map (terrain.json inputs[k]), its up estimate as the page shows it.
json up_estimates(const json& info) {
  json out = json::array();
  if (!info.is_object() || !info.contains("inputs") || !info["inputs"].is_array()) return out;
  for (const json& in : info["inputs"]) {
    if (!in.is_object() || !in.contains("up") || !in.contains("path")) continue;
    const json& up = in["up"];
    const std::string from = up.value("from", "");
    json e{{"path", in["path"]},
           {"method", up_method(from)},
           {"from", from},
           {"pose_source", in.contains("pose") ? in["pose"].value("source", "") : ""},
           {"sensor_frame", in.contains("pose") ? in["pose"].value("sensor_frame", "") : ""},
           {"plane_found", up.contains("found") ? up["found"] : json(nullptr)},
           {"tilt_deg", nullptr},
           {"sensor_height_m", nullptr},
           {"inlier_share", nullptr}};
    if (up.value("found", false)) {
      e["tilt_deg"] = num(up.value("tilt_deg", NAN), 2);
      e["sensor_height_m"] = num(up.value("sensor_height", NAN), 3);
      e["inlier_share"] = num(up.value("inlier_share", NAN), 3);
    } else if (up.contains("problem")) {
      e["problem"] = up["problem"];
    }
    out.push_back(std::move(e));
  }
  return out;
}

}  // namespace

json terrain_section(const TerrainView& t, const ReportOptions& options, double foot_radius) {
  // Decimate very large grids for display (every number shown is still a real cell value).
  int stride = 1;
  while (static_cast<size_t>((t.nx + stride - 1) / stride) * ((t.ny + stride - 1) / stride) >
         options.max_display_cells)
    ++stride;
  json xs = json::array(), ys = json::array();
  for (int i = 0; i < t.nx; i += stride) xs.push_back(num(t.center(i, 0).x(), 4));
  for (int j = 0; j < t.ny; j += stride) ys.push_back(num(t.center(0, j).y(), 4));
  // Plotly heatmaps take z[row = y][col = x].
  json height = json::array();
  // The overhang overlay: the underside's z where something is overhead (null elsewhere).
  const bool has_overhead = t.overhead.size() == t.height.size();
  json overhead = json::array();
  std::vector<json> margins(t.radii.size(), json::array());
  for (int j = 0; j < t.ny; j += stride) {
    json hrow = json::array(), orow = json::array();
    std::vector<json> mrows(t.radii.size(), json::array());
    for (int i = 0; i < t.nx; i += stride) {
      const size_t k = t.index(i, j);
      hrow.push_back(num(t.height[k], 4));
      if (has_overhead)
        orow.push_back(std::isfinite(t.overhead[k]) ? num(t.overhead[k], 3) : json(nullptr));
      for (size_t r = 0; r < t.radii.size(); ++r) {
        const double m = t.margin[r][k];
        mrows[r].push_back(num(std::isfinite(m) ? std::min(m, kMarginDisplayCap) : m, 3));
      }
    }
    height.push_back(std::move(hrow));
    if (has_overhead) overhead.push_back(std::move(orow));
    for (size_t r = 0; r < t.radii.size(); ++r) margins[r].push_back(std::move(mrows[r]));
  }

  size_t observed = 0, overhang = 0, overhang_unobserved = 0;
  double hmin = std::numeric_limits<double>::infinity(), hmax = -hmin;
  double min_free = std::numeric_limits<double>::infinity();  // overhang over observed ground
  for (size_t k = 0; k < t.height.size(); ++k) {
    if (t.observed[k]) ++observed;
    if (has_overhead && std::isfinite(t.overhead[k])) {
      ++overhang;
      overhang_unobserved += !t.observed[k];
      if (t.observed[k] && std::isfinite(t.height[k]))
        min_free = std::min<double>(min_free, t.overhead[k] - t.height[k]);
    }
    if (std::isfinite(t.height[k])) {
      hmin = std::min<double>(hmin, t.height[k]);
      hmax = std::max<double>(hmax, t.height[k]);
    }
  }
  json layers = json::array();
  for (size_t r = 0; r < t.radii.size(); ++r) {
    size_t safe = 0;
    for (size_t k = 0; k < t.height.size(); ++k)
      if (t.observed[k] && std::isfinite(t.margin[r][k]) && t.margin[r][k] >= 0.0) ++safe;
    // One definition of the safe fraction: a map's own (SafetyLayer::safe_fraction(), as `map`
    // prints it); a scene's counted here the same way, safe over observed cells.
    const double fraction = r < t.safe_fraction.size() ? t.safe_fraction[r]
                                                       : (observed ? double(safe) / observed : 0.0);
    layers.push_back({{"radius_m", num(t.radii[r], 4)},
                      {"safe_cells", safe},
                      {"safe_fraction", num(fraction, 4)},
                      {"margin", std::move(margins[r])}});
  }
  const int primary = t.radii.empty() ? -1 : closest_radius(t.radii, foot_radius);
  return {
      {"source", t.source},
      {"kind", t.kind},
      {"resolution_m", t.resolution},
      {"nx", t.nx},
      {"ny", t.ny},
      {"origin", {num(t.origin.x(), 4), num(t.origin.y(), 4)}},
      {"display_stride", stride},
      {"cells", t.height.size()},
      {"observed_cells", observed},
      {"observed_fraction", num(t.height.empty() ? 0.0 : double(observed) / t.height.size(), 4)},
      {"overhang_cells", overhang},
      {"overhang_cells_over_unobserved_ground", overhang_unobserved},
      {"min_free_height_m", num(min_free, 3)},  // null: no overhang over observed ground
      {"unreachable_cells", t.unreachable_cells},
      {"inputs", up_estimates(t.info)},
      {"overhead", std::move(overhead)},
      {"height_min_m", num(hmin)},
      {"height_max_m", num(hmax)},
      {"has_octomap", static_cast<bool>(t.octree)},
      {"foot_radius_m", foot_radius},
      {"primary_layer", primary},
      {"safe_fraction", primary >= 0 ? layers[primary]["safe_fraction"] : json(nullptr)},
      {"x", std::move(xs)},
      {"y", std::move(ys)},
      {"height", std::move(height)},
      {"layers", std::move(layers)},
      {"info", t.info},
      {"build_s", num(t.build_s, 4)}};
}

}  // namespace terrastride::service::report
