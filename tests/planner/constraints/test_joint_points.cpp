// Joint rows at chosen instants (joint_points.hpp; the refinement of plan_motion) and the dense
// joint check that chooses them (dense_joint_check): the rows' Jacobians against central
// differences at arbitrary instants of stance and swing segments, their values against an
// independent evaluation (the problem's own continuous solution, the robot's inverse kinematics
// and its leg Jacobian, the fitted force polytope), and the check's worst instants against the
// rows there.
#include <algorithm>
#include <cmath>
#include <random>
#include <set>
#include <stdexcept>

#include "family_test.hpp"
#include "terrastride/planner/dense_checks.hpp"
#include "terrastride/planner/joint_points.hpp"
#include "terrastride/planner/polytope_model.hpp"
#include "terrastride/robot/leg_kinematics.hpp"

namespace terrastride::planner {
namespace {

using namespace testing;

robot::RobotModel joint_points_go2() {
  return robot::load_robot(robot::resolve_robot_path("go2"));
}

// A 1.2 s turning crawl 0.2 m ahead (within Go2's reach), durations variable when `timing`.
ProblemOptions joint_points_options(bool timing) {
  ProblemOptions o = turning_crawl_options(timing);
  o.goal = Eigen::Vector3d(0.2, 0.03, 0.2);
  return o;
}

// Points at random fractions (and both ends) of every foot's segments, stance and swing alike,
// each with both rows.
std::vector<JointPoint> arbitrary_points(const SrbdProblem& p, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> fraction(0.0, 1.0);
  std::vector<JointPoint> points;
  const Layout& L = p.layout();
  for (int f = 0; f < static_cast<int>(p.robot().legs.size()); ++f)
    for (int s = f % 3; s < L.num_segments; s += 3)
      points.push_back({f, s,
                        s == 0                    ? 0.0
                        : s == L.num_segments - 1 ? 1.0
                                                  : fraction(rng),
                        true, true});
  return points;
}

bool has_stance_and_swing(const SrbdProblem& p, const std::vector<JointPoint>& points) {
  bool stance = false, swing = false;
  for (const auto& point : points)
    (p.layout().contact[point.foot][point.segment] ? stance : swing) = true;
  return stance && swing;
}

TEST(JointPoints, RowsAtArbitraryInstantsMatchCentralDifferences) {
  const auto r = joint_points_go2();
  TanhStep terrain(0.03, 0.15, 0.05, 0.01);
  SrbdProblem p(r, terrain, crawl_timeline(r, 1.2), joint_points_options(true));
  const std::vector<JointPoint> points = arbitrary_points(p, 11);
  ASSERT_TRUE(has_stance_and_swing(p, points));
  const auto added = pieces_added_by(p, [&] {
    add_joint_range_points(p, points);
    add_joint_velocity_points(p, points);
  });
  ASSERT_EQ(added.size(), 2 * points.size());
  const std::set<const Piece*> mine(added.begin(), added.end());
  // Small noise: far from the guess Go2's legs near their straight (singular) pose, where the
  // velocity rows reach thousands of rad/s and central differences lose their digits.
  for (unsigned seed : {1u, 2u, 3u})
    EXPECT_EQ(check_piece_derivatives(p, seed, 0.002,
                                      [&](const Piece& piece) { return mine.count(&piece) > 0; }),
              static_cast<int>(added.size()));
  EXPECT_GT(largest_jacobian_entry(p, added), 0.1);  // the rows depend on their variables
}

// The angles and velocities of foot f at time t of the solution x, evaluated independently of
// the rows: the problem's continuous solution, the robot's IK, and the leg's Jacobian (the base's
// rotation rate by differencing its rotation matrix along the Euler rates).
void independent_joints(const SrbdProblem& p, const std::vector<double>& x, int f, double t,
                        Eigen::Vector3d* q, Eigen::Vector3d* qd) {
  const auto st = p.evaluate(x, t);
  const Eigen::Vector3d rel = st.foot_pos[f] - st.pos;
  const double h = 1e-6;
  const Eigen::Matrix3d R = rotation_of(st.euler);
  const Eigen::Matrix3d Rd =
      (rotation_of(st.euler + h * st.euler_rate) - rotation_of(st.euler - h * st.euler_rate)) /
      (2 * h);
  const Eigen::Vector3d v_rel = Rd.transpose() * rel + R.transpose() * (st.foot_vel[f] - st.vel);
  const auto ik = robot::inverse_kinematics(p.robot().legs[f], R.transpose() * rel);
  ASSERT_NE(ik.status, robot::IkStatus::unreachable) << ik.message;
  *q = ik.q;
  *qd = robot::foot_jacobian(p.robot().legs[f], ik.q).inverse() * v_rel;
}

TEST(JointPoints, RowsAreTheJointsOfTheSolutionAtTheirInstant) {
  const auto r = joint_points_go2();
  FlatField flat;
  SrbdProblem p(r, flat, crawl_timeline(r, 1.2), joint_points_options(false));
  const std::vector<JointPoint> points = arbitrary_points(p, 5);
  const auto added = pieces_added_by(p, [&] {
    add_joint_range_points(p, points);
    add_joint_velocity_points(p, points);
  });
  ASSERT_EQ(added.size(), 2 * points.size());
  const std::vector<double> x = perturbed_guess(p, 7, 0.003);
  const Layout& L = p.layout();
  double worst_q = 0.0, worst_qd = 0.0, largest_qd = 0.0;
  for (std::size_t i = 0; i < points.size(); ++i) {
    const JointPoint& point = points[i];
    // Inside the segment (evaluate is right-continuous: a segment's end is the next one's start).
    const double t = segment_start(L, x, point.segment) +
                     std::min(point.sigma, 1.0 - 1e-12) * segment_length(L, x, point.segment);
    Eigen::Vector3d q, qd;
    independent_joints(p, x, point.foot, t, &q, &qd);
    const std::vector<double> angles = rows_at(*added[i], x);
    const std::vector<double> rates = rows_at(*added[points.size() + i], x);
    for (int j = 0; j < 3; ++j) {
      worst_q = std::max(worst_q, std::abs(angles[j] - q[j]));
      worst_qd = std::max(worst_qd, std::abs(rates[j] - qd[j]));
      largest_qd = std::max(largest_qd, std::abs(qd[j]));
    }
  }
  EXPECT_GT(largest_qd, 0.05);  // the perturbed point moves the joints
  EXPECT_LT(worst_q, 1e-8);
  EXPECT_LT(worst_qd, 1e-5);
}

// Go2 with its limits cut so that the guess exceeds them: every interval the check reports has
// its worst instant beyond the limit (the rows there say so), and the largest excess is one of
// those instants'. With the limits widened far beyond the guess's motion nothing is reported.
TEST(JointPoints, DenseCheckReportsTheWorstInstantOfEachExceedingInterval) {
  auto r = joint_points_go2();
  FlatField flat;
  const PhaseTimeline timeline = crawl_timeline(r, 1.2);
  {
    robot::RobotModel wide = r;
    for (auto& leg : wide.legs) {
      leg.velocity_limit *= 100.0;
      leg.q_min.array() -= 1.0;
      leg.q_max.array() += 1.0;
    }
    SrbdProblem p(wide, flat, timeline, joint_points_options(false));
    const JointDenseCheck check = dense_joint_check(p, p.initial_guess(), 0.001);
    EXPECT_TRUE(check.violations.empty());
    EXPECT_GT(check.velocity_ratio, 0.0);
    EXPECT_LT(check.velocity_ratio, 1.0);
    EXPECT_EQ(check.range_excess_rad, 0.0);
    EXPECT_GE(check.samples, 1201);  // 1.2 s at 1 ms or finer, both ends
  }
  for (auto& leg : r.legs) {
    leg.velocity_limit *= 0.02;                                         // a few tenths of a rad/s
    leg.q_max[2] = leg.q_min[2] + 0.5 * (leg.q_max[2] - leg.q_min[2]);  // the knee's upper half
  }
  SrbdProblem p(r, flat, timeline, joint_points_options(false));
  const std::vector<double> x = p.initial_guess();
  const JointDenseCheck check = dense_joint_check(p, x, 0.001);
  ASSERT_FALSE(check.violations.empty());
  EXPECT_GT(check.velocity_ratio, 1.0);
  const auto added = pieces_added_by(p, [&] {
    add_joint_range_points(p, check.violations);
    add_joint_velocity_points(p, check.violations);
  });
  double largest_ratio = 0.0, largest_excess = 0.0;
  std::size_t next = 0;
  bool ranges = false, velocities = false;
  for (const JointPoint& point : check.violations) {
    const robot::LegModel& leg = r.legs[point.foot];
    if (point.range) {
      ranges = true;
      const std::vector<double> q = rows_at(*added.at(next++), x);
      double excess = 0.0;
      for (int j = 0; j < 3; ++j)
        excess = std::max({excess, leg.q_min[j] - q[j], q[j] - leg.q_max[j]});
      EXPECT_GT(excess, 0.0) << "foot " << point.foot << " segment " << point.segment;
      largest_excess = std::max(largest_excess, excess);
    }
  }
  for (const JointPoint& point : check.violations) {
    const robot::LegModel& leg = r.legs[point.foot];
    if (point.velocity) {
      velocities = true;
      const std::vector<double> qd = rows_at(*added.at(next++), x);
      double ratio = 0.0;
      for (int j = 0; j < 3; ++j) ratio = std::max(ratio, std::abs(qd[j]) / leg.velocity_limit[j]);
      EXPECT_GT(ratio, 1.0) << "foot " << point.foot << " segment " << point.segment;
      largest_ratio = std::max(largest_ratio, ratio);
    }
  }
  EXPECT_EQ(next, added.size());
  EXPECT_TRUE(ranges && velocities);
  EXPECT_NEAR(largest_ratio, check.velocity_ratio, 1e-9 * check.velocity_ratio);
  EXPECT_NEAR(largest_excess, check.range_excess_rad, 1e-9);
}

// Points at random fractions (and both ends) of stance segments only, each wanting the force
// polytope rows (torques).
std::vector<JointPoint> arbitrary_stance_points(const SrbdProblem& p, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> fraction(0.0, 1.0);
  std::vector<JointPoint> points;
  const Layout& L = p.layout();
  int k = 0;
  for (int f = 0; f < static_cast<int>(p.robot().legs.size()); ++f)
    for (int s = 0; s < L.num_segments; ++s) {
      if (!L.contact[f][s] || (k++ % 3) != 0) continue;
      JointPoint point{f, s, k % 7 == 0 ? 0.0 : k % 7 == 1 ? 1.0 : fraction(rng)};
      point.torque = true;
      points.push_back(point);
    }
  return points;
}

TEST(JointPoints, PolytopeRowsAtArbitraryStanceInstantsMatchCentralDifferences) {
  const auto r = joint_points_go2();
  TanhStep terrain(0.03, 0.15, 0.05, 0.01);
  SrbdProblem p(r, terrain, crawl_timeline(r, 1.2), joint_points_options(true));
  const std::vector<JointPoint> points = arbitrary_stance_points(p, 13);
  ASSERT_GE(points.size(), 8u);
  const auto added = pieces_added_by(p, [&] {
    add_joint_range_points(p, points);  // no point wants them: nothing
    add_joint_velocity_points(p, points);
    add_polytope_points(p, points);
  });
  ASSERT_EQ(added.size(), points.size());
  const std::set<const Piece*> mine(added.begin(), added.end());
  for (unsigned seed : {1u, 2u, 3u})
    EXPECT_EQ(check_piece_derivatives(p, seed, 0.002,
                                      [&](const Piece& piece) { return mine.count(&piece) > 0; }),
              static_cast<int>(added.size()));
  for (const Piece* piece : added) {
    EXPECT_EQ(piece->kind, "polytope");
    EXPECT_EQ(piece->rows(), kPolytopeFacets);
  }
  EXPECT_GT(largest_jacobian_entry(p, added), 1e-3);  // the rows depend on their variables
}

// The rows' values are the fitted polytope's facets at the problem's own continuous solution
// (base pose, foothold and the force interpolated between its knots), divided by m g.
TEST(JointPoints, PolytopeRowsAreTheFacetsAtTheirInstant) {
  const auto r = joint_points_go2();
  FlatField flat;
  SrbdProblem p(r, flat, crawl_timeline(r, 1.2), joint_points_options(false));
  const std::vector<JointPoint> points = arbitrary_stance_points(p, 3);
  const auto added = pieces_added_by(p, [&] { add_polytope_points(p, points); });
  ASSERT_EQ(added.size(), points.size());
  const std::vector<double> x = perturbed_guess(p, 9, 0.003);
  const auto model = shared_polytope_model(r);
  const Layout& L = p.layout();
  double worst = 0.0, largest = 0.0;
  for (std::size_t i = 0; i < points.size(); ++i) {
    const JointPoint& point = points[i];
    const double t = segment_start(L, x, point.segment) +
                     std::min(point.sigma, 1.0 - 1e-12) * segment_length(L, x, point.segment);
    const auto st = p.evaluate(x, t);
    const Eigen::Matrix3d Rt = rotation_of(st.euler).transpose();
    // Evaluated here: `auto` of the quotient would keep an expression over a dead temporary.
    const Eigen::VectorXd expected =
        model->legs[point.foot].constraint(Rt * (st.foot_pos[point.foot] - st.pos),
                                           Rt * st.force[point.foot]) /
        (r.mass * kGravity);
    const std::vector<double> rows = rows_at(*added[i], x);
    for (int j = 0; j < kPolytopeFacets; ++j) {
      worst = std::max(worst, std::abs(rows[j] - expected[j]));
      largest = std::max(largest, std::abs(expected[j]));
    }
  }
  EXPECT_GT(largest, 0.01);
  EXPECT_LT(worst, 1e-7);
}

// Torques in the dense check: with Go2's torque limits widened nothing is reported; cut, every
// reported torque point lies in a stance segment, the largest ratio scales exactly with the
// inverse of the limits (the torques do not depend on them), and a torque point in a swing is
// refused by add_polytope_points.
TEST(JointPoints, DenseCheckReportsTorquesBeyondTheirLimitsInStance) {
  auto r = joint_points_go2();
  FlatField flat;
  const PhaseTimeline timeline = crawl_timeline(r, 1.2);
  auto checked = [&](double torque_scale) {
    robot::RobotModel scaled = r;
    for (auto& leg : scaled.legs) {
      leg.torque_limit *= torque_scale;
      leg.velocity_limit *= 100.0;
      leg.q_min.array() -= 1.0;
      leg.q_max.array() += 1.0;
    }
    SrbdProblem p(scaled, flat, timeline, joint_points_options(false));
    return dense_joint_check(p, p.initial_guess(), 0.001);
  };
  const JointDenseCheck wide = checked(100.0);
  EXPECT_TRUE(wide.violations.empty());
  EXPECT_GT(wide.torque_ratio, 0.0);
  EXPECT_LT(wide.torque_ratio, 1.0);
  const double at_limit = wide.torque_ratio * 100.0;  // the ratio against the file's limits
  const double cut = 0.5 * at_limit;                  // limits at half the largest torque
  const JointDenseCheck tight = checked(cut);
  EXPECT_NEAR(tight.torque_ratio, 2.0, 1e-9);
  ASSERT_FALSE(tight.violations.empty());
  SrbdProblem p(r, flat, timeline, joint_points_options(false));
  for (const JointPoint& point : tight.violations) {
    EXPECT_FALSE(point.range || point.velocity);
    EXPECT_TRUE(point.torque);
    EXPECT_TRUE(p.layout().contact[point.foot][point.segment])
        << "foot " << point.foot << " segment " << point.segment;
  }
  int swing = 0;
  while (p.layout().contact[0][swing]) ++swing;
  JointPoint in_swing{0, swing, 0.5};
  in_swing.torque = true;
  EXPECT_THROW(add_polytope_points(p, {in_swing}), std::invalid_argument);
}

// The check's largest torque is the leg's inverse dynamics at its instant, evaluated
// independently: the problem's continuous solution (base acceleration as apparent gravity, the
// force between its knots), the angles and velocities as above, the joint accelerations as a
// difference of those velocities 0.1 ms away. The base's acceleration jumps at the knots (C1
// splines), so at a segment's end or start the check reads that segment's side: the
// independent evaluation there takes the side the check's value agrees with, before the knot
// (backward difference) or after it (forward).
TEST(JointPoints, DenseCheckTorqueIsTheLegDynamicsAtItsInstant) {
  const auto r = joint_points_go2();
  FlatField flat;
  SrbdProblem p(r, flat, crawl_timeline(r, 1.2), joint_points_options(false));
  const std::vector<double> x = perturbed_guess(p, 4, 0.002);
  const JointDenseCheck check = dense_joint_check(p, x, 0.001);
  ASSERT_GE(check.torque_foot, 0);
  const int f = check.torque_foot, j = check.torque_joint;
  const robot::LegModel& leg = r.legs[f];
  const double dt = 1e-4;
  // The ratio at time t from velocities at t_a and t_b (t_a < t_b).
  auto ratio_at = [&](double t, double t_a, double t_b) {
    Eigen::Vector3d q, qd, q_a, qd_a, q_b, qd_b;
    independent_joints(p, x, f, t, &q, &qd);
    independent_joints(p, x, f, t_a, &q_a, &qd_a);
    independent_joints(p, x, f, t_b, &q_b, &qd_b);
    const auto st = p.evaluate(x, t);
    EXPECT_TRUE(st.contact[f]);
    const Eigen::Matrix3d Rt = rotation_of(st.euler).transpose();
    const Eigen::Vector3d tau =
        robot::joint_torques(leg, q, qd, (qd_b - qd_a) / (t_b - t_a), Rt * st.force[f],
                             Rt * (Eigen::Vector3d(0, 0, -kGravity) - st.acc));
    return std::abs(tau[j]) / leg.torque_limit[j];
  };
  const double t = check.torque_t;
  bool at_knot = false;
  for (int s = 1; s < p.layout().num_segments; ++s)
    at_knot = at_knot || std::abs(segment_start(p.layout(), x, s) - t) < 1e-9;
  std::vector<double> candidates;
  if (at_knot)
    candidates = {ratio_at(t - 1e-9, t - dt, t - 1e-9), ratio_at(t, t, t + dt)};
  else
    candidates = {ratio_at(t, t - dt, t + dt)};
  double nearest = candidates[0];
  for (double c : candidates)
    if (std::abs(c - check.torque_ratio) < std::abs(nearest - check.torque_ratio)) nearest = c;
  EXPECT_GT(nearest, 0.05);
  EXPECT_NEAR(check.torque_ratio, nearest, 1e-3 * nearest);
}

TEST(JointPoints, APointOutsideTheProblemIsRefused) {
  const auto r = joint_points_go2();
  FlatField flat;
  SrbdProblem p(r, flat, crawl_timeline(r, 1.2), joint_points_options(false));
  const int S = p.layout().num_segments;
  for (const JointPoint& bad :
       {JointPoint{4, 0, 0.5, true, true}, JointPoint{0, S, 0.5, true, true},
        JointPoint{0, 0, 1.5, true, true}}) {
    EXPECT_THROW(add_joint_range_points(p, {bad}), std::invalid_argument);
    EXPECT_THROW(add_joint_velocity_points(p, {bad}), std::invalid_argument);
  }
  EXPECT_THROW(dense_joint_check(p, p.initial_guess(), 0.0), std::invalid_argument);
}

}  // namespace
}  // namespace terrastride::planner
