// "shin" (constraints/shin.cpp; the paper's shin collision, fixed-angle shin): Jacobians against
// central differences (per-point and merged rows), and the rows against the paper's inequality
// evaluated from the continuous-time solution.
#include <cmath>

#include "family_test.hpp"

namespace terrastride::planner {
namespace {

using namespace testing;

TEST(Shin, JacobianMatchesCentralDifferences) {
  const auto r = hyq();
  MarginStep terrain(0.1, 0.5, 0.05, 0.01);
  ProblemOptions o = turning_crawl_options();
  o.constraints = {"shin"};
  const SrbdProblem p(r, terrain, crawl_timeline(r), o);
  ASSERT_GT(count_kinds(p)["shin"], 0);
  EXPECT_GT(check_kind_derivatives(p, "shin"), 0);
  EXPECT_GT(largest_jacobian_entry(p, "shin"), 0.1);  // not vacuous
}

// Both variants: a row per point (shin_softmin 0), and one merged row per stance segment.
class ShinVariants : public ::testing::TestWithParam<double> {};
INSTANTIATE_TEST_SUITE_P(SoftScale, ShinVariants, ::testing::Values(0.0, 0.003));
TEST_P(ShinVariants, JacobianMatchesCentralDifferences) {
  const double t_soft = GetParam();
  const auto r = hyq();
  MarginStep terrain(0.1, 0.5, 0.05, 0.01);
  SrbdProblem p(r, terrain, crawl_timeline(r), turning_crawl_options());
  FeasibilityOptions fo;
  fo.shin_softmin = t_soft;
  const auto pieces = pieces_added_by(p, [&] { build_shin_set(p, fo); });
  ASSERT_FALSE(pieces.empty());
  for (const Piece* piece : pieces) EXPECT_EQ(piece->rows(), t_soft > 0 ? 1 : fo.shin_points);
  EXPECT_GT(check_kind_derivatives(p, "shin"), 0);
}

TEST(Shin, MonopedJacobianMatchesCentralDifferences) {
  const auto r = robot::load_robot(robot::resolve_robot_path("monoped"));
  MarginStep terrain(0.0, 0.5, 0.05, 0.01);
  ProblemOptions o;
  o.gait = "hop";
  o.optimize_timing = true;
  o.constraints = {"shin"};
  const PhaseTimeline tl = make_timeline(load_gait(resolve_gait_path("hop")), feet_of(r), 1, 0.0);
  const SrbdProblem p(r, terrain, tl, o);
  EXPECT_GT(
      check_piece_derivatives(p, 5u, 0.01, [](const Piece& piece) { return piece.kind == "shin"; }),
      0);
}

// The paper's points k = 1/3, 2/3, 1 along the 0.3 m shin at the yaw of each stance knot:
// p_z + k s sin(beta) - h(q_k) for q_k = p + k s cos(beta) (cos psi, sin psi). One row per point
// and yaw point only at the knots, so the smallest row is the smallest of these values.
TEST(Shin, RowsAreThePapersShinInequality) {
  const auto r = hyq();
  MarginStep terrain(0.1, 0.5, 0.05, 0.01);
  SrbdProblem p(r, terrain, crawl_timeline(r), paper_test_options());
  const std::vector<double> x = perturbed_guess(p, 11, 0.01);
  FeasibilityOptions fo;
  fo.shin_yaw_points = 1;
  fo.shin_points = 3;
  fo.shin_exclusion = 0.1;  // k = 1/3, 2/3, 1 on the 0.3 m shin, as in the paper
  fo.shin_softmin = 0.0;    // one row per point, so the extremes compare exactly
  const auto pieces = pieces_added_by(p, [&] { build_shin_set(p, fo); });
  double piece_min = 1e300;
  for (const Piece* piece : pieces)
    for (double v : rows_at(*piece, x)) piece_min = std::min(piece_min, v);
  const Layout& L = p.layout();
  double formula_min = 1e300;
  for (const auto& st : L.stances) {
    const auto& leg = r.legs[st.foot];
    const Eigen::Vector3d pf = vec3_at(x, st.pos_var);
    for (int k = st.first_seg; k <= st.last_seg + 1; ++k) {
      const double t =
          k == st.last_seg + 1 ? segment_start(L, x, k) - 1e-9 : segment_start(L, x, k);
      const double psi = p.evaluate(x, t).euler[0];
      for (int j = 1; j <= 3; ++j) {
        const double a = j / 3.0 * leg.shin_length;
        const double qx = pf.x() + a * std::cos(leg.shin_angle) * std::cos(psi);
        const double qy = pf.y() + a * std::cos(leg.shin_angle) * std::sin(psi);
        formula_min =
            std::min(formula_min, pf.z() + a * std::sin(leg.shin_angle) - terrain.height(qx, qy));
      }
    }
  }
  EXPECT_NEAR(piece_min, formula_min, 1e-7);
}

// Each merged row is the soft minimum of the per-point rows of its stance segment (so it lies
// below every one of them).
TEST(Shin, MergedRowIsTheSoftMinimumOfTheSegmentsPointRows) {
  const auto r = hyq();
  MarginStep terrain(0.1, 0.5, 0.05, 0.01);
  SrbdProblem p(r, terrain, crawl_timeline(r), paper_test_options());
  const std::vector<double> x = perturbed_guess(p, 5, 0.01);
  FeasibilityOptions fp, fm;
  fp.shin_softmin = 0.0;
  fm.shin_softmin = 0.004;
  const auto pp = pieces_added_by(p, [&] { build_shin_set(p, fp); });
  const auto mp = pieces_added_by(p, [&] { build_shin_set(p, fm); });
  // Per stance segment: shin_yaw_points pieces (one more in the stance's last segment).
  const int ny = fp.shin_yaw_points;
  std::size_t next = 0, m = 0;
  for (const auto& st : p.layout().stances) {
    if (!(r.legs[st.foot].shin_length > 0.0)) continue;
    for (int seg = st.first_seg; seg <= st.last_seg; ++seg, ++m) {
      const int group = ny + (seg == st.last_seg ? 1 : 0);
      std::vector<double> all;
      for (int k = 0; k < group; ++k) {
        ASSERT_LT(next, pp.size());
        const auto g = rows_at(*pp[next++], x);
        all.insert(all.end(), g.begin(), g.end());
      }
      ASSERT_LT(m, mp.size());
      const double merged = rows_at(*mp[m], x)[0];
      double sum = 0.0, mn = 1e300;
      for (double v : all) mn = std::min(mn, v);
      for (double v : all) sum += std::exp(-(v - mn) / fm.shin_softmin);
      EXPECT_NEAR(merged, mn - fm.shin_softmin * std::log(sum), 1e-12);
      EXPECT_LE(merged, mn);
    }
  }
  EXPECT_EQ(next, pp.size());
  EXPECT_EQ(m, mp.size());
  EXPECT_GT(m, 10u);
}

// The default takes the yaw at a point inside every stance segment besides its ends.
TEST(Shin, DefaultsAddAPointInsideEachStanceSegment) {
  const auto r = hyq();
  FlatField flat;
  SrbdProblem knots(r, flat, crawl_timeline(r), ProblemOptions{}),
      dflt(r, flat, crawl_timeline(r), ProblemOptions{});
  FeasibilityOptions fo, fd;
  fo.shin_yaw_points = 1;
  fo.shin_softmin = fd.shin_softmin = 0.0;  // piece counts of the per-point rows
  build_shin_set(knots, fo);
  build_shin_set(dflt, fd);
  int stance_segments = 0;
  for (const auto& st : knots.layout().stances) stance_segments += st.last_seg - st.first_seg + 1;
  EXPECT_EQ(count_kinds(dflt)["shin"] - count_kinds(knots)["shin"], stance_segments);
}

}  // namespace
}  // namespace terrastride::planner
