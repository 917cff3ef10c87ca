// Where a robot may stand and go on a map: the connected regions of safe ground large enough for a
// robot's stance, each with a suggested start pose and goals reachable inside it
// (`terrastride regions`). A map of a building floor is tens of metres across; a user should not
// have to read its NPY layers to find where a plan can start.
#pragma once

#include <Eigen/Core>
#include <cstddef>
#include <string>
#include <vector>

#include "terrastride/terrain/terrain_map.hpp"

namespace terrastride::terrain {

// The robot as the listing needs it: its nominal foot points in the base frame (x, y) and the
// foot radius whose safety layer judges them. Terrain knows no robot; the caller derives this
// from one (service: robot::RobotModel's nominal feet).
struct StanceFootprint {
  std::vector<Eigen::Vector2d> feet;
  double foot_radius = 0.02;
  // The body over the stance: within the rectangle of half-extents body_half about the base
  // (base frame, m; grown to hold the feet) the ground, feet included, may rise at most max_rise
  // above the lowest foot (a wall or a high step beside the stance would meet the trunk). HyQ:
  // half its trunk's 0.5 m clearance. Headings along the grid's axes use the rectangle; others
  // the square that holds it turned (conservative).
  Eigen::Vector2d body_half = Eigen::Vector2d::Zero();
  double max_rise = 0.25;
};

struct RegionOptions {
  StanceFootprint footprint;
  // Headings tried at every cell (rad); a cell is standable when the stance fits at one of them.
  std::vector<double> yaws{0.0, 0.7853981633974483, 1.5707963267948966, 2.356194490397448};
  size_t max_regions = 10;    // the largest ones; the listing says how many were left out
  // Regions of fewer base positions than this area (m2) are left out and counted: slivers beside
  // an edge where the stance fits at a row of cells are no place to start a plan.
  double min_area = 0.05;
  double goal_distance = 1.0;  // m, along the region's long axis from the start
};

// A pose on the map: position of the base over the ground and heading.
struct RegionPose {
  Eigen::Vector2d xy = Eigen::Vector2d::Zero();
  double yaw = 0.0;
  double height = 0.0;  // the ground (map field) at xy
};

struct RegionGoal {
  RegionPose pose;
  double path_length = 0.0;  // m, shortest path through standable cells from the start
};

struct SafeRegion {
  int id = 0;                 // 1 = the largest
  size_t cells = 0;           // standable cells
  double area_m2 = 0.0;       // their area
  Eigen::Vector2d lo, hi;     // bounding box of the cells
  double length_m = 0.0;      // extent along the long axis (principal direction of the cells)
  double width_m = 0.0;       // extent across it
  double axis_yaw = 0.0;      // the long axis's heading (rad, in (-pi/2, pi/2])
  double height_min = 0.0;    // ground heights over the region
  double height_max = 0.0;
  RegionPose start;           // the standable cell farthest from the region's border
  double start_border_m = 0.0;  // its distance to the nearest non-standable cell
  std::vector<RegionGoal> goals;  // up to goal_distance ahead and behind, and the farthest cell
};

struct RegionListing {
  std::vector<SafeRegion> regions;  // largest first, at most max_regions
  size_t regions_total = 0;         // at least min_area, before the max_regions cut
  size_t regions_too_small = 0;     // left out for min_area
  size_t standable_cells = 0;
  double foot_radius = 0.0;
  double resolution = 0.0;
};

// Throws perception::InputError for an empty footprint or a non-finite foot point.
RegionListing list_safe_regions(const TerrainMap& map, const RegionOptions& options);

// One line per region for people ("region 1: 7.6 m x 1.1 m (corridor-like) ...").
std::string describe_regions(const RegionListing& listing);

}  // namespace terrastride::terrain
