// "polytope" (constraints/polytope.cpp; the paper's force polytopes): Jacobians against central
// differences (per-facet and merged rows, HyQ and the monoped), and the rows against the fitted
// model's facets evaluated from the continuous-time solution.
#include <cmath>

#include "family_test.hpp"
#include "terrastride/planner/polytope_model.hpp"

namespace terrastride::planner {
namespace {

using namespace testing;

TEST(Polytope, JacobianMatchesCentralDifferences) {
  const auto r = hyq();
  MarginStep terrain(0.1, 0.5, 0.05, 0.01);
  ProblemOptions o = turning_crawl_options();
  o.constraints = {"polytope"};
  const SrbdProblem p(r, terrain, crawl_timeline(r), o);
  ASSERT_GT(count_kinds(p)["polytope"], 0);
  EXPECT_GT(check_kind_derivatives(p, "polytope"), 0);
  EXPECT_GT(largest_jacobian_entry(p, "polytope"), 1e-3);  // not vacuous
}

// Both variants: a row per facet at each point (polytope_softmax 0), and one merged row per
// stance segment (the default).
class PolytopeVariants : public ::testing::TestWithParam<double> {};
INSTANTIATE_TEST_SUITE_P(SoftScale, PolytopeVariants, ::testing::Values(0.0, 0.003));
TEST_P(PolytopeVariants, JacobianMatchesCentralDifferences) {
  const double t_soft = GetParam();
  const auto r = hyq();
  MarginStep terrain(0.1, 0.5, 0.05, 0.01);
  SrbdProblem p(r, terrain, crawl_timeline(r), turning_crawl_options());
  FeasibilityOptions fo;
  fo.polytope_softmax = t_soft;
  const auto pieces = pieces_added_by(p, [&] { build_polytope_set(p, fo); });
  ASSERT_FALSE(pieces.empty());
  for (const Piece* piece : pieces) EXPECT_EQ(piece->rows(), t_soft > 0 ? 1 : 6);
  EXPECT_GT(check_kind_derivatives(p, "polytope"), 0);
}

TEST(Polytope, MonopedJacobianMatchesCentralDifferences) {
  const auto r = robot::load_robot(robot::resolve_robot_path("monoped"));
  MarginStep terrain(0.0, 0.5, 0.05, 0.01);
  ProblemOptions o;
  o.gait = "hop";
  o.optimize_timing = true;
  o.constraints = {"polytope"};
  const PhaseTimeline tl = make_timeline(load_gait(resolve_gait_path("hop")), feet_of(r), 1, 0.0);
  const SrbdProblem p(r, terrain, tl, o);
  EXPECT_GT(count_kinds(p)["polytope"], 0);
  EXPECT_GT(check_piece_derivatives(p, 5u, 0.01,
                                    [](const Piece& piece) { return piece.kind == "polytope"; }),
            0);
}

// The facet values n^j(p_b)^T f_b - d^j(p_b) of the fitted model over m g, for foot f at time t
// of the continuous-time solution (p_b, f_b in the base frame).
Eigen::VectorXd facets_over_mg(const SrbdProblem& p, const RobotPolytopeModel& model,
                               const std::vector<double>& x, int f, double t) {
  const auto state = p.evaluate(x, t);
  const Eigen::Matrix3d R = rotation_of(state.euler);
  const Eigen::Vector3d pb = R.transpose() * (state.foot_pos[f] - state.pos);
  const Eigen::Vector3d fb = R.transpose() * state.force[f];
  return model.legs[f].constraint(pb, fb) / (p.robot().mass * 9.81);
}

// Per-facet rows at the force knots only (no inner points): their largest value is the largest
// facet value at the stance knots.
TEST(Polytope, RowsAreTheFittedFacetsInTheBaseFrame) {
  const auto r = hyq();
  MarginStep terrain(0.1, 0.5, 0.05, 0.01);
  SrbdProblem p(r, terrain, crawl_timeline(r), paper_test_options());
  const std::vector<double> x = perturbed_guess(p, 11, 0.01);
  FeasibilityOptions fo;
  fo.polytope_inner_points = 0;
  fo.polytope_softmax = 0.0;
  const auto pieces = pieces_added_by(p, [&] { build_polytope_set(p, fo); });
  double piece_max = -1e300;
  for (const Piece* piece : pieces) {
    for (double v : rows_at(*piece, x)) piece_max = std::max(piece_max, v);
    for (int j = 0; j < piece->rows(); ++j) {
      EXPECT_EQ(piece->ub[j], 0.0);
      EXPECT_LE(piece->lb[j], -1e19);
    }
  }
  const Layout& L = p.layout();
  const auto model = load_polytope_model(r);
  double formula_max = -1e300;
  for (const auto& st : L.stances)
    for (int k = st.first_seg; k <= st.last_seg + 1; ++k) {
      const double t =
          k == st.last_seg + 1 ? segment_start(L, x, k) - 1e-9 : segment_start(L, x, k);
      formula_max = std::max(formula_max, facets_over_mg(p, model, x, st.foot, t).maxCoeff());
    }
  EXPECT_NEAR(piece_max, formula_max, 1e-7);
}

// The merged row of a stance segment is the soft maximum of the facet values at its two force
// knots and its midpoint (polytope_inner_points 1), so it lies above every one of them.
TEST(Polytope, MergedRowIsTheSoftMaximumOfTheFacetsAtTheSegmentsPoints) {
  const auto r = hyq();
  MarginStep terrain(0.1, 0.5, 0.05, 0.01);
  SrbdProblem p(r, terrain, crawl_timeline(r), paper_test_options());
  const std::vector<double> x = perturbed_guess(p, 5, 0.01);
  FeasibilityOptions fm;
  fm.polytope_softmax = 0.004;
  const auto pieces = pieces_added_by(p, [&] { build_polytope_set(p, fm); });
  const Layout& L = p.layout();
  const auto model = load_polytope_model(r);
  std::size_t q = 0;
  for (int f = 0; f < static_cast<int>(r.legs.size()); ++f)
    for (int s = 0; s < L.num_segments; ++s) {
      if (!L.contact[f][s]) continue;
      ASSERT_LT(q, pieces.size());
      const double t0 = segment_start(L, x, s), t1 = t0 + segment_length(L, x, s);
      std::vector<double> facets;
      for (double t : {t0 + 1e-12, 0.5 * (t0 + t1), t1 - 1e-12}) {
        const Eigen::VectorXd v = facets_over_mg(p, model, x, f, t);
        facets.insert(facets.end(), v.data(), v.data() + v.size());
      }
      double mx = -1e300, sum = 0.0;
      for (double v : facets) mx = std::max(mx, v);
      for (double v : facets) sum += std::exp((v - mx) / fm.polytope_softmax);
      const double merged = rows_at(*pieces[q++], x)[0];
      EXPECT_NEAR(merged, mx + fm.polytope_softmax * std::log(sum), 1e-7);
      EXPECT_GE(merged, mx - 1e-7);
    }
  EXPECT_EQ(q, pieces.size());
  EXPECT_GT(q, 10u);
}

// The default puts a point inside every stance segment besides its force knots.
TEST(Polytope, DefaultsAddAPointInsideEachStanceSegment) {
  const auto r = hyq();
  FlatField flat;
  SrbdProblem knots(r, flat, crawl_timeline(r), ProblemOptions{}),
      dflt(r, flat, crawl_timeline(r), ProblemOptions{});
  FeasibilityOptions fo, fd;
  fo.polytope_inner_points = 0;
  fo.polytope_softmax = fd.polytope_softmax = 0.0;  // piece counts of the per-facet rows
  build_polytope_set(knots, fo);
  build_polytope_set(dflt, fd);
  int stance_segments = 0;
  for (const auto& st : knots.layout().stances) stance_segments += st.last_seg - st.first_seg + 1;
  EXPECT_EQ(count_kinds(dflt)["polytope"] - count_kinds(knots)["polytope"], stance_segments);
}

}  // namespace
}  // namespace terrastride::planner
