// The initial guess of the SRBD problem's variables (TOWR keeps its initialization/ apart from
// the constraints), built in this order, each step reading what the previous ones set:
//  1. the base from the start to the goal, and as bounds what is not free: the start state, the
//     goal pose and the robot's locked degrees of freedom (base_guess.cpp);
//  2. the feet: footholds under the guessed base, swing knots between them (feet_guess.cpp);
//  3. contact forces that balance the guessed base motion (force_guess.cpp).
// A re-plan then overwrites the free variables with the previous plan (SrbdProblem::
// warm_start_from).
#pragma once

#include <Eigen/Core>

#include "terrastride/planner/nlp.hpp"

namespace terrastride::planner::initialization {

// What the guess is made from.
struct GuessInputs {
  const robot::RobotModel& robot;
  const terrain::HeightField& terrain;
  const PhaseTimeline& timeline;
  const ProblemOptions& options;
  const Layout& layout;
  const SrbdProblem::StartState* start;  // null: the nominal stance at options.start
};

// The base's state at the start and its pose at the goal, between which the guess runs.
struct BaseBoundary {
  Eigen::Vector3d start_position, start_euler, start_velocity, start_euler_rates;
  Eigen::Vector3d goal_position, goal_euler;
};

// All of the guess. `variables` holds the layout's bounds; this sets every initial value, and the
// bounds of the variables the start, the goal and the robot's locked degrees of freedom fix.
void build_initial_guess(const GuessInputs& in, Variables* variables);

// The base knots from the start to the goal, and those two states.
BaseBoundary guess_base_motion(const GuessInputs& in, Variables* variables);
// The start state and the goal as bounds; locked degrees of freedom held at their start value.
void fix_base_boundary(const GuessInputs& in, const BaseBoundary& boundary, Variables* variables);
// Stance footholds under the guessed base (the initial stances' fixed where they stand).
void guess_footholds(const GuessInputs& in, const BaseBoundary& boundary, Variables* variables);
// Swing knots between the footholds, lifted above the terrain around them.
void guess_swing_feet(const GuessInputs& in, const BaseBoundary& boundary, Variables* variables);
// Contact forces in dynamic balance with the guessed base motion, at knots first..last (all by
// default).
void guess_forces(const GuessInputs& in, Variables* variables, int first_knot = 0,
                  int last_knot = -1);

}  // namespace terrastride::planner::initialization
