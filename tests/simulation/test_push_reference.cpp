// The push benchmark's physical references (tests/bench/push_reference.hpp) on cases worked by
// hand: the support's edge along a push, the inverted pendulum's limit without a step, and what a
// step changes (a standing foot that lifts takes its support away until it lands).
#include <gtest/gtest.h>

#include <cmath>

#include "bench/push_reference.hpp"

namespace {

using terrastride::bench::OutwardStep;
using terrastride::bench::push_limit;
using terrastride::bench::support_edge;
using terrastride::bench::support_reach;
using V2 = Eigen::Vector2d;

constexpr double g = 9.81;

// A 0.8 x 0.5 m stance around the origin, as HyQ's feet stand.
std::vector<V2> four_feet() {
  return {{0.4, 0.25}, {0.4, -0.25}, {-0.4, 0.25}, {-0.4, -0.25}};
}

TEST(PushReference, SupportEdgeIsWhereThePushLeavesTheFeet) {
  const V2 c(0.0, 0.0);
  EXPECT_NEAR(support_reach(four_feet(), c, V2(0, 1)), 0.25, 1e-12);
  EXPECT_NEAR(support_reach(four_feet(), c, V2(1, 0)), 0.4, 1e-12);
  EXPECT_NEAR(support_edge(four_feet(), c, V2(0, -1)), 0.25, 1e-12);
  // Outside the hull there is nothing to push against.
  EXPECT_EQ(support_reach(four_feet(), V2(0.0, 0.3), V2(0, 1)), 0.0);
  // Two feet: where the push's line crosses the line between them, ahead or behind.
  const std::vector<V2> left_pair = {{0.4, 0.25}, {-0.4, 0.25}};
  EXPECT_NEAR(support_edge(left_pair, c, V2(0, 1)), 0.25, 1e-12);
  EXPECT_NEAR(support_edge(left_pair, c, V2(0, -1)), -0.25, 1e-12);
  // A diagonal pair crossed off its centre.
  const std::vector<V2> diagonal = {{0.4, 0.25}, {-0.4, -0.25}};
  EXPECT_NEAR(support_edge(diagonal, V2(0.0, -0.1), V2(0, 1)), 0.1, 1e-12);
  // A push along the pair, or one that misses the segment, and a single foot: no edge.
  EXPECT_EQ(support_edge(left_pair, V2(0, 0.25), V2(1, 0)), 0.0);
  EXPECT_EQ(support_edge(left_pair, V2(0.6, 0.0), V2(0, 1)), 0.0);
  EXPECT_EQ(support_edge({{0.4, 0.25}}, c, V2(0, 1)), 0.0);
}

TEST(PushReference, WithoutAStepTheLimitIsThePendulumsOrbit) {
  // A push too short to move the body before it ends is an impulse: the body leaves at v = a tau,
  // and the linear inverted pendulum over an edge r away (h high, friction not binding) stops it
  // when v <= omega r, omega = sqrt(g / h) (its orbital energy). 10 ms of push moves the body
  // 5 mm of the 25 and brakes it little, so the limit is within a few percent of that.
  const double h = 0.6, r = 0.25, tau = 0.01;
  const double omega_r = std::sqrt(g / h) * r;
  EXPECT_NEAR(push_limit(r, h, 10.0, tau) * tau, omega_r, 0.04 * omega_r);
  // With little friction the body slides instead, stopping within v^2 / (2 mu g): it is lost when
  // that reaches the edge, v = sqrt(2 mu g r).
  const double mu = 0.01, slide = std::sqrt(2 * mu * g * r);
  EXPECT_NEAR(push_limit(r, h, mu, tau) * tau, slide, 0.02 * slide);
  // ...and a wider support or a lower body stops more.
  EXPECT_GT(push_limit(0.35, h, 0.5, 0.2), push_limit(0.25, h, 0.5, 0.2));
  EXPECT_GT(push_limit(r, 0.4, 0.5, 0.2), push_limit(r, h, 0.5, 0.2));
}

TEST(PushReference, AStepOutwardHelpsTheSoonerItLands) {
  const double h = 0.6, r = 0.25, mu = 0.5, tau = 0.2;
  const double no_step = push_limit(r, h, mu, tau);
  const double late = push_limit(r, h, mu, tau, {0.4, 0.5});
  const double soon = push_limit(r, h, mu, tau, {0.3, 0.5});
  EXPECT_GT(late, no_step);
  EXPECT_GT(soon, late);
  // A foot landing inside the old edge changes nothing.
  EXPECT_NEAR(push_limit(r, h, mu, tau, {0.3, 0.1}), no_step, 1e-6 * no_step);
}

TEST(PushReference, AStandingFootThatStepsTakesItsSupportAwayMeanwhile) {
  const double h = 0.6, r = 0.25, mu = 0.5, tau = 0.2;
  // The same landing, by the swing under way (the support stays) and by a foot that stood, whose
  // lift 0.1 s into the push leaves the body over a pair of feet whose line lies at the base (0 m
  // ahead) or 10 cm behind it.
  const double swing = push_limit(r, h, mu, tau, {0.3, 0.5});
  OutwardStep lifted{0.3, 0.5, 0.1, 0.0};
  const double from_stance = push_limit(r, h, mu, tau, lifted);
  lifted.edge_while_lifted = -0.1;
  const double from_stance_behind = push_limit(r, h, mu, tau, lifted);
  EXPECT_LT(from_stance, swing);
  EXPECT_LT(from_stance_behind, from_stance);
  // A lift the landing comes before does nothing.
  EXPECT_NEAR(push_limit(r, h, mu, tau, {0.3, 0.5, 0.35, -0.1}), swing, 1e-6 * swing);
}

}  // namespace
