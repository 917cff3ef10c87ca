// "swing_apex" (constraints/swing_apex.cpp): Jacobians against central differences
// (fixed and optimised timing), the rows against the swing foot spline's Bezier control points'
// heights above the higher end of the swing, and no rows when off.
#include <algorithm>
#include <utility>
#include <vector>

#include "family_test.hpp"

namespace terrastride::planner {
namespace {

using namespace testing;

ProblemOptions with_apex(ProblemOptions o, double rise) {
  o.constraints = {"swing_apex"};
  o.feasibility_settings = {{"swing_apex_rise", rise}};
  return o;
}

TEST(SwingApex, JacobianMatchesCentralDifferences) {
  const auto r = hyq();
  TanhStep terrain(0.1, 0.5, 0.05, 0.01);
  for (bool timing : {false, true}) {
    const SrbdProblem p(r, terrain, crawl_timeline(r), with_apex(turning_crawl_options(timing), 0.1));
    EXPECT_GT(check_kind_derivatives(p, "swing_apex"), 4) << "timing " << timing;
    EXPECT_GT(largest_jacobian_entry(p, "swing_apex"), 0.5);
  }
}

// Over a 10 cm step (feet landing on it rise from the ground), per swing segment: the heights of
// the control points of its two halves (and of its end when an inner knot) above the swing end
// that is higher in the guess, <= rise; control points equal to the lift-off or touch-down point
// (zero velocity there) get no row. Where the terrain under the guess's swing path (its knots,
// probed +-clearance_probe in x and y) is higher than that end, the reference is that terrain
// height, a constant (the foot must rise over it anyway).
TEST(SwingApex, RowsAreTheControlPointsHeightsAboveTheHigherEndOrTheTerrainPassed) {
  const auto r = hyq();
  TanhStep step(0.1, 0.6, 0.02);  // the front feet end on it, the hind feet stay below
  for (bool timing : {false, true}) {
    ProblemOptions o = with_apex(turning_crawl_options(timing), 0.08);
    o.goal = Eigen::Vector3d(0.4, 0.0, 0.0);
    SrbdProblem p(r, step, crawl_timeline(r), o);
    const Layout& L = p.layout();
    const auto& guess = p.initial_guess();
    const std::vector<double> x = perturbed_guess(p, 11, 0.02);
    std::vector<const Piece*> pieces;
    for (const auto& piece : p.pieces())
      if (piece->kind == "swing_apex") pieces.push_back(piece.get());
    std::size_t k = 0;
    int rows = 0, up_steps = 0, terrain_refs = 0, end_refs = 0;
    for (const auto& sw : L.swings) {
      const int f = sw.foot, k0 = sw.first_seg, k1 = sw.last_seg + 1;
      auto foot_z = [&](const std::vector<double>& at, int knot) {
        return p.evaluate(at, segment_start(L, at, knot)).foot_pos[f].z();
      };
      auto last_z = [&](const std::vector<double>& at) {
        return p.evaluate(at, segment_start(L, at, k1 - 1) + segment_length(L, at, k1 - 1))
            .foot_pos[f]
            .z();
      };
      const bool lift_off_higher = foot_z(guess, k0) >= last_z(guess);
      double terrain_passed = -1e9;
      for (int knot = k0; knot <= k1; ++knot) {
        const double fx = guess[L.foot_pos[f][knot]], fy = guess[L.foot_pos[f][knot] + 1];
        for (const auto& [dx, dy] : std::vector<std::pair<double, double>>{
                 {0, 0}, {0.05, 0}, {-0.05, 0}, {0, 0.05}, {0, -0.05}})
          terrain_passed = std::max(terrain_passed, step.sample(fx + dx, fy + dy).height);
      }
      const double guess_end = std::max(foot_z(guess, k0), last_z(guess));
      const bool over_terrain = terrain_passed > guess_end + 1e-12;
      (over_terrain ? terrain_refs : end_refs) += 1;
      const double ref = over_terrain ? terrain_passed : lift_off_higher ? foot_z(x, k0) : last_z(x);
      up_steps += last_z(guess) > foot_z(guess, k0) + 0.05;
      auto pos = [f](const SrbdProblem::State& st) { return st.foot_pos[f]; };
      auto vel = [f](const SrbdProblem::State& st) { return st.foot_vel[f]; };
      for (int s = k0; s < k1; ++s) {
        const auto P = half_bezier_points(p, x, s, pos, vel);
        std::vector<double> expected;
        for (int i = s > k0 ? 1 : 2; i <= (s + 1 < k1 ? 6 : 4); ++i) expected.push_back(P[i].z() - ref);
        ASSERT_LT(k, pieces.size());
        const auto g = rows_at(*pieces[k], x);
        ASSERT_EQ(g.size(), expected.size()) << "swing of foot " << f << " segment " << s;
        for (std::size_t i = 0; i < g.size(); ++i) {
          EXPECT_NEAR(g[i], expected[i], 1e-9) << "foot " << f << " segment " << s;
          EXPECT_EQ(pieces[k]->ub[i], 0.08);
          EXPECT_LE(pieces[k]->lb[i], -1e19);
        }
        rows += static_cast<int>(g.size());
        ++k;
      }
    }
    EXPECT_EQ(k, pieces.size());
    EXPECT_GT(rows, 8);
    EXPECT_GT(up_steps, 0);  // some swings land on the step: their reference is the touch-down
    EXPECT_GT(terrain_refs, 0) << "timing " << timing;  // some pass the step's rise
    EXPECT_GT(end_refs, 0) << "timing " << timing;
  }
}

// On by default; the setting 0 turns it off.
TEST(SwingApex, OnByDefaultOffAtZero) {
  const auto r = hyq();
  FlatField flat;
  ProblemOptions o = turning_crawl_options(false);
  o.constraints = {"swing_apex"};
  EXPECT_GT(count_kinds(SrbdProblem(r, flat, crawl_timeline(r), o)).count("swing_apex"), 0u);
  o.feasibility_settings = {{"swing_apex_rise", 0.0}};
  EXPECT_EQ(count_kinds(SrbdProblem(r, flat, crawl_timeline(r), o)).count("swing_apex"), 0u);
}

}  // namespace
}  // namespace terrastride::planner
