// Private to collision/: signed distances of one FCL shape to the terrain's OctoMap and to the
// certain solid, shared by the leg-capsule check (leg_clearance.cpp) and the trunk-box check
// (trunk_clearance.cpp).
#pragma once

#include <fcl/broadphase/broadphase_dynamic_AABB_tree.h>
#include <fcl/broadphase/default_broadphase_callbacks.h>
#include <fcl/geometry/octree/octree.h>
#include <fcl/geometry/shape/box.h>
#include <fcl/geometry/shape/capsule.h>
#include <fcl/geometry/shape/utility.h>
#include <fcl/math/bv/utility.h>
#include <fcl/narrowphase/detail/gjk_solver_libccd.h>
#include <fcl/narrowphase/collision.h>
#include <fcl/narrowphase/distance.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <vector>

#include "terrastride/collision/checks.hpp"
#include "terrastride/collision/octree_terrain.hpp"

namespace terrastride::collision::detail {

using fcl::Transform3d;
using Shape = fcl::CollisionGeometry<double>;

// A lower bound on the distance between an axis-aligned box and a capsule (segment p-q, radius r),
// never above the true distance by more than rounding: two separating-direction bounds, along the
// direction from the segment's point nearest the box centre to that centre (cheap; tight for
// boxes beside or below the capsule) and, for leaves only (`exact`), the box-segment distance
// itself, minimised over the segment by golden-section search on the convex function
// t -> dist(box, p + t (q - p)) and lowered by the search's remaining interval times the
// segment's length (the function's Lipschitz constant). The search is left out when the first
// bound already reaches `prune_at` (the caller only asks whether the bound reaches it).
inline double box_capsule_lower_bound(const fcl::AABB<double>& box, const Eigen::Vector3d& p,
                                      const Eigen::Vector3d& q, double r, bool exact,
                                      double prune_at) {
  const Eigen::Vector3d c = 0.5 * (box.min_ + box.max_), h = 0.5 * (box.max_ - box.min_);
  const Eigen::Vector3d u = q - p;
  const double uu = u.squaredNorm();
  const double t0 = uu > 0 ? std::clamp((c - p).dot(u) / uu, 0.0, 1.0) : 0.0;
  Eigen::Vector3d n = c - (p + t0 * u);
  double bound = 0.0;
  const double len = n.norm();
  if (len > 0) {
    n /= len;
    const double box_near = n.dot(c) - n.cwiseAbs().dot(h);  // min of n.x over the box
    const double seg_far = std::max(n.dot(p), n.dot(q));     // max of n.x over the segment
    bound = box_near - seg_far - r;
  }
  if (!exact || bound >= prune_at) return bound;
  const auto box_distance = [&](double t) {
    const Eigen::Vector3d x = p + t * u;
    return (x - x.cwiseMax(box.min_).cwiseMin(box.max_)).norm();
  };
  constexpr double kInvPhi = 0.6180339887498949;
  double a = 0.0, b = 1.0;
  double x1 = b - kInvPhi * (b - a), x2 = a + kInvPhi * (b - a);
  double f1 = box_distance(x1), f2 = box_distance(x2);
  for (int it = 0; it < 24; ++it) {  // interval 0.618^24 ~ 1e-5 of the segment (~1 um)
    if (f1 <= f2) {
      b = x2;
      x2 = x1;
      f2 = f1;
      x1 = b - kInvPhi * (b - a);
      f1 = box_distance(x1);
    } else {
      a = x1;
      x1 = x2;
      f1 = f2;
      x2 = a + kInvPhi * (b - a);
      f2 = box_distance(x2);
    }
  }
  // The minimum lies in [a, b] (convexity), where the function is at least f(x) - |u| (b - a)
  // for either probe x in it; the ends 0 and 1 are probed too, for segments of length ~0.
  const double seg = std::sqrt(uu) * (b - a);
  const double f_min = std::min({f1, f2, box_distance(0.0), box_distance(1.0)}) - seg;
  return std::max(bound, f_min - r);
}

// fcl::distance(&tree, I, &capsule, pose, request, result) with a default DistanceRequest (FCL
// 0.7's OcTreeSolver::OcTreeShapeDistanceRecurse, GJKSolver_libccd), returning the same
// result.min_distance from `seed` on, bit for bit, with far fewer GJK runs. FCL descends into
// every child whose axis-aligned box is nearer to the capsule's axis-aligned box than the best
// distance so far, and runs GJK on every occupied leaf it reaches; for an inclined capsule over
// the ground that box is loose, and most of those GJK runs (about 8,000 instructions each, 30 a
// query) only confirm a voxel is farther. Here a node is also skipped when a lower bound on its
// distance to the capsule itself (box_capsule_lower_bound, minus a 1e-9 m rounding allowance) is
// not below the best so far: every leaf under it would have given a GJK distance (the norm of a
// point of the Minkowski difference, never below the true distance) that does not lower the best,
// so the best evolves, and FCL's traversal visits, finds and stops exactly as without the skip.
// Rounding allowance of the lower bounds (m).
inline constexpr double kRounding = 1e-9;

inline double capsule_octree_distance(const fcl::OcTree<double>& tree,
                                      const fcl::Capsule<double>& capsule, const Transform3d& pose,
                                      double seed) {
  const Transform3d identity = Transform3d::Identity();
  const fcl::DistanceRequest<double> request;
  fcl::detail::GJKSolver_libccd<double> solver;
  solver.distance_tolerance = request.distance_tolerance;
  fcl::AABB<double> shape_box;
  fcl::computeBV(capsule, pose, shape_box);
  const Eigen::Vector3d axis = pose.linear().col(2) * (0.5 * capsule.lz);
  const Eigen::Vector3d p = pose.translation() - axis, q = pose.translation() + axis;
  double best = seed;
  // Returns true when a distance <= 0 ends the search (DistanceRequest::isSatisfied).
  struct Search {
    const fcl::OcTree<double>& tree;
    const fcl::Capsule<double>& capsule;
    const Transform3d& pose;
    const Transform3d& identity;
    const fcl::AABB<double>& shape_box;
    const Eigen::Vector3d &p, &q;
    fcl::detail::GJKSolver_libccd<double>& solver;
    double& best;
    bool recurse(const octomap::OcTreeNode* node, const fcl::AABB<double>& bv) const {
      if (!tree.nodeHasChildren(node)) {
        if (!tree.isNodeOccupied(node)) return false;
        if (box_capsule_lower_bound(bv, p, q, capsule.radius, true, best + kRounding) -
                kRounding >=
            best)
          return false;
        fcl::Box<double> box;
        Transform3d box_tf;
        fcl::constructBox(bv, identity, box, box_tf);
        double dist;
        Eigen::Vector3d p1 = Eigen::Vector3d::Zero(), p2 = Eigen::Vector3d::Zero();
        solver.shapeDistance(box, box_tf, capsule, pose, &dist, &p1, &p2);
        if (best > dist) best = dist;
        return best <= 0;
      }
      if (!tree.isNodeOccupied(node)) return false;
      // The children nearest the capsule first (by a lower bound on their distance): the nearest
      // voxels tighten `best` early, so the farther children are pruned, and a capsule in
      // collision meets a voxel it touches after a few boxes instead of after every box in index
      // order. The order changes which boxes are visited, not the minimum.
      struct Child {
        const octomap::OcTreeNode* node;
        fcl::AABB<double> bv;
        double bound;
      };
      Child children[8];
      int count = 0;
      for (unsigned int i = 0; i < 8; ++i) {
        if (!tree.nodeChildExists(node, i)) continue;
        Child& c = children[count];
        c.node = tree.getNodeChild(node, i);
        fcl::computeChildBV(bv, i, c.bv);
        fcl::AABB<double> child_box;
        fcl::convertBV(c.bv, identity, child_box);
        const double box_distance = child_box.distance(shape_box);
        if (!(box_distance < best)) continue;
        c.bound = std::max(box_distance,
                           box_capsule_lower_bound(c.bv, p, q, capsule.radius, false, 0.0));
        ++count;
      }
      for (int k = 1; k < count; ++k)  // insertion sort of at most 8
        for (int j = k; j > 0 && children[j].bound < children[j - 1].bound; --j)
          std::swap(children[j], children[j - 1]);
      for (int k = 0; k < count; ++k) {
        const Child& c = children[k];
        if (!(c.bound - kRounding < best)) break;  // sorted: every later child is as far
        if (recurse(c.node, c.bv)) return true;
      }
      return false;
    }
  };
  const Search search{tree, capsule, pose, identity, shape_box, p, q, solver, best};
  if (tree.getRoot()) search.recurse(tree.getRoot(), tree.getRootBV());
  return best;
}

// The signed distance of a shape found touching the tree (distance <= 0): minus its deepest
// penetration into any single node (FCL's contacts, every one), or 0 when FCL's collision query
// finds none (touching within GJK's tolerance).
inline double contact_signed_distance(const fcl::OcTree<double>& tree, const Shape& shape,
                                      const Transform3d& pose) {
  const Transform3d identity = Transform3d::Identity();
  fcl::CollisionRequest<double> creq(std::numeric_limits<int>::max() / 2, true);
  fcl::CollisionResult<double> cres;
  fcl::collide(&tree, identity, &shape, pose, creq, cres);
  if (!cres.isCollision()) return 0.0;
  double depth = 0.0;
  for (size_t c = 0; c < cres.numContacts(); ++c)
    depth = std::max(depth, cres.getContact(c).penetration_depth);
  return -depth;
}

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
  return contact_signed_distance(tree, shape, pose);
}

// signed_distance for a capsule: the distance query through capsule_octree_distance (the same
// result as fcl::distance, with fewer GJK runs), the collision branch as above.
inline double signed_distance(const fcl::OcTree<double>& tree, const fcl::Capsule<double>& capsule,
                              const Transform3d& pose, double cutoff, double upper_bound) {
  const double d = capsule_octree_distance(tree, capsule, pose, std::min(cutoff, upper_bound));
  if (d > 1e-9) return std::min(d, cutoff);
  return contact_signed_distance(tree, capsule, pose);
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

// How deep into occupied voxels a contact may reach and still be explained by the map
// (ClearanceOptions::deep_contact_depth; negative: one voxel edge for the quantisation, plus the
// depth the sensor noise alone fills with voxels above the true surface, CertainSolid::noise_depth:
// on a floor whose points spread 26 mm, occupied voxels stand ~8 cm above it, and a shin 6 cm
// into them while 1 cm clear of the certain solid is noise, not a collision).
inline double deep_contact_depth(const ClearanceOptions& options, const octomap::OcTree& octree,
                                 const CertainSolid* certain) {
  if (options.deep_contact_depth >= 0) return options.deep_contact_depth;
  return octree.getResolution() + (certain ? certain->noise_depth : 0.0);
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
