// "dynamics_angular" (constraints/dynamics_angular.cpp): Jacobians against central differences,
// and the rows against the angular momentum balance evaluated independently: the problem's
// continuous-time solution, the world angular velocity w = E(e) e' and its rate by differences.
#include "family_test.hpp"

namespace terrastride::planner {
namespace {

using namespace testing;

TEST(DynamicsAngular, JacobianMatchesCentralDifferences) {
  const auto r = hyq();
  TanhStep terrain(0.1, 0.5, 0.05, 0.01);
  const SrbdProblem p(r, terrain, crawl_timeline(r), turning_crawl_options());
  EXPECT_GT(check_kind_derivatives(p, "dynamics_angular"), 0);
}

// w = E(e) e' for ZYX Euler angles e = (yaw, pitch, roll).
Eigen::Vector3d angular_velocity(const SrbdProblem::State& st) {
  const double cy = std::cos(st.euler[0]), sy = std::sin(st.euler[0]);
  const double cp = std::cos(st.euler[1]), sp = std::sin(st.euler[1]);
  Eigen::Matrix3d E;
  E << 0, -sy, cy * cp, 0, cy, sy * cp, 1, 0, -sp;
  return E * st.euler_rate;
}

// Per segment one piece at each of `angular_points` fractions (ends included), three rows:
// (I w' + w x I w - sum (p_f - r) x f) / (0.1 m g), with I = R I_b R^T; zero at the segment ends,
// within +-angular_band inside. Checked at the points before the segment's end, where the
// continuous-time solution is the segment's own cubic.
TEST(DynamicsAngular, RowsAreTheAngularMomentumBalance) {
  const auto r = hyq();
  TanhStep terrain(0.1, 0.5, 0.05, 0.01);
  const ProblemOptions o = turning_crawl_options();
  SrbdProblem p(r, terrain, crawl_timeline(r), o);
  const std::vector<double> x = perturbed_guess(p, 5, 0.01);
  const Layout& L = p.layout();
  const double scale = 1.0 / (0.1 * r.mass * 9.81);
  int checked = 0;
  for (int s = 0; s < L.num_segments; ++s) {
    const auto pieces = pieces_added_by(p, [&] { add_dynamics_angular(p, s); });
    const std::vector<double> sigmas = L.segment_points(s, o.angular_points - 1, true);
    ASSERT_EQ(pieces.size(), sigmas.size());
    for (std::size_t i = 0; i < sigmas.size(); ++i) {
      const bool interior = sigmas[i] > 0.0 && sigmas[i] < 1.0;
      for (int d = 0; d < 3; ++d) {
        EXPECT_NEAR(pieces[i]->ub[d], interior ? o.angular_band * scale : 0.0, 1e-15);
        EXPECT_NEAR(pieces[i]->lb[d], -pieces[i]->ub[d], 1e-15);
      }
      if (sigmas[i] == 1.0) continue;
      const double t = segment_start(L, x, s) + sigmas[i] * segment_length(L, x, s);
      const auto st = p.evaluate(x, t);
      // w' by a one-sided second-order difference inside the segment.
      const double dt = 1e-5;
      const Eigen::Vector3d w = angular_velocity(st);
      const Eigen::Vector3d wd = (-3 * w + 4 * angular_velocity(p.evaluate(x, t + dt)) -
                                  angular_velocity(p.evaluate(x, t + 2 * dt))) /
                                 (2 * dt);
      const Eigen::Matrix3d R = rotation_of(st.euler);
      const Eigen::Matrix3d I = R * r.inertia * R.transpose();
      Eigen::Vector3d expected = I * wd + w.cross(I * w);
      for (std::size_t f = 0; f < r.legs.size(); ++f)
        if (st.contact[f]) expected -= (st.foot_pos[f] - st.pos).cross(st.force[f]);
      const auto g = rows_at(*pieces[i], x);
      for (int d = 0; d < 3; ++d)
        EXPECT_NEAR(g[d], expected[d] * scale, 1e-5) << "segment " << s << " sigma " << sigmas[i];
      ++checked;
    }
  }
  EXPECT_GT(checked, 20);
}

// A base that cannot rotate (the monoped on its slider) has no angular rows.
TEST(DynamicsAngular, NoRowsForABaseThatCannotRotate) {
  const auto r = robot::load_robot(robot::resolve_robot_path("monoped"));
  FlatField flat;
  ProblemOptions o;
  o.gait = "hop";
  const PhaseTimeline tl = make_timeline(load_gait(resolve_gait_path("hop")), feet_of(r), 1, 0.0);
  SrbdProblem p(r, flat, tl, o);
  EXPECT_EQ(count_kinds(p).count("dynamics_angular"), 0u);
  EXPECT_TRUE(pieces_added_by(p, [&] { add_dynamics_angular(p, 0); }).empty());
}

}  // namespace
}  // namespace terrastride::planner
