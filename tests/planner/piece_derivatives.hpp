// Finite-difference check of constraint pieces, shared by the NLP and feasibility tests: every
// checked piece's exact Jacobian against central differences of its own values, at the initial
// guess perturbed by Gaussian noise. Also: the number of pieces of each kind.
#pragma once

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <map>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "terrastride/planner/nlp.hpp"

namespace terrastride::planner::testing {

// Pieces per kind ("swing" -> 24, ...).
inline std::map<std::string, int> count_kinds(const SrbdProblem& p) {
  std::map<std::string, int> c;
  for (const auto& piece : p.pieces()) ++c[piece->kind];
  return c;
}

// Checks the pieces for which `select(piece)` is true; stops at the first mismatch (reported with
// the piece kind, row and variable). Returns the number of pieces checked.
// The same over another list of pieces (the objective's cost pieces) of problem p.
inline int check_piece_derivatives(const SrbdProblem& p,
                                   const std::vector<std::unique_ptr<Piece>>& pieces, unsigned seed,
                                   double noise_size,
                                   const std::function<bool(const Piece&)>& select) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0.0, 1.0);
  std::vector<double> x = const_cast<SrbdProblem&>(p).initial_guess();
  for (double& v : x) v += noise_size * noise(rng);
  int checked = 0;
  for (const auto& piece : pieces) {
    if (!select(*piece)) continue;
    ++checked;
    const int n = static_cast<int>(piece->vars.size()), m = piece->rows();
    std::vector<double> xl(n), g(m), J(m * n), g2(m), gp(m), gm(m);
    for (int i = 0; i < n; ++i) xl[i] = x[piece->vars[i]];
    piece->eval_jacobian(xl.data(), g.data(), J.data());
    piece->eval(xl.data(), g2.data());
    for (int r = 0; r < m; ++r) {
      if (!(std::abs(g[r] - g2[r]) <= 1e-12)) {
        ADD_FAILURE() << piece->kind << " row " << r << ": value with Jacobian " << g[r]
                      << ", without " << g2[r];
        return checked;
      }
    }
    for (int i = 0; i < n; ++i) {
      const double h = 1e-6 * std::max(1.0, std::abs(xl[i]));
      auto xp = xl, xm = xl;
      xp[i] += h;
      xm[i] -= h;
      piece->eval(xp.data(), gp.data());
      piece->eval(xm.data(), gm.data());
      for (int r = 0; r < m; ++r) {
        const double fd = (gp[r] - gm[r]) / (2 * h);
        if (!(std::abs(J[r * n + i] - fd) <= 1e-5 * std::max(1.0, std::abs(fd)))) {
          ADD_FAILURE() << piece->kind << " row " << r << " var " << i << " (global "
                        << piece->vars[i] << "): jacobian " << J[r * n + i]
                        << ", central difference " << fd;
          return checked;
        }
      }
    }
  }
  return checked;
}

inline int check_piece_derivatives(const SrbdProblem& p, unsigned seed, double noise_size,
                                   const std::function<bool(const Piece&)>& select) {
  return check_piece_derivatives(p, p.pieces(), seed, noise_size, select);
}

}  // namespace terrastride::planner::testing
