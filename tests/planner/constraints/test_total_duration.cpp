// "total_duration" (constraints/total_duration.cpp): Jacobian against central differences, and
// the row against the plan's duration at the point.
#include "family_test.hpp"

namespace terrastride::planner {
namespace {

using namespace testing;

TEST(TotalDuration, JacobianMatchesCentralDifferences) {
  const auto r = hyq();
  TanhStep terrain(0.1, 0.5, 0.05, 0.01);
  const SrbdProblem p(r, terrain, crawl_timeline(r), turning_crawl_options(true));
  EXPECT_EQ(check_kind_derivatives(p, "total_duration"), 3);  // one piece, three seeds
}

// With optimised timing one piece: the sum of the phase durations, equal to the timeline's
// duration. With fixed timing none.
TEST(TotalDuration, RowIsTheSumOfThePhaseDurations) {
  const auto r = hyq();
  FlatField flat;
  SrbdProblem p(r, flat, crawl_timeline(r, 2.0), turning_crawl_options(true));
  const std::vector<double> x = perturbed_guess(p, 11, 0.01);
  const auto pieces = pieces_added_by(p, [&] { add_total_duration(p); });
  ASSERT_EQ(pieces.size(), 1u);
  const auto g = rows_at(*pieces[0], x);
  ASSERT_EQ(g.size(), 1u);
  EXPECT_NEAR(g[0], p.duration(x), 1e-12);
  EXPECT_NE(g[0], 2.0);  // the durations moved
  EXPECT_NEAR(pieces[0]->lb[0], 2.0, 1e-12);
  EXPECT_NEAR(pieces[0]->ub[0], 2.0, 1e-12);

  SrbdProblem fixed(r, flat, crawl_timeline(r, 2.0), turning_crawl_options(false));
  EXPECT_EQ(count_kinds(fixed).count("total_duration"), 0u);
  EXPECT_TRUE(pieces_added_by(fixed, [&] { add_total_duration(fixed); }).empty());
}

}  // namespace
}  // namespace terrastride::planner
