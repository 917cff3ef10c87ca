// SolverForkGuard (planner/solver_fork.hpp): a fork made while no solve runs, and a child that
// solves as if the parent had never solved. The mixed-load service test shows the crash this
// prevents; these tests pin the guard's contract one property at a time.
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <thread>

#include "terrastride/planner/gait.hpp"
#include "terrastride/planner/nlp.hpp"
#include "terrastride/planner/solver.hpp"
#include "terrastride/planner/solver_fork.hpp"
#include "test_robots.hpp"
#include "test_terrains.hpp"

namespace terrastride::planner {
namespace {

using testing::feet_of;
using testing::hyq;

// A 1-cycle crawl 0.2 m ahead over a 5 cm step: a solve of some iterations.
struct SmallProblem {
  PlannerOptions options;
  testing::TanhStep terrain{0.05, 0.3, 0.08, 0.01};
  robot::RobotModel robot = hyq();
  PhaseTimeline timeline =
      make_timeline(load_gait(resolve_gait_path("crawl")), feet_of(robot), 1, 2.0);
  SmallProblem() {
    options.has_goal = true;
    options.goal = Eigen::Vector3d(0.2, 0.0, 0.0);
  }
};

// While a guard is held, no solve starts (and a second guard that is asked to stop gives up); the
// solve starts once the guard is released.
TEST(SolverForkGuard, HoldsSolvesOffUntilReleased) {
  SmallProblem sp;
  SrbdProblem p(sp.robot, sp.terrain, sp.timeline, sp.options);
  SolverForkGuard guard([] { return false; });
  ASSERT_TRUE(guard.held());
  {
    // Another guard asked to stop while this one holds the solver gives up, not held.
    SolverForkGuard second([] { return true; });
    EXPECT_FALSE(second.held());
  }
  std::atomic<bool> done{false};
  SolveResult result;
  std::thread solver([&] {
    result = solve(p, sp.options);
    done = true;
  });
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  EXPECT_FALSE(done.load()) << "a solve ran while the fork guard was held";
  guard.release();
  solver.join();
  EXPECT_TRUE(result.success) << result.status;
}

// A guard waits for the solve in progress.
// The solve's iterations call should_stop while it holds the solver; none may come after the
// guard took it.
TEST(SolverForkGuard, WaitsForTheSolveInProgressOrStops) {
  SmallProblem sp;
  SrbdProblem p(sp.robot, sp.terrain, sp.timeline, sp.options);
  std::atomic<int> iterations{0};
  PlannerOptions o = sp.options;
  o.should_stop = [&] {
    iterations++;
    return false;
  };
  std::thread solver([&] { solve(p, o); });
  while (iterations.load() == 0) std::this_thread::sleep_for(std::chrono::milliseconds(1));
  SolverForkGuard guard([] { return false; });
  ASSERT_TRUE(guard.held());
  const int at_guard = iterations.load();
  std::this_thread::sleep_for(std::chrono::milliseconds(100));
  EXPECT_EQ(iterations.load(), at_guard) << "the solve iterated while the guard was held";
  guard.release();
  solver.join();
}

// A child forked under the guard solves, and the parent solves again after it: neither inherits
// a lock it cannot release.
TEST(SolverForkGuard, ChildForkedUnderTheGuardSolves) {
  SmallProblem sp;
  SrbdProblem p(sp.robot, sp.terrain, sp.timeline, sp.options);
  ASSERT_TRUE(solve(p, sp.options).success);  // the parent has solved before
  SolverForkGuard guard([] { return false; });
  ASSERT_TRUE(guard.held());
  const pid_t pid = ::fork();
  ASSERT_GE(pid, 0);
  if (pid == 0) {
    guard.release_in_child();
    SrbdProblem cp(sp.robot, sp.terrain, sp.timeline, sp.options);
    ::_exit(solve(cp, sp.options).success ? 0 : 3);
  }
  guard.release();
  int status = 0;
  ASSERT_EQ(::waitpid(pid, &status, 0), pid);
  ASSERT_TRUE(WIFEXITED(status)) << "the child was ended by signal " << WTERMSIG(status);
  EXPECT_EQ(WEXITSTATUS(status), 0);
  EXPECT_TRUE(solve(p, sp.options).success);
}

}  // namespace
}  // namespace terrastride::planner
