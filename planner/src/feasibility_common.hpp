// Shared helpers of the feasibility constraint sets (foot_radius_set.cpp, shin_set.cpp,
// polytope_set.cpp): AD overloads of the terrain/model queries they use.
#pragma once

#include <cmath>

#include "terrastride/planner/piece_math.hpp"

namespace terrastride::planner::feasibility {

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

}  // namespace terrastride::planner::feasibility
