// Private to collision/: signed distances of one FCL shape to the terrain's OctoMap and to the
// certain solid, shared by the leg-capsule check (leg_clearance.cpp) and the trunk-box check
// (trunk_clearance.cpp).
#pragma once

#include <fcl/broadphase/broadphase_dynamic_AABB_tree.h>
#include <fcl/broadphase/default_broadphase_callbacks.h>
#include <fcl/geometry/octree/octree.h>
#include <fcl/geometry/shape/box.h>
#include <fcl/narrowphase/collision.h>
#include <fcl/narrowphase/distance.h>

#include <algorithm>
#include <limits>
#include <memory>
#include <vector>

#include "terrastride/collision/checks.hpp"
#include "terrastride/collision/octree_terrain.hpp"

namespace terrastride::collision::detail {

using fcl::Transform3d;
using Shape = fcl::CollisionGeometry<double>;

// Signed distance from a shape to the occupied voxels: >= 0 clearance (capped at `cutoff`), < 0 in
// collision, where it is minus the deepest penetration into any single node of the tree (a voxel,
// or a pruned block of voxels that are all occupied). Only the sign and whether that depth exceeds
// what the map's quantisation explains (ContactVerdict) are relied on.
inline double signed_distance(const fcl::OcTree<double>& tree, const Shape& shape,
                              const Transform3d& pose, double cutoff, double upper_bound) {
  const Transform3d identity = Transform3d::Identity();
  fcl::DistanceRequest<double> dreq;
  fcl::DistanceResult<double> dres;
  // Seeding the result bounds the search: FCL skips octree nodes whose box is farther than the
  // best distance so far, so nothing beyond the bound is ever visited.
  dres.min_distance = std::min(cutoff, upper_bound);
  fcl::distance(&tree, identity, &shape, pose, dreq, dres);
  if (dres.min_distance > 1e-9) return std::min(dres.min_distance, cutoff);
  fcl::CollisionRequest<double> creq(std::numeric_limits<int>::max() / 2, true);
  fcl::CollisionResult<double> cres;
  fcl::collide(&tree, identity, &shape, pose, creq, cres);
  if (!cres.isCollision()) return 0.0;  // touching within GJK's tolerance
  double depth = 0.0;
  for (size_t c = 0; c < cres.numContacts(); ++c)
    depth = std::max(depth, cres.getContact(c).penetration_depth);
  return -depth;
}

// The certain solid (boxes) in an FCL broadphase tree, queried with the same shapes.
class SolidGeometry {
 public:
  explicit SolidGeometry(const CertainSolid& solid) {
    objects_.reserve(solid.boxes.size());
    for (const auto& b : solid.boxes) {
      auto box = std::make_shared<fcl::Box<double>>(b.hi - b.lo);
      Transform3d tf = Transform3d::Identity();
      tf.translation() = 0.5 * (b.lo + b.hi);
      objects_.push_back(std::make_unique<fcl::CollisionObject<double>>(box, tf));
    }
    // One bulk (top-down) build of the AABB tree: much cheaper than inserting leaf by leaf.
    std::vector<fcl::CollisionObject<double>*> all;
    all.reserve(objects_.size());
    for (const auto& o : objects_) all.push_back(o.get());
    manager_.registerObjects(all);
    manager_.setup();
  }

  // Signed distance as for the octree: >= 0 clearance (capped at cutoff), < 0 minus the deepest
  // penetration into one box (a rough depth; the sign is the verdict).
  double signed_distance(const std::shared_ptr<Shape>& shape, const Transform3d& pose,
                         double cutoff) {
    if (objects_.empty()) return cutoff;
    fcl::CollisionObject<double> obj(shape, pose);
    fcl::DefaultDistanceData<double> dd;
    dd.result.min_distance = cutoff;
    manager_.distance(&obj, &dd, fcl::DefaultDistanceFunction<double>);
    if (dd.result.min_distance > 1e-9) return std::min(dd.result.min_distance, cutoff);
    fcl::DefaultCollisionData<double> cd;
    cd.request = fcl::CollisionRequest<double>(std::numeric_limits<int>::max() / 2, true);
    manager_.collide(&obj, &cd, fcl::DefaultCollisionFunction<double>);
    if (!cd.result.isCollision()) return 0.0;
    double depth = 0.0;
    for (size_t c = 0; c < cd.result.numContacts(); ++c)
      depth = std::max(depth, cd.result.getContact(c).penetration_depth);
    return -depth;
  }

 private:
  std::vector<std::unique_ptr<fcl::CollisionObject<double>>> objects_;
  fcl::DynamicAABBTreeCollisionManager<double> manager_;
};

// How deep into occupied voxels a contact may reach and still be explained by the map's
// quantisation (ClearanceOptions::deep_contact_depth; negative: one voxel edge).
inline double deep_contact_depth(const ClearanceOptions& options, const octomap::OcTree& octree) {
  return options.deep_contact_depth >= 0 ? options.deep_contact_depth : octree.getResolution();
}

// The verdict of one sample from its distance to the occupied voxels (`voxel`) and to the certain
// solid (`certain`): a certain collision when it reaches into the certain solid, or deeper into
// occupied voxels than the quantisation explains; a contact within the map's uncertainty when it
// only touches occupied voxels; clear otherwise.
inline ContactVerdict contact_verdict(double voxel, double certain, double deep_depth) {
  if (certain <= 0 || voxel < -deep_depth) return ContactVerdict::certain;
  if (voxel <= 0) return ContactVerdict::uncertain;
  return ContactVerdict::clear;
}

}  // namespace terrastride::collision::detail
