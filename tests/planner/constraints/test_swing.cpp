// "swing" (constraints/swing.cpp; swing-foot acceleration bound): Jacobians against central
// differences, and the rows against the foot spline's second difference.
#include <cmath>

#include "family_test.hpp"

namespace terrastride::planner {
namespace {

using namespace testing;

TEST(Swing, JacobianMatchesCentralDifferences) {
  const auto r = hyq();
  TanhStep terrain(0.1, 0.5, 0.05, 0.01);
  for (bool timing : {false, true}) {  // with timing, the segment duration is a variable too
    PlannerOptions o;
    o.has_goal = true;
    o.goal = Eigen::Vector3d(0.4, 0.05, 0.3);
    o.optimize_timing = timing;
    o.constraints = {"swing"};
    SrbdProblem p(r, terrain, crawl_timeline(r), o);
    ASSERT_GT(count_kinds(p)["swing"], 0);
    for (unsigned seed : {1u, 2u})
      EXPECT_GT(check_piece_derivatives(p, seed, 0.02,
                                        [](const Piece& piece) { return piece.kind == "swing"; }),
                0)
          << "timing " << timing;
  }
}

// Every swing segment gets one piece whose six rows are the foot's acceleration at the segment's
// two ends over the bound, which must agree with the spline the problem evaluates.
TEST(Swing, RowsAreTheSplineAccelerationOverTheBound) {
  const auto r = hyq();
  FlatField flat;
  PlannerOptions o;
  o.has_goal = true;
  o.goal = Eigen::Vector3d(0.4, 0.0, 0.0);
  SrbdProblem p(r, flat, crawl_timeline(r), o);
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

}  // namespace
}  // namespace terrastride::planner
