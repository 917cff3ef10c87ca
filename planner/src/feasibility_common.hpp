// Shared helpers of the feasibility constraint sets (foot_radius_set.cpp, shin_set.cpp,
// polytope_set.cpp): AD overloads of the terrain/model queries they use.
#pragma once

#include <cmath>

#include "terrastride/planner/piece_math.hpp"

namespace terrastride::planner::feasibility {

constexpr double kGravity = 9.81;
constexpr double kInf = 2e19;

// d = a * da + b * db for AD derivative vectors that may be empty (constants).
inline AdVector chain2(double a, const AdVector& da, double b, const AdVector& db) {
  if (da.size() && db.size()) return a * da + b * db;
  if (da.size()) return a * da;
  if (db.size()) return b * db;
  return AdVector();
}
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

// Scalar cubic Hermite value on a segment of duration h at fraction s.
template <class T>
T hermite_value(double s, const T& h, const T& p0, const T& v0, const T& p1, const T& v1) {
  const double s2 = s * s, s3 = s2 * s;
  return (2 * s3 - 3 * s2 + 1) * p0 + (s3 - 2 * s2 + s) * h * v0 + (-2 * s3 + 3 * s2) * p1 +
         (s3 - s2) * h * v1;
}

}  // namespace terrastride::planner::feasibility
