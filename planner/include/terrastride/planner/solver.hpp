// Solving an SrbdProblem with Ipopt (C++ TNLP interface, MUMPS, limited-memory Hessian).
#pragma once

#include <string>
#include <utility>
#include <vector>

#include "terrastride/planner/nlp.hpp"

namespace terrastride::planner {

struct SolveResult {
  // optimal, acceptable, infeasible, time_limit, stalled (see SolverOptions::stall_iterations),
  // max_iterations, diverging, error, ...
  std::string status;
  bool success = false;  // optimal or acceptable
  int ipopt_status = 0;
  int iterations = 0;
  double wall_s = 0.0;
  std::vector<double> x;
  double max_violation = 0.0;  // largest bound/constraint violation of x
  // "feasible_point": stopped at the first iterate verified feasible to
  // options.feasibility_stop_tolerance (the objective is zero, so that is a solution);
  // "ipopt": Ipopt's own termination.
  std::string termination;
  // With an objective: the iterations of the feasibility phase and of the improvement phase
  // (iterations is their sum), and the objective at the feasibility phase's point.
  int feasibility_iterations = 0;
  int objective_iterations = 0;  // improvement and polish
  int polish_iterations = 0;
  double objective_start = 0.0;
};

// Honours options.max_time on this call (Ipopt's max_cpu_time plus a wall-clock check in the
// intermediate callback, so also repeated solves in one process each get the full budget).
// `extra_options` are Ipopt name=value strings (tests use them, e.g. for the derivative checker).
SolveResult solve(const SrbdProblem& problem, const SolverOptions& options,
                  const std::vector<std::pair<std::string, std::string>>& extra_options = {});

// The Ipopt options in the environment variable `variable`, "name=value name=value ..." (tuning
// runs: TERRASTRIDE_IPOPT_OPTIONS for every solve, TERRASTRIDE_STEP_IPOPT_OPTIONS for planning
// session steps); none when it is unset. Items without '=' are ignored.
std::vector<std::pair<std::string, std::string>> ipopt_options_from_env(const char* variable);

}  // namespace terrastride::planner
