// "force_ramp" (constraints/force_ramp.cpp and the layout's missing force knots):
// which force knots the layout leaves out, the rate rows' Jacobian against central differences,
// the rows against the force change over each stance segment, and none in the first segment of a
// re-plan from a given start.
#include <algorithm>

#include "family_test.hpp"

namespace terrastride::planner {
namespace {

using namespace testing;

// With force ramps every touch-down and lift-off knot is identically zero (no variable); the
// initial stance's first knot and the final stance's last knot keep theirs. Without, none is zero.
TEST(ForceRamp, LayoutLeavesOutTouchDownAndLiftOffKnots) {
  const auto r = hyq();
  FlatField flat;
  for (const std::vector<std::string>& sets :
       {std::vector<std::string>{"force_ramp"}, std::vector<std::string>{"all"},
        std::vector<std::string>{"baseline"}}) {
    ProblemOptions o = paper_test_options();
    o.constraints = sets;
    const bool ramps = sets.front() != "baseline";
    EXPECT_EQ(requests_constraint_set(o.constraints, "force_ramp"), ramps);
    const SrbdProblem p(r, flat, crawl_timeline(r), o);
    const Layout& L = p.layout();
    int zero_knots = 0;
    for (const auto& st : L.stances) {
      const bool starts = st.first_seg > 0, ends = st.last_seg < L.num_segments - 1;
      EXPECT_EQ(L.force[st.foot][st.first_seg][0] < 0, ramps && starts) << sets.front();
      EXPECT_EQ(L.force[st.foot][st.last_seg][1] < 0, ramps && ends) << sets.front();
      zero_knots += (L.force[st.foot][st.first_seg][0] < 0) + (L.force[st.foot][st.last_seg][1] < 0);
      for (int s = st.first_seg; s < st.last_seg; ++s)  // inner knots: shared variables
        EXPECT_GE(L.force[st.foot][s][1], 0);
    }
    EXPECT_EQ(zero_knots, ramps ? 8 : 0);  // one cycle: four swings, each a lift-off and touch-down
  }
}

// A trot's diagonal pairs swap at one instant: no foot's stance passes through that switch knot,
// so zero forces there would leave the body without support (every trot with 'all' stalled).
// Such knots keep their force variables; a switch that another stance carries through (the
// trot's lead-in and lead-out, every crawl switch) is ramped.
TEST(ForceRamp, SwitchKnotsWithoutContinuousSupportKeepTheirForces) {
  const auto r = hyq();
  FlatField flat;
  ProblemOptions o = paper_test_options();
  o.constraints = {"force_ramp"};
  const PhaseTimeline trot = make_timeline(load_gait(resolve_gait_path("trot")), feet_of(r), 2, 2.1);
  const SrbdProblem p(r, flat, trot, o);
  const Layout& L = p.layout();
  int switches = 0, unsupported = 0;
  for (int k = 1; k < L.num_segments; ++k) {
    bool carried = false;
    for (int f = 0; f < 4; ++f) carried = carried || (L.contact[f][k - 1] && L.contact[f][k]);
    for (int f = 0; f < 4; ++f) {
      const bool down = L.contact[f][k - 1] != L.contact[f][k];
      if (!down) continue;
      ++switches;
      const int var = L.contact[f][k] ? L.force[f][k][0] : L.force[f][k - 1][1];
      if (!carried) ++unsupported;
      EXPECT_EQ(var < 0, carried) << "foot " << f << " knot " << k;
    }
  }
  EXPECT_GT(switches, unsupported);  // the lead-in's and lead-out's switches ramp
  EXPECT_GT(unsupported, 0);         // the pairs' swaps keep their forces
}

TEST(ForceRamp, JacobianMatchesCentralDifferences) {
  const auto r = hyq();
  TanhStep terrain(0.1, 0.5, 0.05, 0.01);
  for (bool timing : {false, true}) {
    ProblemOptions o = turning_crawl_options(timing);
    o.constraints = {"force_ramp"};
    const SrbdProblem p(r, terrain, crawl_timeline(r), o);
    EXPECT_GT(check_kind_derivatives(p, "force_ramp"), 0) << "timing " << timing;
    EXPECT_GT(largest_jacobian_entry(p, "force_ramp"), 0.0);
  }
}

// One row per stance segment that carries force: |f1 - f0|^2 / (rate h)^2 <= 1.
TEST(ForceRamp, RowsAreTheSquaredForceChangeOverTheBound) {
  const auto r = hyq();
  FlatField flat;
  ProblemOptions o = paper_test_options();
  o.constraints = {"force_ramp"};
  SrbdProblem p(r, flat, crawl_timeline(r), o);
  const Layout& L = p.layout();
  std::vector<double> x = perturbed_guess(p, 3, 0.02);
  FeasibilityOptions fo;
  fo.force_rate_max = 1500.0;
  const auto pieces = pieces_added_by(p, [&] { build_force_ramp_set(p, fo); });
  std::size_t k = 0;
  int checked = 0;
  for (int f = 0; f < 4; ++f)
    for (int s = 0; s < L.num_segments; ++s) {
      if (!L.contact[f][s]) continue;
      ASSERT_LT(k, pieces.size());
      const double h = segment_length(L, x, s);
      auto force = [&](int v) { return v < 0 ? Eigen::Vector3d::Zero().eval() : vec3_at(x, v); };
      const Eigen::Vector3d df = force(L.force[f][s][1]) - force(L.force[f][s][0]);
      const auto g = rows_at(*pieces[k], x);
      ASSERT_EQ(g.size(), 1u);
      EXPECT_NEAR(g[0], df.squaredNorm() / std::pow(1500.0 * h, 2), 1e-9 * (1 + g[0]));
      EXPECT_EQ(pieces[k]->ub[0], 1.0);
      ++k;
      ++checked;
    }
  EXPECT_EQ(k, pieces.size());
  EXPECT_GT(checked, 10);
  fo.force_rate_max = 0.0;  // the layout's ramps alone
  EXPECT_TRUE(pieces_added_by(p, [&] { build_force_ramp_set(p, fo); }).empty());
}

// A re-plan from a given start (a measured state, a session step) has no row in its first
// segment: the start's forces are not measured, and a lift-off ending a cropped first segment
// would hold the start's force to force_rate_max h. Every later stance segment keeps its row, and
// the same timeline planned from rest has the first segment's rows too.
TEST(ForceRamp, ARePlanFromAGivenStartHasNoRowInItsFirstSegment) {
  const auto r = hyq();
  FlatField flat;
  ProblemOptions o = paper_test_options();
  o.constraints = {"force_ramp"};
  SrbdProblem cold(r, flat, crawl_timeline(r), o);
  FeasibilityOptions fo;
  fo.force_rate_max = 1500.0;
  int first_segment_rows = 0;
  for (const double t : {0.5, 0.93, 1.37}) {
    const SrbdProblem::StartState start = start_state_of(cold.evaluate(cold.initial_guess(), t));
    const PhaseTimeline tl = crawl_timeline(r).cropped(t);
    SrbdProblem replan(r, flat, tl, o, &start);
    SrbdProblem from_rest(r, flat, tl, o);
    const Layout& L = replan.layout();
    // Stance segments with a force at either end: after the first, and in it.
    int later = 0, first = 0;
    for (int f = 0; f < 4; ++f)
      for (int s = 0; s < L.num_segments; ++s)
        if (L.contact[f][s] && (L.force[f][s][0] >= 0 || L.force[f][s][1] >= 0))
          ++(s == 0 ? first : later);
    const auto replan_rows = pieces_added_by(replan, [&] { build_force_ramp_set(replan, fo); });
    const auto rest_rows = pieces_added_by(from_rest, [&] { build_force_ramp_set(from_rest, fo); });
    EXPECT_EQ(static_cast<int>(replan_rows.size()), later) << "t " << t;
    EXPECT_EQ(static_cast<int>(rest_rows.size()), later + first) << "t " << t;
    for (const Piece* piece : replan_rows)
      for (int f = 0; f < 4; ++f)
        if (L.force[f][0][0] >= 0)  // knot 0's force appears only in the first segment's row
          EXPECT_EQ(std::count(piece->vars.begin(), piece->vars.end(), L.force[f][0][0]), 0);
    first_segment_rows += first;
  }
  EXPECT_GE(first_segment_rows, 3);
}

}  // namespace
}  // namespace terrastride::planner
