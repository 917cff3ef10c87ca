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
                       const Transform3d& pose, double cutoff) {
  const Transform3d identity = Transform3d::Identity();
  fcl::DistanceRequest<double> dreq;
  fcl::DistanceResult<double> dres;
  // Seeding the result bounds the search: FCL skips octree nodes whose box is farther than the
  // best distance so far, so nothing beyond the cutoff is ever visited.
  dres.min_distance = cutoff;
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
  const double nan = std::numeric_limits<double>::quiet_NaN();

  ClearanceReport rep;
  rep.time = kin.time;
  rep.octree_resolution = octree.getResolution();
  auto exclusion_for = [&](const robot::LegModel& leg) {
    return options.shin_exclusion >= 0
               ? options.shin_exclusion
               : 2 * model.foot_radius + leg.shin_radius + options.exclusion_margin;
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

  std::vector<char> shin_hit(n, 0), thigh_hit(n, 0);
  for (size_t i = 0; i < n_legs; ++i) {
    const auto& leg = model.legs[i];
    const double exclusion = exclusion_for(leg);
    if (!(exclusion < leg.l2))
      throw std::invalid_argument("shin exclusion " + std::to_string(exclusion) +
                                  " m leaves nothing of leg " + leg.name + "'s lower leg (" +
                                  std::to_string(leg.l2) + " m)");
    const fcl::Capsule<double> shin(leg.shin_radius, leg.l2 - exclusion);
    const fcl::Capsule<double> thigh(leg.thigh_radius, leg.l1);
    LegClearanceSeries& series = rep.legs[i];
    series.leg = leg.name;
    series.shin_min = options.distance_cutoff;
    series.thigh_min = options.distance_cutoff;
    series.shin_distance.assign(n, nan);
    if (options.check_thigh) series.thigh_distance.assign(n, nan);
    for (size_t k = 0; k < n; ++k) {
      const LegSample& ls = kin.legs[i][k];
      if (!ls.has_q()) continue;
      const auto& base = traj.samples[k].base;
      const Eigen::Matrix3d rot = rotation_zyx(base.euler_zyx);
      auto world = [&](const Eigen::Vector3d& p) -> Eigen::Vector3d {
        return base.position + rot * p;
      };
      const Eigen::Vector3d knee = world(robot::knee_position(leg, ls.q));
      const Eigen::Vector3d foot = world(robot::foot_position(leg, ls.q));
      const Eigen::Vector3d shin_end = foot + (knee - foot).normalized() * exclusion;
      const double d_shin =
          signed_distance(tree, shin, capsule_pose(shin_end, knee), options.distance_cutoff);
      series.shin_distance[k] = d_shin;
      if (d_shin < series.shin_min) {
        series.shin_min = d_shin;
        series.shin_min_sample = static_cast<int>(k);
      }
      bool hit = false;
      if (d_shin <= 0) {
        ++series.shin_collision_samples;
        shin_hit[k] = 1;
        hit = true;
      }
      if (options.check_thigh) {
        const Eigen::Vector3d hfe = world(robot::hfe_position(leg, ls.q));
        const double d_thigh =
            signed_distance(tree, thigh, capsule_pose(hfe, knee), options.distance_cutoff);
        series.thigh_distance[k] = d_thigh;
        if (d_thigh < series.thigh_min) {
          series.thigh_min = d_thigh;
          series.thigh_min_sample = static_cast<int>(k);
        }
        if (d_thigh <= 0) {
          ++series.thigh_collision_samples;
          thigh_hit[k] = 1;
          hit = true;
        }
      }
      if (hit && series.first_collision_t < 0) series.first_collision_t = kin.time[k];
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
