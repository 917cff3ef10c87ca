// How far the terrain around a foothold departs from its tangent plane: the measure the
// `foothold_planarity` constraint bounds (constraints/foothold_planarity.cpp), the initial guess uses to move footholds off
// step edges, and the end-stance reachability check (reachability.hpp) uses to find ground a foot
// can stand on. One definition, so that the three agree.
#pragma once

#include <algorithm>
#include <cmath>

#include "terrastride/planner/piece_math.hpp"
#include "terrastride/terrain/height_field.hpp"

namespace terrastride::planner {

// The four residuals h(p + probe o) - h(p) - probe grad h(p) . o for o = +x, -x, +y, -y: zero
// where the terrain is planar within `probe` of (x, y). T is double or the AD scalar.
template <class T>
void foothold_planarity_residuals(const terrain::HeightField& field, const T& x, const T& y,
                                  double probe, T* residuals) {
  const T h0 = terrain_height(field, x, y);
  T hx, hy;
  terrain_gradient(field, x, y, &hx, &hy);
  static const double ox[4] = {1, -1, 0, 0}, oy[4] = {0, 0, 1, -1};
  for (int i = 0; i < 4; ++i)
    residuals[i] = terrain_height(field, x + probe * ox[i], y + probe * oy[i]) - h0 -
                   probe * (hx * ox[i] + hy * oy[i]);
}

// The largest of the residuals' magnitudes (m).
inline double foothold_planarity_error(const terrain::HeightField& field, double x, double y,
                                       double probe) {
  double r[4];
  foothold_planarity_residuals(field, x, y, probe, r);
  double e = 0.0;
  for (double v : r) e = std::max(e, std::abs(v));
  return e;
}

}  // namespace terrastride::planner
