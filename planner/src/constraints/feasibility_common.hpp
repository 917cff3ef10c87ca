// Shared helpers of the feasibility constraint sets (foot.cpp, shin.cpp, shin_ik.cpp, polytope.cpp,
// joints.cpp): AD overloads of the terrain/model queries they use. (The leg's IK is the
// robot's, robot/geometry.hpp.)
#pragma once

#include <algorithm>
#include <cmath>

#include "terrastride/planner/piece_math.hpp"
#include "terrastride/robot/robot_model.hpp"

namespace terrastride::planner {

// A small fixed-size AD scalar for the inner part of a piece that depends on the piece's many
// variables only through a few intermediate scalars (leg_capsule_clearance.hpp: the link's two
// ends, and a few more): that part runs on derivatives with respect to these scalars (9, fixed
// size: no copies of 72-slot vectors), and its result is chained to the piece's variables once.
using AdInner = Eigen::AutoDiffScalar<Eigen::Matrix<double, 9, 1>>;
inline double value_of(const AdInner& v) { return v.value(); }
inline AdInner terrain_height(const terrain::HeightField& f, const AdInner& x, const AdInner& y) {
  Eigen::Vector2d g;
  const double h = f.height_and_gradient(x.value(), y.value(), &g);
  return AdInner(h, g.x() * x.derivatives() + g.y() * y.derivatives());
}

}  // namespace terrastride::planner

namespace terrastride::planner::feasibility {

constexpr int kMaxShinValues = 128;  // values one shin piece may fold into its soft minimum

inline void accumulate(AdVector* d, double a, const AdVector& da) {
  if (!da.size() || a == 0.0) return;
  if (!d->size())
    *d = a * da;
  else
    *d += a * da;
}

// Signed foothold-safety margin for a foot of radius r, its gradient chained through (x, y).
inline double safety_margin(const terrain::HeightField& f, double x, double y, double r) {
  return f.safety_margin(x, y, r).margin;
}
inline Ad safety_margin(const terrain::HeightField& f, const Ad& x, const Ad& y, double r) {
  const terrain::MarginSample s = f.safety_margin(x.value(), y.value(), r);
  return Ad(s.margin, chain2(s.gradient.x(), x.derivatives(), s.gradient.y(), y.derivatives()));
}

// Smooth conservative minimum of v[0..n-1] at scale t > 0 (log-sum-exp):
//   soft_min = -t log(sum_k exp(-v_k / t)),  min_k v_k - t log(n) <= soft_min <= min_k v_k.
// So soft_min >= c implies v_k >= c for every k: one row soft_min(v) >= c replaces n rows
// v_k >= c without admitting anything they forbid, and asks at most t log(n) more (as much only
// when all v_k are equal; a value t above the minimum weighs exp(-1) of it). Shifted by the
// minimum's value (a constant for the derivatives) so the exponentials cannot overflow.
template <class T>
T soft_min(const T* v, int n, double t) {
  using std::exp;
  using std::log;
  double m = value_of(v[0]);
  for (int k = 1; k < n; ++k) m = std::min(m, value_of(v[k]));
  T sum = exp(-(v[0] - m) / t);
  for (int k = 1; k < n; ++k) sum += exp(-(v[k] - m) / t);
  return m - t * log(sum);
}
// The conservative smooth maximum: soft_max >= max_k v_k (so soft_max <= c implies v_k <= c).
template <class T>
T soft_max(const T* v, int n, double t) {
  using std::exp;
  using std::log;
  double m = value_of(v[0]);
  for (int k = 1; k < n; ++k) m = std::max(m, value_of(v[k]));
  T sum = exp((v[0] - m) / t);
  for (int k = 1; k < n; ++k) sum += exp((v[k] - m) / t);
  return m + t * log(sum);
}

}  // namespace terrastride::planner::feasibility
