// The objective's terms by weight, and its value and gradient (costs.hpp).
#include <algorithm>

#include "costs.hpp"
#include "terrastride/planner/piece_math.hpp"

namespace terrastride::planner {

void build_objective(SrbdProblem& problem) {
  const ObjectiveWeights& w = problem.options().objective;
  if (w.base_acceleration > 0 || w.base_angular_acceleration > 0)
    add_base_acceleration_cost(problem, w.base_acceleration, w.base_angular_acceleration);
  if (w.force_rate > 0) add_force_rate_cost(problem, w.force_rate);
  if (w.swing_acceleration > 0) add_swing_acceleration_cost(problem, w.swing_acceleration);
  if (w.body_height > 0 || w.heading > 0 || w.lateral > 0 || w.progress > 0)
    add_nominal_pose_cost(problem, w.body_height, w.heading, w.lateral, w.progress);
  if (w.base_jerk > 0) add_base_jerk_cost(problem, w.base_jerk);
}

void SrbdProblem::add_cost(std::unique_ptr<Piece> piece) { cost_pieces_.push_back(std::move(piece)); }

double SrbdProblem::eval_objective(const double* x) const {
  double xl[kMaxPieceVars], g[64];
  double f = 0.0;
  for (const auto& p : cost_pieces_) {
    for (std::size_t k = 0; k < p->vars.size(); ++k) xl[k] = x[p->vars[k]];
    p->eval(xl, g);
    for (int r = 0; r < p->rows(); ++r) f += g[r] * g[r];
  }
  return f;
}

void SrbdProblem::eval_objective_gradient(const double* x, double* grad) const {
  std::fill(grad, grad + num_variables(), 0.0);
  double xl[kMaxPieceVars], g[64];
  std::vector<double> jac(64 * kMaxPieceVars);
  for (const auto& p : cost_pieces_) {
    const int n = static_cast<int>(p->vars.size());
    for (int k = 0; k < n; ++k) xl[k] = x[p->vars[k]];
    p->eval_jacobian(xl, g, jac.data());
    for (int r = 0; r < p->rows(); ++r)
      for (int k = 0; k < n; ++k) grad[p->vars[k]] += 2.0 * g[r] * jac[r * n + k];
  }
}

}  // namespace terrastride::planner
