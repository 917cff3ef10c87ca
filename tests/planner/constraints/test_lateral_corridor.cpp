// "lateral_corridor" (constraints/lateral_corridor.cpp; issue #17): Jacobians against central
// differences (fixed and optimised timing), the rows against the base spline's Bezier control
// points' offsets across the start-to-goal line (a diagonal one), and no rows when off.
#include "family_test.hpp"

namespace terrastride::planner {
namespace {

using namespace testing;

ProblemOptions with_corridor(ProblemOptions o, double w) {
  o.constraints = {"lateral_corridor"};
  o.feasibility_settings = {{"lateral_corridor", w}};
  return o;
}

TEST(LateralCorridor, JacobianMatchesCentralDifferences) {
  const auto r = hyq();
  TanhStep terrain(0.1, 0.5, 0.05, 0.01);
  for (bool timing : {false, true}) {
    const SrbdProblem p(r, terrain, crawl_timeline(r),
                        with_corridor(turning_crawl_options(timing), 0.02));
    EXPECT_GT(check_kind_derivatives(p, "lateral_corridor"), 10) << "timing " << timing;
    EXPECT_GT(largest_jacobian_entry(p, "lateral_corridor"), 0.5);
  }
}

// Rows: the offset across the line of every control point of the segments' halves that the solve
// can move (not the start's, nor the goal's, nor the first one after a start at rest, nor the last
// one before a goal at rest), in [-w, w].
TEST(LateralCorridor, RowsAreTheControlPointsOffsetsAcrossTheGoalLine) {
  const auto r = hyq();
  FlatField flat;
  for (bool timing : {false, true}) {
    SrbdProblem p(r, flat, crawl_timeline(r), with_corridor(turning_crawl_options(timing), 0.03));
    const Layout& L = p.layout();
    const int S = L.num_segments;
    const auto& guess = p.initial_guess();
    const Eigen::Vector3d start = p.evaluate(guess, 0.0).pos,
                          goal = p.evaluate(guess, p.duration(guess)).pos;
    const Eigen::Vector2d d = (goal - start).head<2>().normalized();
    const Eigen::Vector2d n(-d.y(), d.x());
    auto across = [&](const Eigen::Vector3d& q) { return n.dot(q.head<2>() - start.head<2>()); };
    const std::vector<double> x = perturbed_guess(p, 7, 0.02);
    std::vector<const Piece*> pieces;
    for (const auto& piece : p.pieces())
      if (piece->kind == "lateral_corridor") pieces.push_back(piece.get());
    ASSERT_EQ(static_cast<int>(pieces.size()), S);
    auto pos = [](const SrbdProblem::State& st) { return st.pos; };
    auto vel = [](const SrbdProblem::State& st) { return st.vel; };
    for (int s = 0; s < S; ++s) {
      const auto P = half_bezier_points(p, x, s, pos, vel);
      const auto P_guess = half_bezier_points(p, guess, s, pos, vel);
      std::vector<double> expected;
      for (int i = s == 0 ? 0 : 1; i < 7; ++i)
        if (std::abs(across(P[i]) - across(P_guess[i])) > 1e-9)  // movable (not rounding)
          expected.push_back(across(P[i]));
      const auto g = rows_at(*pieces[s], x);
      ASSERT_EQ(g.size(), expected.size()) << "segment " << s;
      EXPECT_EQ(g.size(), s == 0 ? 5u : s == S - 1 ? 4u : 6u) << "segment " << s;
      for (std::size_t i = 0; i < g.size(); ++i) {
        EXPECT_NEAR(g[i], expected[i], 1e-9) << "segment " << s << " row " << i;
        EXPECT_EQ(pieces[s]->lb[i], -0.03);
        EXPECT_EQ(pieces[s]->ub[i], 0.03);
      }
      for (double v : rows_at(*pieces[s], guess)) EXPECT_NEAR(v, 0.0, 1e-9);  // on the line
    }
  }
}

TEST(LateralCorridor, OffByDefault) {
  const auto r = hyq();
  FlatField flat;
  ProblemOptions o = turning_crawl_options(false);
  o.constraints = {"lateral_corridor"};
  EXPECT_EQ(count_kinds(SrbdProblem(r, flat, crawl_timeline(r), o)).count("lateral_corridor"), 0u);
}

}  // namespace
}  // namespace terrastride::planner
