// The terrain the planner uses: a C2 smoothed height field over a HeightGrid, foothold-safety masks
// and signed safety margins for several foot radii, clearance queries, and the on-disk format
// written by `terrastride map` (DIR/terrain.json + DIR/layers/*.npy).
#pragma once

#include <Eigen/Core>
#include <limits>
#include <cstdint>
#include <deque>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "terrastride/terrain/height_field.hpp"
#include "terrastride/terrain/height_grid.hpp"
#include "terrastride/terrain/levels.hpp"

namespace terrastride::terrain {

class Scene;

// A uniform bicubic B-spline over the cell centres, C2 everywhere (also across cell borders).
// interpolate = false: the control points are the cell values (the B-spline approximant: it
// reproduces planes exactly and never overshoots a step; used for heights). interpolate = true:
// control points solved so the spline passes through every cell value (used for the safety
// margin, whose sign at a cell centre must match the mask). Beyond the grid the border control
// points are continued, so the field stays C2 and becomes constant a cell outside.
class BSplineField {
 public:
  BSplineField() = default;
  BSplineField(const GridGeometry& geometry, const std::vector<float>& values,
               bool interpolate = false);
  double value(double x, double y) const;
  // Value and gradient only (the planner's hot path).
  double value_gradient(double x, double y, Eigen::Vector2d* gradient) const;
  HeightSample sample(double x, double y) const;  // value, gradient, Hessian
  // sample()'s value and gradient to the bit, without its Hessian.
  double sample_value_gradient(double x, double y, Eigen::Vector2d* gradient) const;

 private:
  // Padded control points: 2 extra on the low side, 3 on the high side of each axis.
  const double* locate(double x, double y, double* tx, double* ty) const;
  GridGeometry geometry_;
  double inv_resolution_ = 0.0;
  double gradient_scale_ = 0.0;  // 1 / (12 resolution), see value_gradient
  int stride_ = 0;
  std::vector<double> coeffs_;
};

// Foothold-safety criteria (docs/design.md §5.4). A cell is safe for radius r when every cell whose
// centre lies within r + res/2 of its centre is observed, the raw step (highest cell max minus
// lowest cell min) in that disk is at most max_step, a plane fitted to the disk's elevations has an
// RMS residual of at most max_rms, and that plane's slope is at most max_slope (tan of the angle;
// the friction coefficient is the limit for a foot that must not slip without tangential help).
// On scanned grids (grid.surface set) the slope test is on the field the planner sees instead: the
// plane fitted to the smoothed surface over the disk (the foot's contact plane) and the field's
// gradient at the cell centre are both at most max_slope, without a noise allowance (the smoothing
// took the noise out), so a safe foothold is one the planner can stand on.
// Step and RMS limits grow with the grid's estimated sensor noise sigma: max_step +
// step_noise_factor sigma and max_rms + rms_noise_factor sigma (a disk's extreme raw points lie
// about 3 sigma either side of the surface), so a noisy plane is not called rough; the slope limit
// grows by slope_noise_factor standard errors of the fitted slope (small disks of noisy cells).
struct SafetyOptions {
  double max_step = 0.05;
  double max_rms = 0.01;
  double max_slope = 0.6;
  double step_noise_factor = 6.0;
  double rms_noise_factor = 1.0;
  double slope_noise_factor = 4.0;
  // Levels (levels.hpp): observed ground that no step of at most max_climb joins to the floor
  // level (a cupboard top, a partition's crest) is unreachable: never safe, out of the safe
  // fraction. 0.8 m: the longest leg of the shipped robots (HyQ's 0.771 m) rounded up, so the map
  // refuses only what no robot could climb; planner::check_level_reach judges each robot's own
  // legs. +infinity: every level counts as reachable.
  double max_climb = 0.8;
};

struct SafetyLayer {
  double radius = 0.0;
  std::vector<uint8_t> safe;  // per cell, 1 = safe
  std::vector<float> margin;  // signed distance (m) to the nearest unsafe cell, negative inside
  size_t safe_cells = 0;
  // Walkable observed cells: grid.observed != 0 (measured or interpolated) and on the floor's level.
  size_t observed_cells = 0;
  size_t unreachable_cells = 0;  // observed cells on unreachable levels (not in observed_cells)
  BSplineField margin_field;  // C2 interpolation of `margin` (built by TerrainMap, not here)

  // THE safe fraction of a map (terrain.json safety.radii[].safe_fraction, `map`, the report):
  // safe cells over walkable observed cells (measured or interpolated, on the floor's level).
  // Unobserved cells (hole-filled, bridged, uncertain, overhang-only, outside the scan) are left
  // out of the denominator: they say nothing about the ground, and their number depends on the
  // grid's bounding box; unreachable levels are reported apart (unreachable_cells). Every safe cell is observed,
  // so the figure is in [0, 1]; 0 when nothing was observed.
  double safe_fraction() const {
    return observed_cells ? double(safe_cells) / double(observed_cells) : 0.0;
  }
};

// Computes the mask and the margin: Euclidean distance transform (Felzenszwalb-Huttenlocher) from
// the unsafe cells for safe cells and from the safe cells for unsafe ones, each minus half a cell
// so the zero level lies on the border between a safe and an unsafe cell.
// Several radii share the radius-independent work (prefix sums, sliding extrema).
std::vector<SafetyLayer> compute_safety(const HeightGrid& grid, const std::vector<double>& radii,
                                        const SafetyOptions& options = {});
SafetyLayer compute_safety(const HeightGrid& grid, double radius,
                           const SafetyOptions& options = {});
// The same with the grid's levels for options.max_climb already computed (ground_levels; an empty
// GroundLevels when it is +infinity).
std::vector<SafetyLayer> compute_safety(const HeightGrid& grid, const std::vector<double>& radii,
                                        const SafetyOptions& options, const GroundLevels& levels);

struct Clearance {
  double min = 0.0;    // min over the segment of p_z - h(p_x, p_y)
  Eigen::Vector3d at;  // where it is attained
};

// What `terrastride query` and the socket's map.query answer at a point of a map.
struct PointAnswer {
  HeightSample ground;   // the planner's height field
  bool observed = false;
  bool safe = false;     // the cell's safety mask for the foot radius
  // The cell's safety margin (the layer's distance-transform value, m): > 0 exactly where `safe`.
  double margin = 0.0;
  // The C2 margin field the planner's foothold rows use; it interpolates the cells' margins, so
  // within half a cell of a safe/unsafe border its sign may differ from the cell's.
  double field_margin = 0.0;
  // The underside of the lowest overhang above the ground in the cell (world z), +infinity where
  // none; the free height is overhead - the cell's elevation where the ground was observed.
  double overhead = std::numeric_limits<double>::infinity();
  double free_height = std::numeric_limits<double>::infinity();
  bool overhang_only = false;  // an overhang and no walkable ground beneath it was seen
  bool unreachable = false;    // observed ground on a level no step joins to the floor's
  std::string unsafe_because;  // why the point is not safe ground; empty when safe
};

class TerrainMap : public HeightField {
 public:
  // Computes the safety layers for `radii` up front; other radii are computed on first use.
  TerrainMap(HeightGrid grid, const std::vector<double>& radii, SafetyOptions options = {});
  // The planner's C2 version of a sharp scene, on the same kind of grid as a scanned terrain.
  static std::unique_ptr<TerrainMap> from_scene(const Scene& scene, double resolution,
                                                const std::vector<double>& radii,
                                                SafetyOptions options = {});

  HeightSample sample(double x, double y) const override { return height_.sample(x, y); }
  double height_and_gradient(double x, double y, Eigen::Vector2d* gradient) const override {
    return height_.sample_value_gradient(x, y, gradient);
  }
  double height_gradient(double x, double y, Eigen::Vector2d* gradient) const {
    return height_.value_gradient(x, y, gradient);
  }
  MarginSample safety_margin(double x, double y, double foot_radius) const override;
  // The C2 field of grid().overhead (see overhead_field below): +infinity farther than four cells
  // from every overhang; elsewhere never above the raw overhead of the cell holding (x, y).
  double overhead_and_gradient(double x, double y, Eigen::Vector2d* gradient) const override;
  bool observed(double x, double y) const override;
  bool safe(double x, double y, double foot_radius) const;
  // The query's answer at (x, y), inside the grid (min_corner() to max_corner()).
  PointAnswer answer(double x, double y, double foot_radius) const;
  Eigen::Vector2d min_corner() const override { return grid_.geometry.origin; }
  Eigen::Vector2d max_corner() const override { return grid_.geometry.max_corner(); }
  std::string describe() const override;

  // Clearance of the segment a-b above the smoothed surface, sampled every quarter cell.
  Clearance clearance(const Eigen::Vector3d& a, const Eigen::Vector3d& b) const;

  const HeightGrid& grid() const { return grid_; }
  const SafetyOptions& safety_options() const { return options_; }
  // The layer for a radius (computed and cached on first use; thread safe).
  const SafetyLayer& layer(double foot_radius) const;
  std::vector<double> radii() const;
  int cell_index(double x, double y) const;  // -1 outside the grid
  // The grid's levels for safety_options().max_climb (empty when it is +infinity).
  const GroundLevels& levels() const { return levels_; }

 private:
  void build_overhead_field();

  HeightGrid grid_;
  SafetyOptions options_;
  GroundLevels levels_;
  BSplineField height_;
  // Built when grid_.overhead has a finite cell: the B-spline approximant of the overhead eroded by
  // two cells (a 5 x 5 minimum), each value capped at kOverheadCap above the cell's elevation. A
  // point's spline value is a convex combination of control points at most two cells from its
  // cell, each at most that cell's raw overhead, so the field never rises into an overhang at its
  // edge (it errs low, towards less headroom). near_overhead_ flags cells within four cells of an
  // overhang, the reach of those control points; elsewhere the field is +infinity.
  BSplineField overhead_field_;
  std::vector<uint8_t> near_overhead_;
  mutable std::mutex mutex_;
  mutable std::deque<SafetyLayer> layers_;  // deque: references stay valid as layers are added
};

// Headroom above which an overhang no longer matters to any robot the planner serves (m): the
// overhead field is capped this far above the elevation, so a ceiling 3 m up and no ceiling give
// the same smooth field.
constexpr double kOverheadCap = 2.0;

// Writes DIR/layers/*.npy (elevation, variance, min, max, count, support, observed, and per radius
// safe_rXXX and margin_rXXX, XXX the radius in mm; overhead when the grid has one, +inf where
// nothing is overhead) into `dir` (which must exist) and returns the
// metadata block for terrain.json ("format", "grid", "layers", "safety", "statistics").
nlohmann::json write_terrain_layers(const TerrainMap& map, const std::string& dir);

// Loads a directory written by `terrastride map`. Throws perception::InputError naming the file
// and the problem (missing, not a terrastride terrain, wrong layer shape or type).
std::unique_ptr<TerrainMap> load_terrain_dir(const std::string& dir);

}  // namespace terrastride::terrain
