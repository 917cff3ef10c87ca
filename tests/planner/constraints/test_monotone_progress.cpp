// "monotone_progress" (constraints/monotone_progress.cpp; issue #17): Jacobians against central
// differences (fixed and optimised timing), the rows against the base spline's Bezier control
// points along the start-to-goal line, and no rows when the setting is off.
#include "family_test.hpp"

namespace terrastride::planner {
namespace {

using namespace testing;

ProblemOptions with_monotone(ProblemOptions o) {
  o.constraints = {"monotone_progress"};
  o.feasibility_settings = {{"monotone_progress", 1.0}};
  return o;
}

TEST(MonotoneProgress, JacobianMatchesCentralDifferences) {
  const auto r = hyq();
  TanhStep terrain(0.1, 0.5, 0.05, 0.01);
  for (bool timing : {false, true}) {
    const SrbdProblem p(r, terrain, crawl_timeline(r), with_monotone(turning_crawl_options(timing)));
    EXPECT_GT(check_kind_derivatives(p, "monotone_progress"), 10) << "timing " << timing;
    EXPECT_GT(largest_jacobian_entry(p, "monotone_progress"), 0.5);
  }
}

// Per segment: d . (P2 - P1) and, where the knot's velocity is free, d . v at the segment's end
// (the start knot's too for the first segment), d the unit start-to-goal direction. At rest at
// both ends the first and last knots' velocities are fixed: no rows on them.
TEST(MonotoneProgress, RowsAreTheControlPointDifferencesAlongTheGoalLine) {
  const auto r = hyq();
  FlatField flat;
  for (bool timing : {false, true}) {
    SrbdProblem p(r, flat, crawl_timeline(r), with_monotone(turning_crawl_options(timing)));
    const Layout& L = p.layout();
    const int S = L.num_segments;
    const auto& guess = p.initial_guess();
    const Eigen::Vector3d start = p.evaluate(guess, 0.0).pos,
                          goal = p.evaluate(guess, p.duration(guess)).pos;
    const Eigen::Vector3d d =
        Eigen::Vector3d(goal.x() - start.x(), goal.y() - start.y(), 0.0).normalized();
    EXPECT_NEAR(goal.x(), 0.4, 1e-9);
    EXPECT_NEAR(goal.y(), 0.05, 1e-9);  // a diagonal line
    const std::vector<double> x = perturbed_guess(p, 5, 0.02);
    std::vector<const Piece*> pieces;
    for (const auto& piece : p.pieces())
      if (piece->kind == "monotone_progress") pieces.push_back(piece.get());
    ASSERT_EQ(static_cast<int>(pieces.size()), S);
    for (int s = 0; s < S; ++s) {
      const auto P = bezier_points(
          p, x, s, [](const SrbdProblem::State& st) { return st.pos; },
          [](const SrbdProblem::State& st) { return st.vel; });
      const double h = segment_length(L, x, s);
      std::vector<double> expected{d.dot(P[2] - P[1])};
      if (s + 1 < S) expected.push_back(d.dot(P[3] - P[2]) * 3.0 / h);  // d . v at the knot
      const auto g = rows_at(*pieces[s], x);
      ASSERT_EQ(g.size(), expected.size()) << "segment " << s;
      for (std::size_t i = 0; i < g.size(); ++i) {
        EXPECT_NEAR(g[i], expected[i], 1e-9) << "segment " << s << " row " << i;
        EXPECT_EQ(pieces[s]->lb[i], 0.0);
        EXPECT_GE(pieces[s]->ub[i], 1e19);
      }
    }
    // The guess (minimum-jerk progress along the line) satisfies every row.
    for (const auto* piece : pieces)
      for (double v : rows_at(*piece, guess)) EXPECT_GE(v, -1e-12);
  }
}

TEST(MonotoneProgress, OffByDefaultAndWithoutAGoal) {
  const auto r = hyq();
  FlatField flat;
  ProblemOptions o = turning_crawl_options(false);
  o.constraints = {"monotone_progress"};
  EXPECT_EQ(count_kinds(SrbdProblem(r, flat, crawl_timeline(r), o)).count("monotone_progress"),
            0u);
  o = with_monotone(o);
  o.has_goal = false;  // the goal is the start: no line
  EXPECT_EQ(count_kinds(SrbdProblem(r, flat, crawl_timeline(r), o)).count("monotone_progress"),
            0u);
}

}  // namespace
}  // namespace terrastride::planner
