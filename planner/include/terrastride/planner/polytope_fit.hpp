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
#include <cstdint>
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
};

// The paper's model with three exact reference polytopes (most retracted, nominal and most
// extended leg length of `feet`, along the nominal foot's direction), nothing fitted.
// with_roll = false: the paper's sagittal-only variant, hip fixed at the nominal HFE joint.
// with_roll = true: an ablation step towards ours: roll about the HAA axis and l, alpha measured
// from the (rolled) HFE joint, taken from the robot's joint geometry.
LegPolytopeModel paper_polytope_model(const robot::LegModel& leg,
                                      const std::vector<Eigen::Vector3d>& feet,
                                      bool with_roll = false);

// Our variant, fitted by least squares on the exact polytopes at `feet` (see polytope_fit.cpp).
LegPolytopeModel fit_leg_polytope(const robot::LegModel& leg,
                                  const std::vector<Eigen::Vector3d>& feet,
                                  const PolytopeFitOptions& options, LegFitReport* report);

// Samples and fits every leg of a robot.
RobotPolytopeModel fit_robot_polytopes(const robot::RobotModel& model,
                                       const PolytopeFitOptions& options,
                                       std::vector<LegFitReport>* reports);

}  // namespace terrastride::planner
