// "dynamics_linear" (constraints/dynamics_linear.cpp): Jacobians against central differences, and
// the rows against Newton's law evaluated from the base knots' cubic Hermite segment.
#include "family_test.hpp"

namespace terrastride::planner {
namespace {

using namespace testing;

TEST(DynamicsLinear, JacobianMatchesCentralDifferences) {
  const auto r = hyq();
  TanhStep terrain(0.1, 0.5, 0.05, 0.01);
  const SrbdProblem p(r, terrain, crawl_timeline(r), turning_crawl_options());
  EXPECT_GT(check_kind_derivatives(p, "dynamics_linear"), 0);
}

// Per segment two pieces, its start and its end: (m r'' + m g e_z - sum of the stance forces at
// that knot) / m g, with r'' the second derivative of the base's cubic Hermite segment there.
TEST(DynamicsLinear, RowsAreNewtonsLawAtTheSegmentEndsInBodyWeights) {
  const auto r = hyq();
  TanhStep terrain(0.1, 0.5, 0.05, 0.01);
  SrbdProblem p(r, terrain, crawl_timeline(r), turning_crawl_options());
  const std::vector<double> x = perturbed_guess(p, 4, 0.02);
  const Layout& L = p.layout();
  const double mg = r.mass * 9.81;
  for (int s = 0; s < L.num_segments; ++s) {
    const auto pieces = pieces_added_by(p, [&] { add_dynamics_linear(p, s); });
    ASSERT_EQ(pieces.size(), 2u);
    const double h = segment_length(L, x, s);
    const Eigen::Vector3d p0 = vec3_at(x, L.base[s]), v0 = vec3_at(x, L.base[s] + 3),
                          p1 = vec3_at(x, L.base[s + 1]), v1 = vec3_at(x, L.base[s + 1] + 3);
    for (int side = 0; side < 2; ++side) {
      const Eigen::Vector3d acc =
          side == 0 ? Eigen::Vector3d(6 * (p1 - p0) / (h * h) - (4 * v0 + 2 * v1) / h)
                    : Eigen::Vector3d(-6 * (p1 - p0) / (h * h) + (2 * v0 + 4 * v1) / h);
      Eigen::Vector3d expected = r.mass * acc + Eigen::Vector3d(0, 0, mg);
      for (std::size_t f = 0; f < r.legs.size(); ++f)
        if (L.force[f][s][side] >= 0) expected -= vec3_at(x, L.force[f][s][side]);
      const auto g = rows_at(*pieces[side], x);
      ASSERT_EQ(g.size(), 3u);
      for (int d = 0; d < 3; ++d) {
        EXPECT_NEAR(g[d], expected[d] / mg, 1e-9) << "segment " << s << " side " << side;
        EXPECT_EQ(pieces[side]->lb[d], 0.0);
        EXPECT_EQ(pieces[side]->ub[d], 0.0);
      }
    }
  }
}

// The monoped's base moves only vertically: one row, the vertical one.
TEST(DynamicsLinear, OnlyTheFreeDirectionsOfTheBaseHaveRows) {
  const auto r = robot::load_robot(robot::resolve_robot_path("monoped"));
  FlatField flat;
  ProblemOptions o;
  o.gait = "hop";
  const PhaseTimeline tl = make_timeline(load_gait(resolve_gait_path("hop")), feet_of(r), 1, 0.0);
  SrbdProblem p(r, flat, tl, o);
  const std::vector<double> x = perturbed_guess(p, 2, 0.01);
  const Layout& L = p.layout();
  const auto pieces = pieces_added_by(p, [&] { add_dynamics_linear(p, 0); });
  ASSERT_EQ(pieces.size(), 2u);
  const double h = segment_length(L, x, 0);
  const double z0 = x[L.base[0] + 2], w0 = x[L.base[0] + 5], z1 = x[L.base[1] + 2],
               w1 = x[L.base[1] + 5];
  double expected = r.mass * (6 * (z1 - z0) / (h * h) - (4 * w0 + 2 * w1) / h) + r.mass * 9.81;
  if (L.force[0][0][0] >= 0) expected -= x[L.force[0][0][0] + 2];
  const auto g = rows_at(*pieces[0], x);
  ASSERT_EQ(g.size(), 1u);
  EXPECT_NEAR(g[0], expected / (r.mass * 9.81), 1e-9);
  EXPECT_GT(check_kind_derivatives(p, "dynamics_linear", 0.01), 0);
}

}  // namespace
}  // namespace terrastride::planner
