// "trunk" (constraints/trunk.cpp; the trunk box's bottom face above tall terrain): Jacobians
// against central differences (per-point and merged rows), no pieces where the terrain is low or
// for a robot without a trunk, and the rows against the box corners of robot/geometry.hpp.
#include <cmath>

#include "family_test.hpp"
#include "terrastride/robot/geometry.hpp"

namespace terrastride::planner {
namespace {

using namespace testing;

// A 0.4 m rise under the trunk's front half (the crawl's base stands 0.58 m up, the box's bottom
// about 0.5 m): tall by the set's rule, not touching at the initial guess.
TanhStep tall_step() { return TanhStep(0.4, 0.3, 0.05, 0.01); }

class TrunkVariants : public ::testing::TestWithParam<double> {};
INSTANTIATE_TEST_SUITE_P(SoftScale, TrunkVariants, ::testing::Values(0.0, 0.003));
TEST_P(TrunkVariants, JacobianMatchesCentralDifferences) {
  const auto r = hyq();
  ASSERT_TRUE(r.has_trunk());
  const TanhStep terrain = tall_step();
  SrbdProblem p(r, terrain, crawl_timeline(r), turning_crawl_options());
  FeasibilityOptions fo;
  fo.shin_softmin = GetParam();
  const auto pieces = pieces_added_by(p, [&] { build_trunk_set(p, fo); });
  ASSERT_FALSE(pieces.empty());
  for (const Piece* piece : pieces) EXPECT_EQ(piece->vars.size(), 6u);  // base position, euler
  EXPECT_GT(check_kind_derivatives(p, "trunk"), 0);
  EXPECT_GT(largest_jacobian_entry(p, "trunk"), 0.1);
}

// Flat ground and the 15 cm pallet are far below the trunk: no rows (those plans pay nothing).
TEST(Trunk, NoPiecesWhereTheTerrainIsLow) {
  const auto r = hyq();
  FlatField flat;
  TanhStep pallet(0.15, 0.5, 0.01);
  for (const terrain::HeightField* t : {static_cast<const terrain::HeightField*>(&flat),
                                        static_cast<const terrain::HeightField*>(&pallet)}) {
    SrbdProblem p(r, *t, crawl_timeline(r), turning_crawl_options());
    EXPECT_TRUE(pieces_added_by(p, [&] { build_trunk_set(p, {}); }).empty()) << t->describe();
  }
}

// The first and last grid points are corners 0 (-x, -y, bottom) and 3 (+x, +y, bottom) of
// robot::trunk_corner_world, each above the terrain under it (unmerged rows, no margin).
TEST(Trunk, RowsAreTheBoxCornersAboveTheTerrain) {
  const auto r = hyq();
  const TanhStep terrain = tall_step();
  SrbdProblem p(r, terrain, crawl_timeline(r), turning_crawl_options(false));
  FeasibilityOptions fo;
  fo.shin_softmin = 0.0;
  fo.trunk_margin = 0.0;
  const auto pieces = pieces_added_by(p, [&] { build_trunk_set(p, fo); });
  ASSERT_GT(pieces.size(), 3u);
  const std::vector<double> x = perturbed_guess(p, 9, 0.02);
  // The rows of one knot (66 points on HyQ: pieces of at most 64 rows over the same variables).
  for (std::size_t i = 0; i < pieces.size();) {
    std::vector<double> g;
    std::size_t j = i;
    for (; j < pieces.size() && pieces[j]->vars == pieces[i]->vars; ++j) {
      const auto gj = rows_at(*pieces[j], x);
      g.insert(g.end(), gj.begin(), gj.end());
      EXPECT_DOUBLE_EQ(pieces[j]->lb[0], 0.0);
    }
    const Eigen::Vector3d base = vec3_at(x, pieces[i]->vars[0]), e = vec3_at(x, pieces[i]->vars[3]);
    const Eigen::Vector3d c0 = robot::trunk_corner_world<double>(*r.trunk, 0, base, e);
    const Eigen::Vector3d c3 = robot::trunk_corner_world<double>(*r.trunk, 3, base, e);
    EXPECT_NEAR(g.front(), c0.z() - terrain.height(c0.x(), c0.y()), 1e-9);
    EXPECT_NEAR(g.back(), c3.z() - terrain.height(c3.x(), c3.y()), 1e-9);
    i = j;
  }
}

}  // namespace
}  // namespace terrastride::planner
