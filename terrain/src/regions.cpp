// The connected regions of a map where a robot's stance fits on safe ground (regions.hpp).
//
// A cell is standable when, for one of the tried headings, every nominal foot point of a base
// centred on the cell lies on a cell the foot radius's safety layer calls safe, and no ground
// within the body's reach (feet included) rises above the lowest foot by more than the body
// clears. Standable cells
// that touch (8-neighbours) form a region: the base can shuffle from one to the next, a cell at a
// time, with every foot on safe ground. This is a necessary condition for a plan, not a
// sufficient one (the feet need not stay at their nominal points; the gait's footholds may fall
// elsewhere), which is why the listing suggests a start deep inside a region and goals along it.
#include "terrastride/terrain/regions.hpp"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <deque>
#include <functional>
#include <iomanip>
#include <limits>
#include <queue>
#include <sstream>
#include <utility>

#include "terrastride/perception/point_cloud.hpp"

namespace terrastride::terrain {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr int kDi[8] = {-1, -1, -1, 0, 0, 1, 1, 1};
constexpr int kDj[8] = {-1, 0, 1, -1, 1, -1, 0, 1};

// Per cell, the highest elevation within `hx` cells along x and `hy` along y (a rectangular
// window), as two separable passes.
std::vector<float> window_max(const GridGeometry& g, const std::vector<float>& v, int hx, int hy) {
  std::vector<float> rows(v.size()), out(v.size());
  for (int i = 0; i < g.nx; ++i)
    for (int j = 0; j < g.ny; ++j) {
      float m = -std::numeric_limits<float>::infinity();
      for (int a = std::max(0, i - hx); a <= std::min(g.nx - 1, i + hx); ++a)
        m = std::max(m, v[g.index(a, j)]);
      rows[g.index(i, j)] = m;
    }
  for (int i = 0; i < g.nx; ++i)
    for (int j = 0; j < g.ny; ++j) {
      float m = -std::numeric_limits<float>::infinity();
      for (int b = std::max(0, j - hy); b <= std::min(g.ny - 1, j + hy); ++b)
        m = std::max(m, rows[g.index(i, b)]);
      out[g.index(i, j)] = m;
    }
  return out;
}

// The body's window for a heading: the rectangle turned onto the grid's axes when the heading is
// (a multiple of 90 deg) along them, else the square holding the rectangle at any heading.
Eigen::Vector2i body_window(const Eigen::Vector2d& half, double yaw, double resolution) {
  const double q = std::remainder(yaw, 0.5 * kPi);
  Eigen::Vector2d h;
  if (std::abs(q) < 1e-9) {
    const bool swapped = std::abs(std::sin(yaw)) > 0.5;
    h = swapped ? Eigen::Vector2d(half.y(), half.x()) : half;
  } else {
    h = Eigen::Vector2d::Constant(half.norm());
  }
  return {static_cast<int>(std::ceil(h.x() / resolution - 1e-9)),
          static_cast<int>(std::ceil(h.y() / resolution - 1e-9))};
}

// Per cell, one bit per heading at which the stance fits (0: not standable). At most 8 headings.
std::vector<uint8_t> standable_headings(const TerrainMap& map, const RegionOptions& o) {
  const GridGeometry& g = map.grid().geometry;
  const std::vector<uint8_t>& safe = map.layer(o.footprint.foot_radius).safe;
  const std::vector<float>& elevation = map.grid().elevation;
  Eigen::Vector2d half = o.footprint.body_half;
  for (const auto& f : o.footprint.feet) half = half.cwiseMax(f.cwiseAbs());
  // One window per distinct shape (at most three: along x, along y, turned).
  std::vector<Eigen::Vector2i> shapes;
  std::vector<std::vector<float>> highest;
  std::vector<size_t> window_of;
  for (double yaw : o.yaws) {
    const Eigen::Vector2i w = body_window(half, yaw, g.resolution);
    size_t k = 0;
    while (k < shapes.size() && shapes[k] != w) ++k;
    if (k == shapes.size()) {
      shapes.push_back(w);
      highest.push_back(window_max(g, elevation, w.x(), w.y()));
    }
    window_of.push_back(k);
  }
  std::vector<std::vector<Eigen::Vector2d>> rotated;
  for (double yaw : o.yaws) {
    const double c = std::cos(yaw), s = std::sin(yaw);
    std::vector<Eigen::Vector2d> feet;
    for (const auto& f : o.footprint.feet)
      feet.emplace_back(c * f.x() - s * f.y(), s * f.x() + c * f.y());
    rotated.push_back(std::move(feet));
  }
  std::vector<uint8_t> bits(g.size(), 0);
  for (int i = 0; i < g.nx; ++i)
    for (int j = 0; j < g.ny; ++j) {
      if (!safe[g.index(i, j)]) continue;  // the base's own cell need not hold a foot, but a
                                           // stance over an unsafe centre is a poor suggestion
      const Eigen::Vector2d c = g.center(i, j);
      for (size_t y = 0; y < rotated.size(); ++y) {
        bool fits = true;
        float low_foot = std::numeric_limits<float>::infinity();
        for (const auto& f : rotated[y]) {
          const int k = map.cell_index(c.x() + f.x(), c.y() + f.y());
          if (k < 0 || !safe[static_cast<size_t>(k)]) {
            fits = false;
            break;
          }
          low_foot = std::min(low_foot, elevation[static_cast<size_t>(k)]);
        }
        // The window holds the feet too: no foot, and no ground the body passes over, more than
        // max_rise above the lowest foot (a foot on a wall top is no stance).
        fits = fits && highest[window_of[y]][g.index(i, j)] <= low_foot + o.footprint.max_rise;
        if (fits) bits[g.index(i, j)] |= static_cast<uint8_t>(1u << y);
      }
    }
  return bits;
}

// Connected components of the standable cells (8-neighbours); -1 for other cells.
std::vector<std::vector<size_t>> components(const GridGeometry& g,
                                            const std::vector<uint8_t>& bits,
                                            std::vector<int>* label) {
  label->assign(g.size(), -1);
  std::vector<std::vector<size_t>> out;
  for (size_t seed = 0; seed < g.size(); ++seed) {
    if (!bits[seed] || (*label)[seed] >= 0) continue;
    const int id = static_cast<int>(out.size());
    out.emplace_back();
    std::deque<size_t> todo{seed};
    (*label)[seed] = id;
    while (!todo.empty()) {
      const size_t k = todo.front();
      todo.pop_front();
      out.back().push_back(k);
      const int i = static_cast<int>(k) / g.ny, j = static_cast<int>(k) % g.ny;
      for (int d = 0; d < 8; ++d) {
        const int a = i + kDi[d], b = j + kDj[d];
        if (a < 0 || b < 0 || a >= g.nx || b >= g.ny) continue;
        const size_t n = g.index(a, b);
        if (bits[n] && (*label)[n] < 0) {
          (*label)[n] = id;
          todo.push_back(n);
        }
      }
    }
  }
  return out;
}

// Per standable cell, the number of 8-neighbour steps to the nearest cell that is not standable
// (or outside the grid): breadth-first from the region borders.
std::vector<int> border_steps(const GridGeometry& g, const std::vector<uint8_t>& bits) {
  std::vector<int> steps(g.size(), -1);
  std::deque<size_t> todo;
  for (int i = 0; i < g.nx; ++i)
    for (int j = 0; j < g.ny; ++j) {
      const size_t k = g.index(i, j);
      if (!bits[k]) continue;
      bool border = false;
      for (int d = 0; d < 8 && !border; ++d) {
        const int a = i + kDi[d], b = j + kDj[d];
        border = a < 0 || b < 0 || a >= g.nx || b >= g.ny || !bits[g.index(a, b)];
      }
      if (border) {
        steps[k] = 1;
        todo.push_back(k);
      }
    }
  while (!todo.empty()) {
    const size_t k = todo.front();
    todo.pop_front();
    const int i = static_cast<int>(k) / g.ny, j = static_cast<int>(k) % g.ny;
    for (int d = 0; d < 8; ++d) {
      const int a = i + kDi[d], b = j + kDj[d];
      if (a < 0 || b < 0 || a >= g.nx || b >= g.ny) continue;
      const size_t n = g.index(a, b);
      if (bits[n] && steps[n] < 0) {
        steps[n] = steps[k] + 1;
        todo.push_back(n);
      }
    }
  }
  return steps;
}

// Shortest path lengths (m) from `start` through the cells of one region (Dijkstra, 8-neighbours).
std::vector<double> path_lengths(const GridGeometry& g, const std::vector<int>& label, int id,
                                 size_t start) {
  std::vector<double> dist(g.size(), std::numeric_limits<double>::infinity());
  using Item = std::pair<double, size_t>;
  std::priority_queue<Item, std::vector<Item>, std::greater<Item>> queue;
  dist[start] = 0.0;
  queue.push({0.0, start});
  while (!queue.empty()) {
    const auto [d, k] = queue.top();
    queue.pop();
    if (d > dist[k]) continue;
    const int i = static_cast<int>(k) / g.ny, j = static_cast<int>(k) % g.ny;
    for (int n = 0; n < 8; ++n) {
      const int a = i + kDi[n], b = j + kDj[n];
      if (a < 0 || b < 0 || a >= g.nx || b >= g.ny) continue;
      const size_t m = g.index(a, b);
      if (label[m] != id) continue;
      const double step = g.resolution * ((kDi[n] && kDj[n]) ? std::sqrt(2.0) : 1.0);
      if (d + step < dist[m]) {
        dist[m] = d + step;
        queue.push({dist[m], m});
      }
    }
  }
  return dist;
}

// The region's shape: bounding box, principal axis and extents along and across it.
void measure_shape(const GridGeometry& g, const std::vector<size_t>& cells, SafeRegion* r) {
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();
  r->lo = Eigen::Vector2d::Constant(std::numeric_limits<double>::infinity());
  r->hi = -r->lo;
  for (size_t k : cells) {
    const Eigen::Vector2d c = g.center(static_cast<int>(k) / g.ny, static_cast<int>(k) % g.ny);
    mean += c;
    r->lo = r->lo.cwiseMin(c);
    r->hi = r->hi.cwiseMax(c);
  }
  mean /= static_cast<double>(cells.size());
  Eigen::Matrix2d cov = Eigen::Matrix2d::Zero();
  for (size_t k : cells) {
    const Eigen::Vector2d d =
        g.center(static_cast<int>(k) / g.ny, static_cast<int>(k) % g.ny) - mean;
    cov += d * d.transpose();
  }
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> eig(cov);
  Eigen::Vector2d axis = eig.eigenvectors().col(1);  // largest eigenvalue last
  if (axis.x() < 0 || (axis.x() == 0 && axis.y() < 0)) axis = -axis;
  r->axis_yaw = std::atan2(axis.y(), axis.x());
  const Eigen::Vector2d across(-axis.y(), axis.x());
  double a0 = std::numeric_limits<double>::infinity(), a1 = -a0, c0 = a0, c1 = -a0;
  for (size_t k : cells) {
    const Eigen::Vector2d c = g.center(static_cast<int>(k) / g.ny, static_cast<int>(k) % g.ny);
    a0 = std::min(a0, c.dot(axis));
    a1 = std::max(a1, c.dot(axis));
    c0 = std::min(c0, c.dot(across));
    c1 = std::max(c1, c.dot(across));
  }
  r->length_m = a1 - a0 + g.resolution;
  r->width_m = c1 - c0 + g.resolution;
  r->lo -= Eigen::Vector2d::Constant(0.5 * g.resolution);
  r->hi += Eigen::Vector2d::Constant(0.5 * g.resolution);
}

// The heading among the standable ones at `bits` nearest to the axis (headings taken modulo pi:
// a robot may walk the axis either way).
int heading_near(uint8_t bits, const std::vector<double>& yaws, double axis_yaw) {
  int best = -1;
  double best_gap = std::numeric_limits<double>::infinity();
  for (size_t y = 0; y < yaws.size(); ++y) {
    if (!(bits & (1u << y))) continue;
    double gap = std::fmod(std::abs(yaws[y] - axis_yaw), kPi);
    gap = std::min(gap, kPi - gap);
    if (gap < best_gap) {
      best_gap = gap;
      best = static_cast<int>(y);
    }
  }
  return best;
}

RegionPose pose_at(const TerrainMap& map, size_t k, double yaw) {
  const GridGeometry& g = map.grid().geometry;
  RegionPose p;
  p.xy = g.center(static_cast<int>(k) / g.ny, static_cast<int>(k) % g.ny);
  p.yaw = yaw;
  p.height = map.height(p.xy.x(), p.xy.y());
  return p;
}

// Goals inside the region: the cells standable at the start's heading nearest to the points
// goal_distance ahead of and behind the start along that heading, and the cell farthest along a
// path.
void choose_goals(const TerrainMap& map, const std::vector<size_t>& cells,
                  const std::vector<uint8_t>& bits, const std::vector<double>& dist,
                  int start_heading, const RegionOptions& o, SafeRegion* r) {
  const GridGeometry& g = map.grid().geometry;
  // Ahead and behind along the start's heading: the way the robot walks from its start.
  const double yaw = o.yaws[static_cast<size_t>(start_heading)];
  const Eigen::Vector2d axis(std::cos(yaw), std::sin(yaw));
  std::vector<size_t> picked;
  for (double sign : {1.0, -1.0}) {
    const Eigen::Vector2d target = r->start.xy + sign * o.goal_distance * axis;
    size_t best = cells.front();
    double best_d = std::numeric_limits<double>::infinity();
    for (size_t k : cells) {
      if (!(bits[k] & (1u << start_heading)) || !std::isfinite(dist[k])) continue;
      const double d =
          (g.center(static_cast<int>(k) / g.ny, static_cast<int>(k) % g.ny) - target).norm();
      if (d < best_d) {
        best_d = d;
        best = k;
      }
    }
    if (std::isfinite(best_d) && dist[best] >= 0.5 * o.goal_distance) picked.push_back(best);
  }
  size_t far = cells.front();
  for (size_t k : cells)
    if (std::isfinite(dist[k]) && dist[k] > dist[far]) far = k;
  if (std::find(picked.begin(), picked.end(), far) == picked.end() && dist[far] > 0)
    picked.push_back(far);
  for (size_t k : picked) {
    const int h = bits[k] & (1u << start_heading) ? start_heading
                                                   : heading_near(bits[k], o.yaws, yaw);
    r->goals.push_back({pose_at(map, k, o.yaws[static_cast<size_t>(h)]), dist[k]});
  }
}

SafeRegion describe_component(const TerrainMap& map, const std::vector<size_t>& cells,
                              const std::vector<uint8_t>& bits, const std::vector<int>& label,
                              const std::vector<int>& steps, const RegionOptions& o) {
  const GridGeometry& g = map.grid().geometry;
  SafeRegion r;
  r.cells = cells.size();
  r.area_m2 = static_cast<double>(cells.size()) * g.resolution * g.resolution;
  measure_shape(g, cells, &r);
  r.height_min = std::numeric_limits<double>::infinity();
  r.height_max = -r.height_min;
  size_t start = cells.front();
  for (size_t k : cells) {
    const double z = map.grid().elevation[k];
    r.height_min = std::min(r.height_min, z);
    r.height_max = std::max(r.height_max, z);
    if (steps[k] > steps[start]) start = k;  // first of the deepest, in index order
  }
  // Along an elongated region (a corridor) the robot faces its long axis; on a roundish one it
  // faces +x, the planner's default heading.
  const double preferred = r.length_m >= 1.5 * r.width_m ? r.axis_yaw : 0.0;
  const int heading = heading_near(bits[start], o.yaws, preferred);
  r.start = pose_at(map, start, o.yaws[static_cast<size_t>(heading)]);
  r.start_border_m = steps[start] * g.resolution;
  const std::vector<double> dist = path_lengths(g, label, label[start], start);
  choose_goals(map, cells, bits, dist, heading, o, &r);
  return r;
}

}  // namespace

RegionListing list_safe_regions(const TerrainMap& map, const RegionOptions& o) {
  if (o.footprint.feet.empty())
    throw perception::InputError("regions: the robot's footprint has no foot");
  for (const auto& f : o.footprint.feet)
    if (!f.allFinite()) throw perception::InputError("regions: a foot point is not finite");
  if (!(o.footprint.body_half.minCoeff() >= 0 && o.footprint.body_half.maxCoeff() < 100) ||
      !(o.footprint.max_rise >= 0))
    throw perception::InputError("regions: body radius and rise must be finite and >= 0");
  if (o.yaws.empty() || o.yaws.size() > 8)
    throw perception::InputError("regions: between 1 and 8 headings are tried");
  const GridGeometry& g = map.grid().geometry;
  RegionListing out;
  out.foot_radius = o.footprint.foot_radius;
  out.resolution = g.resolution;
  const std::vector<uint8_t> bits = standable_headings(map, o);
  std::vector<int> label;
  std::vector<std::vector<size_t>> comps = components(g, bits, &label);
  for (const auto& c : comps) out.standable_cells += c.size();
  const double cell_area = g.resolution * g.resolution;
  const auto small = std::remove_if(comps.begin(), comps.end(), [&](const auto& c) {
    return static_cast<double>(c.size()) * cell_area < o.min_area;
  });
  out.regions_too_small = static_cast<size_t>(comps.end() - small);
  comps.erase(small, comps.end());
  out.regions_total = comps.size();
  std::stable_sort(comps.begin(), comps.end(),
                   [](const auto& a, const auto& b) { return a.size() > b.size(); });
  if (comps.size() > o.max_regions) comps.resize(o.max_regions);
  const std::vector<int> steps = border_steps(g, bits);
  for (const auto& c : comps) {
    out.regions.push_back(describe_component(map, c, bits, label, steps, o));
    out.regions.back().id = static_cast<int>(out.regions.size());
  }
  return out;
}

std::string describe_regions(const RegionListing& l) {
  std::ostringstream os;
  os << std::fixed << std::setprecision(2);
  if (l.regions.empty()) {
    os << "no region of this map holds the robot's stance on safe ground (foot radius "
       << l.foot_radius << " m";
    if (l.regions_too_small) os << "; " << l.regions_too_small << " too small";
    os << ")\n";
    return os.str();
  }
  os << l.regions_total << " region" << (l.regions_total == 1 ? "" : "s")
     << " where the robot's stance fits on safe ground (foot radius " << l.foot_radius << " m)";
  if (l.regions_total > l.regions.size()) os << "; the " << l.regions.size() << " largest";
  if (l.regions_too_small)
    os << " (" << l.regions_too_small << " smaller than the minimum area left out)";
  os << "\n";
  for (const SafeRegion& r : l.regions) {
    // Elongated: the base may walk along it much farther than across (a corridor, an aisle).
    const bool corridor = r.length_m >= 2.5 * r.width_m && r.length_m >= 2.0;
    os << "region " << r.id << ": " << r.length_m << " m x " << r.width_m << " m"
       << (corridor ? " (corridor-like)" : "") << ", " << r.area_m2 << " m2, x " << r.lo.x()
       << ".." << r.hi.x() << ", y " << r.lo.y() << ".." << r.hi.y() << ", ground at z "
       << r.height_min << ".." << r.height_max << "\n";
    os << "  start " << r.start.xy.x() << "," << r.start.xy.y() << " heading "
       << r.start.yaw * 180.0 / kPi << " deg (" << r.start_border_m << " m from the border)";
    for (const RegionGoal& goal : r.goals)
      os << "\n  goal  " << goal.pose.xy.x() << "," << goal.pose.xy.y() << " (" << goal.path_length
         << " m away)";
    os << "\n";
  }
  return os.str();
}

}  // namespace terrastride::terrain
