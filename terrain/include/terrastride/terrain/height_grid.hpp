// The raw height grid: points binned into square cells with a robust per-cell support elevation.
//
// Cell (i, j) covers [x0 + i res, x0 + (i+1) res) x [y0 + j res, y0 + (j+1) res); arrays are stored
// with index k = i * ny + j (x index major), which is also the layout of the NPY layers (shape
// nx x ny).
//
// Support surface per cell: the cell's heights are sorted and split into clusters wherever two
// consecutive heights are more than `cluster_gap` apart. The support is the highest cluster that
// holds a substantial share of the cell's points (see-through returns under a grating are then
// ignored: the grating is the support; a sparser cluster above the support is promoted when a
// neighbouring cell's support lies at its height; narrow pits are bridged), unless the sensor saw
// beneath it: when most rays that reached a lower cluster entered the cell's column below that
// cluster (they came from the side, under a table top) it is an overhang and the next lower
// substantial cluster is the support, provided the free height between the two is at least
// `overhang_free_height` (less: a deck seen from the side, which is ground). A thin cluster whose
// own rays rose into it from a sensor that free height or more below it was seen only from beneath
// (a ceiling over a floor the sensor did not see): the cell has no walkable ground. Those tests
// need the sensor origin; clouds without one get the see-through interpretation only, and inputs
// that know free space (an OctoMap) hand their overhangs in directly (PointBatch::overhangs).
// Overhangs are kept as the overhead layer: the underside of the lowest one above the support, or
// over a cell without ground, which is then unobserved (never interpolated, never safe). A sparse cluster above the support that neither a
// neighbour corroborates (promotion) nor the sensor saw beneath (overhang) makes the cell
// uncertain: something stands above the lower surface there (a grating tread seen by few rays), so
// the lower surface is not offered as ground and the cell is unobserved.
//
// Scanned grids also carry `surface`, the support smoothed at a length set by the estimated sensor
// noise, the point spacing and the foot radius (see smooth_surface in height_grid.cpp); the
// planner's field interpolates it. Rasterised scenes leave it empty (the field is the elevation).
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "terrastride/perception/point_cloud.hpp"

namespace terrastride::terrain {

struct GridGeometry {
  Eigen::Vector2d origin = Eigen::Vector2d::Zero();  // min corner of cell (0, 0)
  double resolution = 0.02;
  int nx = 0;
  int ny = 0;

  size_t size() const { return static_cast<size_t>(nx) * static_cast<size_t>(ny); }
  size_t index(int i, int j) const { return static_cast<size_t>(i) * ny + j; }
  Eigen::Vector2d center(int i, int j) const {
    return origin + resolution * Eigen::Vector2d(i + 0.5, j + 0.5);
  }
  Eigen::Vector2d max_corner() const { return origin + resolution * Eigen::Vector2d(nx, ny); }
  bool contains(double x, double y) const {
    const Eigen::Vector2d hi = max_corner();
    return x >= origin.x() && x <= hi.x() && y >= origin.y() && y <= hi.y();
  }
};

struct HeightGridOptions {
  double resolution = 0.02;   // cell size, m; accepted range [0.002, 1]
  double cluster_gap = 0.05;  // vertical gap that separates two surfaces in a cell, m (at least
                              // 4 times the estimated sensor noise is used)
  double min_support_fraction = 0.2;  // a cluster must hold this share of the cell's points...
  int min_support_points = 2;         // ...and at least this many to count as a surface
  int min_cell_points = 2;            // fewer points in the support: the cell stays unobserved
  double overhang_vote = 0.5;         // share of "seen from beneath" rays that marks an overhang
  // Free height beneath a surface that makes it an overhang (m); see perception::kOverhangFreeHeight.
  double overhang_free_height = perception::kOverhangFreeHeight;
  // Pits up to 2 * bridge_cells wide and deeper than cluster_gap are bridged as see-through
  // openings of the surface around them (and flagged unobserved); 0 = off.
  int bridge_cells = 2;
  // Grid extent; default: the xy bounding box of the points (snapped to whole cells).
  std::optional<Eigen::Vector2d> lo, hi;
  size_t max_cells =
      25'000'000;  // refuse grids larger than this (absurd resolution for the extent)
  // The smoothed surface (HeightGrid::surface). Its Gaussian length is the larger of foot_radius /
  // 2 (a Gaussian with the second moment of the foot's contact disk: detail below it is not felt by
  // the foot) and the length that brings the 95th percentile of the noise slope on a flat surface
  // down to noise_slope_p95, capped at max_smoothing_length.
  double foot_radius = 0.02;          // m (HyQ's foot)
  double noise_slope_p95 = 0.1;       // tan; a sixth of the default friction-cone slope 0.6
  double max_smoothing_length = 0.1;  // m
  // The input's own sample spacing when the input states it (an OctoMap: one support point per
  // voxel, its resolution), m; 0: the points are a cloud, their spacing estimated (noise). The
  // notes' resolution advice is then in terms of it rather than of a "sparse cloud".
  double input_voxel = 0.0;
};

// The sensor noise estimate (HeightGrid::noise). Heights are binned in squares of bin_size (two
// cells, or more when the cloud is too sparse: the median occupied bin must hold 12 points, up to
// 0.32 m); per bin, the largest cluster of heights (one surface) gets a least-squares plane and
// the MAD of its residuals; sigma is the median over the bins whose plane is ground-like (not
// steeper than 1 by more than three standard errors of its slope, and spread by at most 0.1 m):
// walls and other vertical surfaces are not read as noise, nor are slopes, steps or see-through
// returns. Fewer than 10 bins with 6 points of one surface: not estimated, and `note` says why.
struct NoiseEstimate {
  bool estimated = false;
  double sigma = 0.0;          // m (standard deviation of one point's height); 0 when not estimated
  size_t bins = 0;             // bins the figure is the median of
  size_t rejected_bins = 0;    // bins with enough points whose surface was not ground-like
  double bin_size = 0.0;       // m
  double point_spacing = 0.0;  // m, typical distance between neighbouring points on a surface
  std::string note;            // when not estimated: why (and what to do)
};

struct HeightGrid {
  GridGeometry geometry;
  // Per cell, from the support cluster (filled cells: see fill_holes).
  std::vector<float> elevation;  // median height of the support cluster
  std::vector<float> variance;   // variance of the support cluster's heights
  std::vector<float> min;        // lowest / highest point of the support cluster
  std::vector<float> max;
  std::vector<uint32_t> count;    // all points that fell in the cell
  std::vector<uint32_t> support;  // points in the support cluster
  std::vector<uint8_t> observed;  // 1 = measured, 2 = sampling gap interpolated, 0 = unobserved
  // The smoothed support surface the planner's field interpolates (scanned grids; empty for
  // rasterised scenes): per cell, a Gaussian-weighted mean of the observed cells around it on the
  // same surface (cells whose heights differ by more than 3 standard errors are not averaged, so
  // steps stay sharp); a cell with no such cell within reach keeps its elevation.
  std::vector<float> surface;
  // Per cell, the world z of the underside of the lowest overhang above the walkable surface (a
  // shelf, a table top, a ceiling: a surface with free space beneath it that a robot may pass
  // under); +infinity where nothing is overhead. Empty: no overhang anywhere (every map before
  // overhangs were kept, and scenes without one).
  std::vector<float> overhead;
  double smoothing_length = 0.0;  // m, the Gaussian's standard deviation; 0 = no smoothing
  // Sensor noise (standard deviation of a single surface's heights, m; noise.sigma); the safety
  // criteria allow for it. 0 for rasterised scenes and when it could not be estimated.
  double noise_sigma = 0.0;
  NoiseEstimate noise;
  double cluster_gap = 0.0;  // the gap actually used: max(option, 4 noise_sigma)
  // Cells without (enough) points of their own count as sampling gaps (observed = 2) when measured
  // cells of one surface surround them within this radius: 1.5 cells, or 2.5 point spacings (at
  // most 10 cm) for sparse clouds (a 4 cm spaced cloud leaves most 2 cm cells empty).
  double gap_radius = 0.0;
  std::vector<std::string> notes;  // what a user should know about this grid (sparse cloud, ...)
  // Statistics.
  size_t points_in = 0;
  size_t points_in_grid = 0;
  size_t observed_cells = 0;
  size_t see_through_cells = 0;   // cells where lower returns were ignored as see-through
  size_t uncertain_cells = 0;     // lower surface under an uncorroborated upper one: unobserved
  size_t overhang_cells = 0;      // cells with an overhang (finite overhead)
  size_t overhang_unobserved_cells = 0;  // of those, without observed ground beneath (unobserved)
  size_t bridged_cells = 0;       // narrow see-through pits bridged (then filled, unobserved)
  size_t interpolated_cells = 0;  // single-cell sampling gaps (observed = 2)
  size_t filled_cells = 0;
};

// One batch of points with its sensor origin (when known).
struct PointBatch {
  const Eigen::Vector3f* points = nullptr;
  size_t size = 0;
  std::optional<Eigen::Vector3d> origin;
  // Overhang undersides known to the input (perception::PointCloud::overhangs): not support; the
  // lowest above a cell's support is its overhead, and a cell with overhangs and no point has no
  // walkable ground.
  const Eigen::Vector3f* overhangs = nullptr;
  size_t overhang_count = 0;
};

// Builds the grid from several batches (all in the world frame). Throws perception::InputError when
// there are no finite points, or when the resolution is outside [0.002, 1] m or gives more than
// max_cells cells (the message names the resolution). Non-finite points are skipped. Unobserved
// cells are filled by fill_holes.
HeightGrid build_height_grid(const std::vector<PointBatch>& batches,
                             const HeightGridOptions& options = {});
HeightGrid build_height_grid(const std::vector<perception::PointCloud>& clouds,
                             const HeightGridOptions& options = {});

// Throws perception::InputError naming `resolution` when it is outside [0.002, 1] m, the range of
// every grid's cells (a map read back is held to it too).
void validate_resolution(double resolution);

// Sets overhang_cells and overhang_unobserved_cells from `overhead` and `observed` (a grid built
// or read back from its layers).
void count_overhangs(HeightGrid& grid);

// Sampling-gap interpolation at the scale of the point spacing (HeightGrid::gap_radius). `sample`
// flags cells whose support is a surface sample (it may be a lone point: a sparse cloud's surface
// is made of them, and a flying pixel is not corroborated by its neighbours). An unobserved cell
// without points, or whose support is a sample too small to count (lone returns), is interpolated
// (observed = 2, elevation = the support-weighted mean) when sample cells surround it within
// `radius` (all eight neighbours for a one-cell radius, all four quadrants for wider ones) and all
// of them, with its own sample, span at most cluster_gap. Unobserved cells with points that are
// not samples (uncertain, bridged) stay holes.
void fill_sampling_gaps(HeightGrid& grid, const std::vector<uint8_t>& sample, double radius);

// Computes grid.surface (see HeightGrid::surface) for the Gaussian standard deviation `length`
// (0: surface = elevation). Sources are the observed cells, weighted by their support (measured) or
// as one point (interpolated); a cell is averaged with those whose height differs from its own by
// at most 3 standard errors of the difference (grid.noise_sigma, medians of `support` points).
void smooth_surface(HeightGrid& grid, double length);

// Conservative hole filling. A cell without (enough) points whose eight neighbours measured one
// surface is a sampling gap: it is interpolated (mean of the neighbours) and flagged observed = 2.
// Every other unobserved cell takes the highest elevation among its already known 8-neighbours,
// growing inwards ring by ring (a higher filled surface errs towards more clearance for swing feet
// and shins; the cell stays flagged unobserved, hence unsafe). Cells with fewer than `min_points`
// points count as holes for the sampling-gap rule.
void fill_holes(HeightGrid& grid, int min_points = 2);
// The same, leaving the cells flagged in `keep` (unobserved, with a height already set: bridged
// openings) as they are and growing the fill from them too.
void fill_holes_around(HeightGrid& grid, int min_points, const std::vector<uint8_t>& keep);

class Scene;
// Rasterises an analytic scene into the same grid: elevation = exact height at the cell centre,
// min / max = the lowest / highest exact height over the cell's footprint (so sharp edges show as
// raw steps), variance 0, every cell observed; overhead = the lowest underside of the scene's
// overhangs over any part of the cell (left empty for a scene without one).
HeightGrid rasterize_scene(const Scene& scene, double resolution,
                           std::optional<Eigen::Vector2d> lo = std::nullopt,
                           std::optional<Eigen::Vector2d> hi = std::nullopt);

}  // namespace terrastride::terrain
