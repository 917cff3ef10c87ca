// The sets beyond the paper that bound the legs' own motion: "swing" (swing foot acceleration) and
// "joints" (joint ranges), and the NAME=VALUE settings of all sets. Jacobians against central differences, values against independent
// evaluations (the foot spline's second derivative; the robot's inverse kinematics), and how
// "swing" is pulled in by "polytope".
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <map>
#include <utility>
#include <vector>
#include <string>

#include "terrastride/planner/feasibility.hpp"
#include "terrastride/planner/gait.hpp"
#include "terrastride/planner/nlp.hpp"
#include "terrastride/robot/leg_kinematics.hpp"
#include "piece_derivatives.hpp"
#include "test_robots.hpp"
#include "test_terrains.hpp"

namespace terrastride::planner {
namespace {

using testing::count_kinds;
using testing::feet_of;
using testing::hyq;

PhaseTimeline crawl(const robot::RobotModel& r) {
  return make_timeline(load_gait(resolve_gait_path("crawl")), feet_of(r), 1, 2.0);
}

TEST(SwingSetDerivatives, PiecesMatchFiniteDifferences) {
  const auto r = hyq();
  testing::TanhStep terrain(0.1, 0.5, 0.05, 0.01);
  for (bool timing : {false, true}) {  // with timing, the segment duration is a variable too
    PlannerOptions o;
    o.has_goal = true;
    o.goal = Eigen::Vector3d(0.4, 0.05, 0.3);
    o.optimize_timing = timing;
    o.constraints = {"swing"};
    SrbdProblem p(r, terrain, crawl(r), o);
    ASSERT_GT(count_kinds(p)["swing"], 0);
    for (unsigned seed : {1u, 2u})
      EXPECT_GT(testing::check_piece_derivatives(
                    p, seed, 0.02,
                    [](const Piece& piece) { return piece.kind == "swing"; }),
                0)
          << "timing " << timing;
  }
}

// Every swing segment gets one piece whose six rows are the foot's acceleration at the segment's
// two ends over the bound, which must agree with the spline the problem evaluates.
TEST(SwingSetValues, RowsAreTheSplineAccelerationOverTheBound) {
  const auto r = hyq();
  testing::FlatField flat;
  PlannerOptions o;
  o.has_goal = true;
  o.goal = Eigen::Vector3d(0.4, 0.0, 0.0);
  SrbdProblem p(r, flat, crawl(r), o);
  FeasibilityOptions fo;
  fo.swing_acceleration = 50.0;
  const std::size_t before = p.pieces().size();
  build_swing_set(p, fo);
  const Layout& L = p.layout();
  int swing_segments = 0;
  for (const auto& sw : L.swings) swing_segments += sw.last_seg - sw.first_seg + 1;
  ASSERT_EQ(static_cast<int>(p.pieces().size() - before), swing_segments);

  // A perturbed initial guess, so the swing splines are not symmetric; fixed variables (the
  // interval durations among them) stay, so the knots stay at their nominal times.
  std::vector<double> x = p.initial_guess();
  for (std::size_t i = 0; i < x.size(); ++i)
    if (p.lower()[i] < p.upper()[i]) x[i] += 0.01 * std::sin(1.7 * static_cast<double>(i));
  std::vector<double> g(p.num_constraints());
  p.eval_constraints(x.data(), g.data());
  int row = 0;
  for (std::size_t i = 0; i < before; ++i) row += p.pieces()[i]->rows();
  const double eps = 1e-6;
  for (const auto& sw : L.swings)
    for (int s = sw.first_seg; s <= sw.last_seg; ++s, row += 6) {
      const double t0 = L.nominal_knot_time[s], t1 = L.nominal_knot_time[s + 1];
      for (int side = 0; side < 2; ++side) {
        // Second difference of the position, one-sided into the segment.
        const double t = side == 0 ? t0 + 2 * eps : t1 - 2 * eps;
        const auto a = p.evaluate(x, t - eps).foot_pos[sw.foot];
        const auto b = p.evaluate(x, t).foot_pos[sw.foot];
        const auto c = p.evaluate(x, t + eps).foot_pos[sw.foot];
        const Eigen::Vector3d acc = (a - 2 * b + c) / (eps * eps);
        for (int k = 0; k < 3; ++k)
          EXPECT_NEAR(g[row + 3 * side + k], acc[k] / fo.swing_acceleration,
                      2e-3 + 1e-3 * std::abs(acc[k] / fo.swing_acceleration))
              << "segment " << s << " side " << side << " axis " << k;
      }
      const Piece& piece = *p.pieces()[before];
      for (int k = 0; k < 6; ++k) {
        EXPECT_EQ(piece.lb[k], -1.0);
        EXPECT_EQ(piece.ub[k], 1.0);
      }
    }
  FeasibilityOptions bad;
  bad.swing_acceleration = 0.0;
  EXPECT_THROW(build_swing_set(p, bad), std::invalid_argument);
}

TEST(SwingSetRegistry, PolytopeImpliesSwing) {
  const auto r = hyq();
  testing::FlatField flat;
  PlannerOptions poly, both, base, all;
  poly.constraints = {"polytope"};
  both.constraints = {"polytope", "swing"};
  base.constraints = {"baseline"};
  all.constraints = {"all"};
  const SrbdProblem pp(r, flat, crawl(r), poly), pb(r, flat, crawl(r), both),
      p0(r, flat, crawl(r), base), pa(r, flat, crawl(r), all);
  EXPECT_GT(count_kinds(pp)["swing"], 0);
  EXPECT_EQ(count_kinds(pp), count_kinds(pb));  // added once
  EXPECT_EQ(count_kinds(p0).count("swing"), 0u);
  EXPECT_EQ(count_kinds(pa)["swing"], count_kinds(pp)["swing"]);
  const auto names = constraint_set_names();
  EXPECT_NE(std::find(names.begin(), names.end(), "swing"), names.end());
}

TEST(JointLimitSetDerivatives, PiecesMatchFiniteDifferences) {
  const auto r = hyq();
  testing::TanhStep terrain(0.1, 0.5, 0.05, 0.01);
  PlannerOptions o;
  o.has_goal = true;
  o.goal = Eigen::Vector3d(0.4, 0.05, 0.3);  // a turn: yaw enters the base-frame foot position
  o.constraints = {"joints"};
  SrbdProblem p(r, terrain, crawl(r), o);
  ASSERT_GT(count_kinds(p)["joints"], 0);
  for (unsigned seed : {1u, 2u, 3u})
    EXPECT_GT(testing::check_piece_derivatives(
                  p, seed, 0.02, [](const Piece& piece) { return piece.kind == "joints"; }),
              0);
}

// One piece per foot and base knot, then one per swing segment at its middle; the rows are the IK
// joint angles, bounded by the joint range shrunk by the margin.
TEST(JointLimitSetValues, RowsAreTheIkAnglesWithinTheRangeLessTheMargin) {
  const auto r = hyq();
  testing::FlatField flat;
  PlannerOptions o;
  o.has_goal = true;
  o.goal = Eigen::Vector3d(0.4, 0.0, 0.2);
  SrbdProblem p(r, flat, crawl(r), o);
  const std::size_t before = p.pieces().size();
  FeasibilityOptions fo;
  fo.joint_margin = 0.05;
  build_joints_set(p, fo);
  const Layout& L = p.layout();
  const int nf = static_cast<int>(r.legs.size());
  int swing_segments = 0;
  for (int f = 0; f < nf; ++f)
    for (int s = 0; s < L.num_segments; ++s) swing_segments += !L.contact[f][s];
  ASSERT_EQ(static_cast<int>(p.pieces().size() - before),
            nf * (L.num_segments + 1) + swing_segments);
  std::vector<double> x = p.initial_guess();
  for (std::size_t i = 0; i < x.size(); ++i)
    if (p.lower()[i] < p.upper()[i]) x[i] += 0.02 * std::sin(2.3 * static_cast<double>(i));
  std::vector<double> g(p.num_constraints());
  p.eval_constraints(x.data(), g.data());
  int row = 0;
  for (std::size_t i = 0; i < before; ++i) row += p.pieces()[i]->rows();
  int knots_checked = 0;
  for (int f = 0; f < nf; ++f)
    for (int k = 0; k <= L.num_segments; ++k, row += 3) {
      const auto v = [&](int i) { return Eigen::Vector3d(x[i], x[i + 1], x[i + 2]); };
      const Eigen::Vector3d e = v(L.base[k] + 6);
      const Eigen::Matrix3d R = (Eigen::AngleAxisd(e[0], Eigen::Vector3d::UnitZ()) *
                                 Eigen::AngleAxisd(e[1], Eigen::Vector3d::UnitY()) *
                                 Eigen::AngleAxisd(e[2], Eigen::Vector3d::UnitX()))
                                    .toRotationMatrix();
      const auto ik =
          robot::inverse_kinematics(r.legs[f], R.transpose() * (v(L.foot_pos[f][k]) - v(L.base[k])));
      // The perturbed guess may put a foot out of reach (no IK angles to compare with).
      if (ik.status == robot::IkStatus::unreachable) continue;
      ++knots_checked;
      const Piece& piece = *p.pieces()[before + f * (L.num_segments + 1) + k];
      for (int j = 0; j < 3; ++j) {
        EXPECT_NEAR(g[row + j], ik.q[j], 1e-9) << "foot " << f << " knot " << k << " joint " << j;
        EXPECT_DOUBLE_EQ(piece.lb[j], r.legs[f].q_min[j] + 0.05);
        EXPECT_DOUBLE_EQ(piece.ub[j], r.legs[f].q_max[j] - 0.05);
      }
    }
  EXPECT_GT(knots_checked, 3 * nf * (L.num_segments + 1) / 4);
  // Then one piece per swing segment of each foot, at the segment's middle: the IK angles of the
  // splines evaluated there.
  std::size_t piece_index = before + nf * (L.num_segments + 1);
  int swing_checked = 0;
  for (int f = 0; f < nf; ++f)
    for (int s = 0; s < L.num_segments; ++s) {
      if (L.contact[f][s]) continue;
      const Piece& piece = *p.pieces()[piece_index++];
      ASSERT_EQ(piece.kind, "joints");
      const double t_mid = 0.5 * (L.nominal_knot_time[s] + L.nominal_knot_time[s + 1]);
      const auto st = p.evaluate(x, t_mid);
      const Eigen::Vector3d e = st.euler;
      const Eigen::Matrix3d R = (Eigen::AngleAxisd(e[0], Eigen::Vector3d::UnitZ()) *
                                 Eigen::AngleAxisd(e[1], Eigen::Vector3d::UnitY()) *
                                 Eigen::AngleAxisd(e[2], Eigen::Vector3d::UnitX()))
                                    .toRotationMatrix();
      const auto ik = robot::inverse_kinematics(r.legs[f], R.transpose() * (st.foot_pos[f] - st.pos));
      row += 3;
      if (ik.status == robot::IkStatus::unreachable) continue;
      for (int j = 0; j < 3; ++j)
        EXPECT_NEAR(g[row - 3 + j], ik.q[j], 1e-9) << "foot " << f << " swing segment " << s;
      ++swing_checked;
    }
  EXPECT_GT(swing_checked, 3 * swing_segments / 4);
  EXPECT_GT(swing_segments, 0);
  FeasibilityOptions bad;
  bad.joint_margin = 2.0;  // more than half of every range
  EXPECT_THROW(build_joints_set(p, bad), std::invalid_argument);
}

// NAME=VALUE settings reach the sets: a tighter swing bound scales the rows, a joint margin
// moves the bounds; bad settings are refused naming themselves.
TEST(FeasibilitySettings, ReachTheSetsAndBadOnesAreNamed) {
  const auto r = hyq();
  testing::FlatField flat;
  PlannerOptions a, b;
  a.constraints = b.constraints = {"swing", "joints"};
  b.feasibility_settings = {{"swing_acceleration", 50.0}, {"joint_margin", 0.1}};
  SrbdProblem pa(r, flat, crawl(r), a), pb(r, flat, crawl(r), b);
  ASSERT_EQ(pa.num_constraints(), pb.num_constraints());
  std::vector<double> ga(pa.num_constraints()), gb(pb.num_constraints());
  pa.eval_constraints(pa.initial_guess().data(), ga.data());
  pb.eval_constraints(pb.initial_guess().data(), gb.data());
  int row = 0, swing_rows = 0;
  for (const auto& piece : pa.pieces()) {
    if (piece->kind == "swing") {
      for (int k = 0; k < piece->rows(); ++k, ++swing_rows)
        EXPECT_NEAR(gb[row + k], 2.0 * ga[row + k], 1e-12);  // a / 50 against a / 100
    }
    row += piece->rows();
  }
  EXPECT_GT(swing_rows, 0);
  const FeasibilityOptions fo = feasibility_options(b.feasibility_settings);
  EXPECT_EQ(fo.swing_acceleration, 50.0);
  EXPECT_EQ(fo.joint_margin, 0.1);
  for (std::size_t i = 0; i < pb.pieces().size(); ++i)
    if (pb.pieces()[i]->kind == "joints") {
      EXPECT_DOUBLE_EQ(pb.pieces()[i]->lb[1], r.legs[0].q_min[1] + 0.1);
      break;
    }
  for (const auto& bad : std::vector<std::pair<std::string, double>>{
           {"nope", 1.0}, {"shin_points", 0.0}, {"swing_acceleration", std::nan("")}}) {
    try {
      feasibility_options({bad});
      ADD_FAILURE() << bad.first;
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find(bad.first), std::string::npos) << e.what();
    }
  }
  EXPECT_EQ(feasibility_option_names().size(), 11u);
}

}  // namespace
}  // namespace terrastride::planner
