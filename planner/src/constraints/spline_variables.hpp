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

// The inner Bezier control points of a scalar cubic Hermite segment split at its middle (de
// Casteljau): A = p0 + h v0 / 6, B = pm - h vm / 6, C = pm, D = pm + h vm / 6, E = p1 - h v1 / 6,
// with pm and vm the value and rate at the middle. Each half lies in the hull of its control points
// (four times closer to the curve than the whole segment's), so bounds on them bound the curve
// (lateral_corridor, swing_apex).
template <class T>
struct HalfControlPoints {
  T a, b, c, d, e;
};
template <class T>
HalfControlPoints<T> half_control_points(const T& h, const T& p0, const T& v0, const T& p1,
                                         const T& v1) {
  const T pm = hermite_value(0.5, h, p0, v0, p1, v1);
  const T hvm = 1.5 * (p1 - p0) - h * (v0 + v1) / 4.0;  // h times the rate at the middle
  return {p0 + h * v0 / 6.0, pm - hvm / 6.0, pm, pm + hvm / 6.0, p1 - h * v1 / 6.0};
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

// What a leg's rows at fraction sigma of segment s read: the base position's, the Euler angles'
// and foot f's Hermite segments and the segment's duration (the rates scale by it), with their
// values and, unless value_only, rates there.
struct LegSplinePoint {
  HermiteLocal base, euler, foot;
  int duration = -1;
  double seg_fraction = 0.0, sigma = 0.0;
  // Null outputs are not computed.
  template <class T>
  void eval(const T* x, Vec3<T>* r, Vec3<T>* rv, Vec3<T>* e, Vec3<T>* ev, Vec3<T>* p,
            Vec3<T>* pv) const {
    const T h = x[duration] * seg_fraction;
    hermite<T>(sigma, h, x, base, r, rv, nullptr);
    hermite<T>(sigma, h, x, euler, e, ev, nullptr);
    hermite<T>(sigma, h, x, foot, p, pv, nullptr);
  }
};
inline LegSplinePoint add_leg_spline_point(LocalVars& lv, const Layout& L, int f, int s,
                                           double sigma, bool value_only) {
  LegSplinePoint lp;
  lp.base = add_base_position(lv, L, s, sigma, value_only);
  lp.euler = add_base_euler(lv, L, s, sigma, value_only);
  lp.foot = add_foot_position(lv, L, f, s, sigma, value_only);
  lp.duration = add_segment_duration(lv, L, s);
  lp.seg_fraction = L.seg_fraction[s];
  lp.sigma = sigma;
  return lp;
}

}  // namespace terrastride::planner
