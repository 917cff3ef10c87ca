// The NLP's pieces: gaits and timelines, every constraint's Jacobian against finite differences,
// and Ipopt's own derivative checker on a small problem.
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <random>
#include <set>
#include <sstream>
#include <string>

#include "terrastride/planner/gait.hpp"
#include "terrastride/planner/nlp.hpp"
#include "terrastride/planner/solver.hpp"
#include "terrastride/robot/robot_model.hpp"
#include "piece_derivatives.hpp"
#include "test_robots.hpp"
#include "test_states.hpp"
#include "test_terrains.hpp"

namespace terrastride::planner {
namespace {

using testing::feet_of;
using testing::hyq;

TEST(Gait, AllShippedGaitsBuildTimelines) {
  const auto r = hyq();
  for (const std::string name : {"crawl", "walk", "trot", "pace", "bound"}) {
    const Gait g = load_gait(resolve_gait_path(name));
    const PhaseTimeline tl = make_timeline(g, feet_of(r), 2, 0.0);
    ASSERT_GE(tl.num_intervals(), 2) << name;
    for (int j = 0; j < tl.num_intervals(); ++j) EXPECT_LT(tl.events[j], tl.events[j + 1]) << name;
    for (std::size_t f = 0; f < 4; ++f) {
      // Every leg swings at least twice and starts and ends... (crawl, walk) in stance.
      int swings = 0;
      for (const auto& p : tl.phases(f)) swings += !p.contact;
      EXPECT_GE(swings, 1) << name;
    }
  }
  const auto mono = robot::load_robot(robot::resolve_robot_path("monoped"));
  const PhaseTimeline hop = make_timeline(load_gait(resolve_gait_path("hop")), feet_of(mono), 3, 0.0);
  EXPECT_EQ(hop.phases(0).size(), 7u);  // stance, (flight, stance) x 3
}

TEST(Gait, CrawlMatchesThePaperSchedule) {
  const Gait g = load_gait(resolve_gait_path("crawl"));
  const PhaseTimeline tl = make_timeline(g, feet_of(hyq()), 3, 11.0);
  EXPECT_NEAR(tl.duration(), 11.0, 1e-12);
  for (int f = 0; f < 4; ++f) {
    int swings = 0;
    for (const auto& p : tl.phases(f)) swings += !p.contact;
    EXPECT_EQ(swings, 3);
  }
  // Never more than one foot in the air (statically stable crawl).
  for (int j = 0; j < tl.num_intervals(); ++j) {
    int air = 0;
    for (int f = 0; f < 4; ++f) air += !tl.contact[f][j];
    EXPECT_LE(air, 1);
  }
  const PhaseTimeline c = tl.cropped(0.5);
  EXPECT_NEAR(c.duration(), 10.5, 1e-9);
}

// A plan from rest with force ramps gets a lead-in long enough for its second lift-off (plan_motion:
// W / force_rate_max, 0.407 s for HyQ at 2000 N/s). The 2.4 s crawl lifts LF off at 0.22 s: its
// lead-in grows and its cycles shorten, the duration kept; the 11 s crawl (LF at 1.01 s) and the
// trot (its pairs at 0.2 and 0.6 s) keep theirs; without a duration the cycle is kept instead.
TEST(Gait, RestLeadInDelaysAnEarlySecondLiftOff) {
  const auto feet = feet_of(hyq());
  auto lift_offs = [&](const PhaseTimeline& tl) {
    std::vector<double> t;
    for (int f = 0; f < 4; ++f)
      for (const auto& p : tl.phases(f))
        if (!p.contact) t.push_back(p.start);
    std::sort(t.begin(), t.end());
    return t;
  };
  const Gait crawl = load_gait(resolve_gait_path("crawl"));
  const double second = 0.407;
  EXPECT_NEAR(lift_offs(make_timeline(crawl, feet, 3, 2.4))[1], 0.22, 1e-9);
  const Gait led = with_rest_lead_in(crawl, feet, 3, 2.4, second);
  EXPECT_GT(led.lead_in, 0.25);
  const PhaseTimeline tl = make_timeline(led, feet, 3, 2.4);
  EXPECT_NEAR(tl.duration(), 2.4, 1e-12);
  const auto t = lift_offs(tl);
  ASSERT_EQ(t.size(), 12u);
  EXPECT_NEAR(t[1], second, 1e-9);
  EXPECT_GT(t[0], 0.2);  // LH too: the four feet stand for the first 0.22 s
  // Each foot still swings three times, one at a time, in the same order.
  int swings = 0;
  for (int f = 0; f < 4; ++f)
    for (const auto& p : tl.phases(f)) swings += !p.contact;
  EXPECT_EQ(swings, 12);
  // Late enough already: unchanged.
  EXPECT_EQ(with_rest_lead_in(crawl, feet, 3, 11.0, second).lead_in, crawl.lead_in);
  const Gait trot = load_gait(resolve_gait_path("trot"));
  EXPECT_EQ(with_rest_lead_in(trot, feet, 3, 0.0, second).lead_in, trot.lead_in);
  // No duration: the gait's cycle is kept and the plan grows by the lead-in.
  Gait fast = crawl;
  fast.cycle_duration = 0.8;
  const PhaseTimeline grown = make_timeline(with_rest_lead_in(fast, feet, 3, 0.0, second), feet, 3, 0.0);
  EXPECT_NEAR(lift_offs(grown)[1], second, 1e-9);
  EXPECT_NEAR(grown.duration() - 2.4, second - 0.22, 1e-9);
  // A duration with no room for it: unchanged.
  EXPECT_EQ(with_rest_lead_in(crawl, feet, 3, 0.4, second).lead_in, crawl.lead_in);
  // Room, but only by packing the cycles into less than half their length (3 cycles in 0.5 s
  // would swing for 7 ms instead of 33): unchanged. At 1.0 s the cycle shrinks 0.33 -> 0.22 s,
  // more than half: changed.
  EXPECT_EQ(with_rest_lead_in(crawl, feet, 3, 0.5, second).lead_in, crawl.lead_in);
  EXPECT_GT(with_rest_lead_in(crawl, feet, 3, 1.0, second).lead_in, crawl.lead_in);
}

// A cropped timeline remembers how far into its first interval it starts, and the problem built on
// it keeps the knots of the uncropped one at the same absolute times (so a warm start can
// reproduce the previous plan's splines exactly); cropping twice accumulates.
TEST(Gait, CroppedTimelineKeepsTheSegmentKnots) {
  const auto r = hyq();
  testing::FlatField flat;
  const PhaseTimeline tl = make_timeline(load_gait(resolve_gait_path("crawl")), feet_of(r), 3, 11.0);
  PlannerOptions o;
  const SrbdProblem full(r, flat, tl, o);
  std::vector<double> knots = full.layout().nominal_knot_time;
  for (double shift : {0.1, 0.37, 1.0}) {
    const PhaseTimeline c = tl.cropped(shift);
    int j = 0;  // the interval of tl that contains `shift`
    while (tl.events[j + 1] <= shift) ++j;
    EXPECT_NEAR(c.first_interval_elapsed, shift - tl.events[j], 1e-12) << shift;
    const SrbdProblem part(r, flat, c, o);
    // Every knot of the cropped problem after its first segment is a knot of the full one.
    const auto& kc = part.layout().nominal_knot_time;
    for (std::size_t k = 1; k < kc.size(); ++k) {
      const double t = kc[k] + shift;
      const auto it = std::min_element(knots.begin(), knots.end(), [t](double a, double b) {
        return std::abs(a - t) < std::abs(b - t);
      });
      EXPECT_NEAR(*it, t, 1e-9) << "shift " << shift << " knot " << k;
    }
    const PhaseTimeline cc = c.cropped(0.25);
    int i = 0;
    while (tl.events[i + 1] <= shift + 0.25) ++i;
    EXPECT_NEAR(cc.first_interval_elapsed, shift + 0.25 - tl.events[i], 1e-9) << shift;
  }
}

// A foot in swing at the crop point remembers when it lifted off, also across two crops and
// from a swing that began intervals earlier; feet in stance have 0.
TEST(Gait, CroppedTimelineRemembersWhenSwingingFeetLiftedOff) {
  const auto r = hyq();
  const PhaseTimeline tl = make_timeline(load_gait(resolve_gait_path("trot")), feet_of(r), 3, 0.0);
  for (double shift : {0.05, 0.3, 0.77, 1.1}) {
    const PhaseTimeline c = tl.cropped(shift);
    ASSERT_EQ(c.swing_elapsed.size(), tl.feet.size());
    for (std::size_t f = 0; f < tl.feet.size(); ++f) {
      // Lift-off: the start of the swing phase containing `shift`, from the uncropped timeline.
      double lift_off = -1.0;
      for (const auto& ph : tl.phases(static_cast<int>(f)))
        if (!ph.contact && ph.start <= shift + 1e-9 && shift < ph.end - 1e-6) lift_off = ph.start;
      EXPECT_NEAR(c.swing_elapsed_of(f), lift_off < 0.0 ? 0.0 : shift - lift_off, 1e-9)
          << "shift " << shift << " foot " << f;
      const PhaseTimeline cc = c.cropped(0.02);
      const bool still_swinging = lift_off >= 0.0 && !cc.contact[f][0];
      EXPECT_NEAR(cc.swing_elapsed_of(f), still_swinging ? shift + 0.02 - lift_off : 0.0, 1e-9)
          << "twice, shift " << shift << " foot " << f;
    }
  }
}

TEST(Gait, BadInputIsNamed) {
  EXPECT_THROW(resolve_gait_path("no_such_gait"), GaitError);
  const std::string path = ::testing::TempDir() + "/bad_gait.yaml";
  std::ofstream(path) << "name: bad\nswing:\n  LF: [[0.5, 0.2]]\n";
  try {
    load_gait(path);
    FAIL();
  } catch (const GaitError& e) {
    EXPECT_NE(std::string(e.what()).find("swing.LF[0]"), std::string::npos) << e.what();
  }
  // Names that are not text: the file and the field, not yaml-cpp's "bad conversion".
  for (const char* text : {"name: [1, 2]\nswing:\n  LF: [[0.1, 0.2]]\n",
                           "name: bad\nswing:\n  [LF, RF]: [[0.1, 0.2]]\n",
                           "name: {a: 1}\nswing:\n  LF: [[0.1, 0.2]]\n"}) {
    std::ofstream(path) << text;
    try {
      load_gait(path);
      ADD_FAILURE() << text;
    } catch (const GaitError& e) {
      EXPECT_NE(std::string(e.what()).find(path), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("expected a name"), std::string::npos) << e.what();
    }
  }
  std::ofstream(path) << "name: bad\nswing:\n  XX: [[0.1, 0.2]]\n";
  const Gait g = load_gait(path);
  EXPECT_THROW(make_timeline(g, feet_of(hyq()), 1, 1.0), GaitError);
}

// Every piece's Jacobian against central differences of its own values, at a perturbed point.
void check_all_pieces(const SrbdProblem& p, std::set<std::string>* kinds) {
  const int checked = testing::check_piece_derivatives(p, 7, 0.01, [&](const Piece& piece) {
    kinds->insert(piece.kind);
    return true;
  });
  EXPECT_EQ(checked, static_cast<int>(p.pieces().size()));
}

TEST(NlpDerivatives, EveryPieceMatchesFiniteDifferences) {
  const auto r = hyq();
  testing::TanhStep terrain(0.1, 0.5, 0.05, 0.01);
  PlannerOptions o;
  o.has_goal = true;
  o.goal = Eigen::Vector3d(0.4, 0.05, 0.1);
  o.optimize_timing = true;
  o.cycles = 1;
  const PhaseTimeline tl =
      make_timeline(load_gait(resolve_gait_path("crawl")), feet_of(r), 1, 2.0);
  SrbdProblem p(r, terrain, tl, o);
  std::set<std::string> kinds;
  check_all_pieces(p, &kinds);
  for (const std::string k : {"dynamics_linear", "dynamics_angular", "range_of_motion",
                              "stance_height", "friction", "swing_clearance", "total_duration",
                              "foothold_planarity"})
    EXPECT_TRUE(kinds.count(k)) << "no piece of kind " << k;
}

TEST(NlpDerivatives, MonopedPiecesMatchFiniteDifferences) {
  const auto r = robot::load_robot(robot::resolve_robot_path("monoped"));
  testing::TanhStep terrain(0.0, 0.5, 0.05, 0.01);
  PlannerOptions o;
  o.gait = "hop";
  o.optimize_timing = true;
  const PhaseTimeline tl = make_timeline(load_gait(resolve_gait_path("hop")), feet_of(r), 1, 0.0);
  SrbdProblem p(r, terrain, tl, o);
  std::set<std::string> kinds;
  check_all_pieces(p, &kinds);
  EXPECT_FALSE(kinds.count("dynamics_angular"));  // rotations held by the slider
  EXPECT_TRUE(kinds.count("dynamics_linear"));
}

// The objective is zero, so the solve may stop at the first iterate that is feasible; the point it
// returns must really be feasible (checked here independently), and with the early stop disabled
// Ipopt's own convergence ends the solve.
TEST(Solve, StopsAtAVerifiedFeasiblePoint) {
  const auto r = hyq();
  testing::TanhStep terrain(0.05, 0.3, 0.08, 0.01);
  PlannerOptions o;
  o.has_goal = true;
  o.goal = Eigen::Vector3d(0.2, 0.0, 0.0);
  o.objective = ObjectiveWeights{};  // with the objective's phases too
  const PhaseTimeline tl = make_timeline(load_gait(resolve_gait_path("crawl")), feet_of(r), 1, 2.0);
  SrbdProblem p(r, terrain, tl, o);
  const SolveResult early = solve(p, o);
  ASSERT_TRUE(early.success) << early.status;
  EXPECT_EQ(early.termination, "feasible_point");
  EXPECT_LE(p.max_violation(early.x), o.feasibility_stop_tolerance);
  PlannerOptions full = o;
  full.feasibility_stop_tolerance = 0.0;
  const SolveResult converged = solve(p, full);
  ASSERT_TRUE(converged.success) << converged.status;
  EXPECT_EQ(converged.termination, "ipopt");
  EXPECT_EQ(converged.status, "optimal");
  // The feasibility phase stops earlier than Ipopt's own convergence (the objective's
  // improvement and polish come after it, SolverOptions::objective_max_iterations).
  EXPECT_LE(early.feasibility_iterations, converged.iterations);
  EXPECT_EQ(early.iterations, early.feasibility_iterations + early.objective_iterations);
}

// A 2 s crawl 0.2 m ahead over a 5 cm step (TanhStep(0.05, 0.3, 0.08, 0.01)) with every
// feasibility set: a problem whose solve takes a few cut steps and iterations.
PlannerOptions all_sets_crawl_over_step() {
  PlannerOptions o;
  o.has_goal = true;
  o.goal = Eigen::Vector3d(0.2, 0.0, 0.0);
  o.constraints = {"all"};
  return o;
}
PhaseTimeline crawl_2s(const robot::RobotModel& r) {
  return make_timeline(load_gait(resolve_gait_path("crawl")), feet_of(r), 1, 2.0);
}

// Ipopt evaluates the Jacobian at an accepted iterate before its intermediate callback sees the
// iterate; a solve that stops at a verified feasible point declines that Jacobian instead of
// computing one it would never use: one Jacobian per iteration, none at the point it stops at
// (Ipopt counts the declined request, so the smaller of its two Jacobian counts is the number
// computed), and the point and iteration count are the ones the callback would have stopped at.
TEST(Solve, ComputesNoJacobianAtThePointItStopsAt) {
  const auto r = hyq();
  testing::TanhStep terrain(0.05, 0.3, 0.08, 0.01);
  const PlannerOptions o = all_sets_crawl_over_step();
  SrbdProblem p(r, terrain, crawl_2s(r), o);
  const std::string log =
      ::testing::TempDir() + "/ipopt_jacobian_count_" + std::to_string(::getpid()) + ".txt";
  std::filesystem::remove(log);
  const SolveResult result =
      solve(p, o, {{"output_file", log}, {"file_print_level", "5"}, {"print_level", "0"}});
  std::ifstream in(log);
  std::stringstream ss;
  ss << in.rdbuf();
  const std::string text = ss.str();
  std::filesystem::remove(log);
  ASSERT_TRUE(result.success) << result.status;
  EXPECT_EQ(result.termination, "feasible_point");
  EXPECT_LE(p.max_violation(result.x), o.feasibility_stop_tolerance);
  auto count = [&](const std::string& label) {
    const auto at = text.find(label);
    if (at == std::string::npos) return -1;
    return std::stoi(text.substr(text.find('=', at) + 1));
  };
  const int equality = count("Number of equality constraint Jacobian evaluations");
  const int inequality = count("Number of inequality constraint Jacobian evaluations");
  ASSERT_GE(equality, 0) << text.substr(0, 2000);
  ASSERT_GE(inequality, 0) << text.substr(0, 2000);
  ASSERT_GT(result.iterations, 0);
  // Iterates 0 .. iterations - 1 had their Jacobian; the last iterate, where it stopped, had none.
  // (Ipopt's own "Number of Iterations" is not compared: on the evaluation error it is sometimes
  // the iterate before, where session steps count, as before, the iterate the solve stopped at.)
  EXPECT_EQ(std::min(equality, inequality), result.iterations);
}

// TERRASTRIDE_DEBUG_STEPS (planner/src/step_blockers.hpp) names the rows that cut each step: a
// step is at most the fraction-to-the-boundary rule's, tau (<= 1) times the smallest ratio it
// prints, and a step cut by that rule alone is 0.99 times it (tau = 0.99 while mu > 0.01), so the
// row it names first is the one that cut the step.
TEST(Solve, DebugStepsNamesTheRowsThatCutTheStep) {
  const auto r = hyq();
  testing::TanhStep terrain(0.05, 0.3, 0.08, 0.01);
  const PlannerOptions o = all_sets_crawl_over_step();
  SrbdProblem p(r, terrain, crawl_2s(r), o);
  ::setenv("TERRASTRIDE_DEBUG_STEPS", "1", 1);
  ::testing::internal::CaptureStderr();
  const SolveResult result = solve(p, o);
  const std::string err = ::testing::internal::GetCapturedStderr();
  ::unsetenv("TERRASTRIDE_DEBUG_STEPS");
  ASSERT_TRUE(result.success) << result.status;
  std::istringstream lines(err);
  std::string line;
  int steps = 0, cut_by_the_named_row = 0;
  double alpha = 0.0;
  std::set<std::string> kinds;
  for (const auto& piece : p.pieces()) kinds.insert(piece->kind);
  while (std::getline(lines, line)) {
    int step = 0;
    if (std::sscanf(line.c_str(), "step %d alpha_pr %lf", &step, &alpha) == 2) {
      ++steps;
      continue;
    }
    const std::string head = "  smallest gap/(-dgap): ";
    if (line.rfind(head, 0) != 0) continue;
    // "KIND row N (FEET kA-B) [before -> after in lo, hi] RATIO; ..."
    const std::string first = line.substr(head.size(), line.find(';') - head.size());
    EXPECT_TRUE(kinds.count(first.substr(0, first.find(' '))) > 0) << first;
    const double ratio = std::stod(first.substr(first.rfind(' ') + 1));
    EXPECT_LE(alpha, ratio * 1.01) << line;  // printed to 3 digits
    if (alpha < 1.0 && std::abs(alpha - 0.99 * ratio) <= 0.01 * ratio) ++cut_by_the_named_row;
  }
  // Every regular iteration (restoration-phase ones are not reported).
  EXPECT_GT(steps, 0);
  EXPECT_LE(steps, result.feasibility_iterations);
  EXPECT_GT(cut_by_the_named_row, 0) << err;
}

TEST(NlpDerivatives, IpoptDerivativeCheckerFindsNoErrors) {
  const auto r = hyq();
  testing::TanhStep terrain(0.05, 0.3, 0.08, 0.01);
  PlannerOptions o;
  o.has_goal = true;
  o.goal = Eigen::Vector3d(0.2, 0.0, 0.0);
  o.optimize_timing = true;
  o.max_iterations = 0;
  const PhaseTimeline tl = make_timeline(load_gait(resolve_gait_path("trot")), feet_of(r), 1, 0.8);
  SrbdProblem p(r, terrain, tl, o);
  // Per process: ctest runs test binaries (and other checkouts run theirs) at the same time.
  const std::string log =
      ::testing::TempDir() + "/ipopt_derivative_test_" + std::to_string(::getpid()) + ".txt";
  std::filesystem::remove(log);
  solve(p, o,
        {{"derivative_test", "first-order"},
         {"derivative_test_perturbation", "1e-7"},
         {"derivative_test_tol", "1e-4"},
         {"output_file", log},
         {"file_print_level", "4"}});
  std::ifstream in(log);
  std::stringstream ss;
  ss << in.rdbuf();
  const std::string text = ss.str();
  std::filesystem::remove(log);
  ASSERT_NE(text.find("derivative checker"), std::string::npos) << "no checker output in " << log;
  EXPECT_NE(text.find("No errors detected by derivative checker"), std::string::npos)
      << text.substr(0, 4000);
}

// The goal pose rests on the terrain: its pitch follows the plane through the terrain under the
// nominal feet (nose up when the front feet stand higher), and is level on flat ground. A level
// base could not stand with its front feet 0.24 m above its hind feet: the range-of-motion box
// spans 2 x 0.10 m in height (the stairs scenario).
TEST(Nlp, GoalPitchFollowsTheTerrainUnderTheNominalFeet) {
  const auto r = hyq();
  const PhaseTimeline tl =
      make_timeline(load_gait(resolve_gait_path("crawl")), feet_of(r), 3, 11.0);
  PlannerOptions o;
  o.has_goal = true;
  o.goal = Eigen::Vector3d(1.0, 0.0, 0.0);
  testing::FlatField flat;
  // 0 under the hind feet (x 0.69), 0.24 m under the front feet (x 1.31).
  testing::TanhStep step(0.24, 1.0, 0.005);
  const SrbdProblem pf(r, flat, tl, o), ps(r, step, tl, o);
  const int gf = pf.layout().base.back(), gs = ps.layout().base.back();
  for (int d = 7; d <= 8; ++d) {  // pitch, roll: fixed at the goal
    EXPECT_EQ(pf.lower()[gf + d], pf.upper()[gf + d]);
    EXPECT_EQ(ps.lower()[gs + d], ps.upper()[gs + d]);
  }
  EXPECT_NEAR(pf.lower()[gf + 7], 0.0, 1e-12);
  EXPECT_NEAR(pf.lower()[gf + 8], 0.0, 1e-12);
  const double dx = r.legs[0].nominal_foot.x() - r.legs[2].nominal_foot.x();  // 0.62 m
  EXPECT_NEAR(ps.lower()[gs + 7], -std::atan(0.24 / dx), 1e-4);
  EXPECT_NEAR(ps.lower()[gs + 8], 0.0, 1e-9);
}

// A receding-horizon step (planning sessions) holds the end at the reference's state:
// the base, the feet at its foot positions and its forces, so that the next step's guess (this
// plan, then the reference) agrees across the splice; a stance the start fixes keeps the start's.
TEST(Nlp, HorizonEndPinsTheBaseAndTheFeet) {
  const auto r = hyq();
  testing::FlatField flat;
  PlannerOptions o;
  o.has_goal = true;
  o.goal = Eigen::Vector3d(0.3, 0.0, 0.0);
  const PhaseTimeline tl = make_timeline(load_gait(resolve_gait_path("crawl")), feet_of(r), 1, 2.0);
  SrbdProblem free_end(r, flat, tl, o);
  auto state_at = [&](double t) {
    return testing::start_state_of(free_end.evaluate(free_end.initial_guess(), t));
  };
  const SrbdProblem::StartState start = state_at(0.0);
  SrbdProblem::StartState end = state_at(free_end.duration(free_end.initial_guess()));
  // Footholds and forces the problem's own guess would not choose, to see them pinned.
  for (auto& p : end.foot_position) p += Eigen::Vector3d(0.03, -0.02, 0.0);
  for (std::size_t f = 0; f < r.legs.size(); ++f)
    end.foot_force.push_back(Eigen::Vector3d(10.0 + f, -5.0, 150.0 + 10.0 * f));
  SrbdProblem p(r, flat, tl, o, &start, &end);
  const Layout& L = p.layout();
  const int S = L.num_segments;
  int pinned = 0;
  for (std::size_t f = 0; f < r.legs.size(); ++f) {
    const int pv = L.foot_pos[f][S];
    ASSERT_GE(pv, 0);
    bool fixed_by_start = false;
    for (const auto& st : L.stances)
      fixed_by_start |= st.foot == static_cast<int>(f) && st.fixed && st.last_seg == S - 1;
    const Eigen::Vector3d& want = fixed_by_start ? start.foot_position[f] : end.foot_position[f];
    for (int d = 0; d < 3; ++d) {
      EXPECT_EQ(p.lower()[pv + d], p.upper()[pv + d]) << "foot " << f << " axis " << d;
      EXPECT_DOUBLE_EQ(p.lower()[pv + d], want[d]) << "foot " << f << " axis " << d;
    }
    pinned += !fixed_by_start;
  }
  EXPECT_EQ(pinned, static_cast<int>(r.legs.size()));  // a 2 s crawl: no stance spans it all
  int forces = 0;
  for (std::size_t f = 0; f < r.legs.size(); ++f) {
    const int fv = L.force[f][S - 1][1];
    if (fv < 0) continue;  // no force variable at the end knot (a ramp's zero)
    ++forces;
    for (int d = 0; d < 3; ++d) {
      EXPECT_EQ(p.lower()[fv + d], p.upper()[fv + d]) << "foot " << f << " axis " << d;
      EXPECT_DOUBLE_EQ(p.lower()[fv + d], end.foot_force[f][d]) << "foot " << f << " axis " << d;
    }
  }
  EXPECT_GT(forces, 0);
  const int g = L.base[S];
  for (int d = 0; d < 3; ++d) {
    EXPECT_EQ(p.lower()[g + d], end.position[d]);
    EXPECT_EQ(p.upper()[g + d], end.position[d]);
  }
  // Without an end state the last footholds stay free.
  for (std::size_t f = 0; f < r.legs.size(); ++f) {
    const int pv = free_end.layout().foot_pos[f][S];
    EXPECT_LT(free_end.lower()[pv], free_end.upper()[pv]);
  }
}

TEST(Nlp, UnknownConstraintSetIsNamed) {
  const auto r = hyq();
  testing::FlatField flat;
  PlannerOptions o;
  o.constraints = {"baseline", "warp_drive"};
  const PhaseTimeline tl = make_timeline(load_gait(resolve_gait_path("trot")), feet_of(r), 1, 0.8);
  try {
    SrbdProblem p(r, flat, tl, o);
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("warp_drive"), std::string::npos);
  }
}

}  // namespace
}  // namespace terrastride::planner
