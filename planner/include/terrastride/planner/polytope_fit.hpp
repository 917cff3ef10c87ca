// Fitting the interpolated force-polytope model (polytope_model.hpp) to exact polytopes sampled
// over a leg's workspace, with Ceres, and the quality figures rho_out / rho_in.
//
// rho_out(p) = max over the approximate polytope's vertices v of max_i |J_i^T v| / tau_i: the
//   smallest s with P_approx inside s * P_exact. 1 = exact; > 1: a force the approximation allows
//   exceeds a torque limit by that factor.
// rho_in(p)  = the largest s with s * P_exact inside P_approx, i.e. 1 / max over the exact
//   vertices w and approximate facets j of n_j^T w / d_j: how much of the exact polytope the
//   approximation keeps (1 = all of it; 0.9 = every exact force scaled by 0.9 is allowed).
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "terrastride/planner/polytope_model.hpp"
#include "terrastride/robot/robot_model.hpp"

namespace terrastride::planner {

struct PolytopeFitOptions {
  // Training foot positions per leg. 600 fit as well as 1200 on held-out positions (Go2:
  // worst rho_out 1.0098 vs 1.0078, rho_in median 0.988 both) in half the time.
  int samples = 600;
  uint64_t seed = 1;
  double box_scale = 1.25;  // sample the range-of-motion box scaled by this around the nominal
  int l_refs = 7;           // reference leg lengths (>= 2)
  int alpha_refs = 3;       // reference tilts (1 = the paper's interpolation in l only)
  bool fit_hip = true;      // refine the hip point and offset (start: HAA origin and L0)
  // Weight of torque-ratio residuals above 1 (a force allowed beyond a limit) relative to those
  // below 1 (a feasible force cut off): > 1 biases the fit to the conservative side.
  double overshoot_weight = 8.0;
  // Weight of the smoothness prior on the reference grid (second differences), relative to the
  // data; scaled with sqrt(samples) so its share stays put as the sample count changes.
  double smoothness = 0.02;
  // After the fit all offsets are scaled so that the training samples' worst rho_out is at most
  // this (<= 0 disables the scaling).
  double max_training_rho_out = 1.01;
  int max_iterations = 60;  // Ceres iterations per round
  int rounds = 2;           // re-assign samples to grid cells after the hip moved
  // Threads: legs are fitted in parallel, one leg per thread (fit_robot_polytopes); a single
  // leg's fit gives them to Ceres' Jacobian evaluation.
  int num_threads = 2;
  // Legs that are copies of an earlier leg (LegCopy: mirror twins, translated copies) take its
  // fitted model mirrored instead of a fit of their own, when on their own training samples the
  // copy's rho_in median is at most `copy_rho_in_tolerance` below the source's (after the same
  // conservative offset scaling); otherwise they are fitted.
  bool copy_legs = true;
  double copy_rho_in_tolerance = 0.005;
};

// The fit's settings as one line, recorded in the polytope file ("fit").
std::string describe_fit(const PolytopeFitOptions& options);

// Uniform samples in the scaled range-of-motion box whose inverse kinematics lies within the
// joint limits. Throws std::runtime_error naming the leg when too few positions are feasible.
std::vector<Eigen::Vector3d> sample_leg_workspace(const robot::LegModel& leg, int count,
                                                  uint64_t seed, double box_scale = 1.25);

// rho_out and rho_in of `model` at one foot position (see above).
double polytope_rho_out(const LegPolytopeModel& model, const robot::LegModel& leg,
                        const Eigen::Vector3d& foot);
double polytope_rho_in(const LegPolytopeModel& model, const robot::LegModel& leg,
                       const Eigen::Vector3d& foot);

struct PolytopeQuality {
  int samples = 0;
  double rho_out_median = 0, rho_out_p95 = 0, rho_out_max = 0;
  double rho_in_median = 0, rho_in_min = 0;
};
PolytopeQuality evaluate_polytope_quality(const LegPolytopeModel& model, const robot::LegModel& leg,
                                          const std::vector<Eigen::Vector3d>& feet);

struct LegFitReport {
  std::string leg;
  int samples = 0;
  double initial_cost = 0, final_cost = 0;
  int iterations = 0;
  double offset_scale = 1.0;  // the final conservative scaling of the offsets
  PolytopeQuality training;
  double wall_s = 0;
  // Non-empty when the leg was not fitted but copied from an identical or mirrored leg
  // (LegCopy): that leg's name and the mapping, e.g. "LF mirrored in y".
  std::string copied_from;
  // Non-empty when the fit started from such a copy (rejected as it was: fitted worse than its
  // source, see fit_robot_polytopes) instead of from the exact polytopes.
  std::string started_from;
};

// Leg `target` is a copy of leg `source` when its exact force polytope at every foot position p
// is the source's at p_s = source.haa_origin + M (p - target.haa_origin), mirrored by M:
// M = diag(mirror_x, mirror_y, 1) (mirror_y = -1: a left leg's right twin; mirror_x = -1: a
// front leg's hind twin with the knee mirrored too; both +1: a translated copy). Facet j of the
// target is the mirror image of facet source_facet[j] of the source (a mirrored joint axis
// swaps its + and - torque-limit facets).
struct LegCopy {
  int source = -1;  // index of the source leg in the robot
  int mirror_x = 1, mirror_y = 1;
  std::array<int, kPolytopeFacets> source_facet{{0, 1, 2, 3, 4, 5}};
  std::string describe(const std::string& source_name) const;
};

// Whether `target` is a copy of `source` under one of the four mirrors (tried in the order
// translated, mirrored in y, in x, in both), checked numerically on the exact polytopes at the
// target's nominal foot and at `check_feet`: unit normals and offsets equal within 1e-9
// relative. The source leg's index is left to the caller.
std::optional<LegCopy> find_leg_copy(const robot::LegModel& source, const robot::LegModel& target,
                                     const std::vector<Eigen::Vector3d>& check_feet);

// The source leg's fitted model carried over to the target leg by the copy's mirror (exact: the
// mirrored model's facets at p equal the mirror of the source model's at p_s).
LegPolytopeModel copy_leg_polytope(const LegPolytopeModel& fitted_source,
                                   const robot::LegModel& source, const robot::LegModel& target,
                                   const LegCopy& copy);

// The paper's model with three exact reference polytopes (most retracted, nominal and most
// extended leg length of `feet`, along the nominal foot's direction), nothing fitted.
// with_roll = false: the paper's sagittal-only variant, hip fixed at the nominal HFE joint.
// with_roll = true: an ablation step towards ours: roll about the HAA axis and l, alpha measured
// from the (rolled) HFE joint, taken from the robot's joint geometry.
LegPolytopeModel paper_polytope_model(const robot::LegModel& leg,
                                      const std::vector<Eigen::Vector3d>& feet,
                                      bool with_roll = false);

// Our variant, fitted by least squares on the exact polytopes at `feet` (see polytope_fit.cpp).
// `start`: a model of this leg to start from, its grid (options' l_refs x alpha_refs), hip and
// nodes (a twin leg's mirrored model), instead of the grid over the feet's range with the exact
// polytopes of the samples nearest its nodes.
LegPolytopeModel fit_leg_polytope(const robot::LegModel& leg,
                                  const std::vector<Eigen::Vector3d>& feet,
                                  const PolytopeFitOptions& options, LegFitReport* report,
                                  const LegPolytopeModel* start = nullptr);

// Samples and fits every leg of a robot. A leg that is a copy of an earlier fitted leg
// (find_leg_copy) takes that leg's model mirrored when, on its own training samples and after
// the same conservative offset scaling as a fit, it fits as well as the source did on its own
// (rho_out max <= max_training_rho_out, rho_in median within copy_rho_in_tolerance of the
// source's); otherwise it is fitted, starting from the mirrored model.
RobotPolytopeModel fit_robot_polytopes(const robot::RobotModel& model,
                                       const PolytopeFitOptions& options,
                                       std::vector<LegFitReport>* reports);

}  // namespace terrastride::planner
