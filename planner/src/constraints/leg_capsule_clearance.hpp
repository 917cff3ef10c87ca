// Shared by the leg clearance families (shin_ik.cpp, thigh.cpp): the values that keep one leg
// link, a capsule of radius r around the axis a -> b, clear of the terrain, for any scalar type.
//
// The model. nk points q_j on the axis, from the fraction t_start (the shin leaves out the part
// next to the foot that stands on the ground by design) to b. Each point must stand above the
// terrain by gap = r / cos(inclination) (a terrain point right below the axis is then one radius
// away from it, perpendicular distance = gap cos(inclination)), with cos capped at 0.5 (steeper,
// the lowest points could not clear flat ground by r / cos). The terrain is read
//  - under the point and under the NEXT point (the axis rises from a to b, so a step edge between
//    two points is held by the lower one too);
//  - and `probe` to either side of the point, across the base's heading. A capsule is as wide as
//    it is high: a board edge or a riser beside the axis (eur_pallet's deck boards, 41 mm apart)
//    is within r of it while the terrain right under the axis is the gap between the boards.
//    Measured on eur_pallet --goal 1.5,0,0 before the probes: RF's shin stood 7.8 mm above its
//    vertical bound on the exact terrain while its capsule was 8.7 mm into a deck board beside it.
//    The probe distance is r plus the spread of the planner's smoothed terrain (a step reaches its
//    full height within one 2 cm cell of its edge), so the probe sees the full height of anything
//    within r of the axis.
// Any terrain point within `probe` across the axis is thus below the axis by at least gap, so at
// least r from it; a point farther across is more than r away. Values are in m, >= 0 when clear.
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <vector>

#include "feasibility_common.hpp"
#include "spline_variables.hpp"
#include "terrastride/planner/feasibility.hpp"
#include "terrastride/planner/nlp.hpp"
#include "terrastride/planner/piece_math.hpp"
#include "terrastride/terrain/height_field.hpp"

namespace terrastride::planner::feasibility {

// Constraint points per segment for each leg, [foot][segment]: options.leg_clearance_points where
// the terrain near the leg is tall, 0 elsewhere (leg_clearance_points.cpp). "Near the leg": within
// kTallTerrainReach horizontally of the foot's initial-guess position at either end of the
// segment, the terrain rises more than kTallTerrainRise above the lower of those two foot heights.
constexpr double kTallTerrainReach = 0.45;  // m: the shin or thigh reach ~0.35 m from the foot
constexpr double kTallTerrainRise = 0.03;   // m
std::vector<std::vector<int>> leg_clearance_points(SrbdProblem& problem,
                                                   const FeasibilityOptions& options);

// Values one capsule adds: per point, the terrain under it and (but the last) under the next
// point, and with probe > 0 two probes across.
constexpr int capsule_clearance_values(int nk, bool probed) { return (probed ? 4 : 2) * nk - 1; }

// The rows of one link's pieces, shared by shin_ik and thigh. The capsule is the link's radius
// grown by options.leg_capsule_margin (what the planner holds clear is a fatter link than the
// post-hoc check and MuJoCo judge; see FeasibilityOptions::leg_capsule_margin); a fixed vertical
// clearance (fixed_gap, shin_ik's shin_clearance >= 0) replaces the grown radius's gap.
struct CapsuleRows {
  double gap_radius = 0.0;  // the radius whose gap r / cos(inclination) the values subtract
  double probe = 0.0;       // across the axis, 0: no probes
  int n_values = 0;         // values per piece (folded into one row with shin_softmin > 0)
  std::vector<double> lo, hi;
};
inline CapsuleRows capsule_rows(const std::string& family, double link_radius, bool fixed_gap,
                                double lower, int nk, const FeasibilityOptions& options) {
  CapsuleRows c;
  const double grown = link_radius + options.leg_capsule_margin;
  c.gap_radius = fixed_gap ? 0.0 : grown;
  c.probe = options.leg_probe_margin >= 0.0 ? grown + options.leg_probe_margin : 0.0;
  c.n_values = capsule_clearance_values(nk, c.probe > 0.0);
  if (c.n_values > kMaxShinValues || (options.shin_softmin <= 0.0 && c.n_values > 64))
    throw std::invalid_argument(family + ": too many points along the link (" +
                                std::to_string(nk) + " make " + std::to_string(c.n_values) +
                                " values per piece)");
  const int rows = options.shin_softmin > 0.0 ? 1 : c.n_values;
  c.lo.assign(rows, lower);
  c.hi.assign(rows, kInf);
  return c;
}

// One constraint point of a leg link's piece: the variables it reads (foot f's, the base position
// and Euler angles at fraction sigma of segment s, the segment's duration when a Hermite needs it;
// in stance also the base pose at the stance's first knot) and, for any scalar type, the leg's
// pose there.
//
// The foot rolls. A foot is a sphere fixed to the shin: while the shin turns during a stance the
// sphere rolls, and its centre and contact point move along the ground by r_foot times the
// shin's turn, which the planner's fixed foothold does not show. Measured in MuJoCo
// (simulation::simulate_plan) on the 11 s pallet_15 crawl with `all`: the RH contact point crept
// 11 mm towards the pallet over its 2.6 s stance (no sliding: the material point's slip was
// 1.6 mm; the report's "centre drift" is this roll, 17 mm at worst over the plan), and the shin,
// 5 mm clear of the edge in the plan, met it for 6.1 N s. So in stance the link rows use the foot
// rolled from the stance's touchdown: p + r_foot * dphi * h, h the heading and dphi the change of
// the shin's pitch in the vertical plane along h (atan2(u . h, u_z) of the foot-to-knee axis u)
// since the stance's first knot (rolling about an axis across the heading; a roll sideways, from
// the HAA joint, is small on a crawl and left out). A re-plan starting inside a stance counts the
// roll from its own start (the earlier part is in the measured state).
struct LegPoint {
  HermiteLocal foot, base, euler;
  int duration = -1;  // local index of the segment's duration, -1: not needed
  double sigma = 0.0, seg_fraction = 1.0;
  double roll_radius = 0.0;  // the foot sphere's radius in stance, 0 in swing (no roll)
  std::array<int, 3> touchdown_base{{-1, -1, -1}}, touchdown_euler{{-1, -1, -1}};

  // The point's raw scalars (kLegInnerScalars): the foot before its roll, the base position and
  // Euler angles at the point, and in stance the base position and Euler angles at the stance's
  // first knot (zeros in swing).
  template <class T>
  void raw(const T* x, Vec3<T>* out) const {
    const T h = duration >= 0 ? T(x[duration] * seg_fraction) : T(1.0);
    hermite<T>(sigma, h, x, foot, &out[0], nullptr, nullptr);
    hermite<T>(sigma, h, x, base, &out[1], nullptr, nullptr);
    hermite<T>(sigma, h, x, euler, &out[2], nullptr, nullptr);
    out[3] = roll_radius > 0.0 ? gather3(x, touchdown_base) : Vec3<T>::Zero();
    out[4] = roll_radius > 0.0 ? gather3(x, touchdown_euler) : Vec3<T>::Zero();
  }
  // From the raw scalars: the foot (rolled in stance), base position, Euler angles and rotation.
  template <class T>
  void pose(const robot::LegModel& leg, const Vec3<T>* raw, Vec3<T>* foot_w, Vec3<T>* base_w,
            Vec3<T>* euler_w, Eigen::Matrix<T, 3, 3>* R) const {
    using std::atan2;
    using std::cos;
    using std::sin;
    *foot_w = raw[0];
    *base_w = raw[1];
    *euler_w = raw[2];
    *R = rotation_zyx<T>(*euler_w);
    if (roll_radius <= 0.0) return;
    const Vec3<T> p = *foot_w;
    const Vec3<T> heading(cos((*euler_w)[0]), sin((*euler_w)[0]), T(0.0));
    const auto pitch = [&](const Vec3<T>& b, const Eigen::Matrix<T, 3, 3>& Rb) {
      const Vec3<T> u =
          b + Rb * robot::knee_in_base<T>(leg, robot::leg_joint_angles<T>(leg, Rb.transpose() * (p - b))) - p;
      return atan2(u.dot(heading), u[2]);
    };
    const T dphi = pitch(*base_w, *R) - pitch(raw[3], rotation_zyx<T>(raw[4]));
    *foot_w = p + (roll_radius * dphi) * heading;
  }
  // The foot (rolled in stance), base position, Euler angles and rotation at this point.
  template <class T>
  void eval(const robot::LegModel& leg, const T* x, Vec3<T>* foot_w, Vec3<T>* base_w,
            Vec3<T>* euler_w, Eigen::Matrix<T, 3, 3>* R) const {
    Vec3<T> r[5];
    raw(x, r);
    pose(leg, r, foot_w, base_w, euler_w, R);
  }
};
inline LegPoint add_leg_point(LocalVars& lv, const Layout& L, int f, int s, double sigma,
                              double foot_radius) {
  LegPoint p;
  p.sigma = sigma;
  p.seg_fraction = L.seg_fraction[s];
  p.foot = add_foot_position(lv, L, f, s, sigma, true);
  p.base = add_base_position(lv, L, s, sigma, true);
  p.euler = add_base_euler(lv, L, s, sigma, true);
  if (p.foot.needs_duration || p.base.needs_duration || p.euler.needs_duration)
    p.duration = add_segment_duration(lv, L, s);
  if (foot_radius > 0.0 && L.contact[f][s])
    for (const Layout::Stance& st : L.stances)
      if (st.foot == f && st.first_seg <= s && s <= st.last_seg) {
        p.roll_radius = foot_radius;
        p.touchdown_base = lv.add3(L.base[st.first_seg]);
        p.touchdown_euler = lv.add3(L.base[st.first_seg] + 6);
      }
  return p;
}

// Writes capsule_clearance_values(nk, probe > 0) values to out. `across` is the horizontal unit vector across
// the base's heading (-sin psi, cos psi). `t_start` is the fraction of the axis left out at a.
template <class T>
void capsule_clearance(const terrain::HeightField& field, const Vec3<T>& a, const Vec3<T>& b,
                       double radius, double probe, const T& t_start, int nk, const T& across_x,
                       const T& across_y, T* out) {
  using std::sqrt;
  const Vec3<T> d = b - a;
  const T len = sqrt(d.squaredNorm() + 1e-12);
  const T horiz = sqrt(d[0] * d[0] + d[1] * d[1] + 1e-12);
  T cosi = horiz / len;
  if (value_of(cosi) < 0.5) cosi = T(0.5);
  const T gap = radius / cosi;
  int n = 0;
  Vec3<T> prev;
  for (int j = 0; j < nk; ++j) {
    const T t = t_start + (1.0 - t_start) * (static_cast<double>(j) / std::max(1, nk - 1));
    const Vec3<T> q = a + t * d;
    const T under = terrain_height(field, q[0], q[1]);  // read once for both values
    out[n++] = q[2] - under - gap;
    if (j > 0) out[n++] = prev[2] - under - gap;
    if (probe > 0.0) {
      const T left_x = q[0] + probe * across_x, left_y = q[1] + probe * across_y;
      const T right_x = q[0] - probe * across_x, right_y = q[1] - probe * across_y;
      out[n++] = q[2] - terrain_height(field, left_x, left_y) - gap;
      out[n++] = q[2] - terrain_height(field, right_x, right_y) - gap;
    }
    prev = q;
  }
}

// The soft minimum (soft_min at scale t_soft) of one capsule's n_values values: the folded row of
// shin_ik and thigh. For AD scalars the row depends on the piece's variables only through the 9
// scalars a, b, t_start and across, so its 4 nk - 1 values and their soft minimum are
// differentiated with respect to these 9 (AdInner) and the result chained to the outer scalars
// once, instead of carrying every value's derivatives over all the outer ones (shin_ik: 79 values
// by ~22 variables). The same value; derivatives equal up to round-off.
template <class T>
T capsule_soft_min(const terrain::HeightField& field, const Vec3<T>& a, const Vec3<T>& b,
                   double radius, double probe, const T& t_start, int nk, const T& across_x,
                   const T& across_y, int n_values, double t_soft) {
  if constexpr (std::is_same_v<T, double> || std::is_same_v<T, AdInner>) {
    T values[kMaxShinValues] = {};
    capsule_clearance<T>(field, a, b, radius, probe, t_start, nk, across_x, across_y, values);
    return soft_min(values, n_values, t_soft);
  } else {
    const T* outer[9] = {&a[0], &a[1], &a[2], &b[0], &b[1], &b[2], &t_start, &across_x, &across_y};
    AdInner inner[9];
    for (int i = 0; i < 9; ++i) inner[i] = AdInner(outer[i]->value(), 9, i);
    const AdInner r = capsule_soft_min<AdInner>(
        field, Vec3<AdInner>(inner[0], inner[1], inner[2]),
        Vec3<AdInner>(inner[3], inner[4], inner[5]), radius, probe, inner[6], nk, inner[7],
        inner[8], n_values, t_soft);
    return chain_inner(r, outer, 9);
  }
}

// One link's rows of a shin_ik or thigh piece into g: the folded soft minimum (t_soft > 0, one
// row) or every value (rows.n_values rows).
template <class T>
void link_capsule_rows(const terrain::HeightField& field, const Vec3<T>& a, const Vec3<T>& b,
                       const CapsuleRows& rows, const T& t_start, int nk, const T& across_x,
                       const T& across_y, double t_soft, T* g) {
  if (t_soft > 0.0)
    g[0] = capsule_soft_min<T>(field, a, b, rows.gap_radius, rows.probe, t_start, nk, across_x,
                               across_y, rows.n_values, t_soft);
  else
    capsule_clearance<T>(field, a, b, rows.gap_radius, rows.probe, t_start, nk, across_x,
                         across_y, g);
}

// A leg point's rows: rows(foot, base, euler, R, g) for any scalar type, at the point's pose
// (LegPoint::eval), n of them into g. For the piece's AD scalars the rows depend on its variables
// only through the point's 15 raw scalars (LegPoint::raw), so the pose (rotation, inverse
// kinematics, the foot's roll) and the rows are differentiated with respect to those (AdLeg, fixed
// size) and chained to the piece's variables once per row, instead of carrying the leg's
// kinematics over all the piece's variables (22-37). The same values; derivatives equal up to
// round-off.
template <class T, class Rows>
void leg_point_rows(const LegPoint& at, const robot::LegModel& leg, const T* x, int n, T* g,
                    const Rows& rows) {
  Vec3<T> raw[5];
  at.raw(x, raw);
  if constexpr (std::is_same_v<T, double>) {
    Vec3<double> foot, base, euler;
    Eigen::Matrix3d R;
    at.pose(leg, raw, &foot, &base, &euler, &R);
    rows(foot, base, euler, R, g);
  } else {
    // In swing the last 6 raw scalars are unused zeros: not seeded, not chained.
    const int used = at.roll_radius > 0.0 ? kLegInnerScalars : 9;
    const T* outer[kLegInnerScalars];
    Vec3<AdLeg> inner[5];
    for (int k = 0; k < 5; ++k)
      for (int i = 0; i < 3; ++i) {
        const int slot = 3 * k + i;
        outer[slot] = &raw[k][i];
        inner[k][i] = slot < used ? AdLeg(raw[k][i].value(), kLegInnerScalars, slot)
                                  : AdLeg(raw[k][i].value());
      }
    Vec3<AdLeg> foot, base, euler;
    Eigen::Matrix<AdLeg, 3, 3> R;
    at.pose(leg, inner, &foot, &base, &euler, &R);
    AdLeg inner_rows[kMaxShinValues];
    rows(foot, base, euler, R, inner_rows);
    for (int r = 0; r < n; ++r) g[r] = chain_inner(inner_rows[r], outer, used);
  }
}

}  // namespace terrastride::planner::feasibility
