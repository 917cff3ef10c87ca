// "monotone_progress" (constraints/monotone_progress.cpp): Jacobians against central
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
    const SrbdProblem p(r, terrain, crawl_timeline(r),
                        with_monotone(turning_crawl_options(timing)));
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

// A re-plan from a state ahead of its motion (ProblemOptions::start_lead): the knots'
// velocity rows within the first second are bounded by -u instead of 0 and the middle rows carry
// + h u / 3 (the middle velocity control point >= -u), u = lead / the end time of the last such
// segment, so the base gives back at most the lead; later rows as without a lead. Derivatives
// against central differences with fixed and optimised timing.
TEST(MonotoneProgress, AStartAheadOfItsMotionMayGiveItsLeadBack) {
  const auto r = hyq();
  FlatField flat;
  ProblemOptions o = with_monotone(turning_crawl_options(false));
  o.goal = Eigen::Vector3d(0.4, 0.0, 0.0);
  const SrbdProblem cold(r, flat, crawl_timeline(r), o);
  const SrbdProblem::StartState start =
      start_state_of(cold.evaluate(const_cast<SrbdProblem&>(cold).initial_guess(), 0.3));
  o.feasibility_settings.emplace_back("replan_path_shape", 1.0);  // rows from a state too
  o.has_path_line = true;
  o.path_line_start = Eigen::Vector2d(0.0, 0.0);
  o.path_line_end = Eigen::Vector2d(0.4, 0.0);
  const auto timeline = crawl_timeline(r).cropped(0.3);
  const double lead = 0.03;
  for (bool timing : {false, true}) {
    ProblemOptions oo = o;
    oo.optimize_timing = timing;
    oo.start_lead = lead;
    const SrbdProblem p(r, flat, timeline, oo, &start);
    EXPECT_GT(check_kind_derivatives(p, "monotone_progress"), 10) << "timing " << timing;
  }
  ProblemOptions without = o, with = o;
  with.start_lead = lead;
  SrbdProblem p0(r, flat, timeline, without, &start), p1(r, flat, timeline, with, &start);
  const Layout& L = p1.layout();
  int n = 0;  // segments starting before 1 s
  while (L.nominal_knot_time[n] < 1.0) ++n;
  const double u = lead / L.nominal_knot_time[n];
  std::vector<const Piece*> a, b;
  for (const auto& piece : p0.pieces())
    if (piece->kind == "monotone_progress") a.push_back(piece.get());
  for (const auto& piece : p1.pieces())
    if (piece->kind == "monotone_progress") b.push_back(piece.get());
  ASSERT_EQ(a.size(), b.size());
  ASSERT_EQ(static_cast<int>(b.size()), L.num_segments);
  const std::vector<double> x = perturbed_guess(p1, 3, 0.02);
  int relaxed_knots = 0;
  for (int s = 0; s < L.num_segments; ++s) {
    ASSERT_EQ(a[s]->rows(), b[s]->rows()) << "segment " << s;
    // The start's velocity is fixed: each segment has its middle row first, then its end knot's.
    const auto ga = rows_at(*a[s], x), gb = rows_at(*b[s], x);
    const double h = segment_length(L, x, s);
    EXPECT_NEAR(gb[0] - ga[0], s < n ? h * u / 3.0 : 0.0, 1e-12) << "segment " << s;
    EXPECT_EQ(b[s]->lb[0], 0.0);
    if (b[s]->rows() > 1) {
      EXPECT_NEAR(gb[1], ga[1], 1e-12);
      EXPECT_EQ(b[s]->lb[1], s + 1 < n ? -u : 0.0) << "segment " << s;
      EXPECT_EQ(a[s]->lb[1], 0.0);
      relaxed_knots += s + 1 < n;
    }
  }
  EXPECT_EQ(relaxed_knots, n - 1);
  EXPECT_GE(n, 3);
}

// The re-plan rule (FeasibilityOptions::replan_path_shape): a problem from a given
// start state (a planning session's step, `plan --init`) carries none of the three path-shape
// families unless replan_path_shape = 1; a plan from rest carries them whatever that setting.
TEST(PathShape, AReplanFromAStateCarriesTheRowsOnlyWhenAsked) {
  const auto r = hyq();
  FlatField flat;
  ProblemOptions o = turning_crawl_options(false);
  o.constraints = {"monotone_progress", "lateral_corridor", "swing_apex"};
  o.feasibility_settings = {
      {"monotone_progress", 1.0}, {"lateral_corridor", 0.02}, {"swing_apex_rise", 0.1}};
  o.goal = Eigen::Vector3d(0.4, 0.0, 0.0);
  const SrbdProblem cold(r, flat, crawl_timeline(r), o);
  const SrbdProblem::StartState start =
      start_state_of(cold.evaluate(const_cast<SrbdProblem&>(cold).initial_guess(), 0.3));
  const auto timeline = crawl_timeline(r).cropped(0.3);
  const char* kinds[] = {"monotone_progress", "lateral_corridor", "swing_apex"};
  const auto from_rest = count_kinds(cold);
  const auto replan = count_kinds(SrbdProblem(r, flat, timeline, o, &start));
  ProblemOptions asked = o;
  asked.feasibility_settings.emplace_back("replan_path_shape", 1.0);
  const auto replan_asked = count_kinds(SrbdProblem(r, flat, timeline, asked, &start));
  const auto from_rest_asked = count_kinds(SrbdProblem(r, flat, crawl_timeline(r), asked));
  for (const char* kind : kinds) {
    EXPECT_GT(from_rest.count(kind), 0u) << kind;
    EXPECT_EQ(replan.count(kind), 0u) << kind;
    EXPECT_GT(replan_asked.count(kind), 0u) << kind;
    EXPECT_EQ(from_rest_asked.at(kind), from_rest.at(kind)) << kind;
  }
}

// On by default; the setting 0 turns it off.
TEST(MonotoneProgress, OnByDefaultOffAtZeroAndWithoutAGoal) {
  const auto r = hyq();
  FlatField flat;
  ProblemOptions o = turning_crawl_options(false);
  o.constraints = {"monotone_progress"};
  EXPECT_GT(count_kinds(SrbdProblem(r, flat, crawl_timeline(r), o)).count("monotone_progress"), 0u);
  o.feasibility_settings = {{"monotone_progress", 0.0}};
  EXPECT_EQ(count_kinds(SrbdProblem(r, flat, crawl_timeline(r), o)).count("monotone_progress"), 0u);
  o = with_monotone(o);
  o.has_goal = false;  // the goal is the start: no line
  EXPECT_EQ(count_kinds(SrbdProblem(r, flat, crawl_timeline(r), o)).count("monotone_progress"), 0u);
}

}  // namespace
}  // namespace terrastride::planner
