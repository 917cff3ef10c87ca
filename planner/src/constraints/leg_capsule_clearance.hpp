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
#include <cmath>

#include <vector>

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
    out[n++] = q[2] - terrain_height(field, q[0], q[1]) - gap;
    if (j > 0) out[n++] = prev[2] - terrain_height(field, q[0], q[1]) - gap;
    if (probe > 0.0) {
      out[n++] = q[2] - terrain_height(field, q[0] + probe * across_x, q[1] + probe * across_y) - gap;
      out[n++] = q[2] - terrain_height(field, q[0] - probe * across_x, q[1] - probe * across_y) - gap;
    }
    prev = q;
  }
}

}  // namespace terrastride::planner::feasibility
