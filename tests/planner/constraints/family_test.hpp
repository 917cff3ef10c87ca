// Shared by the constraint-family tests (one file per family, beside constraints/FAMILY.cpp): a
// small problem on which every derivative path is exercised, a perturbed point, the pieces one
// call of a family's builder adds, a piece's rows at a point, and what the checks compare against
// (the time a segment starts, the base rotation from Eigen's angle-axis product).
#pragma once

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <functional>
#include <random>
#include <string>
#include <vector>

#include "../piece_derivatives.hpp"
#include "../test_robots.hpp"
#include "../test_states.hpp"
#include "../test_terrains.hpp"
#include "terrastride/planner/constraints.hpp"
#include "terrastride/planner/feasibility.hpp"
#include "terrastride/planner/gait.hpp"
#include "terrastride/planner/nlp.hpp"

namespace terrastride::planner::testing {

// HyQ's crawl, one cycle in 2 s, to a goal 0.4 m ahead and turned by 0.3 rad (so the yaw paths are
// exercised), with the phase durations as variables when `timing` (so are the duration paths).
inline ProblemOptions turning_crawl_options(bool timing = true) {
  ProblemOptions o;
  o.has_goal = true;
  o.goal = Eigen::Vector3d(0.4, 0.05, 0.3);
  o.optimize_timing = timing;
  o.cycles = 1;
  return o;
}
// The feasibility sets' value tests: the same crawl to (0.4, 0, 0.3), fixed timing.
inline ProblemOptions paper_test_options() {
  ProblemOptions o = turning_crawl_options(false);
  o.goal = Eigen::Vector3d(0.4, 0.0, 0.3);
  return o;
}
inline PhaseTimeline crawl_timeline(const robot::RobotModel& r, double duration = 2.0) {
  return make_timeline(load_gait(resolve_gait_path("crawl")), feet_of(r), 1, duration);
}

// The initial guess with Gaussian noise of standard deviation `size` on every free variable.
inline std::vector<double> perturbed_guess(SrbdProblem& p, unsigned seed, double size) {
  std::vector<double> x = p.initial_guess();
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0.0, size);
  for (std::size_t i = 0; i < x.size(); ++i)
    if (p.lower()[i] < p.upper()[i]) x[i] += noise(rng);
  return x;
}

// The pieces `add()` appends to `p`, in order.
inline std::vector<const Piece*> pieces_added_by(SrbdProblem& p, const std::function<void()>& add) {
  const std::size_t before = p.pieces().size();
  add();
  std::vector<const Piece*> out;
  for (std::size_t i = before; i < p.pieces().size(); ++i) out.push_back(p.pieces()[i].get());
  return out;
}

// A piece's rows at the point x (all variables).
inline std::vector<double> rows_at(const Piece& piece, const std::vector<double>& x) {
  std::vector<double> xl(piece.vars.size()), g(piece.rows());
  for (std::size_t i = 0; i < xl.size(); ++i) xl[i] = x[piece.vars[i]];
  piece.eval(xl.data(), g.data());
  return g;
}

// The number of pieces of `kind` whose Jacobian matches central differences (3 seeds; stops at
// the first mismatch, reported by check_piece_derivatives).
inline int check_kind_derivatives(const SrbdProblem& p, const std::string& kind,
                                  double noise = 0.02) {
  int checked = 0;
  for (unsigned seed : {1u, 2u, 3u})
    checked += check_piece_derivatives(p, seed, noise,
                                       [&](const Piece& piece) { return piece.kind == kind; });
  return checked;
}

// The largest |dg/dx| over the given pieces (or those of `kind`) at the initial guess: a derivative test passes
// trivially for rows that ignore their variables.
inline double largest_jacobian_entry(const SrbdProblem& p, const std::vector<const Piece*>& pieces) {
  const auto& x = const_cast<SrbdProblem&>(p).initial_guess();
  double largest = 0.0;
  for (const Piece* piece : pieces) {
    const int n = static_cast<int>(piece->vars.size()), m = piece->rows();
    std::vector<double> xl(n), g(m), J(m * n);
    for (int i = 0; i < n; ++i) xl[i] = x[piece->vars[i]];
    piece->eval_jacobian(xl.data(), g.data(), J.data());
    for (double v : J) largest = std::max(largest, std::abs(v));
  }
  return largest;
}

inline double largest_jacobian_entry(const SrbdProblem& p, const std::string& kind) {
  std::vector<const Piece*> of_kind;
  for (const auto& piece : p.pieces())
    if (piece->kind == kind) of_kind.push_back(piece.get());
  return largest_jacobian_entry(p, of_kind);
}

// When segment s starts at the point x (its duration variables), and how long it lasts.
inline double segment_start(const Layout& L, const std::vector<double>& x, int s) {
  double t = 0.0;
  for (int k = 0; k < s; ++k) t += x[L.interval_var[L.seg_interval[k]]] * L.seg_fraction[k];
  return t;
}
inline double segment_length(const Layout& L, const std::vector<double>& x, int s) {
  return x[L.interval_var[L.seg_interval[s]]] * L.seg_fraction[s];
}

// The four Bezier control points of segment s of a cubic Hermite spline, from the values and
// derivatives the problem evaluates at the segment's ends (value(state) and rate(state) pick the
// spline: the base position, a foot's position...): P0, P0 + h v0 / 3, P1 - h v1 / 3, P1.
inline std::array<Eigen::Vector3d, 4> bezier_points(
    const SrbdProblem& p, const std::vector<double>& x, int s,
    const std::function<Eigen::Vector3d(const SrbdProblem::State&)>& value,
    const std::function<Eigen::Vector3d(const SrbdProblem::State&)>& rate) {
  const double t0 = segment_start(p.layout(), x, s), h = segment_length(p.layout(), x, s);
  const auto a = p.evaluate(x, t0), b = p.evaluate(x, t0 + h);  // C1: either side of the knot
  return {value(a), value(a) + h * rate(a) / 3.0, value(b) - h * rate(b) / 3.0, value(b)};
}

// The control points of segment s's two halves (split at its middle), from the values and rates
// the problem evaluates at the segment's start, middle and end: A0 A1 A2 M B1 B2 B3 (M ends the
// first half and starts the second).
inline std::array<Eigen::Vector3d, 7> half_bezier_points(
    const SrbdProblem& p, const std::vector<double>& x, int s,
    const std::function<Eigen::Vector3d(const SrbdProblem::State&)>& value,
    const std::function<Eigen::Vector3d(const SrbdProblem::State&)>& rate) {
  const double t0 = segment_start(p.layout(), x, s), h = segment_length(p.layout(), x, s);
  const auto a = p.evaluate(x, t0), m = p.evaluate(x, t0 + 0.5 * h), b = p.evaluate(x, t0 + h);
  const double k = h / 6.0;  // (h / 2) / 3
  return {value(a),          value(a) + k * rate(a), value(m) - k * rate(m), value(m),
          value(m) + k * rate(m), value(b) - k * rate(b), value(b)};
}

inline Eigen::Vector3d vec3_at(const std::vector<double>& x, int i) {
  return Eigen::Vector3d(x[i], x[i + 1], x[i + 2]);
}

// R = Rz(yaw) Ry(pitch) Rx(roll) from Eigen's angle-axis product (not the planner's formula).
inline Eigen::Matrix3d rotation_of(const Eigen::Vector3d& euler_zyx) {
  return (Eigen::AngleAxisd(euler_zyx[0], Eigen::Vector3d::UnitZ()) *
          Eigen::AngleAxisd(euler_zyx[1], Eigen::Vector3d::UnitY()) *
          Eigen::AngleAxisd(euler_zyx[2], Eigen::Vector3d::UnitX()))
      .toRotationMatrix();
}

}  // namespace terrastride::planner::testing
