// "rest_boundary" (constraints/rest_boundary.cpp): Jacobian against central
// differences, and the rows against the base's accelerations at the plan's ends as the problem's
// own solution evaluation gives them; a re-plan from a state gets the end rows only.
#include "family_test.hpp"

namespace terrastride::planner {
namespace {

using namespace testing;

TEST(RestBoundary, JacobianMatchesCentralDifferences) {
  const auto r = hyq();
  TanhStep terrain(0.1, 0.5, 0.05, 0.01);
  for (bool timing : {false, true}) {
    const SrbdProblem p(r, terrain, crawl_timeline(r), turning_crawl_options(timing));
    EXPECT_EQ(check_kind_derivatives(p, "rest_boundary"), 6) << "timing " << timing;  // 2 x 3
    EXPECT_GT(largest_jacobian_entry(p, "rest_boundary"), 0.1);
  }
}

TEST(RestBoundary, RowsAreTheBaseAccelerationsAtBothEnds) {
  const auto r = hyq();
  FlatField flat;
  SrbdProblem p(r, flat, crawl_timeline(r, 2.0), turning_crawl_options(true));
  const std::vector<double> x = perturbed_guess(p, 5, 0.02);
  const auto pieces = pieces_added_by(p, [&] { add_rest_boundary(p); });
  ASSERT_EQ(pieces.size(), 2u);
  const double T = p.duration(x);
  int end = 0;
  for (double t : {0.0, T}) {
    const auto st = p.evaluate(x, t);
    const auto g = rows_at(*pieces[end++], x);
    ASSERT_EQ(g.size(), 6u);
    for (int d = 0; d < 3; ++d) {
      EXPECT_NEAR(g[d], st.acc[d] / 9.81, 1e-9) << "t " << t << " axis " << d;
      EXPECT_NEAR(g[3 + d], st.euler_acc[d], 1e-9) << "t " << t << " angle " << d;
    }
    EXPECT_GT(Eigen::Map<const Eigen::VectorXd>(g.data(), 6).norm(), 1e-3);  // perturbed: not 0
  }
  for (const Piece* piece : pieces)
    for (int i = 0; i < piece->rows(); ++i) {
      EXPECT_EQ(piece->lb[i], 0.0);
      EXPECT_EQ(piece->ub[i], 0.0);
    }
}

// A plan from a given start state (a re-plan) keeps that state's motion: the end rows only. And
// the rows go with rest_boundaries.
TEST(RestBoundary, StartRowsOnlyForAPlanFromRest) {
  const auto r = hyq();
  FlatField flat;
  SrbdProblem::StartState start;
  start.position = Eigen::Vector3d(0.0, 0.0, r.nominal_base_height);
  start.euler_zyx = Eigen::Vector3d::Zero();
  start.linear_velocity = Eigen::Vector3d(0.1, 0.0, 0.0);
  start.euler_rates = Eigen::Vector3d::Zero();
  for (const auto& leg : r.legs) {
    start.foot_position.push_back(start.position + leg.nominal_foot);
    start.foot_position.back().z() = 0.0;
    start.foot_velocity.push_back(Eigen::Vector3d::Zero());
  }
  ProblemOptions o = turning_crawl_options(false);
  const SrbdProblem from_state(r, flat, crawl_timeline(r), o, &start);
  EXPECT_FALSE(from_state.starts_at_rest());
  EXPECT_EQ(count_kinds(from_state)["rest_boundary"], 1);
  const SrbdProblem from_rest(r, flat, crawl_timeline(r), o);
  EXPECT_TRUE(from_rest.starts_at_rest());
  EXPECT_EQ(count_kinds(from_rest)["rest_boundary"], 2);
  o.rest_boundaries = false;
  const SrbdProblem without(r, flat, crawl_timeline(r), o);
  EXPECT_EQ(count_kinds(without).count("rest_boundary"), 0u);
  // A receding-horizon step pinned in motion at its end (end_state) is not at rest there either.
  o.rest_boundaries = true;
  SrbdProblem::StartState end = start;
  end.position.x() = 0.3;
  const SrbdProblem pinned(r, flat, crawl_timeline(r), o, &start, &end);
  EXPECT_FALSE(pinned.ends_at_rest());
  EXPECT_EQ(count_kinds(pinned).count("rest_boundary"), 0u);
  const SrbdProblem pinned_from_rest(r, flat, crawl_timeline(r), o, nullptr, &end);
  EXPECT_EQ(count_kinds(pinned_from_rest)["rest_boundary"], 1);
}

}  // namespace
}  // namespace terrastride::planner
