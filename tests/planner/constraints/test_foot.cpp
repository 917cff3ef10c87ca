// "foot" (constraints/foot.cpp; the paper's foot radius): Jacobians against central differences,
// and the rows against the terrain's safety margin under each free foothold.
#include "family_test.hpp"

namespace terrastride::planner {
namespace {

using namespace testing;

ProblemOptions with_foot(ProblemOptions o) {
  o.constraints = {"foot"};
  return o;
}

TEST(Foot, JacobianMatchesCentralDifferences) {
  const auto r = hyq();
  MarginStep terrain(0.1, 0.5, 0.05, 0.01);
  const SrbdProblem p(r, terrain, crawl_timeline(r), with_foot(turning_crawl_options()));
  ASSERT_GT(count_kinds(p)["foot"], 0);
  EXPECT_GT(check_kind_derivatives(p, "foot"), 0);
  // Not vacuous: the rows depend on the foothold.
  EXPECT_GT(largest_jacobian_entry(p, "foot"), 0.1);
}

TEST(Foot, MonopedJacobianMatchesCentralDifferences) {
  const auto r = robot::load_robot(robot::resolve_robot_path("monoped"));
  MarginStep terrain(0.0, 0.5, 0.05, 0.01);
  ProblemOptions o;
  o.gait = "hop";
  o.optimize_timing = true;
  o.constraints = {"foot"};
  const PhaseTimeline tl = make_timeline(load_gait(resolve_gait_path("hop")), feet_of(r), 1, 0.0);
  const SrbdProblem p(r, terrain, tl, o);
  EXPECT_GT(
      check_piece_derivatives(p, 5u, 0.01, [](const Piece& piece) { return piece.kind == "foot"; }),
      0);
}

// One piece per free stance (the initial stances are given): the signed foothold-safety margin
// for the foot's radius at the foothold, at least foot_margin.
TEST(Foot, RowsAreTheSafetyMarginAtEachFreeFoothold) {
  const auto r = hyq();
  MarginStep terrain(0.1, 0.5, 0.05, 0.01);
  SrbdProblem p(r, terrain, crawl_timeline(r), paper_test_options());
  const std::vector<double> x = perturbed_guess(p, 11, 0.01);
  FeasibilityOptions fo;
  const auto pieces = pieces_added_by(p, [&] { build_foot_set(p, fo); });
  std::size_t i = 0;
  double smallest = 1e300;
  for (const auto& st : p.layout().stances) {
    if (st.fixed) continue;
    ASSERT_LT(i, pieces.size());
    const Eigen::Vector3d foot = vec3_at(x, st.pos_var);
    const double margin = terrain.safety_margin(foot.x(), foot.y(), r.foot_radius).margin;
    const auto g = rows_at(*pieces[i], x);
    ASSERT_EQ(g.size(), 1u);
    EXPECT_NEAR(g[0], margin, 1e-12);
    EXPECT_EQ(pieces[i]->lb[0], fo.foot_margin);
    EXPECT_GE(pieces[i]->ub[0], 1e19);
    smallest = std::min(smallest, margin);
    ++i;
  }
  EXPECT_EQ(i, pieces.size());
  EXPECT_LT(smallest, 0.0);  // the test terrain has unsafe spots under the guess: not vacuous
}

}  // namespace
}  // namespace terrastride::planner
