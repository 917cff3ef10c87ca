// The local variables of the splines a constraint piece evaluates at fraction sigma of segment s
// (see HermiteLocal: at a segment end, with value_only, only that knot's value enters).
#pragma once

#include "terrastride/planner/layout.hpp"
#include "terrastride/planner/piece_math.hpp"

namespace terrastride::planner {

// The duration variable of segment s's interval (the segment lasts x[duration] * seg_fraction[s]).
inline int add_segment_duration(LocalVars& lv, const Layout& L, int s) {
  return lv.add(L.interval_var[L.seg_interval[s]]);
}

// The base position's Hermite segment s.
inline HermiteLocal add_base_position(LocalVars& lv, const Layout& L, int s, double sigma,
                                      bool value_only) {
  return add_hermite(lv, L.base[s], L.base[s] + 3, L.base[s + 1], L.base[s + 1] + 3, sigma,
                     value_only);
}

// The base's ZYX Euler angles' Hermite segment s.
inline HermiteLocal add_base_euler(LocalVars& lv, const Layout& L, int s, double sigma,
                                   bool value_only) {
  return add_hermite(lv, L.base[s] + 6, L.base[s] + 9, L.base[s + 1] + 6, L.base[s + 1] + 9, sigma,
                     value_only);
}

// Foot f's Hermite segment s (in stance, both knots share the foothold and have zero velocity).
inline HermiteLocal add_foot_position(LocalVars& lv, const Layout& L, int f, int s, double sigma,
                                      bool value_only) {
  return add_hermite(lv, L.foot_pos[f][s], L.foot_vel[f][s], L.foot_pos[f][s + 1],
                     L.foot_vel[f][s + 1], sigma, value_only);
}

}  // namespace terrastride::planner
