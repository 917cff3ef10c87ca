// "stance_height" (constraints/stance_height.cpp): Jacobians against central differences, and the
// rows against the terrain's height under each free stance foothold.
#include "family_test.hpp"

namespace terrastride::planner {
namespace {

using namespace testing;

TEST(StanceHeight, JacobianMatchesCentralDifferences) {
  const auto r = hyq();
  TanhStep terrain(0.1, 0.5, 0.05, 0.01);
  const SrbdProblem p(r, terrain, crawl_timeline(r), turning_crawl_options());
  EXPECT_GT(check_kind_derivatives(p, "stance_height"), 0);
}

// One piece per stance that is not the initial one: p_z - h(p_x, p_y) = 0.
TEST(StanceHeight, RowsAreTheFootholdsHeightAboveTheTerrain) {
  const auto r = hyq();
  TanhStep terrain(0.1, 0.5, 0.05, 0.01);
  SrbdProblem p(r, terrain, crawl_timeline(r), turning_crawl_options());
  const std::vector<double> x = perturbed_guess(p, 7, 0.02);
  const auto pieces = pieces_added_by(p, [&] { add_stance_height(p); });
  std::size_t i = 0;
  for (const auto& st : p.layout().stances) {
    if (st.fixed) continue;
    ASSERT_LT(i, pieces.size());
    const Eigen::Vector3d foot = vec3_at(x, st.pos_var);
    const auto g = rows_at(*pieces[i], x);
    ASSERT_EQ(g.size(), 1u);
    EXPECT_NEAR(g[0], foot.z() - terrain.sample(foot.x(), foot.y()).height, 1e-12);
    EXPECT_EQ(pieces[i]->lb[0], 0.0);
    EXPECT_EQ(pieces[i]->ub[0], 0.0);
    ++i;
  }
  EXPECT_EQ(i, pieces.size());
  EXPECT_GT(i, 3u);
}

}  // namespace
}  // namespace terrastride::planner
