// "swing_clearance" (constraints/swing_clearance.cpp): Jacobians against central differences, and
// the rows and their bounds against the foot's height above the terrain probed around it and the
// sin^2 clearance profile.
#include <algorithm>
#include <cmath>

#include "family_test.hpp"

namespace terrastride::planner {
namespace {

using namespace testing;

TEST(SwingClearance, JacobianMatchesCentralDifferences) {
  const auto r = hyq();
  TanhStep terrain(0.1, 0.5, 0.05, 0.01);
  const SrbdProblem p(r, terrain, crawl_timeline(r), turning_crawl_options());
  EXPECT_GT(check_kind_derivatives(p, "swing_clearance"), 0);
}

// The fraction of h_min demanded t into a swing of duration T: 0 at lift-off and touch-down, 1
// from `ramp` after the one to `ramp` before the other, sin^2 in between.
double profile(double t, double T, double ramp) {
  const double edge = std::min(t, T - t), tau = std::min(ramp, T / 2);
  const double s = std::sin(M_PI / 2 * std::clamp(edge / tau, 0.0, 1.0));
  return s * s;
}

// Per swing, one piece at each of clearance_points fractions of its segments (not at lift-off):
// p_z - h(p_x + d o_x, p_y + d o_y) for o = 0, +x, -x, +y, -y and d = clearance_probe, each at
// least h_min times the profile at the point's nominal time into the swing.
TEST(SwingClearance, RowsAreTheFootsHeightAboveTheTerrainAroundIt) {
  const auto r = hyq();
  TanhStep terrain(0.1, 0.5, 0.05, 0.01);
  const ProblemOptions o = turning_crawl_options();
  SrbdProblem p(r, terrain, crawl_timeline(r), o);
  const std::vector<double> x = perturbed_guess(p, 10, 0.01);
  const Layout& L = p.layout();
  const auto pieces = pieces_added_by(p, [&] { add_swing_clearance(p); });
  const double d = o.clearance_probe;
  const Eigen::Vector2d offsets[5] = {{0, 0}, {1, 0}, {-1, 0}, {0, 1}, {0, -1}};
  std::size_t i = 0;
  double interior_bounds = 0.0;
  for (const auto& sw : L.swings) {
    const double t0 = L.nominal_knot_time[sw.first_seg];
    const double T = L.nominal_knot_time[sw.last_seg + 1] - t0;
    for (int s = sw.first_seg; s <= sw.last_seg; ++s)
      for (const double sigma : L.segment_points(s, o.clearance_points, false)) {
        if (s == sw.first_seg && sigma == 0.0) continue;
        ASSERT_LT(i, pieces.size());
        const double t_nominal =
            L.nominal_knot_time[s] + sigma * (L.nominal_knot_time[s + 1] - L.nominal_knot_time[s]);
        const double lower = o.swing_clearance * profile(t_nominal - t0, T, o.clearance_ramp);
        const auto st = p.evaluate(x, segment_start(L, x, s) + sigma * segment_length(L, x, s));
        const Eigen::Vector3d foot = st.foot_pos[sw.foot];
        const auto g = rows_at(*pieces[i], x);
        ASSERT_EQ(g.size(), 5u);
        for (int k = 0; k < 5; ++k) {
          const Eigen::Vector2d q = foot.head<2>() + d * offsets[k];
          EXPECT_NEAR(g[k], foot.z() - terrain.sample(q.x(), q.y()).height, 1e-9);
          EXPECT_NEAR(pieces[i]->lb[k], lower, 1e-12);
          EXPECT_GE(pieces[i]->ub[k], 1e19);
        }
        interior_bounds = std::max(interior_bounds, lower);
        ++i;
      }
  }
  EXPECT_EQ(i, pieces.size());
  EXPECT_NEAR(interior_bounds, o.swing_clearance, 1e-12);  // the full h_min mid-swing
}

}  // namespace
}  // namespace terrastride::planner
