// "lateral_corridor" (constraints/lateral_corridor.cpp): Jacobians against central
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

// A re-plan of a motion follows that motion's line (ProblemOptions::path_line, a planning
// session's reference line), not the line from its own start: with the line 0.1 m to the left of
// a straight plan, every row of the plan's guess (on y = 0) is -0.1.
TEST(LateralCorridor, FollowsTheOptionsPathLine) {
  const auto r = hyq();
  FlatField flat;
  ProblemOptions o = with_corridor(turning_crawl_options(false), 0.02);
  o.goal = Eigen::Vector3d(0.4, 0.0, 0.0);
  o.has_path_line = true;
  o.path_line_start = Eigen::Vector2d(-1.0, 0.1);
  o.path_line_end = Eigen::Vector2d(2.0, 0.1);
  SrbdProblem p(r, flat, crawl_timeline(r), o);
  int rows = 0;
  for (const auto& piece : p.pieces())
    if (piece->kind == "lateral_corridor")
      for (double v : rows_at(*piece, p.initial_guess())) {
        EXPECT_NEAR(v, -0.1, 1e-9);
        ++rows;
      }
  EXPECT_GT(rows, 10);
}

// With the end pinned in motion (a receding-horizon step, SrbdProblem's end_state) the rows see
// the end knot as fixed: none is left a constant. Pinned after the rows were built (as before),
// the end knot's corridor row and its velocity's progress row were constants, which a 1 cm offset
// of the line made contradictions (planning-session steps failed).
TEST(LateralCorridor, NoConstantRowsWithAPinnedEnd) {
  const auto r = hyq();
  FlatField flat;
  ProblemOptions o = turning_crawl_options(false);
  o.constraints = {"monotone_progress", "lateral_corridor", "swing_apex"};
  o.feasibility_settings = {
      {"monotone_progress", 1.0}, {"lateral_corridor", 0.02}, {"swing_apex_rise", 0.1},
      {"replan_path_shape", 1.0}};  // the rows from a state too
  o.goal = Eigen::Vector3d(0.4, 0.0, 0.0);
  const SrbdProblem cold(r, flat, crawl_timeline(r), o);
  auto state_at = [&](double t) {
    return start_state_of(cold.evaluate(const_cast<SrbdProblem&>(cold).initial_guess(), t));
  };
  const auto start = state_at(0.5), end = state_at(1.5);
  ASSERT_GT(end.linear_velocity.x(), 0.01);  // pinned in motion
  const auto timeline = crawl_timeline(r).cropped(0.5);
  SrbdProblem p(r, flat, timeline, o, &start, &end);
  const int last = p.layout().base[p.layout().num_segments];
  for (int i = 0; i < 6; ++i) EXPECT_EQ(p.lower()[last + i], p.upper()[last + i]);
  int rows = 0;
  for (const auto& piece : p.pieces()) {
    if (piece->kind != "monotone_progress" && piece->kind != "lateral_corridor" &&
        piece->kind != "swing_apex")
      continue;
    const int n = static_cast<int>(piece->vars.size()), m = piece->rows();
    std::vector<double> xl(n), g(m), J(m * n);
    for (int i = 0; i < n; ++i) xl[i] = p.initial_guess()[piece->vars[i]];
    piece->eval_jacobian(xl.data(), g.data(), J.data());
    for (int row = 0; row < m; ++row) {
      double free_entry = 0.0;
      for (int c = 0; c < n; ++c)
        if (p.lower()[piece->vars[c]] < p.upper()[piece->vars[c]])
          free_entry = std::max(free_entry, std::abs(J[row * n + c]));
      EXPECT_GT(free_entry, 1e-6) << piece->kind << " row " << row << " is a constant";
      ++rows;
    }
  }
  EXPECT_GT(rows, 20);
}

// On by default; the setting 0 turns it off.
TEST(LateralCorridor, OnByDefaultOffAtZero) {
  const auto r = hyq();
  FlatField flat;
  ProblemOptions o = turning_crawl_options(false);
  o.constraints = {"lateral_corridor"};
  EXPECT_GT(count_kinds(SrbdProblem(r, flat, crawl_timeline(r), o)).count("lateral_corridor"), 0u);
  o.feasibility_settings = {{"lateral_corridor", 0.0}};
  EXPECT_EQ(count_kinds(SrbdProblem(r, flat, crawl_timeline(r), o)).count("lateral_corridor"), 0u);
}

}  // namespace
}  // namespace terrastride::planner
