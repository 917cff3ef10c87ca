#include "terrastride/planner/level_reach.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <string>
#include <vector>

#include "terrastride/planner/request_limits.hpp"
#include "terrastride/terrain/levels.hpp"
#include "terrastride/terrain/terrain_map.hpp"

namespace terrastride::planner {
namespace {

// The ground the check walks on: heights per cell, whether a foot can stand there, and the
// overhang's underside where it cannot (for the message).
struct LevelGrid : terrain::LevelInput {
  std::vector<float> overhang;

  int index(double x, double y) const {
    const double fx = (x - geometry.origin.x()) / geometry.resolution;
    const double fy = (y - geometry.origin.y()) / geometry.resolution;
    if (!(fx >= 0 && fy >= 0)) return -1;
    const int i = std::min(static_cast<int>(fx), geometry.nx - 1);
    const int j = std::min(static_cast<int>(fy), geometry.ny - 1);
    if (fx > geometry.nx || fy > geometry.ny) return -1;
    return static_cast<int>(geometry.index(i, j));
  }
};

constexpr double kSceneResolution = 0.02;
constexpr double kMaxSceneCells = 4e6;

LevelGrid level_grid(const terrain::HeightField& terrain) {
  LevelGrid l;
  if (const auto* map = dynamic_cast<const terrain::TerrainMap*>(&terrain)) {
    const terrain::HeightGrid& g = map->grid();
    static_cast<terrain::LevelInput&>(l) = terrain::level_input(g);
    l.overhang.assign(g.geometry.size(), std::numeric_limits<float>::infinity());
    for (size_t k = 0; k < g.geometry.size(); ++k)
      if (!l.ground[k]) l.overhang[k] = g.overhead[k];
    return l;
  }
  const Eigen::Vector2d lo = terrain.min_corner(), hi = terrain.max_corner();
  const Eigen::Vector2d size = hi - lo;
  double res = kSceneResolution;
  if (!(size.x() > 0 && size.y() > 0) || !size.allFinite()) return l;
  res = std::max(res, std::sqrt(size.x() * size.y() / kMaxSceneCells));
  l.geometry.origin = lo;
  l.geometry.resolution = res;
  l.geometry.nx = std::max(1, static_cast<int>(std::ceil(size.x() / res)));
  l.geometry.ny = std::max(1, static_cast<int>(std::ceil(size.y() / res)));
  l.height.resize(l.geometry.size());
  l.ground.assign(l.geometry.size(), 1);
  l.overhang.assign(l.geometry.size(), std::numeric_limits<float>::infinity());
  for (int i = 0; i < l.geometry.nx; ++i)
    for (int j = 0; j < l.geometry.ny; ++j) {
      const Eigen::Vector2d c = l.geometry.center(i, j).cwiseMin(hi);
      l.height[l.geometry.index(i, j)] = static_cast<float>(terrain.height(c.x(), c.y()));
    }
  return l;
}

std::string num(double v) {
  std::ostringstream os;
  os.setf(std::ios::fixed);
  os.precision(2);
  os << v;
  return os.str();
}

std::string pose(const Eigen::Vector3d& p) {
  std::ostringstream os;
  os << "[" << p.x() << ", " << p.y() << ", " << p.z() << "]";
  return os.str();
}

}  // namespace

double leg_reach(const robot::RobotModel& robot) {
  double reach = 0.0;
  for (const auto& leg : robot.legs) {
    double sum = 0.0;
    for (const auto& d : leg.joint_offset) sum += d.norm();
    reach = std::max(reach, sum);
  }
  return reach;
}

void check_level_reach(const terrain::HeightField& terrain, const robot::RobotModel& robot,
                       const Eigen::Vector3d& start, const Eigen::Vector3d& goal) {
  const double reach = leg_reach(robot);
  if (!(reach > 0) || robot.legs.empty()) return;
  const LevelGrid l = level_grid(terrain);
  if (l.geometry.size() == 0) return;
  struct Foot {
    std::string name;
    Eigen::Vector2d xy;
    int cell;
  };
  const auto feet = [&](const Eigen::Vector3d& p) {
    std::vector<Foot> out;
    for (const auto& leg : robot.legs) {
      const Eigen::Vector3d f =
          robot::nominal_foot_world(leg, Eigen::Vector3d(p.x(), p.y(), 0.0), p.z());
      out.push_back({leg.name, f.head<2>(), l.index(f.x(), f.y())});
    }
    return out;
  };
  const std::vector<Foot> start_feet = feet(start), goal_feet = feet(goal);
  int source = -1;
  for (const Foot& f : start_feet)
    if (f.cell >= 0 && l.ground[f.cell]) {
      source = f.cell;
      break;
    }
  const auto where = [](const Foot& f) {
    return "the nominal " + f.name + " foot at (" + num(f.xy.x()) + ", " + num(f.xy.y()) + ")";
  };
  const auto no_ground = [&](const char* field, const Eigen::Vector3d& p, const Foot& f) {
    std::string level = source >= 0 ? ", the start's ground at z " + num(l.height[source]) + " m" : "";
    throw RequestError(field, pose(p) + ": " + where(f) +
                                  " has no walkable ground: only an overhang (a ceiling, a table "
                                  "top seen from beneath) was seen there, its underside at z " +
                                  num(l.overhang[f.cell]) + " m" + level +
                                  "; choose a " + field + " on the mapped ground");
  };
  for (const Foot& f : start_feet)
    if (f.cell >= 0 && !l.ground[f.cell]) no_ground("start", start, f);
  for (const Foot& f : goal_feet)
    if (f.cell >= 0 && !l.ground[f.cell]) no_ground("goal", goal, f);
  if (source < 0) return;
  const std::vector<uint8_t> reached = terrain::reachable_cells(l, source, reach);
  const auto refuse = [&](const char* field, const Eigen::Vector3d& p, const Foot& f) {
    throw RequestError(
        field, pose(p) + ": " + where(f) + " stands on a surface at z " + num(l.height[f.cell]) +
                   " m that the robot cannot reach from the start's ground at z " +
                   num(l.height[source]) + " m: no way over the map climbs it in steps of at most "
                   "the leg length, " + num(reach) + " m (a ceiling, a cupboard top, a level of its "
                   "own?); choose a " + field + " on the start's level");
  };
  for (const Foot& f : start_feet)
    if (f.cell >= 0 && !reached[f.cell]) refuse("start", start, f);
  for (const Foot& f : goal_feet)
    if (f.cell >= 0 && !reached[f.cell]) refuse("goal", goal, f);
}

}  // namespace terrastride::planner
