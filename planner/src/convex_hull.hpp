// The convex hull of a few points in the horizontal plane (a robot's feet): the support polygon
// that plan_quality's margin and a planning session's capture step both measure against.
#pragma once

#include <Eigen/Core>
#include <algorithm>
#include <vector>

namespace terrastride::planner {

// (a - o) x (b - o): positive when b lies to the left of the line from o through a.
inline double cross_2d(const Eigen::Vector2d& o, const Eigen::Vector2d& a, const Eigen::Vector2d& b) {
  return (a - o).x() * (b - o).y() - (a - o).y() * (b - o).x();
}

// Andrew's monotone chain: the hull's corners counter-clockwise, the first not repeated,
// collinear points left out; one or no point is returned as given.
inline std::vector<Eigen::Vector2d> convex_hull_2d(std::vector<Eigen::Vector2d> points) {
  if (points.size() < 2) return points;
  std::sort(points.begin(), points.end(), [](const auto& a, const auto& b) {
    return a.x() < b.x() || (a.x() == b.x() && a.y() < b.y());
  });
  std::vector<Eigen::Vector2d> hull(2 * points.size());
  std::size_t k = 0;
  for (std::size_t i = 0; i < points.size(); ++i) {  // lower chain
    while (k >= 2 && cross_2d(hull[k - 2], hull[k - 1], points[i]) <= 0) --k;
    hull[k++] = points[i];
  }
  for (std::size_t i = points.size() - 1, lower = k + 1; i-- > 0;) {  // upper chain
    while (k >= lower && cross_2d(hull[k - 2], hull[k - 1], points[i]) <= 0) --k;
    hull[k++] = points[i];
  }
  hull.resize(k - 1);
  return hull;
}

}  // namespace terrastride::planner
