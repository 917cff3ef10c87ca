// The scenarios of docs/design.md §11 as exact analytic terrains: axis-aligned boxes on a ground
// plane, placed along +x ahead of a robot standing at x = 0 with its goal 1 m ahead.
//
// A box whose underside lies more than kOverhangGap above the ground plane is an overhang (a shelf,
// a table top, a stair tread overhead): the walkable surface (sample, edges, safety margin) is what
// lies beneath it, overhead_and_gradient() is its underside, and ray casts, the voxelised scene and
// MuJoCo still meet it as a solid. Boxes resting a few centimetres up (eur_pallet's boards, at most
// 0.122 m) stay ground. The rule looks at the ground plane only: a box stacked on another would
// count as an overhang when it starts more than kOverhangGap up; no scene stacks boxes that high.
//
// A Scene is a HeightField with sharp edges: the height is exact, its gradient and Hessian are zero
// on every flat part (one-sided at the discontinuities), and the safety margin is exact: the set of
// points whose foot disk of radius r touches a height discontinuity is {p : d(p, E) < r}, with E
// the union of the edge segments, so the signed margin is d(p, E) - r. Scenes also ray-cast for the
// scan simulator.
#pragma once

#include <Eigen/Core>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "terrastride/terrain/height_field.hpp"

namespace terrastride::terrain {

// A solid axis-aligned box; `lo` and `hi` are opposite corners (lo < hi componentwise).
struct Box {
  Eigen::Vector3d lo;
  Eigen::Vector3d hi;
};

// A horizontal segment where the terrain height jumps (from `a` to `b` in the xy plane).
struct EdgeSegment {
  Eigen::Vector2d a;
  Eigen::Vector2d b;
  double step = 0.0;  // height difference across the edge (m), > 0
};

struct RayHit {
  double range = 0.0;      // distance along the unit direction
  Eigen::Vector3d point;   // where the ray hit
  Eigen::Vector3d normal;  // outward unit normal of the surface hit
};

class Scene : public HeightField {
 public:
  // Free height (m) beneath a box, above the ground plane, from which on it is an overhang.
  static constexpr double kOverhangGap = 0.2;

  // `ground_z`: the infinite ground plane; boxes stand on it or float above it (deck boards).
  // `lo`/`hi`: the xy extent reported by min_corner()/max_corner() (the region of interest).
  Scene(std::string name, std::string description, double ground_z, std::vector<Box> boxes,
        Eigen::Vector2d lo, Eigen::Vector2d hi);

  const std::string& name() const { return name_; }
  double ground_z() const { return ground_z_; }
  const std::vector<Box>& boxes() const { return boxes_; }
  const std::vector<EdgeSegment>& edges() const { return edges_; }
  // Whether boxes()[i] is an overhang (see the top of this file).
  bool is_overhang(size_t i) const { return overhang_[i] != 0; }
  bool has_overhangs() const;
  // Robot start (x, y of the base) and goal (docs/design.md §11): the origin, and 1 m ahead.
  Eigen::Vector2d start() const { return {0.0, 0.0}; }
  Eigen::Vector2d goal() const { return {1.0, 0.0}; }

  HeightSample sample(double x, double y) const override;
  // Exact: distance to the nearest edge minus r; gradient the unit vector away from that edge.
  // With no edges at all (flat), the margin is +infinity-like (1e9) with zero gradient.
  MarginSample safety_margin(double x, double y, double foot_radius) const override;
  // Exact: the lowest underside of the overhangs whose closed footprint holds (x, y), gradient
  // zero; +infinity where none does.
  double overhead_and_gradient(double x, double y, Eigen::Vector2d* gradient) const override;
  // The lowest underside of the overhangs whose footprint meets the closed rectangle [lo, hi]
  // (+infinity for none): a grid cell's conservative overhead.
  double lowest_overhead(const Eigen::Vector2d& lo, const Eigen::Vector2d& hi) const;
  Eigen::Vector2d min_corner() const override { return lo_; }
  Eigen::Vector2d max_corner() const override { return hi_; }
  std::string describe() const override;

  // Distance in the xy plane from (x, y) to the nearest edge, and the unit vector pointing away
  // from it (zero when there are no edges). Large (1e9) when there are no edges.
  double edge_distance(double x, double y, Eigen::Vector2d* away = nullptr) const;

  // First intersection of the ray origin + t dir (dir need not be unit) with the ground or a
  // box, for 0 < t*|dir| <= max_range; nullopt when nothing is hit within range.
  std::optional<RayHit> ray_cast(const Eigen::Vector3d& origin, const Eigen::Vector3d& dir,
                                 double max_range) const;

 private:
  void compute_edges();

  std::string name_;
  std::string description_;
  double ground_z_;
  std::vector<Box> boxes_;
  std::vector<char> overhang_;  // per box
  Eigen::Vector2d lo_;
  Eigen::Vector2d hi_;
  std::vector<EdgeSegment> edges_;
};

// The named benchmark scenes: flat, pallet_10, pallet_15, eur_pallet, stairs, gap. make_scene
// also makes every pallet_NN (is_scene_name); scene_names_text() lists both for messages.
std::vector<std::string> scene_names();
// Throws perception::InputError (message lists the valid names) for an unknown name.
std::unique_ptr<Scene> make_scene(const std::string& name);

// The height in cm of a pallet_NN scene name (NN from 1 to 60, no leading zero), 0 for any other
// name. make_scene makes every such height (the step scaled to a robot's legs); scene_names()
// lists the two HyQ's benchmarks use.
int pallet_height_cm(const std::string& name);
// The underside height in cm of an overhang scene name, 0 for any other name: shelf_NN (a shelf
// across the path, x in [0.4, 0.9]), half_shelf_NN (one covering the path's left half, y >= 0),
// tread_NN (a stair tread overhead above the start, x in [-0.7, 0.25]); NN from 25 to 150, no
// leading zero.
int overhang_height_cm(const std::string& name);
// A name make_scene makes: one of scene_names(), a pallet_NN or an overhang scene. The one test
// every caller that takes "a scene name or something else" (CLI, socket operations, report) asks.
bool is_scene_name(const std::string& name);
// Every scene name for help texts and errors: "flat, pallet_10, ..., gap, pallet_NN (a box NN cm
// high, 1 to 60), shelf_NN, ...".
std::string scene_names_text();

}  // namespace terrastride::terrain
