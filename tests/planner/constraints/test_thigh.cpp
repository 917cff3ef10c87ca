// "thigh" (constraints/thigh.cpp; the thigh capsule, HFE joint to knee, above the terrain where it
// is tall): Jacobians against central differences (per-point and merged rows), pieces only near
// tall terrain, and the rows against the robot's own kinematic chain.
#include <cmath>

#include "family_test.hpp"
#include "terrastride/robot/leg_kinematics.hpp"

namespace terrastride::planner {
namespace {

using namespace testing;

class ThighVariants : public ::testing::TestWithParam<double> {};
INSTANTIATE_TEST_SUITE_P(SoftScale, ThighVariants, ::testing::Values(0.0, 0.003));
TEST_P(ThighVariants, JacobianMatchesCentralDifferences) {
  const auto r = hyq();
  MarginStep terrain(0.1, 0.5, 0.05, 0.01);  // a 10 cm step within reach of the front feet
  SrbdProblem p(r, terrain, crawl_timeline(r), turning_crawl_options());
  FeasibilityOptions fo;
  fo.shin_softmin = GetParam();
  const auto pieces = pieces_added_by(p, [&] { build_thigh_set(p, fo); });
  ASSERT_FALSE(pieces.empty());
  for (const Piece* piece : pieces)
    EXPECT_EQ(piece->rows(), GetParam() > 0 ? 1 : 4 * fo.thigh_points - 1);
  EXPECT_GT(check_kind_derivatives(p, "thigh"), 0);
  EXPECT_GT(largest_jacobian_entry(p, "thigh"), 0.1);
}

// On flat ground the thigh is a leg length above the terrain: no pieces at all (the flat plans
// pay nothing for the set).
TEST(Thigh, NoPiecesOnFlatGround) {
  const auto r = hyq();
  FlatField flat;
  SrbdProblem p(r, flat, crawl_timeline(r), turning_crawl_options());
  EXPECT_TRUE(pieces_added_by(p, [&] { build_thigh_set(p, {}); }).empty());
}

// The rows are the chain's HFE joint and knee (robot::hfe_position, robot::knee_position at the
// IK angles) above the terrain, by the capsule's radius over the cosine of the thigh's
// inclination (capped at 0.5), the radius grown by leg_capsule_margin: row 0 is the HFE joint,
// row 2 nk - 3 the knee (no probes). (Knot pieces with 9 variables: a swing knot or a stance's
// first knot, where the foot has not rolled yet.)
TEST(Thigh, RowsAreTheChainsThighAboveTheTerrain) {
  const auto r = hyq();
  MarginStep terrain(0.1, 0.5, 0.05, 0.01);
  SrbdProblem p(r, terrain, crawl_timeline(r), turning_crawl_options(false));
  FeasibilityOptions fo;
  fo.shin_softmin = 0.0;
  fo.leg_probe_margin = -1.0;
  const auto pieces = pieces_added_by(p, [&] { build_thigh_set(p, fo); });
  const std::vector<double> x = perturbed_guess(p, 5, 0.01);
  const Layout& L = p.layout();
  const int nk = fo.thigh_points;
  int checked = 0;
  for (const Piece* piece : pieces) {
    if (piece->vars.size() != 9) continue;  // knot pieces: foot (3), base (3), euler (3)
    const int pv = piece->vars[0], bv = piece->vars[3];
    int foot = -1;
    for (std::size_t f = 0; f < L.foot_pos.size(); ++f)
      for (int k = 0; k <= L.num_segments; ++k)
        if (L.foot_pos[f][k] == pv && L.base[k] == bv) foot = static_cast<int>(f);
    ASSERT_GE(foot, 0);
    const robot::LegModel& leg = r.legs[foot];
    const Eigen::Vector3d pf = vec3_at(x, pv), base = vec3_at(x, bv), e = vec3_at(x, bv + 6);
    const Eigen::Matrix3d R = rotation_of(e);
    const auto ik = robot::inverse_kinematics(leg, R.transpose() * (pf - base));
    if (ik.status == robot::IkStatus::unreachable) continue;
    const Eigen::Vector3d hfe = base + R * robot::hfe_position(leg, ik.q);
    const Eigen::Vector3d knee = base + R * robot::knee_position(leg, ik.q);
    const Eigen::Vector3d d = knee - hfe;
    const double gap = (leg.thigh_radius + fo.leg_capsule_margin) / std::max(0.5, d.head<2>().norm() / d.norm());
    const auto g = rows_at(*piece, x);
    ASSERT_EQ(static_cast<int>(g.size()), 2 * nk - 1);
    EXPECT_NEAR(g[0], hfe.z() - terrain.height(hfe.x(), hfe.y()) - gap, 1e-6);
    EXPECT_NEAR(g[2 * nk - 3], knee.z() - terrain.height(knee.x(), knee.y()) - gap, 1e-6);
    ++checked;
  }
  EXPECT_GT(checked, 5);
}

}  // namespace
}  // namespace terrastride::planner
