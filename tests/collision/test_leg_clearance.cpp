// Leg capsules against OctoMaps with FCL: collisions through box edges, clearances, scan trees.
#include <gtest/gtest.h>

#include <cmath>

#include "terrastride/collision/checks.hpp"
#include "terrastride/collision/octree_terrain.hpp"
#include "terrastride/perception/octomap_fusion.hpp"
#include "trajectories.hpp"

using namespace terrastride;
using namespace terrastride::collision;
using terrastride::collision::test::hyq;
using terrastride::collision::test::standing;

namespace {

// Exact distance from the segment a-b to an axis-aligned box (0 inside), by ternary search
// along the segment: the distance from a point moving along a line to a convex set is convex.
double segment_box_distance(const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                            const terrain::Box& box) {
  auto dist = [&](double s) {
    const Eigen::Vector3d p = a + s * (b - a);
    const Eigen::Vector3d q = p.cwiseMax(box.lo).cwiseMin(box.hi);
    return (p - q).norm();
  };
  double lo = 0, hi = 1;
  for (int it = 0; it < 200; ++it) {
    const double m1 = lo + (hi - lo) / 3, m2 = hi - (hi - lo) / 3;
    if (dist(m1) < dist(m2))
      hi = m2;
    else
      lo = m1;
  }
  return dist(0.5 * (lo + hi));
}

double snap(double v, double res) {
  return std::round(v / res) * res;
}

struct ShinGeometry {
  Eigen::Vector3d end, knee;  // the shin capsule's axis in the world frame
};

ShinGeometry shin_of(const robot::RobotModel& model, const planner::Trajectory& traj, int leg_index,
                     double exclusion) {
  const auto& leg = model.legs[leg_index];
  const auto& s = traj.samples.front();
  const Eigen::Matrix3d rot = rotation_zyx(s.base.euler_zyx);
  const Eigen::Vector3d p_b = rot.transpose() * (s.feet[leg_index].position - s.base.position);
  const Eigen::Vector3d q = robot::inverse_kinematics(leg, p_b).q;
  const Eigen::Vector3d knee = s.base.position + rot * robot::knee_position(leg, q);
  const Eigen::Vector3d foot = s.base.position + rot * robot::foot_position(leg, q);
  return {foot + (knee - foot).normalized() * exclusion, knee};
}

ClearanceReport clearance(const robot::RobotModel& model, const planner::Trajectory& traj,
                          const octomap::OcTree& tree, const ClearanceOptions& options = {}) {
  return check_leg_clearance(model, traj, leg_kinematics(model, traj), tree, options);
}

constexpr double kRes = 0.01;

}  // namespace

TEST(LegClearance, StandingOnFlatGroundIsClearByTheExpectedAmount) {
  const auto model = hyq();
  const auto traj = standing(model, 0.01, 0.002);
  Eigen::Vector2d lo, hi;
  trajectory_extent(model, traj, 0.1, &lo, &hi);
  VoxeliseOptions vo;
  vo.resolution = kRes;
  const auto tree = voxelise_boxes(0.0, {}, lo, hi, vo);
  ClearanceOptions far;
  far.distance_cutoff = 0.5;  // resolve the thighs' clearance too
  const ClearanceReport rep = clearance(model, traj, *tree, far);
  EXPECT_EQ(rep.shin_collisions, 0);
  EXPECT_EQ(rep.thigh_collisions, 0);
  const double exclusion = 2 * model.foot_radius + model.legs[0].shin_radius + 0.01;
  EXPECT_NEAR(rep.shin_exclusion, exclusion, 1e-12);
  for (int i = 0; i < 4; ++i) {
    // The ground's top face is z = 0 exactly (voxel-aligned): clearance = lowest axis point - r.
    const ShinGeometry g = shin_of(model, traj, i, exclusion);
    const double expected = std::min(g.end.z(), g.knee.z()) - model.legs[i].shin_radius;
    EXPECT_GT(expected, 0.02) << model.legs[i].name;
    EXPECT_NEAR(rep.legs[i].shin_min, expected, 1e-3) << model.legs[i].name;
    EXPECT_NEAR(rep.legs[i].shin_distance[0], expected, 1e-3);
    const auto& s = traj.samples.front();
    const auto& leg = model.legs[i];
    const Eigen::Vector3d q =
        robot::inverse_kinematics(leg, s.feet[i].position - s.base.position).q;
    const double thigh_expected =
        std::min(robot::hfe_position(leg, q).z(), robot::knee_position(leg, q).z()) +
        s.base.position.z() - leg.thigh_radius;
    EXPECT_NEAR(rep.legs[i].thigh_min, thigh_expected, 1e-3) << model.legs[i].name;
  }
}

TEST(LegClearance, ShinThroughABoxEdgeCollides) {
  const auto model = hyq();
  const auto traj = standing(model, 0.02, 0.002);
  const double exclusion = 2 * model.foot_radius + model.legs[2].shin_radius + 0.01;
  const ShinGeometry g = shin_of(model, traj, 2, exclusion);  // LH, knee pointing forward
  const Eigen::Vector3d mid = 0.5 * (g.end + g.knee);
  // A box whose top rear edge (x = mid.x, z = mid.z, along y) runs through the shin's axis.
  const terrain::Box box{Eigen::Vector3d(mid.x(), mid.y() - 0.15, 0.0),
                         Eigen::Vector3d(mid.x() + 0.3, mid.y() + 0.15, mid.z())};
  Eigen::Vector2d lo, hi;
  trajectory_extent(model, traj, 0.1, &lo, &hi);
  VoxeliseOptions vo;
  vo.resolution = kRes;
  const auto tree = voxelise_boxes(0.0, {box}, lo, hi, vo);
  const ClearanceReport rep = clearance(model, traj, *tree);
  EXPECT_EQ(rep.legs[2].shin_collision_samples, static_cast<int>(traj.samples.size()));
  EXPECT_EQ(rep.shin_collisions, static_cast<int>(traj.samples.size()));
  EXPECT_LE(rep.legs[2].shin_min, 0.0);
  EXPECT_LE(rep.shin_min_distance, 0.0);
  EXPECT_DOUBLE_EQ(rep.first_collision_t, 0.0);
  EXPECT_EQ(rep.legs[0].shin_collision_samples, 0);  // LF stands far from the box

  // The whole check reports it as a failure with the leg's name.
  CheckTerrain terrain;
  terrain.octree = tree;
  const CheckReport all = run_checks(model, traj, terrain);
  EXPECT_FALSE(all.passed());
  EXPECT_LE(all.keys().at("shin_min_distance_m"), 0.0);
  EXPECT_EQ(all.keys().at("shin_collisions"), traj.samples.size());
  bool named = false;
  for (const auto& line : all.failures()) named |= line.find("LH") != std::string::npos;
  EXPECT_TRUE(named);
}

TEST(LegClearance, ShinNearABoxReportsTheClearance) {
  const auto model = hyq();
  const auto traj = standing(model, 0.01, 0.002);
  const double exclusion = 2 * model.foot_radius + model.legs[2].shin_radius + 0.01;
  const ShinGeometry g = shin_of(model, traj, 2, exclusion);
  const Eigen::Vector3d mid = 0.5 * (g.end + g.knee);
  Eigen::Vector2d lo, hi;
  trajectory_extent(model, traj, 0.1, &lo, &hi);
  VoxeliseOptions vo;
  vo.resolution = kRes;
  // The shin's clearance to the ground alone (its top face is z = 0, voxel-aligned).
  const double ground = std::min(g.end.z(), g.knee.z()) - model.legs[2].shin_radius;
  // Boxes in front of the shin at several gaps, faces on the voxel grid so the voxels are exact;
  // short in x so that they stay clear of the front legs.
  for (double gap : {0.0, 0.02, 0.05, 0.11}) {
    const terrain::Box box{
        Eigen::Vector3d(snap(mid.x() + gap, kRes), snap(mid.y() - 0.1, kRes), 0.0),
        Eigen::Vector3d(snap(mid.x() + gap + 0.08, kRes), snap(mid.y() + 0.1, kRes),
                        snap(mid.z(), kRes))};
    const double to_box = segment_box_distance(g.end, g.knee, box) - model.legs[2].shin_radius;
    const double expected = std::min(to_box, ground);
    const auto tree = voxelise_boxes(0.0, {box}, lo, hi, vo);
    const ClearanceReport rep = clearance(model, traj, *tree);
    if (to_box > kRes) {
      EXPECT_NEAR(rep.legs[2].shin_min, expected, kRes) << "gap " << gap;
      EXPECT_EQ(rep.legs[2].shin_collision_samples, 0) << "gap " << gap;
    } else if (to_box < -kRes) {
      EXPECT_LE(rep.legs[2].shin_min, 0.0) << "gap " << gap;
      EXPECT_GT(rep.legs[2].shin_collision_samples, 0) << "gap " << gap;
    }
    EXPECT_EQ(rep.legs[0].shin_collision_samples, 0) << "gap " << gap;
    EXPECT_EQ(rep.legs[1].shin_collision_samples, 0) << "gap " << gap;
  }
}

TEST(LegClearance, ScanOctreeOfAGroundPlaneLeavesStanceLegsClear) {
  // A scan-like tree from perception: hits on the ground seen from a sensor 0.8 m up, so voxels
  // hold the surface only (with free space carved above it) and may stick up to one voxel above it.
  const auto model = hyq();
  const auto traj = standing(model, 0.01, 0.002);
  perception::PointCloud cloud;
  cloud.sensor_origin = Eigen::Vector3d(0, 0, 0.8);
  for (double x = -1.2; x <= 1.2; x += 0.01)
    for (double y = -0.8; y <= 0.8; y += 0.01) cloud.points.emplace_back(x, y, 0.003);
  perception::OctoMapOptions oo;
  oo.resolution = 0.02;
  const auto tree = perception::build_octomap({cloud}, oo);
  const ClearanceReport rep = clearance(model, traj, *tree);
  EXPECT_EQ(rep.shin_collisions, 0);
  EXPECT_EQ(rep.thigh_collisions, 0);
  // The quantisation margin grows to the 2 cm voxel size.
  const double exclusion = 2 * model.foot_radius + model.legs[0].shin_radius + 0.02;
  EXPECT_NEAR(rep.shin_exclusion, exclusion, 1e-12);
  for (int i = 0; i < 4; ++i) {
    const ShinGeometry g = shin_of(model, traj, i, exclusion);
    const double exact = std::min(g.end.z(), g.knee.z()) - model.legs[i].shin_radius;
    // Voxel tops are at 0.02 here (the hits at z = 0.003 fall in [0, 0.02)).
    EXPECT_NEAR(rep.legs[i].shin_min, exact - 0.02, 2e-3) << model.legs[i].name;
  }
  // A scanned step whose top edge runs through LH's shin (hits on its top and front face only,
  // as a sensor sees it): the shell of voxels is enough for FCL to find the collision.
  const ShinGeometry g = shin_of(model, traj, 2, exclusion);
  const Eigen::Vector3d mid = 0.5 * (g.end + g.knee);
  perception::PointCloud step = cloud;
  step.points.clear();
  step.sensor_origin = Eigen::Vector3d(mid.x() - 0.6, mid.y(), 0.8);  // facing the step's face
  for (double y = mid.y() - 0.1; y <= mid.y() + 0.1; y += 0.01) {
    for (double x = mid.x(); x <= mid.x() + 0.1; x += 0.01) step.points.emplace_back(x, y, mid.z());
    for (double z = 0.0; z <= mid.z(); z += 0.01) step.points.emplace_back(mid.x(), y, z);
  }
  const auto stepped = perception::build_octomap({cloud, step}, oo);
  const ClearanceReport hit = clearance(model, traj, *stepped);
  EXPECT_GT(hit.legs[2].shin_collision_samples, 0);
  EXPECT_LE(hit.legs[2].shin_min, 0.0);
  EXPECT_EQ(hit.legs[0].shin_collision_samples, 0);
}

TEST(LegClearance, BoundedSamplesAgreeWithQueryingEverySample) {
  // LF swings its leg back and forth over a box while the base walks and turns: the temporal
  // bounds must give the same collisions, the same minima (within their allowance) and lower
  // bounds that never exceed the exact distance.
  const auto model = hyq();
  auto traj = standing(model, 1.0, 0.002);
  const auto& lf = model.legs[0];
  const Eigen::Vector3d q0 = robot::inverse_kinematics(lf, lf.nominal_foot).q;
  const Eigen::Vector3d amp(0.05, 0.35, 0.45);
  const double w = 2 * M_PI;
  test::BaseMotion motion;
  motion.velocity = Eigen::Vector3d(0.1, 0.0, 0.0);
  motion.yaw_rate = 0.1;
  test::drive_leg(
      model, traj, 0, [&](double t) -> Eigen::Vector3d { return q0 + amp * std::sin(w * t); },
      [&](double t) -> Eigen::Vector3d { return amp * w * std::cos(w * t); }, motion);
  Eigen::Vector2d lo, hi;
  trajectory_extent(model, traj, 0.1, &lo, &hi);
  const terrain::Box box{Eigen::Vector3d(0.25, 0.1, 0.0), Eigen::Vector3d(0.45, 0.5, 0.12)};
  const auto tree = voxelise_boxes(0.0, {box}, lo, hi);
  ClearanceOptions every;
  every.bound_tolerance = 0;
  every.bound_relative = 0;
  const ClearanceReport exact = clearance(model, traj, *tree, every);
  const ClearanceReport bounded = clearance(model, traj, *tree);
  const long capsule_samples = 2 * 4 * static_cast<long>(traj.samples.size());
  // Every capsule piece at every sample (links are split into pieces of <= 0.1 m).
  EXPECT_GE(exact.fcl_queries, capsule_samples);
  EXPECT_LT(bounded.fcl_queries, exact.fcl_queries / 2);
  EXPECT_GT(exact.legs[0].shin_collision_samples, 0);  // the swinging shin does hit the box
  EXPECT_EQ(bounded.shin_collisions, exact.shin_collisions);
  EXPECT_EQ(bounded.thigh_collisions, exact.thigh_collisions);
  EXPECT_DOUBLE_EQ(bounded.first_collision_t, exact.first_collision_t);
  for (size_t i = 0; i < 4; ++i) {
    const auto& e = exact.legs[i];
    const auto& b = bounded.legs[i];
    EXPECT_EQ(b.shin_collision_samples, e.shin_collision_samples);
    for (size_t k = 0; k < traj.samples.size(); ++k) {
      if (b.shin_exact[k]) {
        EXPECT_NEAR(b.shin_distance[k], e.shin_distance[k], 1e-9) << i << " " << k;
      } else {
        EXPECT_LE(b.shin_distance[k], e.shin_distance[k] + 1e-9) << i << " " << k;
        EXPECT_GT(b.shin_distance[k], 0.01) << i << " " << k;
      }
      if (!b.thigh_exact[k]) {
        EXPECT_LE(b.thigh_distance[k], e.thigh_distance[k] + 1e-9) << i << " " << k;
      }
    }
    const double allowance = std::max(0.002, 0.1 * (e.shin_min - 0.01));
    EXPECT_LE(b.shin_min, e.shin_min + 1e-9);
    EXPECT_GE(b.shin_min, e.shin_min - allowance);
  }
}

TEST(LegClearance, VoxeliseRejectsBadInput) {
  EXPECT_THROW(voxelise_boxes(0, {}, Eigen::Vector2d(0, 0), Eigen::Vector2d(1, 1),
                              VoxeliseOptions{0.0, 0.1}),
               std::invalid_argument);
  EXPECT_THROW(voxelise_boxes(0, {}, Eigen::Vector2d(1, 0), Eigen::Vector2d(0, 1)),
               std::invalid_argument);
  const terrain::Box inverted{Eigen::Vector3d(1, 0, 0), Eigen::Vector3d(0, 1, 1)};
  EXPECT_THROW(voxelise_boxes(0, {inverted}, Eigen::Vector2d(0, 0), Eigen::Vector2d(1, 1)),
               std::invalid_argument);
  EXPECT_THROW(read_octomap("/nonexistent/octomap.bt"), std::runtime_error);
}

TEST(LegClearance, VoxelisedBoxHasExactFaces) {
  VoxeliseOptions vo;
  vo.resolution = 0.02;
  const terrain::Box box{Eigen::Vector3d(0.2, -0.2, 0.0), Eigen::Vector3d(0.6, 0.2, 0.1)};
  const auto tree =
      voxelise_boxes(0.0, {box}, Eigen::Vector2d(-0.5, -0.5), Eigen::Vector2d(1.0, 0.5), vo);
  auto occupied = [&](double x, double y, double z) {
    const octomap::OcTreeNode* node = tree->search(x, y, z);
    return node != nullptr && tree->isNodeOccupied(node);
  };
  EXPECT_TRUE(occupied(0.4, 0.0, 0.09));
  EXPECT_TRUE(occupied(0.4, 0.0, 0.01));  // filled, not a skin
  EXPECT_FALSE(occupied(0.4, 0.0, 0.11));
  EXPECT_FALSE(occupied(0.19, 0.0, 0.05));
  EXPECT_TRUE(occupied(0.0, 0.0, -0.01));  // the ground slab
  EXPECT_TRUE(occupied(0.0, 0.0, -0.04));
  EXPECT_FALSE(occupied(0.0, 0.0, 0.01));
  EXPECT_FALSE(occupied(0.0, 0.0, -0.07));
}

// ---- The resolution-aware verdict: certain collisions vs contacts within the map's uncertainty --

namespace {

// A scan-like map of a box standing on the ground, both as terrastride map builds them from the
// same points: a 5 cm OctoMap (every voxel holding a point is occupied) and the 2 cm height grid.
// Points every 5 mm with +-1 mm of deterministic noise on the ground (not under the box), the box
// top and its four side faces.
struct ScannedBox {
  std::shared_ptr<octomap::OcTree> tree;
  terrain::HeightGrid grid;
};

ScannedBox scan_box(const terrain::Box& box, const Eigen::Vector2d& lo, const Eigen::Vector2d& hi,
                    double voxel, const std::vector<Eigen::Vector3f>& extra = {}) {
  std::vector<Eigen::Vector3f> pts = extra;
  unsigned state = 12345;
  auto noise = [&] {
    state = state * 1103515245u + 12345u;
    return ((state >> 8) % 2001) / 1000.0 * 1e-3 - 1e-3;
  };
  auto inside = [&](double x, double y) {
    return x >= box.lo.x() && x <= box.hi.x() && y >= box.lo.y() && y <= box.hi.y();
  };
  const double step = 0.005;
  for (double x = lo.x(); x <= hi.x(); x += step)
    for (double y = lo.y(); y <= hi.y(); y += step)
      pts.emplace_back(x, y, inside(x, y) ? box.hi.z() + noise() : noise());
  for (double z = 0; z < box.hi.z(); z += step) {
    for (double x = box.lo.x(); x <= box.hi.x(); x += step) {
      pts.emplace_back(x, box.lo.y() + noise(), z);
      pts.emplace_back(x, box.hi.y() + noise(), z);
    }
    for (double y = box.lo.y(); y <= box.hi.y(); y += step) {
      pts.emplace_back(box.lo.x() + noise(), y, z);
      pts.emplace_back(box.hi.x() + noise(), y, z);
    }
  }
  ScannedBox s;
  s.tree = std::make_shared<octomap::OcTree>(voxel);
  for (const auto& p : pts) s.tree->updateNode(octomap::point3d(p.x(), p.y(), p.z()), true, true);
  s.tree->updateInnerOccupancy();
  terrain::PointBatch batch;
  batch.points = pts.data();
  batch.size = pts.size();
  s.grid = terrain::build_height_grid(std::vector<terrain::PointBatch>{batch});
  return s;
}

// A 20 x 20 cm box under LH's shin, its top `below` under the capsule's lowest point (negative:
// the capsule reaches that far into it), scanned at 5 cm; the verdicts of the check against it.
struct BoxVerdict {
  ClearanceReport rep;
  double voxel_top = 0.0, capsule_bottom = 0.0;
};

// `mixed_pixels`: also a few stray returns in free air inside the capsule's lowest part, as mixed
// pixels at an edge give (they occupy a voxel the capsule passes through).
BoxVerdict box_under_the_shin(double below, bool mixed_pixels = false) {
  const auto model = hyq();
  const auto traj = standing(model, 0.01, 0.002);
  const double voxel = 0.05;
  const double exclusion = 2 * model.foot_radius + model.legs[2].shin_radius + voxel;
  const ShinGeometry g = shin_of(model, traj, 2, exclusion);
  const double r = model.legs[2].shin_radius;
  const Eigen::Vector3d low = g.end.z() < g.knee.z() ? g.end : g.knee;
  BoxVerdict v;
  v.capsule_bottom = low.z() - r;
  const terrain::Box box{Eigen::Vector3d(low.x() - 0.1, low.y() - 0.1, 0.0),
                         Eigen::Vector3d(low.x() + 0.1, low.y() + 0.1, v.capsule_bottom - below)};
  Eigen::Vector2d lo, hi;
  trajectory_extent(model, traj, 0.1, &lo, &hi);
  std::vector<Eigen::Vector3f> stray;
  if (mixed_pixels)
    for (int m = 0; m < 3; ++m)
      stray.emplace_back(low.x() + 0.004 * m, low.y(), v.capsule_bottom + 0.01 + 0.003 * m);
  const ScannedBox scan = scan_box(box, lo, hi, voxel, stray);
  v.voxel_top = std::ceil(box.hi.z() / voxel) * voxel;
  const auto certain = certain_solid_from_grid(scan.grid, *scan.tree, lo, hi);
  v.rep =
      check_leg_clearance(model, traj, leg_kinematics(model, traj), *scan.tree, {}, certain.get());
  return v;
}

}  // namespace

TEST(LegClearanceVerdict, ShinHoveringMillimetresAboveAScannedBoxIsNotACertainCollision) {
  const BoxVerdict v = box_under_the_shin(0.004);
  // The premise: the box top's voxels stand above the capsule's lowest point.
  ASSERT_GT(v.voxel_top, v.capsule_bottom + 0.01);
  const auto& lh = v.rep.legs[2];
  // The voxel-only check (the old verdict) calls it a collision...
  EXPECT_GT(lh.shin_collision_samples, 0);
  EXPECT_LE(lh.shin_min, -0.01);
  // ...the resolution-aware one: only within the map's uncertainty.
  EXPECT_FALSE(v.rep.certain_source.empty());
  EXPECT_EQ(lh.shin_certain_samples, 0);
  EXPECT_EQ(v.rep.shin_collisions_certain, 0);
  EXPECT_EQ(v.rep.shin_contacts_uncertain, v.rep.shin_collisions);
  // The certain solid lies under the true top, by the noise allowance (3 sigma, ~2 mm here).
  EXPECT_GE(lh.shin_certain_min, 0.004 - 1e-6);
  EXPECT_LE(lh.shin_certain_min, 0.004 + 0.005);
  for (auto verdict : lh.shin_verdict) EXPECT_EQ(verdict, ContactVerdict::uncertain);
  EXPECT_LT(v.rep.first_certain_collision_t, 0.0);
}

TEST(LegClearanceVerdict, MixedPixelsInsideTheCapsuleAreNotACertainCollision) {
  // The stray returns lie inside the capsule: the voxels collide wherever the grid puts them, but
  // the certain solid stays under the box's lowest plausible top.
  const BoxVerdict v = box_under_the_shin(0.004, /*mixed_pixels=*/true);
  const auto& lh = v.rep.legs[2];
  EXPECT_GT(lh.shin_collision_samples, 0);
  EXPECT_EQ(lh.shin_certain_samples, 0);
  EXPECT_GE(lh.shin_certain_min, 0.004 - 1e-6);
}

TEST(LegClearanceVerdict, ShinThreeCentimetresIntoAScannedBoxIsACertainCollision) {
  const BoxVerdict v = box_under_the_shin(-0.03);
  const auto& lh = v.rep.legs[2];
  EXPECT_GT(lh.shin_collision_samples, 0);
  EXPECT_EQ(lh.shin_certain_samples, lh.shin_collision_samples);
  EXPECT_EQ(v.rep.shin_collisions_certain, v.rep.shin_collisions);
  EXPECT_LT(lh.shin_certain_min, 0.0);
  for (auto verdict : lh.shin_verdict) EXPECT_EQ(verdict, ContactVerdict::certain);
  EXPECT_DOUBLE_EQ(v.rep.first_certain_collision_t, 0.0);
  EXPECT_EQ(v.rep.legs[0].shin_collision_samples, 0);  // LF stands far from the box
}

TEST(LegClearanceVerdict, ExactSceneDecidesVoxelContactsAndNoSolidKeepsTheOldVerdict) {
  // An exact box 4 mm under LH's shin, voxelised at 5 cm: the voxels touch the capsule, the exact
  // box does not. Without a certain solid every voxel contact is a certain collision.
  const auto model = hyq();
  const auto traj = standing(model, 0.01, 0.002);
  const double exclusion = 2 * model.foot_radius + model.legs[2].shin_radius + 0.05;
  const ShinGeometry g = shin_of(model, traj, 2, exclusion);
  const Eigen::Vector3d low = g.end.z() < g.knee.z() ? g.end : g.knee;
  const double bottom = low.z() - model.legs[2].shin_radius;
  Eigen::Vector2d lo, hi;
  trajectory_extent(model, traj, 0.1, &lo, &hi);
  for (double below : {0.004, -0.03}) {
    const terrain::Box box{Eigen::Vector3d(low.x() - 0.1, low.y() - 0.1, 0.0),
                           Eigen::Vector3d(low.x() + 0.1, low.y() + 0.1, bottom - below)};
    const terrain::Scene scene("box", "a box", 0.0, {box}, lo, hi);
    VoxeliseOptions vo;
    vo.resolution = 0.05;
    // Voxels are occupied when their centre is inside: a box 5 cm taller puts voxels above the
    // capsule whatever the grid alignment (as a scan's surface voxels stand above its surface).
    const auto tree = voxelise_boxes(
        0.0, {terrain::Box{box.lo, box.hi + Eigen::Vector3d(0, 0, 0.05)}}, lo, hi, vo);
    CheckTerrain terrain;
    terrain.field = &scene;
    terrain.octree = tree;
    const CheckReport rep = run_checks(model, traj, terrain);
    ASSERT_TRUE(rep.clearance);
    EXPECT_GT(rep.clearance->shin_collisions, 0) << below;
    EXPECT_NE(rep.clearance->certain_source.find("exact scene"), std::string::npos);
    if (below > 0) {
      EXPECT_EQ(rep.clearance->shin_collisions_certain, 0);
      EXPECT_TRUE(rep.passed()) << rep.failures().front();
      EXPECT_NEAR(rep.clearance->shin_min_certain_distance, below, 1e-3);
    } else {
      EXPECT_EQ(rep.clearance->shin_collisions_certain, rep.clearance->shin_collisions);
      EXPECT_FALSE(rep.passed());
    }
    CheckTerrain voxels_only;
    voxels_only.octree = tree;
    const CheckReport old = run_checks(model, traj, voxels_only);
    EXPECT_TRUE(old.clearance->certain_source.empty());
    EXPECT_EQ(old.clearance->shin_collisions_certain, old.clearance->shin_collisions);
    EXPECT_FALSE(old.passed());
  }
}

// ---- Depth into occupied voxels beyond what the cell explains ----

namespace {

// LF's thigh over a slab of solid under its knee, voxelised at 2 cm, the voxels' top `depth` above
// the thigh's lowest point (the robot is raised so that point lies mid-voxel); no certain solid
// anywhere (as at a thin wall, which the grid's erosion removes): only the voxels can tell.
ClearanceReport thigh_into_a_slab(double depth) {
  const auto model = hyq();
  const auto& leg = model.legs[0];
  const double voxel = 0.02;
  const auto probe = standing(model, 0.002, 0.002);
  const auto& s0 = probe.samples.front();
  const Eigen::Vector3d q =
      robot::inverse_kinematics(leg, s0.feet[0].position - s0.base.position).q;
  const double low_rel = robot::knee_position(leg, q).z() - leg.thigh_radius;
  const double low = std::floor((0.58 + low_rel) / voxel) * voxel + 0.5 * voxel;
  const Eigen::Vector3d base(0, 0, low - low_rel);
  const auto traj = standing(model, 0.01, 0.002, base);
  const Eigen::Vector3d knee = base + robot::knee_position(leg, q);
  const double voxel_top = low + depth;
  const terrain::Box slab{Eigen::Vector3d(knee.x() - 0.06, knee.y() - 0.06, voxel_top - 0.1),
                          Eigen::Vector3d(knee.x() + 0.06, knee.y() + 0.06, voxel_top - 0.005)};
  Eigen::Vector2d lo, hi;
  trajectory_extent(model, traj, 0.1, &lo, &hi);
  VoxeliseOptions vo;
  vo.resolution = voxel;
  vo.ground_thickness = voxel;
  const auto tree = voxelise_boxes(-1.0, {slab}, lo, hi, vo);
  const CertainSolid none{{}, "test: no certain solid"};
  return check_leg_clearance(model, traj, leg_kinematics(model, traj), *tree, {}, &none);
}

}  // namespace

TEST(LegClearanceVerdict, ThighDeeperIntoVoxelsThanACellIsACertainCollision) {
  // 5 cm into 2 cm voxels: more than any voxel's quantisation explains.
  const ClearanceReport deep = thigh_into_a_slab(0.05);
  EXPECT_NEAR(deep.deep_contact_depth, 0.02, 1e-12);
  const auto& lf = deep.legs[0];
  ASSERT_LT(lf.thigh_min, -0.02);
  EXPECT_GT(lf.thigh_certain_samples, 0);
  EXPECT_EQ(lf.thigh_certain_samples, lf.thigh_collision_samples);
  for (auto v : lf.thigh_verdict) EXPECT_EQ(v, ContactVerdict::certain);
  EXPECT_GT(deep.thigh_collisions_certain, 0);
  CheckReport rep;
  rep.clearance = deep;
  ASSERT_FALSE(rep.passed());
  EXPECT_NE(rep.failures().front().find("thigh"), std::string::npos);
}

TEST(LegClearanceVerdict, ThighTouchingVoxelsWithinACellStaysUncertain) {
  // Less than one voxel in: the measured surface may lie anywhere in that voxel.
  const ClearanceReport shallow = thigh_into_a_slab(0.01);
  const auto& lf = shallow.legs[0];
  ASSERT_LT(lf.thigh_min, 0.0);
  ASSERT_GT(lf.thigh_min, -0.02);
  EXPECT_EQ(lf.thigh_certain_samples, 0);
  EXPECT_GT(lf.thigh_collision_samples, 0);
  EXPECT_EQ(shallow.thigh_collisions_certain, 0);
  EXPECT_GT(shallow.thigh_contacts_uncertain, 0);
}

// ---- The trunk box (robot file `trunk`) against the terrain ----

namespace {

CheckReport checks_on_scene(const robot::RobotModel& model, const planner::Trajectory& traj,
                            const std::vector<terrain::Box>& boxes) {
  Eigen::Vector2d lo, hi;
  trajectory_extent(model, traj, 0.1, &lo, &hi);
  const auto scene = std::make_shared<terrain::Scene>("boxes", "test boxes", 0.0, boxes, lo, hi);
  VoxeliseOptions vo;
  vo.resolution = kRes;
  CheckTerrain terrain;
  terrain.field = scene.get();
  terrain.octree = voxelise_scene(*scene, lo, hi, vo);
  CheckReport rep = run_checks(model, traj, terrain);
  return rep;
}

}  // namespace

TEST(TrunkClearance, StandingOnFlatGroundIsClearByTheTrunksHeight) {
  const auto model = hyq();
  ASSERT_TRUE(model.trunk);
  const auto traj = standing(model, 0.01, 0.002);
  Eigen::Vector2d lo, hi;
  trajectory_extent(model, traj, 0.1, &lo, &hi);
  // The swept extent holds the trunk's corners (it reaches past the feet in x).
  EXPECT_LT(lo.x(), -0.5);
  EXPECT_GT(hi.x(), 0.5);
  VoxeliseOptions vo;
  vo.resolution = kRes;
  const auto tree = voxelise_boxes(0.0, {}, lo, hi, vo);
  ClearanceOptions far;
  far.distance_cutoff = 0.6;
  const TrunkClearanceReport rep = check_trunk_clearance(model, traj, *tree, far);
  // Bottom face at base z - 0.08 = 0.50 m over the ground's top at z = 0.
  EXPECT_NEAR(rep.min_distance, 0.50, 1e-3);
  EXPECT_EQ(rep.collisions, 0);
  EXPECT_EQ(rep.collisions_certain, 0);
  ASSERT_EQ(rep.distance.size(), traj.samples.size());
  EXPECT_EQ(rep.exact.front(), 1);
}

TEST(TrunkClearance, ABlockBetweenTheLegsHitsTheTrunkOnly) {
  const auto model = hyq();
  const auto traj = standing(model, 0.04, 0.002);
  // A block under the belly, between the legs: its top 3 cm above the trunk's bottom (0.50 m).
  const CheckReport hit =
      checks_on_scene(model, traj, {terrain::Box{Eigen::Vector3d(-0.15, -0.08, 0.0),
                                                 Eigen::Vector3d(0.15, 0.08, 0.53)}});
  ASSERT_TRUE(hit.trunk);
  EXPECT_EQ(hit.trunk->collisions_certain, static_cast<int>(traj.samples.size()));
  EXPECT_LT(hit.trunk->min_certain_distance, 0.0);
  EXPECT_NEAR(hit.trunk->first_certain_collision_t, 0.0, 1e-12);
  EXPECT_EQ(hit.clearance->shin_collisions + hit.clearance->thigh_collisions, 0);
  EXPECT_EQ(hit.keys().at("trunk_collisions_certain"), traj.samples.size());
  ASSERT_FALSE(hit.passed());
  EXPECT_NE(hit.failures().front().find("trunk collides with the terrain"), std::string::npos)
      << hit.failures().front();

  // The same block 2 cm lower: clear by 2 cm, measured exactly.
  const CheckReport clear =
      checks_on_scene(model, traj, {terrain::Box{Eigen::Vector3d(-0.15, -0.08, 0.0),
                                                 Eigen::Vector3d(0.15, 0.08, 0.48)}});
  ASSERT_TRUE(clear.trunk);
  EXPECT_EQ(clear.trunk->collisions, 0);
  EXPECT_NEAR(clear.trunk->min_distance, 0.02, 2e-3);
  EXPECT_TRUE(clear.passed()) << clear.failures().front();
}

TEST(TrunkClearance, TheBoxTurnsWithTheBase) {
  const auto model = hyq();
  // A post 45 cm ahead of the base: inside the trunk's front (x up to 0.5) facing +x, but beside
  // it (y up to 0.24) with the base turned by 90 degrees.
  const std::vector<terrain::Box> post{
      terrain::Box{Eigen::Vector3d(0.42, -0.03, 0.0), Eigen::Vector3d(0.48, 0.03, 0.7)}};
  const CheckReport ahead = checks_on_scene(model, standing(model, 0.01, 0.002), post);
  ASSERT_TRUE(ahead.trunk);
  EXPECT_GT(ahead.trunk->collisions_certain, 0);
  const auto turned_traj =
      standing(model, 0.01, 0.002, Eigen::Vector3d(0, 0, 0.58), Eigen::Vector3d(M_PI / 2, 0, 0));
  const CheckReport turned = checks_on_scene(model, turned_traj, post);
  ASSERT_TRUE(turned.trunk);
  EXPECT_EQ(turned.trunk->collisions, 0);
  EXPECT_TRUE(turned.passed()) << turned.failures().front();
  // Resolved past the default 10 cm cutoff: the post's face is 0.42 - 0.2413 m from the side.
  Eigen::Vector2d lo, hi;
  trajectory_extent(model, turned_traj, 0.1, &lo, &hi);
  VoxeliseOptions vo;
  vo.resolution = kRes;
  ClearanceOptions far;
  far.distance_cutoff = 0.3;
  const auto tree = voxelise_boxes(0.0, post, lo, hi, vo);
  EXPECT_NEAR(check_trunk_clearance(model, turned_traj, *tree, far).min_distance, 0.42 - 0.2413,
              2e-3);
}

TEST(TrunkClearance, ARobotWithoutATrunkIsNotChecked) {
  auto model = hyq();
  model.trunk.reset();
  const auto traj = standing(model, 0.01, 0.002);
  const CheckReport rep = checks_on_scene(model, traj, {});
  EXPECT_FALSE(rep.trunk);
  EXPECT_EQ(rep.keys().count("trunk_collisions_certain"), 0u);
  Eigen::Vector2d lo, hi;
  trajectory_extent(model, traj, 0.1, &lo, &hi);
  const auto tree = voxelise_boxes(0.0, {}, lo, hi);
  EXPECT_THROW(check_trunk_clearance(model, traj, *tree), std::invalid_argument);
}

namespace {

CheckReport checks_on_named_scene(const robot::RobotModel& model, const planner::Trajectory& traj,
                                  const terrain::Scene& scene) {
  Eigen::Vector2d lo, hi;
  trajectory_extent(model, traj, 0.1, &lo, &hi);
  VoxeliseOptions vo;
  vo.resolution = kRes;
  CheckTerrain terrain;
  terrain.field = &scene;
  terrain.octree = voxelise_scene(scene, lo, hi, vo);
  return run_checks(model, traj, terrain);
}

}  // namespace

// HyQ standing at its nominal 0.58 m under shelf_60 (underside 0.6 m up over x in [0.4, 0.9]):
// the box's top, 0.68 m up, is 8 cm into the shelf. The check finds it (the voxelised scene and
// the certain solid hold the shelf), and its message names the trunk and the overhang. Go2,
// standing at its nominal height there, is clear of it.
TEST(TrunkClearance, ATrunkDrivenIntoAShelfIsCaughtAndTheOverhangNamed) {
  const auto model = hyq();
  const auto shelf = terrain::make_scene("shelf_60");
  const auto traj = standing(model, 0.02, 0.002, Eigen::Vector3d(0.65, 0.0, 0.58));
  const CheckReport hit = checks_on_named_scene(model, traj, *shelf);
  ASSERT_TRUE(hit.trunk);
  EXPECT_EQ(hit.trunk->collisions_certain, static_cast<int>(traj.samples.size()));
  EXPECT_NEAR(hit.trunk->min_certain_distance, -0.08, 2e-3);
  EXPECT_EQ(hit.clearance->shin_collisions + hit.clearance->thigh_collisions, 0);
  ASSERT_FALSE(hit.passed());
  const std::string why = hit.failures().front();
  EXPECT_NE(why.find("trunk collides"), std::string::npos) << why;
  EXPECT_NE(why.find("overhang"), std::string::npos) << why;
  EXPECT_NE(why.find("underside is at z = 0.600 m, 0.600 m above the walkable surface"),
            std::string::npos)
      << why;

  const auto go2 = robot::load_robot(std::string(TERRASTRIDE_TEST_DATA_DIR) + "/robots/go2.yaml");
  const auto small =
      standing(go2, 0.02, 0.002, Eigen::Vector3d(0.65, 0.0, go2.nominal_base_height));
  const CheckReport clear = checks_on_named_scene(go2, small, *shelf);
  ASSERT_TRUE(clear.trunk);
  EXPECT_EQ(clear.trunk->collisions, 0);
  EXPECT_TRUE(clear.passed()) << clear.failures().front();
}
