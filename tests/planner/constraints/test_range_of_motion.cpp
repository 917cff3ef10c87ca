// "range_of_motion" (constraints/range_of_motion.cpp): Jacobians against central differences, and
// the rows against each foot's position in the base frame from the continuous-time solution.
#include "family_test.hpp"

namespace terrastride::planner {
namespace {

using namespace testing;

TEST(RangeOfMotion, JacobianMatchesCentralDifferences) {
  const auto r = hyq();
  TanhStep terrain(0.1, 0.5, 0.05, 0.01);
  const SrbdProblem p(r, terrain, crawl_timeline(r), turning_crawl_options());
  EXPECT_GT(check_kind_derivatives(p, "range_of_motion"), 0);
}

// Per segment and foot, one piece at each of rom_points fractions (twice as many in swing; the
// segment's end only in the last segment): R^T (p_foot - r) - nominal_foot, within
// +-range_of_motion.
TEST(RangeOfMotion, RowsAreTheFootInTheBaseFrameAroundItsNominalPosition) {
  const auto r = hyq();
  TanhStep terrain(0.1, 0.5, 0.05, 0.01);
  const ProblemOptions o = turning_crawl_options();
  SrbdProblem p(r, terrain, crawl_timeline(r), o);
  const std::vector<double> x = perturbed_guess(p, 6, 0.01);
  const Layout& L = p.layout();
  const int S = L.num_segments;
  int checked = 0;
  for (int s = 0; s < S; ++s) {
    const auto pieces = pieces_added_by(p, [&] { add_range_of_motion(p, s); });
    std::size_t i = 0;
    for (std::size_t f = 0; f < r.legs.size(); ++f) {
      const int n = o.rom_points * (L.contact[f][s] ? 1 : 2);
      for (const double sigma : L.segment_points(s, n, s == S - 1)) {
        ASSERT_LT(i, pieces.size());
        const auto st = p.evaluate(x, segment_start(L, x, s) + sigma * segment_length(L, x, s));
        const Eigen::Vector3d expected =
            rotation_of(st.euler).transpose() * (st.foot_pos[f] - st.pos) - r.legs[f].nominal_foot;
        const auto g = rows_at(*pieces[i], x);
        for (int d = 0; d < 3; ++d) {
          EXPECT_NEAR(g[d], expected[d], 1e-9) << "segment " << s << " foot " << f;
          EXPECT_EQ(pieces[i]->ub[d], r.legs[f].range_of_motion[d]);
          EXPECT_EQ(pieces[i]->lb[d], -r.legs[f].range_of_motion[d]);
        }
        ++i;
        ++checked;
      }
    }
    EXPECT_EQ(i, pieces.size());
  }
  EXPECT_GT(checked, 50);
}

}  // namespace
}  // namespace terrastride::planner
