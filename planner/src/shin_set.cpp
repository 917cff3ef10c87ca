// "shin": shin collision (Bratta et al. 2020, III-B, eq. 13-14; DESIGN.md, Planner). The lower
// leg is modelled as a straight segment of length s from the foot p at a fixed angle beta to the
// ground, in the vertical plane through the base's heading psi (yaw):
//   point k in (0, 1]:  q_k = p + k s (cos(beta) cos(psi), cos(beta) sin(psi), sin(beta)),
// k = 1 the knee. Each point must stay above the terrain under it:
//   p_z + k s sin(beta) - h(q_k,x, q_k,y) >= clearance,
// at `shin_points` points from k_min (the part of the shin next to the foot, which stands on the
// ground by design, is left out, as in the post-hoc capsule check) to the knee; the clearance
// defaults to the shin capsule's radius / |cos(beta)| (see FeasibilityOptions).
// The sign of the horizontal direction is carried by beta: 37 deg on HyQ's hind legs (knee ahead
// of the foot), 127 deg on the front legs (cos < 0: knee behind the foot), as in the paper.
//
// Where: over every stance. A stance foot does not move, but psi does (the base turns while the
// foot stands), so the rows are imposed at every segment end of the stance and at
// `shin_yaw_points - 1` points inside each segment, with psi from the base's yaw spline there.
// Initial (fixed) stances are included: their footholds are given but the yaw is not.
//
// Rows: by default (shin_softmin > 0) all values of one stance segment (shin_points per yaw point)
// are folded into ONE row, their soft minimum (feasibility::soft_min <= every value, so the row
// holds each point's inequality); its variables are those of the segment's inner yaw point
// (foothold, yaw Hermite segment, duration), so cliques do not grow while the rows drop ~20x.
//
// Not in swing (a choice): in swing the real leg folds (the knee rises and the shin angle is far
// from beta), so the fixed-beta model would mostly constrain a configuration the leg is not in;
// a swinging foot is kept clear of the terrain (probed around it) by the baseline's swing
// clearance, and its lift-off and touch-down footholds are stance footholds covered here.
#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <vector>

#include "feasibility_common.hpp"
#include "terrastride/planner/feasibility.hpp"

namespace terrastride::planner {

namespace {
constexpr int kMaxShinValues = 64;  // values one shin piece may fold into its soft minimum
}  // namespace

void build_shin_set(SrbdProblem& problem, const FeasibilityOptions& options) {
  const Layout& L = problem.layout();
  const terrain::HeightField* field = &problem.terrain();
  const int nk = std::max(1, options.shin_points);
  const int ny = std::max(1, options.shin_yaw_points);
  const double t_soft = options.shin_softmin;
  for (const auto& st : L.stances) {
    const auto& leg = problem.robot().legs[st.foot];
    const double s = leg.shin_length, cb = std::cos(leg.shin_angle), sb = std::sin(leg.shin_angle);
    if (!(s > 0.0)) continue;
    const double clearance =
        options.shin_clearance >= 0.0
            ? options.shin_clearance
            : leg.shin_radius / std::max(0.2, std::abs(cb));  // beta near 90 deg: no blow-up
    const double exclusion = options.shin_exclusion >= 0.0
                                 ? options.shin_exclusion
                                 : 2.0 * problem.robot().foot_radius + leg.shin_radius + 0.01;
    const double k_min = std::clamp(exclusion / s, 0.0, 1.0);
    // One piece over the points at fractions `sigmas` of segment seg: nk rows per fraction, or
    // (shin_softmin > 0) one row, their soft minimum.
    auto add = [&](int seg, std::vector<double> sigmas) {
      const int n_values = static_cast<int>(sigmas.size()) * nk;
      if (n_values > kMaxShinValues)
        throw std::invalid_argument("shin: too many points per piece (shin_points x yaw points)");
      const bool merged = t_soft > 0.0;
      const int rows = merged ? 1 : n_values;
      std::vector<double> lo(rows, clearance), hi(rows, kInf);
      LocalVars lv;
      const auto p = lv.add3(st.pos_var);
      // Yaw: only its own knot at a lone segment end, the whole yaw Hermite otherwise.
      int y0 = -1, v0 = -1, y1 = -1, v1 = -1, dur = -1;
      const bool only_start = sigmas.size() == 1 && sigmas[0] == 0.0;
      const bool only_end = sigmas.size() == 1 && sigmas[0] == 1.0;
      if (only_start) {
        y0 = lv.add(L.base[seg] + 6);
      } else if (only_end) {
        y1 = lv.add(L.base[seg + 1] + 6);
      } else {
        y0 = lv.add(L.base[seg] + 6);
        v0 = lv.add(L.base[seg] + 9);
        y1 = lv.add(L.base[seg + 1] + 6);
        v1 = lv.add(L.base[seg + 1] + 9);
        dur = lv.add(L.interval_var[L.seg_interval[seg]]);
      }
      const double frac = L.seg_fraction[seg];
      problem.add_piece(make_piece("shin", lv, lo, hi, [=](const auto* x, auto* g) {
        using T = std::decay_t<decltype(*g)>;
        using std::cos;
        using std::sin;
        T values[kMaxShinValues] = {};
        T* out = merged ? values : g;
        int n = 0;
        for (const double sigma : sigmas) {
          T psi;
          if (dur < 0) {
            psi = y0 >= 0 ? x[y0] : x[y1];
          } else {
            const T h = x[dur] * frac;
            psi = hermite_value<T>(sigma, h, x[y0], x[v0], x[y1], x[v1]);
          }
          const T c = cos(psi), sn = sin(psi);
          for (int k = 1; k <= nk; ++k) {
            const double a = (nk == 1 ? 1.0 : k_min + (1.0 - k_min) * (k - 1) / (nk - 1)) * s;
            const T qx = x[p[0]] + a * cb * c, qy = x[p[1]] + a * cb * sn;
            out[n++] = x[p[2]] + a * sb - terrain_height(*field, qx, qy);
          }
        }
        if (merged) g[0] = feasibility::soft_min(values, n, t_soft);
      }));
    };
    for (int seg = st.first_seg; seg <= st.last_seg; ++seg) {
      std::vector<double> sigmas;
      for (int q = 0; q <= ny; ++q) {
        if (q == ny && seg != st.last_seg) continue;  // the next segment's start covers this end
        sigmas.push_back(static_cast<double>(q) / ny);
      }
      if (t_soft > 0.0) {
        add(seg, sigmas);  // one row for the whole segment
      } else {
        for (const double sigma : sigmas) add(seg, {sigma});
      }
    }
  }
}

// ---------------------------------------------------------------------------------------------
// "shin_ik" (beyond the paper): the same inequality on the leg's REAL shin, from the foot to the
// knee that the leg's inverse kinematics puts there for the current base pose (DESIGN.md, IK):
//   p_b = R^T (p - r), v = p_b - p_HAA, gamma = atan2(v_y, -v_z), rho = hypot(v_y, v_z),
//   X = v_x, Z = -(rho - l0), q_K = kappa acos((X^2 + Z^2 - l1^2 - l2^2) / (2 l1 l2)),
//   q_H = atan2(-X, -Z) - atan2(l2 sin q_K, l1 + l2 cos q_K),
//   knee_b = p_HAA + Rx(gamma) (-l1 sin q_H, 0, -l0 - l1 cos q_H),   knee = r + R knee_b.
// Points q_j = p + t_j (knee - p), t_j from the excluded foot end to 1, must stand above the
// terrain by the capsule radius over the cosine of the shin's actual inclination. The paper's
// fixed beta is a heuristic: measured on our pallet plans, a hind shin flattens to ~30 deg when
// the base moves on over a foot planted before the step, and the knee is ~0.33 m from the foot,
// so the fixed-beta rows hold while the real shin hits the edge (see the issue #5 report).
// Imposed at every knot of the base spline (value-only, few columns), in stance and in swing: a
// foot lifting off beside an edge keeps its shin there for a few hundredths of a second (measured
// on pallet_15 with stance knots only: the RH shin 0.04 s after lift-off touched the edge). With
// shin_softmin > 0 (the default) the 2 nk - 1 rows of one knot are folded into one, their soft
// minimum (as for "shin").
namespace {

template <class T>
Vec3<T> knee_in_base(const robot::LegModel& leg, const Vec3<T>& pb) {
  using std::cos;
  using std::sin;
  const Vec3<T> q = feasibility::leg_joint_angles<T>(leg, pb);
  const T gamma = -static_cast<double>(leg.side) * q[0];
  const T ky = T(0.0), kz = -leg.l0 - leg.l1 * cos(q[1]), kx = -leg.l1 * sin(q[1]);
  const T cg = cos(gamma), sg = sin(gamma);
  return Vec3<T>(leg.haa_origin.x() + kx, leg.haa_origin.y() + cg * ky - sg * kz,
                 leg.haa_origin.z() + sg * ky + cg * kz);
}

}  // namespace

void build_shin_kinematic_set(SrbdProblem& problem, const FeasibilityOptions& options) {
  const Layout& L = problem.layout();
  const terrain::HeightField* field = &problem.terrain();
  const int nk = std::max(2, options.shin_points);
  if (2 * nk - 1 > kMaxShinValues) throw std::invalid_argument("shin_ik: too many shin points");
  const int nf = static_cast<int>(problem.robot().legs.size());
  for (int f = 0; f < nf; ++f) {
    const robot::LegModel leg = problem.robot().legs[f];
    const double exclusion = options.shin_exclusion >= 0.0
                                 ? options.shin_exclusion
                                 : 2.0 * problem.robot().foot_radius + leg.shin_radius + 0.01;
    const double radius = options.shin_clearance >= 0.0 ? -1.0 : leg.shin_radius;
    const double fixed_clearance = options.shin_clearance;
    // shin_softmin > 0: the 2 nk - 1 values folded into one row (their soft minimum).
    const double t_soft = options.shin_softmin;
    const int rows = t_soft > 0.0 ? 1 : 2 * nk - 1;
    std::vector<double> lo(rows, (radius >= 0.0 ? 0.0 : fixed_clearance) + options.shin_ik_margin),
        hi(rows, kInf);
    for (int k = 0; k <= L.num_segments; ++k) {
      LocalVars lv;
      const auto p = lv.add3(L.foot_pos[f][k]);
      const auto r = lv.add3(L.base[k]);
      const auto e = lv.add3(L.base[k] + 6);
      problem.add_piece(make_piece("shin_ik", lv, lo, hi, [=](const auto* x, auto* g) {
        using T = std::decay_t<decltype(*g)>;
        using std::sqrt;
        const Vec3<T> foot = gather3(x, p), base = gather3(x, r);
        const Eigen::Matrix<T, 3, 3> R = rotation_zyx<T>(gather3(x, e));
        const Vec3<T> knee = base + R * knee_in_base<T>(leg, R.transpose() * (foot - base));
        const Vec3<T> d = knee - foot;
        const T len = sqrt(d.squaredNorm());
        const T horiz = sqrt(d[0] * d[0] + d[1] * d[1] + 1e-12);
        // Vertical gap for one capsule radius of perpendicular distance to an edge below the
        // axis: r / cos(inclination), capped at 2 r (inclination 60 deg): steeper, the lowest
        // points (just past the excluded foot end) could not clear flat ground by r / cos.
        T gap = T(0.0);
        if (radius >= 0.0) {
          T cosi = horiz / len;
          if (value_of(cosi) < 0.5) cosi = T(0.5);
          gap = radius / cosi;
        }
        // Rows 0..nk-1: each point above the terrain under it. Rows nk..2nk-2: each point above
        // the terrain under the NEXT point: the shin rises from foot to knee, so a step edge
        // between two points is held by the lower one too (measured on pallet_10 without these
        // rows: the edge slipped between points, capsule 2 cm into it).
        const T t0 = exclusion / len;
        Vec3<T> prev;
        T values[kMaxShinValues] = {};
        T* out = t_soft > 0.0 ? values : g;
        for (int j = 0; j < nk; ++j) {
          const T t = t0 + (1.0 - t0) * (static_cast<double>(j) / (nk - 1));
          const Vec3<T> q = foot + t * d;
          const T h = terrain_height(*field, q[0], q[1]);
          out[j] = q[2] - h - gap;
          if (j > 0) out[nk + j - 1] = prev[2] - h - gap;
          prev = q;
        }
        if (t_soft > 0.0) g[0] = feasibility::soft_min(values, 2 * nk - 1, t_soft);
      }));
    }
  }
}

}  // namespace terrastride::planner
