// "friction" (constraints/friction.cpp): Jacobians against central differences, and the rows
// against the force in the terrain's normal frame at its foothold.
#include "family_test.hpp"

namespace terrastride::planner {
namespace {

using namespace testing;

TEST(Friction, JacobianMatchesCentralDifferences) {
  const auto r = hyq();
  TanhStep terrain(0.1, 0.5, 0.05, 0.01);
  const SrbdProblem p(r, terrain, crawl_timeline(r), turning_crawl_options());
  EXPECT_GT(check_kind_derivatives(p, "friction"), 0);
}

// One piece per force knot (a knot shared by two stance segments once), five rows in body
// weights: f_n in [0, f_max], and +-f_t1 - mu f_n, +-f_t2 - mu f_n <= 0, with n the terrain's
// unit normal at the foothold, t1 its unit tangent along x and t2 = n x t1.
TEST(Friction, RowsAreThePyramidInTheTerrainNormalFrame) {
  const auto r = hyq();
  TanhStep terrain(0.1, 0.5, 0.05, 0.01);
  const ProblemOptions o = turning_crawl_options();
  SrbdProblem p(r, terrain, crawl_timeline(r), o);
  const std::vector<double> x = perturbed_guess(p, 9, 0.05);
  const Layout& L = p.layout();
  const double mg = r.mass * 9.81;
  const auto pieces = pieces_added_by(p, [&] { add_friction(p); });
  std::size_t i = 0;
  for (std::size_t f = 0; f < r.legs.size(); ++f) {
    int last = -1;
    for (int s = 0; s < L.num_segments; ++s)
      for (int side = 0; side < 2; ++side) {
        const int fv = L.force[f][s][side];
        if (fv < 0 || fv == last) continue;
        last = fv;
        ASSERT_LT(i, pieces.size());
        const Eigen::Vector3d foot = vec3_at(x, L.foot_pos[f][s]);
        const auto hs = terrain.sample(foot.x(), foot.y());
        const Eigen::Vector3d n =
            Eigen::Vector3d(-hs.gradient.x(), -hs.gradient.y(), 1.0).normalized();
        const Eigen::Vector3d t1 = Eigen::Vector3d(1.0, 0.0, hs.gradient.x()).normalized();
        const Eigen::Vector3d t2 = n.cross(t1);
        const Eigen::Vector3d force = vec3_at(x, fv) / mg;
        const double fn = n.dot(force), a = t1.dot(force), c = t2.dot(force);
        const double expected[5] = {fn, a - o.friction * fn, -a - o.friction * fn,
                                    c - o.friction * fn, -c - o.friction * fn};
        const auto g = rows_at(*pieces[i], x);
        ASSERT_EQ(g.size(), 5u);
        for (int k = 0; k < 5; ++k) EXPECT_NEAR(g[k], expected[k], 1e-12) << "foot " << f;
        EXPECT_EQ(pieces[i]->lb[0], 0.0);
        EXPECT_NEAR(pieces[i]->ub[0], o.max_normal_force_factor, 1e-15);
        for (int k = 1; k < 5; ++k) EXPECT_EQ(pieces[i]->ub[k], 0.0);
        ++i;
      }
  }
  EXPECT_EQ(i, pieces.size());
}

}  // namespace
}  // namespace terrastride::planner
