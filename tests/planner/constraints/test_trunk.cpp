// "trunk" (constraints/trunk.cpp; the trunk box's bottom face above tall terrain, its top face
// under an overhang): Jacobians against central differences (per-point and merged rows), no
// pieces where the terrain is low and nothing is overhead or for a robot without a trunk, the rows
// against the box corners of robot/geometry.hpp, and the refusal of a trunk that cannot pass
// under an overhang.
#include <cmath>
#include <limits>

#include "family_test.hpp"
#include "terrastride/planner/reachability.hpp"
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

// Flat ground under a smooth ceiling: o = U + A tanh((x - x0) / w) + a small ripple in x and y
// (every derivative path exercised; amplitude `ripple`), for x >= x_from (+infinity before: nothing
// overhead there).
class Ceiling : public FlatField {
 public:
  Ceiling(double U, double A = 0.0, double x_from = -1e9, double ripple = 0.01)
      : U_(U), A_(A), from_(x_from), r_(ripple) {}
  double overhead_and_gradient(double x, double y, Eigen::Vector2d* g) const override {
    g->setZero();
    if (x < from_) return std::numeric_limits<double>::infinity();
    const double th = std::tanh((x - 0.2) / 0.1);
    g->x() = A_ * (1.0 - th * th) / 0.1 - 2.0 * r_ * std::sin(2.0 * x) * std::sin(3.0 * y);
    g->y() = 3.0 * r_ * std::cos(2.0 * x) * std::cos(3.0 * y);
    return U_ + A_ * th + r_ * std::cos(2.0 * x) * std::sin(3.0 * y);
  }
  std::string describe() const override { return "flat under a ceiling"; }

 private:
  double U_, A_, from_, r_;
};

robot::RobotModel load_go2() {
  return robot::load_robot(robot::resolve_robot_path("go2"));
}

// The top face's rows where something is overhead (0.8 m +- 5 cm over HyQ's 0.68 m top): the
// pieces hold the base position and orientation, and their Jacobians match central differences.
TEST_P(TrunkVariants, TopFaceJacobianMatchesCentralDifferences) {
  const auto r = hyq();
  const Ceiling terrain(0.8, 0.05);
  SrbdProblem p(r, terrain, crawl_timeline(r), turning_crawl_options());
  FeasibilityOptions fo;
  fo.shin_softmin = GetParam();
  const auto pieces = pieces_added_by(p, [&] { build_trunk_set(p, fo); });
  ASSERT_FALSE(pieces.empty());  // flat ground: all of them are the top face's
  for (const Piece* piece : pieces) EXPECT_EQ(piece->vars.size(), 6u);
  EXPECT_GT(check_kind_derivatives(p, "trunk"), 0);
  EXPECT_GT(largest_jacobian_entry(p, "trunk"), 0.1);
}

// Unmerged and without margin, a knot's first and last top rows are the overhang's clearance
// above the top face's corners (-x, -y) and (+x, +y); where nothing is overhead (x < 0.1 here)
// a point's row is the cap, 1 m, so no row reads infinity.
TEST(Trunk, TopRowsAreTheOverheadAboveTheTopCorners) {
  const auto r = hyq();
  const Ceiling terrain(0.8, 0.05, 0.1);
  SrbdProblem p(r, terrain, crawl_timeline(r), turning_crawl_options(false));
  FeasibilityOptions fo;
  fo.shin_softmin = 0.0;
  fo.trunk_margin = 0.0;
  const auto pieces = pieces_added_by(p, [&] { build_trunk_set(p, fo); });
  ASSERT_GT(pieces.size(), 3u);
  const std::vector<double> x = perturbed_guess(p, 9, 0.02);
  int capped = 0;
  for (std::size_t i = 0; i < pieces.size();) {
    std::vector<double> g;
    std::size_t j = i;
    for (; j < pieces.size() && pieces[j]->vars == pieces[i]->vars; ++j) {
      const auto gj = rows_at(*pieces[j], x);
      g.insert(g.end(), gj.begin(), gj.end());
    }
    const Eigen::Vector3d base = vec3_at(x, pieces[i]->vars[0]), e = vec3_at(x, pieces[i]->vars[3]);
    // Corners 4 and 7: (-x, -y, top) and (+x, +y, top) of robot::trunk_corner_world.
    const Eigen::Vector3d c4 = robot::trunk_corner_world<double>(*r.trunk, 4, base, e);
    const Eigen::Vector3d c7 = robot::trunk_corner_world<double>(*r.trunk, 7, base, e);
    auto expected = [&](const Eigen::Vector3d& c) {
      return std::min(terrain.overhead(c.x(), c.y()) - c.z(), 1.0);
    };
    EXPECT_NEAR(g.front(), expected(c4), 1e-9);
    EXPECT_NEAR(g.back(), expected(c7), 1e-9);
    for (double v : g) {
      EXPECT_TRUE(std::isfinite(v));
      capped += v == 1.0;
    }
    i = j;
  }
  EXPECT_GT(capped, 0);
}

// Under a ceiling 0.6 m up HyQ cannot walk: with a foot in the air its base stands at least
// 0.48 + 0.05 m up (range-of-motion box, swing clearance), its trunk's top 0.10 m higher. It is
// refused before any solve, naming the trunk and the overhang; Go2 (top at most 0.38 m up) gets
// its rows. Go2's limit is 0.355 m: 0.237 m (box) + 0.05 m (swing) + 0.078 m (top) + 0.02 m
// (margin) less 0.03 m of solver slack.
TEST(Trunk, ARobotTooTallForTheOverhangIsRefused) {
  const auto big = hyq(), small = load_go2();
  const Ceiling low(0.6, 0.0, -1e9, 0.0);
  SrbdProblem p(big, low, crawl_timeline(big), turning_crawl_options());
  try {
    build_trunk_set(p, {});
    FAIL() << "HyQ was not refused under a 0.6 m ceiling";
  } catch (const UnreachableRequest& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("trunk"), std::string::npos) << what;
    EXPECT_NE(what.find("overhang"), std::string::npos) << what;
    EXPECT_NE(what.find("0.60 m above the walkable surface"), std::string::npos) << what;
  }
  SrbdProblem q(small, low, crawl_timeline(small), turning_crawl_options());
  EXPECT_FALSE(pieces_added_by(q, [&] { build_trunk_set(q, {}); }).empty());
  // Ahead of its start (which stands at its nominal height, the top 0.377 m up).
  const Ceiling at_limit(0.36, 0.0, 0.4, 0.0), below(0.35, 0.0, 0.4, 0.0);
  SrbdProblem a(small, at_limit, crawl_timeline(small), turning_crawl_options());
  EXPECT_NO_THROW(build_trunk_set(a, {}));
  SrbdProblem b(small, below, crawl_timeline(small), turning_crawl_options());
  EXPECT_THROW(build_trunk_set(b, {}), UnreachableRequest);
}

// HyQ's fixed start (base 0.58 m up, the box's top 0.68 m) under a 0.66 m ceiling: low enough
// for its crouch (0.62 m), but the start stands in it and no solve can move the start.
TEST(Trunk, AStartInsideAnOverhangIsRefused) {
  const auto r = hyq();
  const Ceiling ceiling(0.66, 0.0, -1e9, 0.0);
  SrbdProblem p(r, ceiling, crawl_timeline(r), turning_crawl_options());
  try {
    build_trunk_set(p, {});
    FAIL() << "a start inside the overhang was not refused";
  } catch (const UnreachableRequest& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("at the start"), std::string::npos) << what;
    EXPECT_NE(what.find("0.66 m above the walkable surface"), std::string::npos) << what;
  }
  const Ceiling high(0.72, 0.0, -1e9, 0.0);
  SrbdProblem q(r, high, crawl_timeline(r), turning_crawl_options());
  EXPECT_FALSE(pieces_added_by(q, [&] { build_trunk_set(q, {}); }).empty());
}

}  // namespace
}  // namespace terrastride::planner
