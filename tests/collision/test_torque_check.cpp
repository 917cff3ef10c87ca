// Joint-torque check along a trajectory (paper (21)): loads, frames, q̇/q̈ and IK failures.
#include <gtest/gtest.h>

#include <cmath>

#include "terrastride/collision/checks.hpp"
#include "trajectories.hpp"

using namespace terrastride;
using namespace terrastride::collision;
using terrastride::collision::test::hyq;
using terrastride::collision::test::standing;

namespace {

TorqueReport torques(const robot::RobotModel& model, const planner::Trajectory& traj,
                     const TorqueOptions& options = {}) {
  const TrajectoryKinematics kin = leg_kinematics(model, traj);
  return check_joint_torques(model, traj, kin, options);
}

}  // namespace

TEST(TorqueCheck, StaticStanceUnderQuarterWeightIsFeasible) {
  const auto model = hyq();
  const auto traj = standing(model);
  const TrajectoryKinematics kin = leg_kinematics(model, traj);
  EXPECT_EQ(kin.unreachable_samples, 0);
  EXPECT_EQ(kin.joint_limit_samples, 0);
  const TorqueReport rep = check_joint_torques(model, traj, kin);
  EXPECT_LT(rep.ratio_max, 1.0);
  // The legs do carry the robot: ~204 N per foot needs tens of N m at the knee.
  EXPECT_GT(rep.ratio_max, 0.15);
  EXPECT_EQ(rep.violating_samples, 0);
  for (const auto& leg : rep.legs) {
    // Standing still: the same torques at every sample, no motion terms.
    EXPECT_NEAR((leg.tau.front() - leg.tau.back()).norm(), 0.0, 1e-9) << leg.leg;
    EXPECT_EQ(leg.violating_samples, 0);
  }
  // Left/right mirror: same |tau| on LF and RF.
  EXPECT_NEAR((rep.legs[0].tau[0].cwiseAbs() - rep.legs[1].tau[0].cwiseAbs()).norm(), 0.0, 1e-9);
}

TEST(TorqueCheck, PushBeyondPolytopeIsFlaggedWithExactRatio) {
  const auto model = hyq();
  // A turned, tilted base: the check must rotate positions and forces into the base frame.
  const Eigen::Vector3d euler(0.7, 0.08, -0.05);
  auto traj = standing(model, 0.1, 0.002, Eigen::Vector3d(0.3, -0.2, 0.58), euler);
  const auto& lf = model.legs[0];
  const robot::IkResult ik = robot::inverse_kinematics(lf, lf.nominal_foot);
  ASSERT_TRUE(ik.ok());
  const robot::ForcePolytope poly = robot::exact_force_polytope(lf, ik.q);
  // 1.4 x a polytope vertex pointing into the ground (largest upward component).
  Eigen::Vector3d vertex = poly.vertices[0];
  for (const auto& v : poly.vertices)
    if (v.z() > vertex.z()) vertex = v;
  const Eigen::Vector3d f_base = 1.4 * vertex;
  const double expected = poly.torque_ratio(f_base);
  EXPECT_NEAR(expected, 1.4, 1e-9);
  const Eigen::Matrix3d rot = rotation_zyx(euler);
  for (auto& s : traj.samples) s.feet[0].force = rot * f_base;

  // Without gravity the check's torque is exactly -J^T f: the polytope's ratio.
  TorqueOptions no_gravity;
  no_gravity.gravity.setZero();
  const TorqueReport exact = torques(model, traj, no_gravity);
  EXPECT_NEAR(exact.legs[0].ratio[0].maxCoeff(), expected, 1e-9);
  EXPECT_NEAR(exact.ratio_max, expected, 1e-9);
  EXPECT_EQ(exact.worst_leg, 0);
  EXPECT_EQ(exact.violating_samples, static_cast<int>(traj.samples.size()));
  EXPECT_EQ(exact.legs[0].violating_samples, static_cast<int>(traj.samples.size()));

  // With gravity the leg's own weight shifts it by at most |g(q)|/tau_lim.
  const TorqueReport with_g = torques(model, traj);
  const Eigen::Vector3d g_base = rot.transpose() * Eigen::Vector3d(0, 0, -9.81);
  const auto terms = robot::dynamics_terms(lf, ik.q, Eigen::Vector3d::Zero(), g_base);
  const double shift = terms.gravity.cwiseQuotient(lf.torque_limit).cwiseAbs().maxCoeff();
  EXPECT_GT(shift, 0.0);
  EXPECT_NEAR(with_g.legs[0].ratio[0].maxCoeff(), expected, shift + 1e-9);
  EXPECT_GT(with_g.ratio_max, 1.0);
  EXPECT_EQ(with_g.violating_samples, static_cast<int>(traj.samples.size()));

  // A swing leg carries nothing, whatever force the plan lists for it.
  for (auto& s : traj.samples) s.feet[0].contact = false;
  const TorqueReport swing = torques(model, traj, no_gravity);
  EXPECT_NEAR(swing.legs[0].ratio[0].maxCoeff(), 0.0, 1e-9);
}

TEST(TorqueCheck, IkFailureIsReportedNotACrash) {
  const auto model = hyq();
  auto traj = standing(model, 0.02, 0.002);
  // RH's foot 1.2 m below its hip for the middle samples: out of reach.
  for (size_t k = 3; k < 7; ++k)
    traj.samples[k].feet[3].position =
        traj.samples[k].base.position + model.legs[3].haa_origin + Eigen::Vector3d(0, 0, -1.2);
  CheckReport rep = run_checks(model, traj, CheckTerrain{});
  EXPECT_EQ(rep.kinematics.unreachable_samples, 4);
  ASSERT_FALSE(rep.kinematics.issues.empty());
  EXPECT_EQ(rep.kinematics.issues.front().sample, 3);
  EXPECT_EQ(rep.kinematics.issues.front().leg, 3);
  EXPECT_NE(rep.kinematics.issues.front().message.find("out of reach"), std::string::npos);
  EXPECT_TRUE(std::isnan(rep.torque.legs[3].tau[4].x()));
  EXPECT_FALSE(std::isnan(rep.torque.legs[3].tau[0].x()));
  EXPECT_FALSE(rep.passed());
  EXPECT_EQ(rep.keys().at("ik_failures"), 4);
  bool mentioned = false;
  for (const auto& line : rep.failures())
    mentioned |= line.find("out of reach") != std::string::npos;
  EXPECT_TRUE(mentioned);

  // A foot inside reach but needing a joint outside its range: reported, torques still computed.
  auto bent = standing(model, 0.02, 0.002);
  const auto& lf = model.legs[0];
  const Eigen::Vector3d q_bad(0.0, 0.3, -0.1);  // KFE -0.1 rad: the range ends at -20 deg
  for (auto& s : bent.samples)
    s.feet[0].position = s.base.position + robot::foot_position(lf, q_bad);
  const CheckReport lim = run_checks(model, bent, CheckTerrain{});
  EXPECT_EQ(lim.kinematics.joint_limit_samples, static_cast<int>(bent.samples.size()));
  EXPECT_FALSE(std::isnan(lim.torque.legs[0].tau[0].x()));
  EXPECT_FALSE(lim.passed());
}

TEST(TorqueCheck, JointRatesMatchAnalyticMotionOnAMovingTurningBase) {
  const auto model = hyq();
  auto traj = standing(model, 1.0, 0.002);
  const auto& lf = model.legs[0];
  const Eigen::Vector3d q0 = robot::inverse_kinematics(lf, lf.nominal_foot).q;
  const Eigen::Vector3d amp(0.1, 0.3, 0.4);
  const double w = 2 * M_PI * 1.5;
  auto q = [&](double t) -> Eigen::Vector3d { return q0 + amp * std::sin(w * t); };
  auto qd = [&](double t) -> Eigen::Vector3d { return amp * w * std::cos(w * t); };
  auto qdd = [&](double t) -> Eigen::Vector3d { return -amp * w * w * std::sin(w * t); };
  test::BaseMotion motion;
  motion.velocity = Eigen::Vector3d(0.4, 0.1, 0.0);
  motion.yaw_rate = 0.5;
  test::drive_leg(model, traj, 0, q, qd, motion);
  const TrajectoryKinematics kin = leg_kinematics(model, traj);
  double worst_q = 0, worst_qd = 0, worst_qdd = 0;
  for (size_t k = 1; k + 1 < traj.samples.size(); ++k) {
    const double t = traj.samples[k].t;
    const LegSample& ls = kin.legs[0][k];
    ASSERT_TRUE(ls.has_q());
    worst_q = std::max(worst_q, (ls.q - q(t)).norm());
    worst_qd = std::max(worst_qd, (ls.qd - qd(t)).norm());
    worst_qdd = std::max(worst_qdd, (ls.qdd - qdd(t)).norm());
  }
  EXPECT_LT(worst_q, 1e-9);
  EXPECT_LT(worst_qd, 1e-9);  // J^-1 on the relative velocity: exact
  // Central differences: error ~ w^2 dt^2 / 6 * |qdd| ~ 6e-5 * 36 rad/s^2.
  EXPECT_LT(worst_qdd, 0.01 * amp.norm() * w * w);

  // The torques are those of the leg dynamics with the analytic q, q̇, q̈ (swing: no force).
  const TorqueReport rep = check_joint_torques(model, traj, kin);
  const size_t k = traj.samples.size() / 3;
  const double t = traj.samples[k].t;
  const Eigen::Matrix3d rt = rotation_zyx(traj.samples[k].base.euler_zyx).transpose();
  const Eigen::Vector3d tau = robot::joint_torques(lf, q(t), qd(t), qdd(t), Eigen::Vector3d::Zero(),
                                                   rt * Eigen::Vector3d(0, 0, -9.81));
  EXPECT_LT((rep.legs[0].tau[k] - tau).norm(), 0.02 * tau.norm() + 0.05);
}

TEST(TorqueCheck, FreeFallingBaseUnloadsASwingLeg) {
  const auto model = hyq();
  auto traj = standing(model, 0.1, 0.002);
  for (auto& s : traj.samples) {
    s.base.linear_acceleration = Eigen::Vector3d(0, 0, -9.81);
    for (auto& f : s.feet) {
      f.contact = false;
      f.force.setZero();
    }
  }
  // Falling with the base, the legs feel no gravity: no torque is needed to hold them.
  const TorqueReport falling = torques(model, traj);
  EXPECT_LT(falling.ratio_max, 1e-9);
  // Ignoring the base acceleration, holding the legs up against gravity takes torque.
  TorqueOptions fixed_base;
  fixed_base.include_base_acceleration = false;
  EXPECT_GT(torques(model, traj, fixed_base).ratio_max, 0.01);
}

TEST(TorqueCheck, BadTrajectoriesAreRejectedNamingTheField) {
  const auto model = hyq();
  auto traj = standing(model, 0.02, 0.002);
  traj.samples[2].feet[1].force.y() = std::nan("");
  try {
    leg_kinematics(model, traj);
    FAIL() << "NaN accepted";
  } catch (const TrajectoryError& e) {
    EXPECT_NE(std::string(e.what()).find("samples[2].feet[1].force"), std::string::npos)
        << e.what();
  }
  auto other = standing(model, 0.02, 0.002);
  other.robot = "anymal";
  EXPECT_THROW(leg_kinematics(model, other), TrajectoryError);
  auto feet = standing(model, 0.02, 0.002);
  feet.feet[2] = "RH";
  EXPECT_THROW(leg_kinematics(model, feet), TrajectoryError);
  auto times = standing(model, 0.02, 0.002);
  times.samples[4].t = times.samples[3].t;
  EXPECT_THROW(leg_kinematics(model, times), TrajectoryError);
  auto missing = standing(model, 0.02, 0.002);
  missing.samples[1].feet.pop_back();
  EXPECT_THROW(leg_kinematics(model, missing), TrajectoryError);
}
