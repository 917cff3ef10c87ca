// "foothold_planarity" (constraints/foothold_planarity.cpp): Jacobians against central
// differences, and the rows against the terrain's departure from its tangent plane.
#include "family_test.hpp"

namespace terrastride::planner {
namespace {

using namespace testing;

TEST(FootholdPlanarity, JacobianMatchesCentralDifferences) {
  const auto r = hyq();
  TanhStep terrain(0.1, 0.5, 0.05, 0.01);
  const SrbdProblem p(r, terrain, crawl_timeline(r), turning_crawl_options());
  EXPECT_GT(check_kind_derivatives(p, "foothold_planarity"), 0);
}

// One piece per free stance, four rows: h(p + d o) - h(p) - d grad h(p) . o for o = +x, -x, +y,
// -y and d = clearance_probe, within +-foothold_planarity.
TEST(FootholdPlanarity, RowsAreTheTerrainsDepartureFromItsTangentPlane) {
  const auto r = hyq();
  TanhStep terrain(0.1, 0.5, 0.05, 0.01);
  const ProblemOptions o = turning_crawl_options();
  SrbdProblem p(r, terrain, crawl_timeline(r), o);
  const std::vector<double> x = perturbed_guess(p, 8, 0.05);
  const auto pieces = pieces_added_by(p, [&] { add_foothold_planarity(p); });
  const double d = o.clearance_probe;
  const Eigen::Vector2d offsets[4] = {{1, 0}, {-1, 0}, {0, 1}, {0, -1}};
  std::size_t i = 0;
  double largest = 0.0;
  for (const auto& st : p.layout().stances) {
    if (st.fixed) continue;
    ASSERT_LT(i, pieces.size());
    const Eigen::Vector3d foot = vec3_at(x, st.pos_var);
    const auto s0 = terrain.sample(foot.x(), foot.y());
    const auto g = rows_at(*pieces[i], x);
    ASSERT_EQ(g.size(), 4u);
    for (int k = 0; k < 4; ++k) {
      const Eigen::Vector2d q = foot.head<2>() + d * offsets[k];
      const double expected =
          terrain.sample(q.x(), q.y()).height - s0.height - d * s0.gradient.dot(offsets[k]);
      EXPECT_NEAR(g[k], expected, 1e-12);
      EXPECT_EQ(pieces[i]->ub[k], o.foothold_planarity);
      EXPECT_EQ(pieces[i]->lb[k], -o.foothold_planarity);
      largest = std::max(largest, std::abs(expected));
    }
    ++i;
  }
  EXPECT_EQ(i, pieces.size());
  EXPECT_GT(largest, 1e-4);  // some foothold near the step, where the rows are not all zero
}

// foothold_planarity = 0 (or no probe) turns the family off.
TEST(FootholdPlanarity, ZeroToleranceMeansNoRows) {
  const auto r = hyq();
  FlatField flat;
  ProblemOptions o = turning_crawl_options();
  o.foothold_planarity = 0.0;
  SrbdProblem p(r, flat, crawl_timeline(r), o);
  EXPECT_EQ(count_kinds(p).count("foothold_planarity"), 0u);
}

}  // namespace
}  // namespace terrastride::planner
