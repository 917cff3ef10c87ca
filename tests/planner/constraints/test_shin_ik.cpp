// "shin_ik" (constraints/shin_ik.cpp; the shin inequality on the leg's IK shin): Jacobians against
// central differences (per-point and merged rows), and the rows against the robot's own inverse
// kinematics and knee position.
#include <cmath>

#include "family_test.hpp"
#include "terrastride/robot/leg_kinematics.hpp"

namespace terrastride::planner {
namespace {

using namespace testing;

TEST(ShinIk, JacobianMatchesCentralDifferences) {
  const auto r = hyq();
  MarginStep terrain(0.1, 0.5, 0.05, 0.01);
  ProblemOptions o = turning_crawl_options(false);
  o.constraints = {"shin_ik"};
  const SrbdProblem p(r, terrain, crawl_timeline(r), o);
  ASSERT_GT(count_kinds(p)["shin_ik"], 0);
  for (unsigned seed : {1u, 2u})
    EXPECT_GT(check_piece_derivatives(p, seed, 0.02,
                                      [](const Piece& piece) { return piece.kind == "shin_ik"; }),
              0);
}

// Both variants: 2 nk - 1 rows per knot (shin_softmin 0), and one merged row per knot.
class ShinIkVariants : public ::testing::TestWithParam<double> {};
INSTANTIATE_TEST_SUITE_P(SoftScale, ShinIkVariants, ::testing::Values(0.0, 0.003));
TEST_P(ShinIkVariants, JacobianMatchesCentralDifferences) {
  const double t_soft = GetParam();
  const auto r = hyq();
  MarginStep terrain(0.1, 0.5, 0.05, 0.01);
  SrbdProblem p(r, terrain, crawl_timeline(r), turning_crawl_options());
  FeasibilityOptions fo;
  fo.shin_softmin = t_soft;
  const auto pieces = pieces_added_by(p, [&] { build_shin_ik_set(p, fo); });
  ASSERT_FALSE(pieces.empty());
  for (const Piece* piece : pieces)
    EXPECT_EQ(piece->rows(), t_soft > 0 ? 1 : 2 * fo.shin_points - 1);
  EXPECT_GT(check_kind_derivatives(p, "shin_ik"), 0);
}

// The knee is the robot's own IK knee: at every knot, the piece's middle row (point nk - 1, the
// knee) is the height of robot::knee_position at the IK solution above the flat ground.
TEST(ShinIk, KneeIsTheIkKnee) {
  const auto r = hyq();
  FlatField flat;
  SrbdProblem p(r, flat, crawl_timeline(r), ProblemOptions{});
  FeasibilityOptions fo;
  fo.shin_clearance = 0.0;  // rows are plain heights above the flat ground
  fo.shin_softmin = 0.0;    // one row per point
  const auto pieces = pieces_added_by(p, [&] { build_shin_ik_set(p, fo); });
  const std::vector<double> x = perturbed_guess(p, 3, 0.01);
  const Layout& L = p.layout();
  int checked = 0;
  for (const Piece* piece : pieces) {
    // Which foot and knot: the piece's variables are the foot's position at a knot (3; its
    // foothold in stance, its spline knot in swing), base position (3), euler (3).
    const int pv = piece->vars[0], bv = piece->vars[3];
    int foot = -1;
    for (std::size_t f = 0; f < L.foot_pos.size(); ++f)
      for (int k = 0; k <= L.num_segments; ++k)
        if (L.foot_pos[f][k] == pv && L.base[k] == bv) foot = static_cast<int>(f);
    ASSERT_GE(foot, 0);
    const Eigen::Vector3d pf = vec3_at(x, pv), base = vec3_at(x, bv), e = vec3_at(x, bv + 6);
    const Eigen::Matrix3d R = rotation_of(e);
    const auto ik = robot::inverse_kinematics(r.legs[foot], R.transpose() * (pf - base));
    if (ik.status == robot::IkStatus::unreachable) continue;
    const Eigen::Vector3d knee = base + R * robot::knee_position(r.legs[foot], ik.q);
    const auto g = rows_at(*piece, x);
    EXPECT_NEAR(g[(g.size() - 1) / 2], knee.z(), 1e-9);  // row nk-1: the knee; flat ground z = 0
    ++checked;
  }
  EXPECT_GT(checked, 10);
}

// Merged (the default): each knot's row is the soft minimum of its 2 nk - 1 point rows.
TEST(ShinIk, MergedRowIsTheSoftMinimumOfTheKnotsPointRows) {
  const auto r = hyq();
  MarginStep terrain(0.1, 0.5, 0.05, 0.01);
  SrbdProblem p(r, terrain, crawl_timeline(r), ProblemOptions{});
  FeasibilityOptions fp, fm;
  fp.shin_softmin = 0.0;
  const auto pp = pieces_added_by(p, [&] { build_shin_ik_set(p, fp); });
  const auto mp = pieces_added_by(p, [&] { build_shin_ik_set(p, fm); });
  ASSERT_GT(fm.shin_softmin, 0.0);
  const std::vector<double> x = perturbed_guess(p, 7, 0.01);
  ASSERT_EQ(pp.size(), mp.size());
  ASSERT_GT(pp.size(), 10u);
  for (std::size_t i = 0; i < pp.size(); ++i) {
    ASSERT_EQ(pp[i]->vars, mp[i]->vars);
    const auto g = rows_at(*pp[i], x);
    const double merged = rows_at(*mp[i], x)[0];
    double mn = 1e300, sum = 0.0;
    for (double v : g) mn = std::min(mn, v);
    for (double v : g) sum += std::exp(-(v - mn) / fm.shin_softmin);
    EXPECT_NEAR(merged, mn - fm.shin_softmin * std::log(sum), 1e-12);
    EXPECT_LE(merged, mn);
  }
}

}  // namespace
}  // namespace terrastride::planner
