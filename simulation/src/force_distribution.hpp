// Stance forces for the tracking controller's trunk wrench (ControllerOptions::force_distribution):
// the clipped distribution's least-norm spread and cone projection, and the constrained one.
// Not part of the library's interface; tests include it from simulation/src.
#pragma once

#include <Eigen/Core>
#include <vector>

namespace terrastride::simulation::internal {

// Spreads a trunk wrench (force, moment about the base) over the stance feet at `lever` from the
// base: the least-norm forces that produce it (the clipped distribution, before into_cone).
std::vector<Eigen::Vector3d> spread_wrench(const Eigen::Matrix<double, 6, 1>& w,
                                           const std::vector<Eigen::Vector3d>& lever);

// Projects a foot force into the cone |f_t| <= mu f_n about the normal n, with f_n >= 0.
Eigen::Vector3d into_cone(const Eigen::Vector3d& f, const Eigen::Vector3d& n, double mu);

// One stance foot: the force the controller would command (planned force plus its share of the
// trunk wrench), the foot's lever from the base, and the terrain's unit normal under it.
struct StanceFoot {
  Eigen::Vector3d desired = Eigen::Vector3d::Zero();
  Eigen::Vector3d lever = Eigen::Vector3d::Zero();
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();
};

// The weights of the constrained distribution: the wrench's moment rows count `angular` times
// its horizontal force rows (N m against N; a foot 0.3-0.4 m from the base makes 1 N m per 3 N)
// and its vertical row `vertical` times, and the forces are held near the desired ones by
// `regularisation` (per N^2 against the wrench's).
struct ForceDistributionWeights {
  double angular = 10.0;
  double vertical = 1.0;
  double regularisation = 1e-2;
};

// The forces, one per foot, each within the pyramid inscribed in its friction cone of
// coefficient mu (an octagonal pyramid, so f.n >= 0: a foot never pulls), whose trunk
// wrench (sum of f, sum of lever x f) is nearest to that of the desired forces and which are
// nearest to them: min |W (G f - G f_desired)|^2 + regularisation |f - f_desired|^2. A bounded
// linear least-squares problem over each foot's pyramid edge weights (>= 0), solved as a
// box-constrained quadratic program by ALGLIB's QuickQP (Ceres's bounded trust region stopped
// 2.5 % above the minimum on such problems). Desired forces already within their pyramids are
// returned as they are (the minimum is then 0 there); otherwise, where the wrench cannot be had
// with every foot pushing, the moment is kept first: the trunk is not rolled by a foot asked to
// pull, which the clipped distribution did (benchmarks.md §12.2).
std::vector<Eigen::Vector3d> constrained_stance_forces(const std::vector<StanceFoot>& feet,
                                                       double mu,
                                                       const ForceDistributionWeights& w = {});

// Whether f lies within the pyramid of constrained_stance_forces about the unit normal n.
bool within_friction_pyramid(const Eigen::Vector3d& f, const Eigen::Vector3d& n, double mu);

}  // namespace terrastride::simulation::internal
