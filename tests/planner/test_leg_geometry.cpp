// The general 3-DoF leg (robot_model.hpp, LegModel; docs/design.md §4.2): forward kinematics
// against an independent homogeneous-transform chain, inverse kinematics round trips over the
// joint ranges for the three leg shapes (in-plane HyQ, lateral offsets, general axes), the foot
// Jacobian and the planner's joint-angle derivatives against central differences, unreachable
// feet, and every shipped robot file.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>
#include <unsupported/Eigen/AutoDiff>

#include "terrastride/robot/geometry.hpp"
#include "terrastride/robot/leg_kinematics.hpp"
#include "terrastride/robot/robot_model.hpp"

namespace terrastride::robot {
namespace {

using Vec = Eigen::Vector3d;

std::string data(const std::string& rel) { return std::string(TERRASTRIDE_TEST_DATA_DIR) + "/" + rel; }

LegModel make_leg(const std::string& name, const Vec& haa, const std::array<Vec, 3>& axes,
                  const std::array<Vec, 3>& offsets, const Vec& q_min, const Vec& q_max,
                  int knee_sign) {
  LegModel leg;
  leg.name = name;
  leg.haa_origin = haa;
  leg.joint_axis = axes;
  leg.joint_offset = offsets;
  leg.q_min = q_min;
  leg.q_max = q_max;
  leg.knee_sign = knee_sign;
  leg.torque_limit = Vec(20, 20, 40);
  for (auto& l : leg.links) {
    l.mass = 0.5;
    l.com = Vec(0.01, 0.02, -0.05);
    l.inertia = Eigen::Matrix3d::Identity() * 1e-3;
  }
  classify_leg_geometry(leg, false);
  return leg;
}

// A Unitree-like leg (lateral HAA->HFE offset, straight thigh and shank, a 2 mm forward foot
// sphere), an ANYmal-C-like leg (forward and lateral hip offsets, a lateral thigh, an angled
// shank, HFE and KFE about -y on the right side), and a leg whose knee axis is tilted 20 degrees
// (no closed form: the numeric solve).
std::vector<LegModel> test_legs() {
  const double d = M_PI / 180.0;
  std::vector<LegModel> legs;
  legs.push_back(make_leg("go2_FL", Vec(0.1934, 0.0465, 0), {Vec::UnitX(), Vec::UnitY(), Vec::UnitY()},
                          {Vec(0, 0.0955, 0), Vec(0, 0, -0.213), Vec(-0.002, 0, -0.213)},
                          Vec(-60 * d, -60 * d, -156 * d), Vec(60 * d, 150 * d, -48 * d), -1));
  legs.push_back(make_leg("go2_RR", Vec(-0.1934, -0.0465, 0), {Vec::UnitX(), Vec::UnitY(), Vec::UnitY()},
                          {Vec(0, -0.0955, 0), Vec(0, 0, -0.213), Vec(-0.002, 0, -0.213)},
                          Vec(-60 * d, -30 * d, -156 * d), Vec(60 * d, 200 * d, -48 * d), -1));
  legs.push_back(make_leg("anymal_RH", Vec(-0.2999, -0.104, 0), {Vec::UnitX(), -Vec::UnitY(), -Vec::UnitY()},
                          {Vec(-0.0599, -0.08381, 0), Vec(0, -0.1003, -0.285), Vec(-0.08795, 0.01305, -0.33797)},
                          Vec(-40 * d, -100 * d, 20 * d), Vec(28 * d, 100 * d, 150 * d), +1));
  legs.push_back(make_leg("anymal_LF", Vec(0.2999, 0.104, 0), {Vec::UnitX(), Vec::UnitY(), Vec::UnitY()},
                          {Vec(0.0599, 0.08381, 0), Vec(0, 0.1003, -0.285), Vec(0.08795, 0.01305, -0.33797)},
                          Vec(-40 * d, -100 * d, -150 * d), Vec(28 * d, 100 * d, -20 * d), -1));
  legs.push_back(make_leg("tilted", Vec(0.3, 0.1, 0),
                          {Vec::UnitX(), Vec::UnitY(),
                           Vec(0, std::cos(20 * d), std::sin(20 * d))},
                          {Vec(0.02, 0.07, -0.01), Vec(0, 0.03, -0.25), Vec(0.01, 0, -0.26)},
                          Vec(-30 * d, -60 * d, -150 * d), Vec(30 * d, 60 * d, -25 * d), -1));
  return legs;
}

// The chain as URDF joints: a homogeneous transform per joint (origin, then rotation about the
// joint's own axis), composed; independent of leg_kinematics.cpp and geometry.hpp.
Vec chain_foot(const LegModel& leg, const Vec& q) {
  Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
  t.translate(leg.haa_origin);
  for (int i = 0; i < 3; ++i) {
    t.rotate(Eigen::AngleAxisd(q[i], leg.joint_axis[i]));
    t.translate(leg.joint_offset[i]);
  }
  return t.translation();
}

TEST(LegGeometry, ShapesAreClassified) {
  const auto legs = test_legs();
  EXPECT_EQ(legs[0].shape, LegShape::lateral_offset);
  EXPECT_EQ(legs[2].shape, LegShape::lateral_offset);
  EXPECT_EQ(legs[4].shape, LegShape::general);
  const RobotModel hyq = load_robot(data("robots/hyq.yaml"));
  for (const auto& leg : hyq.legs) EXPECT_EQ(leg.shape, LegShape::in_plane) << leg.name;
  // Derived lengths of a general leg: the capsules' lengths.
  EXPECT_NEAR(legs[2].l1, std::hypot(0.1003, 0.285), 1e-15);
}

TEST(LegGeometry, ForwardKinematicsIsTheTransformChain) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(0, 1);
  std::vector<LegModel> legs = test_legs();
  for (const auto& l : load_robot(data("robots/hyq.yaml")).legs) legs.push_back(l);
  for (const LegModel& leg : legs)
    for (int k = 0; k < 200; ++k) {
      const Vec q = leg.q_min + Vec(u(rng), u(rng), u(rng)).cwiseProduct(leg.q_max - leg.q_min);
      EXPECT_LT((foot_position(leg, q) - chain_foot(leg, q)).norm(), 1e-12) << leg.name;
      // The planner's templated points are the checks' chain.
      const LegFrames fr = leg_frames(leg, q);
      EXPECT_LT((knee_in_base<double>(leg, q) - fr.origin[2]).norm(), 1e-12) << leg.name;
      EXPECT_LT((hfe_in_base<double>(leg, q) - fr.origin[1]).norm(), 1e-12) << leg.name;
    }
}

// Whether q lies on the closed form's branch: the foot below the HAA axis in the HAA joint's
// frame and the knee bent to its side of the straight leg (robot_model.hpp, LegShape).
bool on_closed_form_branch(const LegModel& leg, const Vec& q) {
  const LegFrames fr = leg_frames(leg, q);
  const Vec u = fr.rotation[0].transpose() * (fr.foot - leg.haa_origin);
  const Vec &d1 = leg.joint_offset[1], &d2 = leg.joint_offset[2];
  const double straight = leg.joint_axis[2].y() *
      std::atan2(d1.x() * d2.z() - d1.z() * d2.x(), d1.x() * d2.x() + d1.z() * d2.z());
  return u.z() < -1e-3 && leg.knee_sign * (q[2] - straight) > 1e-3;
}

// Every configuration on the IK branch comes back from the foot it puts down (the closed forms);
// every foot the leg puts down is reached again (all shapes).
void round_trip(const LegModel& leg, int steps, double q_tol) {
  int on_branch = 0, tested = 0;
  double worst = 0;
  for (int a = 0; a <= steps; ++a)
    for (int h = 0; h <= steps; ++h)
      for (int k = 0; k <= steps; ++k) {
        const Vec t(a / double(steps), h / double(steps), k / double(steps));
        const Vec q = leg.q_min + t.cwiseProduct(leg.q_max - leg.q_min);
        const bool branch = leg.shape == LegShape::general || on_closed_form_branch(leg, q);
        if (!branch) continue;
        const Vec foot = foot_position(leg, q);
        const IkResult ik = inverse_kinematics(leg, foot);
        ASSERT_NE(ik.status, IkStatus::unreachable) << leg.name << " q=" << q.transpose() << ": " << ik.message;
        ++tested;
        worst = std::max(worst, (foot_position(leg, ik.q) - foot).norm());
        if (leg.shape != LegShape::general) {
          EXPECT_LT((ik.q - q).norm(), q_tol) << leg.name << " q=" << q.transpose();
          EXPECT_EQ(ik.status, IkStatus::ok) << ik.message;
        }
        on_branch += (ik.q - q).norm() < q_tol;
      }
  EXPECT_LT(worst, 1e-9) << leg.name;
  const int total = (steps + 1) * (steps + 1) * (steps + 1);
  EXPECT_GT(tested, total / 3) << leg.name;
  // The numeric solve finds the sampled angles themselves for most feet (another configuration
  // within the ranges may put the foot at the same place; the middlemost is taken).
  if (leg.shape == LegShape::general) {
    EXPECT_GT(on_branch, tested / 2) << leg.name;
  }
}

TEST(LegGeometry, InverseKinematicsRoundTripOverTheJointRanges) {
  for (const LegModel& leg : test_legs()) round_trip(leg, leg.shape == LegShape::general ? 8 : 16, 1e-6);
}

TEST(LegGeometry, JacobianMatchesFiniteDifferences) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(0, 1);
  for (const LegModel& leg : test_legs())
    for (int trial = 0; trial < 100; ++trial) {
      const Vec q = leg.q_min + Vec(u(rng), u(rng), u(rng)).cwiseProduct(leg.q_max - leg.q_min);
      const Eigen::Matrix3d jac = foot_jacobian(leg, q);
      for (int j = 0; j < 3; ++j) {
        const double h = 1e-6;
        const Vec fd = (foot_position(leg, q + h * Vec::Unit(j)) - foot_position(leg, q - h * Vec::Unit(j))) / (2 * h);
        EXPECT_LT((jac.col(j) - fd).norm(), 1e-8) << leg.name << " column " << j;
      }
    }
}

// The planner's rows differentiate leg_joint_angles: its automatic derivatives are the inverse
// Jacobian, checked against central differences of the angles themselves.
TEST(LegGeometry, PlannerJointAngleDerivativesMatchFiniteDifferences) {
  using Ad = Eigen::AutoDiffScalar<Eigen::Vector3d>;
  std::mt19937 rng(9);
  std::uniform_real_distribution<double> u(0.15, 0.85);
  for (const LegModel& leg : test_legs())
    for (int trial = 0; trial < 40; ++trial) {
      const Vec q = leg.q_min + Vec(u(rng), u(rng), u(rng)).cwiseProduct(leg.q_max - leg.q_min);
      const Vec foot = foot_position(leg, q);
      // Central differences lose their accuracy next to a singular configuration (the foot on
      // the HAA axis, a stretched knee), where dq/dfoot grows without bound: compared away
      // from them (|J^-1| below 30 rad/m).
      if (foot_jacobian(leg, q).inverse().cwiseAbs().maxCoeff() > 30.0) continue;
      Vector3T<Ad> p;
      for (int i = 0; i < 3; ++i) p[i] = Ad(foot[i], 3, i);
      const Vector3T<Ad> qa = leg_joint_angles<Ad>(leg, p);
      const Vec qd = leg_joint_angles<double>(leg, foot);
      for (int j = 0; j < 3; ++j) {
        const double h = 1e-6;
        const Vec fd = (leg_joint_angles<double>(leg, Vec(foot + h * Vec::Unit(j))) -
                        leg_joint_angles<double>(leg, Vec(foot - h * Vec::Unit(j)))) / (2 * h);
        for (int i = 0; i < 3; ++i) {
          EXPECT_NEAR(qa[i].value(), qd[i], 1e-12) << leg.name;
          EXPECT_NEAR(qa[i].derivatives()[j], fd[i], 1e-5 * (1 + std::abs(fd[i]))) << leg.name << " dq" << i << "/dp" << j;
        }
      }
    }
}

TEST(LegGeometry, UnreachableFeetAreReportedNamingTheLeg) {
  for (const LegModel& leg : test_legs()) {
    const double reach = leg.joint_offset[0].norm() + leg.l1 + leg.l2;
    const Vec far = leg.haa_origin + Vec(0, 0, -(reach + 0.1));
    const IkResult ik = inverse_kinematics(leg, far);
    EXPECT_EQ(ik.status, IkStatus::unreachable) << leg.name;
    EXPECT_NE(ik.message.find(leg.name), std::string::npos) << ik.message;
    EXPECT_NE(ik.message.find("out of reach"), std::string::npos) << ik.message;
    // The planner's rows stay finite there.
    EXPECT_TRUE(leg_joint_angles<double>(leg, far).allFinite()) << leg.name;
  }
}

// HyQ's file rewritten with the general keys is the same robot, to the last bit.
TEST(LegGeometry, HyqInGeneralKeysIsTheInPlaneLeg) {
  std::ifstream in(data("robots/hyq.yaml"));
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const auto replace = [&](const std::string& from, const std::string& to) {
    const size_t at = text.find(from);
    ASSERT_NE(at, std::string::npos) << from;
    text.replace(at, from.size(), to);
  };
  replace("  l0: 0.08                 # HAA -> HFE offset\n  l1: 0.35                 # upper leg\n  l2: 0.341                # lower leg\n",
          "  geometry: {haa_to_hfe: [0, 0, -0.08], hfe_to_kfe: [0, 0, -0.35], kfe_to_foot: [0, 0, -0.341],\n"
          "             axes: {haa: [-1, 0, 0], hfe: [0, 1, 0], kfe: [0, 1, 0]}}\n");
  // The right legs turn about +x.
  for (const char* leg : {"RF", "RH"}) {
    const std::string key = std::string("  - name: ") + leg + "\n";
    replace(key, key + "    geometry: {haa_to_hfe: [0, 0, -0.08], hfe_to_kfe: [0, 0, -0.35], kfe_to_foot: [0, 0, -0.341],\n"
                       "               axes: {haa: [1, 0, 0], hfe: [0, 1, 0], kfe: [0, 1, 0]}}\n");
  }
  const std::string path = (std::filesystem::temp_directory_path() /
                            ("hyq_general_" + std::to_string(::getpid()) + ".yaml")).string();
  std::ofstream(path) << text;
  const RobotModel general = load_robot(path);
  std::filesystem::remove(path);
  const RobotModel hyq = load_robot(data("robots/hyq.yaml"));
  ASSERT_EQ(general.legs.size(), hyq.legs.size());
  for (size_t i = 0; i < hyq.legs.size(); ++i) {
    const LegModel &a = hyq.legs[i], &b = general.legs[i];
    EXPECT_EQ(b.shape, LegShape::in_plane);
    EXPECT_EQ(a.l0, b.l0);
    EXPECT_EQ(a.l1, b.l1);
    EXPECT_EQ(a.l2, b.l2);
    EXPECT_EQ(a.side, b.side);
    const Vec q(0.1, 0.4, a.knee_sign * 1.1);
    EXPECT_EQ(foot_position(a, q), foot_position(b, q));
    EXPECT_EQ(inverse_kinematics(a, a.nominal_foot).q, inverse_kinematics(b, a.nominal_foot).q);
  }
}

// The shipped robot files (data/robots/*.yaml): hyq, go2 and anymal_c at least, every leg.
std::vector<RobotModel> shipped_robots() {
  std::vector<RobotModel> robots;
  for (const auto& entry : std::filesystem::directory_iterator(data("robots"))) {
    const std::string file = entry.path().filename().string();
    if (entry.path().extension() != ".yaml" || file.find(".polytopes.") != std::string::npos) continue;
    robots.push_back(load_robot(entry.path().string()));
  }
  std::sort(robots.begin(), robots.end(),
            [](const RobotModel& a, const RobotModel& b) { return a.name < b.name; });
  return robots;
}

TEST(LegGeometry, ShippedRobotsAreTheThreeQuadrupedsAndMore) {
  std::vector<std::string> names;
  for (const RobotModel& r : shipped_robots()) names.push_back(r.name);
  for (const char* name : {"hyq", "go2", "anymal_c"})
    EXPECT_NE(std::find(names.begin(), names.end(), name), names.end()) << name;
}

// Every shipped robot file: the round trip over its joint ranges (every leg, HyQ's in-plane ones
// too), the nominal stance reachable.
TEST(LegGeometry, EveryShippedRobotRoundTripsOverItsJointRanges) {
  for (const RobotModel& r : shipped_robots()) {
    SCOPED_TRACE(r.name);
    for (const LegModel& leg : r.legs) {
      const IkResult nominal = inverse_kinematics(leg, leg.nominal_foot);
      EXPECT_TRUE(nominal.ok()) << r.name << ": " << nominal.message;
      round_trip(leg, 12, 1e-6);
    }
  }
}

// Every shipped robot file: the foot Jacobian against central differences of the FK on a grid
// over each leg's joint ranges (ends included), and the planner's joint-angle derivatives (the
// inverse Jacobian its rows differentiate) against central differences of the IK.
TEST(LegGeometry, EveryShippedRobotsJacobianMatchesFiniteDifferences) {
  using Ad = Eigen::AutoDiffScalar<Eigen::Vector3d>;
  constexpr int kSteps = 6;
  for (const RobotModel& r : shipped_robots()) {
    SCOPED_TRACE(r.name);
    for (const LegModel& leg : r.legs) {
      int ik_compared = 0;
      for (int a = 0; a <= kSteps; ++a)
        for (int b = 0; b <= kSteps; ++b)
          for (int c = 0; c <= kSteps; ++c) {
            const Vec t(a / double(kSteps), b / double(kSteps), c / double(kSteps));
            const Vec q = leg.q_min + t.cwiseProduct(leg.q_max - leg.q_min);
            const Eigen::Matrix3d jac = foot_jacobian(leg, q);
            const double h = 1e-6;
            for (int j = 0; j < 3; ++j) {
              const Vec fd = (foot_position(leg, q + h * Vec::Unit(j)) -
                              foot_position(leg, q - h * Vec::Unit(j))) / (2 * h);
              EXPECT_LT((jac.col(j) - fd).norm(), 1e-8) << leg.name << " q=" << q.transpose() << " column " << j;
            }
            // The IK's derivatives where the IK gives q back (its branch) and away from the
            // singular configurations, where central differences lose their accuracy.
            if (!(leg.shape != LegShape::general && on_closed_form_branch(leg, q))) continue;
            if (jac.inverse().cwiseAbs().maxCoeff() > 30.0) continue;
            const Vec foot = foot_position(leg, q);
            Vector3T<Ad> p;
            for (int i = 0; i < 3; ++i) p[i] = Ad(foot[i], 3, i);
            const Vector3T<Ad> qa = leg_joint_angles<Ad>(leg, p);
            for (int j = 0; j < 3; ++j) {
              const Vec fd = (leg_joint_angles<double>(leg, Vec(foot + h * Vec::Unit(j))) -
                              leg_joint_angles<double>(leg, Vec(foot - h * Vec::Unit(j)))) / (2 * h);
              for (int i = 0; i < 3; ++i) {
                EXPECT_NEAR(qa[i].value(), q[i], 1e-6) << leg.name;
                EXPECT_NEAR(qa[i].derivatives()[j], fd[i], 1e-5 * (1 + std::abs(fd[i])))
                    << leg.name << " q=" << q.transpose() << " dq" << i << "/dp" << j;
              }
            }
            ++ik_compared;
          }
      EXPECT_GT(ik_compared, 20) << leg.name;
    }
  }
}

}  // namespace
}  // namespace terrastride::robot
