// Leg capsules (shin: knee to near the foot; thigh: HFE to knee) against the terrain's OctoMap,
// with FCL's octree-shape distance and collision queries.
#include <fcl/geometry/octree/octree.h>
#include <fcl/geometry/shape/capsule.h>
#include <fcl/narrowphase/collision.h>
#include <fcl/narrowphase/distance.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <limits>

#include "terrastride/collision/checks.hpp"

namespace terrastride::collision {
namespace {

using fcl::Transform3d;

// Pose of an FCL capsule (axis along its local z, centred at the origin) spanning a -> b.
Transform3d capsule_pose(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  Transform3d tf = Transform3d::Identity();
  tf.translation() = 0.5 * (a + b);
  tf.linear() =
      Eigen::Quaterniond::FromTwoVectors(Eigen::Vector3d::UnitZ(), b - a).toRotationMatrix();
  return tf;
}

// Signed distance from a capsule to the occupied voxels: >= 0 clearance (capped at `cutoff`), < 0
// in collision, where it is minus the deepest penetration into any single voxel. A voxel map holds
// surface and solid cells, not a continuous solid, so that depth is only a rough measure of how far
// in the capsule went; the sign is what the check relies on.
double signed_distance(const fcl::OcTree<double>& tree, const fcl::Capsule<double>& capsule,
                       const Transform3d& pose, double cutoff, double upper_bound) {
  const Transform3d identity = Transform3d::Identity();
  fcl::DistanceRequest<double> dreq;
  fcl::DistanceResult<double> dres;
  // Seeding the result bounds the search: FCL skips octree nodes whose box is farther than the
  // best distance so far, so nothing beyond the bound is ever visited.
  dres.min_distance = std::min(cutoff, upper_bound);
  fcl::distance(&tree, identity, &capsule, pose, dreq, dres);
  if (dres.min_distance > 1e-9) return std::min(dres.min_distance, cutoff);
  fcl::CollisionRequest<double> creq(std::numeric_limits<int>::max() / 2, true);
  fcl::CollisionResult<double> cres;
  fcl::collide(&tree, identity, &capsule, pose, creq, cres);
  if (!cres.isCollision()) return 0.0;  // touching within GJK's tolerance
  double depth = 0.0;
  for (size_t c = 0; c < cres.numContacts(); ++c)
    depth = std::max(depth, cres.getContact(c).penetration_depth);
  return -depth;
}

// One capsule's axis end points over the samples (valid = IK gave a configuration).
struct CapsuleTrack {
  std::vector<Eigen::Vector3d> a, b;
  std::vector<char> valid;
};

// Distances of a moving capsule to the terrain at every valid sample, using temporal coherence
// between samples. Every point of a segment is an affine combination of its end points, so moving
// the end points by at most delta moves every point of the capsule by at most delta, and its
// distance to the (fixed) terrain changes by at most delta: from an exact distance d at an earlier
// pose, d - delta and d + delta bound the distance now. Hence:
//  - the upper bound seeds FCL's search, which then skips every octree node farther away (exact
//    result, far fewer voxels visited);
//  - while delta stays within the allowance (bound_tolerance, or bound_relative of the margin
//    above exact_below when larger) and the lower bound stays above `exact_below`, the sample can
//    be neither in collision nor near it, and the lower bound (within 2 delta of the truth) is
//    reported instead of a query (`exact[k]` = 0). The minimum over the samples is then within the
//    allowance of the true one: every skipped value is >= d - delta for an exact d >= the minimum.
// Collisions (d <= 0 < exact_below) and every distance below `exact_below` are exact.
std::vector<double> capsule_distances(const fcl::OcTree<double>& tree,
                                      const fcl::Capsule<double>& capsule,
                                      const CapsuleTrack& track, const ClearanceOptions& options,
                                      std::vector<char>* exact, long* queries) {
  const size_t n = track.valid.size();
  std::vector<double> out(n, std::numeric_limits<double>::quiet_NaN());
  exact->assign(n, 0);
  bool have = false;
  size_t last = 0;  // last exactly evaluated sample
  double d_last = 0.0;
  for (size_t k = 0; k < n; ++k) {
    if (!track.valid[k]) {
      have = false;  // no pose to bound from across an IK failure
      continue;
    }
    double upper = std::numeric_limits<double>::infinity();
    if (have) {
      const double delta =
          std::max((track.a[k] - track.a[last]).norm(), (track.b[k] - track.b[last]).norm());
      const double allowed = std::max(options.bound_tolerance,
                                      options.bound_relative * (d_last - options.exact_below));
      if (delta <= allowed && d_last - delta > options.exact_below) {
        out[k] = d_last - delta;
        continue;
      }
      // The small slack keeps the nearest voxel strictly inside FCL's "closer than" test.
      if (d_last > 0) upper = d_last + delta + 1e-6;
    }
    d_last = signed_distance(tree, capsule, capsule_pose(track.a[k], track.b[k]),
                             options.distance_cutoff, upper);
    out[k] = d_last;
    (*exact)[k] = 1;
    ++*queries;
    last = k;
    have = true;
  }
  return out;
}

// A link's capsule as the union of `pieces` shorter capsules of the same radius along the same
// axis (their union is exactly the long capsule). FCL prunes octree nodes by the capsule's
// axis-aligned box; a long inclined capsule's box is mostly empty space and reaches down to its
// lowest point along its whole footprint, so FCL would test every voxel under it. Short pieces
// have tight boxes and only the lowest piece comes near the ground. Distance = minimum over
// pieces (a lower bound if that piece's value was a bound).
std::vector<double> link_distances(const fcl::OcTree<double>& tree, double radius,
                                   const CapsuleTrack& track, double length,
                                   const ClearanceOptions& options, std::vector<char>* exact,
                                   long* queries) {
  const size_t n = track.valid.size();
  const int pieces = std::max(1, static_cast<int>(std::ceil(length / options.piece_length - 1e-9)));
  const fcl::Capsule<double> capsule(radius, length / pieces);
  std::vector<double> out(n, std::numeric_limits<double>::quiet_NaN());
  exact->assign(n, 0);
  CapsuleTrack piece = track;
  std::vector<char> piece_exact;
  for (int j = 0; j < pieces; ++j) {
    const double s0 = static_cast<double>(j) / pieces, s1 = static_cast<double>(j + 1) / pieces;
    for (size_t k = 0; k < n; ++k) {
      piece.a[k] = track.a[k] + s0 * (track.b[k] - track.a[k]);
      piece.b[k] = track.a[k] + s1 * (track.b[k] - track.a[k]);
    }
    const std::vector<double> d =
        capsule_distances(tree, capsule, piece, options, &piece_exact, queries);
    for (size_t k = 0; k < n; ++k) {
      if (std::isnan(d[k])) continue;
      if (std::isnan(out[k]) || d[k] < out[k] || (d[k] == out[k] && piece_exact[k])) {
        out[k] = d[k];
        (*exact)[k] = piece_exact[k];
      }
    }
  }
  return out;
}

}  // namespace

ClearanceReport check_leg_clearance(const robot::RobotModel& model, const planner::Trajectory& traj,
                                    const TrajectoryKinematics& kin, const octomap::OcTree& octree,
                                    const ClearanceOptions& options) {
  const size_t n = traj.samples.size();
  const size_t n_legs = model.legs.size();
  if (kin.time.size() != n || kin.legs.size() != n_legs)
    throw TrajectoryError("kinematics do not belong to this trajectory (sample or leg count)");
  if (!(options.distance_cutoff > 0))
    throw std::invalid_argument("clearance distance cutoff must be > 0");
  if (!(options.exact_below >= 0) || !(options.bound_tolerance >= 0) || !(options.piece_length > 0))
    throw std::invalid_argument(
        "clearance options: exact_below and bound_tolerance must be >= 0, piece_length > 0");

  ClearanceReport rep;
  rep.time = kin.time;
  rep.octree_resolution = octree.getResolution();
  auto exclusion_for = [&](const robot::LegModel& leg) {
    return options.shin_exclusion >= 0
               ? options.shin_exclusion
               : 2 * model.foot_radius + leg.shin_radius +
                     std::max(options.exclusion_margin, octree.getResolution());
  };
  for (const auto& leg : model.legs)
    rep.shin_exclusion = std::max(rep.shin_exclusion, exclusion_for(leg));
  rep.shin_min_distance = options.distance_cutoff;
  rep.thigh_min_distance = options.distance_cutoff;
  rep.legs.resize(n_legs);

  // fcl::OcTree only reads the octomap tree; the aliasing constructor shares it without a copy or
  // ownership (the caller keeps `octree` alive for the duration of this call).
  const std::shared_ptr<const octomap::OcTree> view(std::shared_ptr<const octomap::OcTree>(),
                                                    &octree);
  const fcl::OcTree<double> tree(view);

  // Summarises one capsule's series into the leg's minimum, collision count and first collision.
  auto summarise = [&](const std::vector<double>& d, double* min, int* min_sample, int* collisions,
                       std::vector<char>* hit, double* first_t) {
    *min = options.distance_cutoff;
    for (size_t k = 0; k < n; ++k) {
      if (std::isnan(d[k])) continue;
      if (d[k] < *min) {
        *min = d[k];
        *min_sample = static_cast<int>(k);
      }
      if (d[k] <= 0) {
        ++*collisions;
        (*hit)[k] = 1;
        if (*first_t < 0 || kin.time[k] < *first_t) *first_t = kin.time[k];
      }
    }
  };

  std::vector<char> shin_hit(n, 0), thigh_hit(n, 0);
  for (size_t i = 0; i < n_legs; ++i) {
    const auto& leg = model.legs[i];
    const double exclusion = exclusion_for(leg);
    if (!(exclusion < leg.l2))
      throw std::invalid_argument("shin exclusion " + std::to_string(exclusion) +
                                  " m leaves nothing of leg " + leg.name + "'s lower leg (" +
                                  std::to_string(leg.l2) + " m)");
    CapsuleTrack shin_track, thigh_track;
    for (CapsuleTrack* t : {&shin_track, &thigh_track}) {
      t->a.assign(n, Eigen::Vector3d::Zero());
      t->b.assign(n, Eigen::Vector3d::Zero());
      t->valid.assign(n, 0);
    }
    for (size_t k = 0; k < n; ++k) {
      const LegSample& ls = kin.legs[i][k];
      if (!ls.has_q()) continue;
      const auto& base = traj.samples[k].base;
      const Eigen::Matrix3d rot = rotation_zyx(base.euler_zyx);
      const Eigen::Vector3d knee = base.position + rot * robot::knee_position(leg, ls.q);
      const Eigen::Vector3d foot = base.position + rot * robot::foot_position(leg, ls.q);
      shin_track.a[k] = foot + (knee - foot).normalized() * exclusion;
      shin_track.b[k] = knee;
      shin_track.valid[k] = 1;
      thigh_track.a[k] = base.position + rot * robot::hfe_position(leg, ls.q);
      thigh_track.b[k] = knee;
      thigh_track.valid[k] = 1;
    }
    LegClearanceSeries& series = rep.legs[i];
    series.leg = leg.name;
    series.shin_distance = link_distances(tree, leg.shin_radius, shin_track, leg.l2 - exclusion,
                                          options, &series.shin_exact, &rep.fcl_queries);
    summarise(series.shin_distance, &series.shin_min, &series.shin_min_sample,
              &series.shin_collision_samples, &shin_hit, &series.first_collision_t);
    series.thigh_min = options.distance_cutoff;
    if (options.check_thigh) {
      series.thigh_distance = link_distances(tree, leg.thigh_radius, thigh_track, leg.l1, options,
                                             &series.thigh_exact, &rep.fcl_queries);
      summarise(series.thigh_distance, &series.thigh_min, &series.thigh_min_sample,
                &series.thigh_collision_samples, &thigh_hit, &series.first_collision_t);
    }
    rep.shin_min_distance = std::min(rep.shin_min_distance, series.shin_min);
    rep.thigh_min_distance = std::min(rep.thigh_min_distance, series.thigh_min);
    if (series.first_collision_t >= 0 &&
        (rep.first_collision_t < 0 || series.first_collision_t < rep.first_collision_t))
      rep.first_collision_t = series.first_collision_t;
  }
  for (size_t k = 0; k < n; ++k) {
    rep.shin_collisions += shin_hit[k];
    rep.thigh_collisions += thigh_hit[k];
  }
  return rep;
}

}  // namespace terrastride::collision
