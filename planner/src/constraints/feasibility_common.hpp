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
// The same for a leg point's pieces (shin_ik, thigh; leg_capsule_clearance.hpp): their rows depend
// on the piece's variables only through the foot, the base position and Euler angles at the point
// and, in stance, the base pose at the stance's first knot (15 scalars).
constexpr int kLegInnerScalars = 15;
using AdLeg = Eigen::AutoDiffScalar<Eigen::Matrix<double, kLegInnerScalars, 1>>;
inline double value_of(const AdInner& v) { return v.value(); }
inline double value_of(const AdLeg& v) { return v.value(); }
template <int N>
Eigen::AutoDiffScalar<Eigen::Matrix<double, N, 1>> terrain_height(
    const terrain::HeightField& f, const Eigen::AutoDiffScalar<Eigen::Matrix<double, N, 1>>& x,
    const Eigen::AutoDiffScalar<Eigen::Matrix<double, N, 1>>& y) {
  Eigen::Vector2d g;
  const double h = f.height_and_gradient(x.value(), y.value(), &g);
  return {h, g.x() * x.derivatives() + g.y() * y.derivatives()};
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
// The same for a fixed-size derivative vector (always sized; starts at zero).
template <int N>
void accumulate(Eigen::Matrix<double, N, 1>* d, double a, const Eigen::Matrix<double, N, 1>& da) {
  if (a != 0.0) *d += a * da;
}
// d outer / d x of a result r computed on inner AD scalars seeded at outer[0..n-1]:
// sum_i dr/dinner_i * d outer_i / dx, as the outer AD type (Ad, or AdLeg around AdInner).
template <class Outer, class Inner>
Outer chain_inner(const Inner& r, const Outer* const* outer, int n) {
  using Der = typename Outer::DerType;
  Der d;
  if constexpr (Der::SizeAtCompileTime != Eigen::Dynamic) d.setZero();
  for (int i = 0; i < n; ++i) accumulate(&d, r.derivatives()[i], outer[i]->derivatives());
  return Outer(r.value(), d);
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
