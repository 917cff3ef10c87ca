// The limits every plan request meets (request_limits.hpp), and plans solved from several threads
// of one process at once (Debian's MUMPS is not re-entrant; the solver serialises them).
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <limits>
#include <thread>
#include <vector>

#include "terrastride/planner/planner.hpp"
#include "terrastride/planner/request_limits.hpp"
#include "terrastride/robot/robot_model.hpp"
#include "test_terrains.hpp"

namespace terrastride::planner {
namespace {

robot::RobotModel hyq() {
  return robot::load_robot(robot::resolve_robot_path("hyq"));
}

PlannerOptions flat_crawl() {
  PlannerOptions o;
  o.has_goal = true;
  o.goal = Eigen::Vector3d(1.0, 0.0, 0.0);
  o.duration = 2.4;
  return o;
}

// The field a refusal names, or "" when the request passes.
std::string refused_field(const PlannerOptions& o, double sample_dt) {
  try {
    check_plan_request(o, sample_dt);
  } catch (const RequestError& e) {
    EXPECT_EQ(std::string(e.what()), e.field() + ": " + e.problem());
    EXPECT_FALSE(e.problem().empty());
    return e.field();
  }
  return "";
}

TEST(RequestLimits, EachOutOfRangeFieldIsNamed) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  EXPECT_EQ(refused_field(flat_crawl(), 0.01), "");
  EXPECT_EQ(refused_field(flat_crawl(), 0.001), "");
  PlannerOptions o = flat_crawl();
  o.duration = 0.0;  // the gait's default
  EXPECT_EQ(refused_field(o, 0.01), "");
  for (double d : {1e9, 120.5, -1.0, nan, inf}) {
    o.duration = d;
    EXPECT_EQ(refused_field(o, 0.01), "duration") << d;
  }
  // The sampling periods that made 6.6 GB of samples (2e-5) and zero samples (1e-9).
  for (double dt : {2e-5, 1e-9, 0.0, -0.01, 1.5, nan, inf})
    EXPECT_EQ(refused_field(flat_crawl(), dt), "sample_dt") << dt;
  o = flat_crawl();
  for (int c : {0, -3, 51, 1000000}) {
    o.cycles = c;
    EXPECT_EQ(refused_field(o, 0.01), "cycles") << c;
  }
  o = flat_crawl();
  for (double t : {-1.0, nan, inf}) {
    o.max_time = t;
    EXPECT_EQ(refused_field(o, 0.01), "max_time") << t;
  }
  o = flat_crawl();
  o.goal = Eigen::Vector3d(nan, 0, 0);
  EXPECT_EQ(refused_field(o, 0.01), "goal");
  o.goal = Eigen::Vector3d(1e7, 0, 0);
  EXPECT_EQ(refused_field(o, 0.01), "goal");
  o = flat_crawl();
  o.start = Eigen::Vector3d(0, inf, 0);
  EXPECT_EQ(refused_field(o, 0.01), "start");
}

TEST(RequestLimits, PlanMotionRefusesBeforeBuildingAnything) {
  const auto r = hyq();
  testing::FlatField flat;
  PlannerOptions o = flat_crawl();
  o.duration = 1e9;  // reached the OOM killer at 24.3 GB before the limit
  const auto t0 = std::chrono::steady_clock::now();
  try {
    plan_motion(r, flat, flat, o, 0.01);
    FAIL() << "a 1e9 s plan was accepted";
  } catch (const RequestError& e) {
    EXPECT_EQ(e.field(), "duration");
  }
  // Without a duration the horizon is the gait's cycles: 50 crawl cycles exceed 120 s.
  o = flat_crawl();
  o.duration = 0.0;
  o.cycles = 50;
  try {
    plan_motion(r, flat, flat, o, 0.01);
    FAIL() << "50 crawl cycles were accepted";
  } catch (const RequestError& e) {
    EXPECT_EQ(e.field(), "cycles");
    EXPECT_NE(std::string(e.what()).find("120"), std::string::npos) << e.what();
  }
  // Refused at once, not after building a problem (generous bound: this is not a speed test).
  EXPECT_LT(std::chrono::steady_clock::now() - t0, std::chrono::seconds(5));
  // A re-plan continues a plan of at most the same horizon, from a time inside it.
  Trajectory previous;
  previous.robot = r.name;
  for (const auto& leg : r.legs) previous.feet.push_back(leg.name);
  previous.duration = 500.0;
  WarmStart warm;
  warm.previous = &previous;
  try {
    plan_motion(r, flat, flat, flat_crawl(), 0.01, warm);
    FAIL() << "a 500 s init plan was accepted";
  } catch (const RequestError& e) {
    EXPECT_EQ(e.field(), "init.duration");
  }
}

// Two threads planning at once in one process: before the solver lock, Debian's sequential MUMPS
// crashed (SIGSEGV) in every try. Both plans now solve, and each equals the same plan made alone.
TEST(RequestLimits, ConcurrentPlansInOneProcessAreSafe) {
  const auto r = hyq();
  testing::FlatField flat;
  const PlanOutcome alone = plan_motion(r, flat, flat, flat_crawl(), 0.01);
  ASSERT_TRUE(alone.success) << alone.message;
  std::vector<PlanOutcome> outs(4);
  std::vector<std::thread> threads;
  for (auto& out : outs)
    threads.emplace_back([&] { out = plan_motion(r, flat, flat, flat_crawl(), 0.01); });
  for (auto& t : threads) t.join();
  for (const auto& out : outs) {
    ASSERT_TRUE(out.success) << out.message;
    EXPECT_EQ(out.trajectory.solver.iterations, alone.trajectory.solver.iterations);
    ASSERT_EQ(out.trajectory.samples.size(), alone.trajectory.samples.size());
    EXPECT_NEAR(out.trajectory.samples.back().base.position.x(),
                alone.trajectory.samples.back().base.position.x(), 1e-12);
  }
}

// A request stopped while another solve holds the solver does not wait for it.
TEST(RequestLimits, AStoppedRequestDoesNotWaitForTheSolver) {
  const auto r = hyq();
  testing::FlatField flat;
  PlanOutcome first;
  std::thread t([&] {
    PlannerOptions o = flat_crawl();
    o.duration = 11.0;
    first = plan_motion(r, flat, flat, o, 0.01);
  });
  PlannerOptions o = flat_crawl();
  o.should_stop = [] { return true; };
  const PlanOutcome stopped = plan_motion(r, flat, flat, o, 0.01);
  t.join();
  EXPECT_FALSE(stopped.success);
  EXPECT_TRUE(first.success) << first.message;
}

}  // namespace
}  // namespace terrastride::planner
