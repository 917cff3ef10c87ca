// The guess of a re-plan from a disturbed measured state (SrbdProblem::warm_start_from with a
// bridge span): over the span the base goes from the measured velocity and rates to the previous
// plan along a cubic Hermite offset, the previous plan's own beyond it, and the first segments'
// dynamics then need accelerations the feet can give instead of the offset shed in one segment.
#include <gtest/gtest.h>

#include <Eigen/Core>
#include <cmath>
#include <vector>

#include "constraints/family_test.hpp"
#include "terrastride/planner/planner.hpp"
#include "terrastride/planner/trajectory.hpp"

namespace terrastride::planner {
namespace {

using namespace testing;

struct Disturbed {
  Trajectory previous;
  SrbdProblem::StartState start;
  PhaseTimeline timeline;
};

// The cold crawl's guess as the previous plan, and its state at 0.5 s pushed: the base 0.6 m/s
// faster sideways and rolling at 0.8 rad/s more than planned.
Disturbed disturbed_start(const robot::RobotModel& r, const terrain::HeightField& terrain,
                          const ProblemOptions& o) {
  SrbdProblem cold(r, terrain, crawl_timeline(r), o);
  Disturbed d{sample_solution(cold, cold.initial_guess(), 0.01),
              start_state_of(cold.evaluate(cold.initial_guess(), 0.5)),
              crawl_timeline(r).cropped(0.5)};
  d.start.linear_velocity += Eigen::Vector3d(0.1, -0.6, 0.0);
  d.start.euler_rates += Eigen::Vector3d(0.0, 0.0, 0.8);
  return d;
}

TEST(StartBridge, TheGuessLeavesTheMeasuredVelocityAlongTheBridgeAndMeetsThePreviousPlan) {
  const auto r = hyq();
  FlatField flat;
  const ProblemOptions o = paper_test_options();
  const Disturbed d = disturbed_start(r, flat, o);
  SrbdProblem plain(r, flat, d.timeline, o, &d.start), bridged(r, flat, d.timeline, o, &d.start),
      none(r, flat, d.timeline, o, &d.start);
  const double span = 0.3;
  plain.warm_start_from(d.previous, 0.5);
  bridged.warm_start_from(d.previous, 0.5, span);
  none.warm_start_from(d.previous, 0.5, 0.0);
  EXPECT_EQ(none.initial_guess(), plain.initial_guess()) << "span 0: the previous plan as it is";
  const Layout& L = bridged.layout();
  const std::vector<double>&xp = plain.initial_guess(), &xb = bridged.initial_guess();
  // The offset at the start (the previous plan's state there is the cold guess's, so only the
  // velocity and the rates differ).
  const Eigen::Vector3d dv(0.1, -0.6, 0.0), der(0.0, 0.0, 0.8);
  int bridged_knots = 0;
  for (int k = 1; k <= L.num_segments; ++k) {
    const double t = L.nominal_knot_time[k];
    const int b = L.base[k];
    for (int i = 0; i < 12; ++i) {
      if (!(bridged.lower()[b + i] < bridged.upper()[b + i])) continue;
      if (t >= span) {
        EXPECT_EQ(xb[b + i], xp[b + i]) << "knot " << k << " at " << t << " s, entry " << i;
        continue;
      }
      // Hermite offset h00 d + h10 span dv (value), its derivative (rate); d = 0 here.
      const double s = t / span;
      const double h10 = s * s * s - 2 * s * s + s, dh10 = 3 * s * s - 4 * s + 1;
      const Eigen::Vector3d& rate = i < 6 ? dv : der;
      const double expected = (i % 6) < 3 ? h10 * span * rate[i % 3] : dh10 * rate[i % 3];
      EXPECT_NEAR(xb[b + i] - xp[b + i], expected, 1e-9) << "knot " << k << ", entry " << i;
    }
    if (t < span) ++bridged_knots;
  }
  EXPECT_GE(bridged_knots, 2);
  // The base acceleration the guess asks at the start: the previous plan's plus at most the
  // bridge's 4 |dv| / span, instead of the offset shed within the first segment.
  const Eigen::Vector3d a_planned = plain.evaluate(xp, L.nominal_knot_time[1] * 0.5).acc;
  const double a_plain = (plain.evaluate(xp, 0.0).acc - a_planned).norm();
  const double a_bridged = (bridged.evaluate(xb, 0.0).acc - a_planned).norm();
  std::printf("first-segment acceleration off the plan: %.1f m/s2 previous plan, %.1f bridged\n",
              a_plain, a_bridged);
  EXPECT_LT(a_bridged, 4 * dv.norm() / span + 0.5);
  EXPECT_GT(a_plain, 3 * a_bridged);
  // So the dynamics rows start nearer to holding (the forces balance the bridge).
  const auto vp = plain.violation_by_kind(xp), vb = bridged.violation_by_kind(xb);
  std::printf("dynamics_linear violation %.3f previous plan, %.3f bridged; dynamics_angular %.3f, "
              "%.3f\n",
              vp.at("dynamics_linear"), vb.at("dynamics_linear"), vp.at("dynamics_angular"),
              vb.at("dynamics_angular"));
  EXPECT_LT(vb.at("dynamics_linear"), 0.5 * vp.at("dynamics_linear"));
}

// A start on the previous plan has no offset: the bridge leaves the guess as it was.
TEST(StartBridge, AStartOnThePreviousPlanKeepsItsGuess) {
  const auto r = hyq();
  FlatField flat;
  const ProblemOptions o = paper_test_options();
  SrbdProblem cold(r, flat, crawl_timeline(r), o);
  const Trajectory previous = sample_solution(cold, cold.initial_guess(), 0.01);
  const SrbdProblem::StartState start = start_state_of(previous, 0.5);
  const PhaseTimeline tl = crawl_timeline(r).cropped(0.5);
  SrbdProblem plain(r, flat, tl, o, &start), bridged(r, flat, tl, o, &start);
  plain.warm_start_from(previous, 0.5);
  bridged.warm_start_from(previous, 0.5, 0.3);
  const Layout& L = bridged.layout();
  for (int k = 0; k <= L.num_segments; ++k)
    for (int i = 0; i < 12; ++i)
      EXPECT_NEAR(bridged.initial_guess()[L.base[k] + i], plain.initial_guess()[L.base[k] + i],
                  1e-6)
          << "knot " << k << ", entry " << i;
}

}  // namespace
}  // namespace terrastride::planner
