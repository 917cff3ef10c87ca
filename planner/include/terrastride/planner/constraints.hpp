// The constraints of the SRBD problem: one family per file in planner/src/constraints/ (TOWR keeps
// one file per constraint under constraints/), the sets `--constraints` names made of them, and
// the one registry that maps each set's name to its builder.
//
// Names. A family's pieces carry its name as their kind (Piece::kind), and its file has that name:
// the "shin_ik" set adds pieces of kind "shin_ik" from constraints/shin_ik.cpp. The sets beyond
// the baseline are one family each, named as `--constraints` names them (foot, shin, shin_ik,
// polytope, swing, joints; feasibility.hpp). The baseline set is eight families, built in
// constraints/baseline.cpp:
//   dynamics_linear   m r'' = sum f - m g at both ends of every segment;
//   dynamics_angular  the base's angular momentum balance at points of every segment;
//   range_of_motion   each foot in its box around the nominal foot, in the base frame;
//   stance_height     a stance foot on the terrain;
//   foothold_planarity  a stance foot where the terrain is locally planar;
//   friction          contact forces in the friction pyramid, below the normal force limit;
//   swing_clearance   a swing foot above the terrain probed around it;
//   total_duration    the phase durations sum to the plan's duration (optimised timing only);
//   rest_boundary     zero base accelerations where the plan is at rest: its end, and its start
//                     unless it starts from a given state (ProblemOptions::rest_boundaries).
#pragma once

#include <functional>
#include <string>
#include <utility>
#include <vector>

namespace terrastride::planner {

class SrbdProblem;

// ---- The registry of constraint sets ----

// Appends a set's pieces to the problem.
using ConstraintSetBuilder = std::function<void(SrbdProblem&)>;
// Adds (or replaces) a set by name. The built-in sets are there from the start.
void register_constraint_set(const std::string& name, ConstraintSetBuilder builder);
// "baseline", the other registered sets in name order, then "all".
std::vector<std::string> constraint_set_names();

// What "all" expands to, in order.
inline const char* const kAllFeasibilitySets[] = {
    "foot",   "shin_ik",    "thigh",             "trunk",           "polytope",
    "joints", "force_ramp", "monotone_progress", "lateral_corridor", "swing_apex"};
// {set, the set it implies}: the second is added whenever the first is asked for.
inline const std::pair<const char*, const char*> kImpliedFeasibilitySets[] = {
    {"polytope", "swing"}};

// Builds the baseline and then the `requested` sets into `problem`, in order: "all" expanded,
// implied sets added, each set once. Throws std::invalid_argument naming a set that is not
// registered, and the ones that are.
void add_constraint_sets(SrbdProblem& problem, const std::vector<std::string>& requested);

// ---- The baseline set, family by family ----

// Every family below: the per-segment ones segment by segment (each segment's dynamics and range
// of motion together), then the others.
void build_baseline_set(SrbdProblem& problem);

void add_dynamics_linear(SrbdProblem& problem, int segment);
void add_dynamics_angular(SrbdProblem& problem, int segment);
void add_range_of_motion(SrbdProblem& problem, int segment);
void add_stance_height(SrbdProblem& problem);
void add_foothold_planarity(SrbdProblem& problem);
void add_friction(SrbdProblem& problem);
void add_swing_clearance(SrbdProblem& problem);
void add_total_duration(SrbdProblem& problem);
void add_rest_boundary(SrbdProblem& problem);

// Whether the sets `requested` (as --constraints names them) include `set`, with "all" expanded
// and implied sets added (the layout asks this of "force_ramp", which removes force variables).
bool requests_constraint_set(const std::vector<std::string>& requested, const std::string& set);

}  // namespace terrastride::planner
