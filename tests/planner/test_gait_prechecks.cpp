// The checks a walk meets before any solve (gait.hpp): require_joint_speeds_reachable refuses a
// walk whose swings need a joint faster than the robot file's velocity limit, naming the leg, the
// joint, the speeds and a --duration that passes.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <string>

#include "terrastride/planner/gait.hpp"
#include "terrastride/planner/request_limits.hpp"
#include "terrastride/robot/robot_model.hpp"

namespace terrastride::planner {
namespace {

robot::RobotModel shipped(const std::string& name) {
  return robot::load_robot(robot::resolve_robot_path(name));
}

std::vector<std::string> feet_of(const robot::RobotModel& robot) {
  std::vector<std::string> feet;
  for (const auto& leg : robot.legs) feet.push_back(leg.name);
  return feet;
}

// The gait timed for `robot`, `cycles` of it over `duration` s (0: the gait's own).
PhaseTimeline walk(const robot::RobotModel& robot, const std::string& gait, int cycles,
                   double duration) {
  return make_timeline(timed_for_robot(load_gait(resolve_gait_path(gait)), robot), feet_of(robot),
                       cycles, duration);
}

TEST(JointSpeedPrecheck, RobotsWithoutVelocityLimitsAreNotJudged) {
  const auto hyq = shipped("hyq");
  EXPECT_EQ(
      require_joint_speeds_reachable(walk(hyq, "crawl", 3, 0.5), "crawl", hyq, 5.0), 0.0);
}

TEST(JointSpeedPrecheck, ShippedRobotsWalkTheirDefaultCrawl) {
  for (const std::string name : {"go2", "anymal_c"}) {
    const auto robot = shipped(name);
    const double ratio =
        require_joint_speeds_reachable(walk(robot, "crawl", 4, 0.0), "crawl", robot, 1.0);
    EXPECT_GT(ratio, 0.01) << name;
    EXPECT_LT(ratio, 0.5) << name;  // the estimate is a floor: the plans reach 0.72-0.95
  }
}

// The needed speed scales with 1 / duration (the steps relative to the base stay the same).
TEST(JointSpeedPrecheck, NeededSpeedScalesWithTheInverseDuration) {
  const auto go2 = shipped("go2");
  const auto needed = [&](double duration, double distance) {
    return require_joint_speeds_reachable(walk(go2, "crawl", 4, duration), "crawl", go2, distance);
  };
  EXPECT_NEAR(needed(8.0, 1.0) / needed(16.0, 1.0), 2.0, 1e-9);
  EXPECT_EQ(needed(8.0, 0.0), 0.0);  // no walk: nothing to judge
}

// A Go2 whose motors turn at a third of what the default crawl needs on average: refused,
// naming the leg, the joint, both speeds and the fix; the --duration it names passes.
TEST(JointSpeedPrecheck, SlowMotorsAreRefusedWithADurationThatPasses) {
  robot::RobotModel slow = shipped("go2");
  const PhaseTimeline fast = walk(slow, "crawl", 4, 0.0);
  const double ratio = require_joint_speeds_reachable(fast, "crawl", slow, 1.0);
  for (auto& leg : slow.legs) leg.velocity_limit *= ratio / 3.0;
  std::string message;
  try {
    require_joint_speeds_reachable(fast, "crawl", slow, 1.0);
  } catch (const RequestError& e) {
    EXPECT_EQ(e.field(), "duration");
    message = e.problem();
  }
  ASSERT_FALSE(message.empty()) << "not refused";
  for (const std::string part : {"robot 'go2'", "crawl gait", "leg ", "rad/s on average",
                                 "velocity_limit", "--duration ", "--cycles"})
    EXPECT_NE(message.find(part), std::string::npos) << part << " in: " << message;
  EXPECT_TRUE(message.find("HAA") != std::string::npos ||
              message.find("HFE") != std::string::npos || message.find("KFE") != std::string::npos)
      << message;
  const size_t at = message.find("--duration ") + std::string("--duration ").size();
  const double hint = std::stod(message.substr(at));
  EXPECT_NEAR(hint, 3.0 * fast.duration(), 0.1 + 1e-9) << message;
  EXPECT_LE(
      require_joint_speeds_reachable(walk(slow, "crawl", 4, hint), "crawl", slow, 1.0),
      1.0);
}

// The walk Go2's rows hold at 0.93 of an 8 rad/s knee limit (test_any_quadruped: a 1 m trot in
// 1.6 s) is not refused: the estimate stays below what a plan needs.
TEST(JointSpeedPrecheck, AFeasibleFastTrotPasses) {
  robot::RobotModel go2 = shipped("go2");
  for (auto& leg : go2.legs) leg.velocity_limit[2] = 8.0;
  const double ratio =
      require_joint_speeds_reachable(walk(go2, "trot", 4, 1.6), "trot", go2, 1.0);
  std::printf("go2, 8 rad/s knees, 1 m trot in 1.6 s: the estimate is %.3f of the limit\n",
              ratio);
  EXPECT_GT(ratio, 0.05);
  EXPECT_LT(ratio, 1.0);
}

// Go2 with 1 rad/s knees can crawl its default 1 m within the limit (a plan with velocity rows
// inside the stance segments too held 0.96 of it): not refused. Counting a 5 cm lift refused it.
TEST(JointSpeedPrecheck, AFeasibleSlowCrawlPasses) {
  robot::RobotModel go2 = shipped("go2");
  for (auto& leg : go2.legs) leg.velocity_limit[2] = 1.0;
  EXPECT_LT(require_joint_speeds_reachable(walk(go2, "crawl", 4, 0.0), "crawl", go2, 1.0), 1.0);
}

}  // namespace
}  // namespace terrastride::planner
