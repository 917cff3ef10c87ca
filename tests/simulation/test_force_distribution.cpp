// The controller's constrained stance-force distribution (simulation/src/force_distribution.hpp):
// forces within their friction pyramids, the desired ones kept when they already are, and, when
// the wrench cannot be had with every foot pushing, a moment nearer to it than clipping gives.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <limits>

#include "force_distribution.hpp"

namespace {

using Eigen::Vector3d;
using terrastride::simulation::internal::constrained_stance_forces;
using terrastride::simulation::internal::StanceFoot;
using terrastride::simulation::internal::within_friction_pyramid;

constexpr double kMu = 0.45;

// HyQ's four feet 0.6 m below the base, 0.37 m ahead or behind and 0.21 m aside, on flat ground.
std::vector<StanceFoot> four_feet(const std::vector<Vector3d>& desired) {
  const Vector3d lever[] = {
      {0.37, 0.21, -0.6}, {0.37, -0.21, -0.6}, {-0.37, 0.21, -0.6}, {-0.37, -0.21, -0.6}};
  std::vector<StanceFoot> feet;
  for (std::size_t i = 0; i < desired.size(); ++i)
    feet.push_back({desired[i], lever[i], Vector3d::UnitZ()});
  return feet;
}

Eigen::Matrix<double, 6, 1> wrench(const std::vector<StanceFoot>& feet,
                                   const std::vector<Vector3d>& forces) {
  Eigen::Matrix<double, 6, 1> w = Eigen::Matrix<double, 6, 1>::Zero();
  for (std::size_t i = 0; i < feet.size(); ++i) {
    w.head<3>() += forces[i];
    w.tail<3>() += feet[i].lever.cross(forces[i]);
  }
  return w;
}

// Each foot's force clipped into its cone, as the `clipped` distribution does.
Vector3d clipped(const Vector3d& f, double mu) {
  if (f.z() <= 0) return Vector3d::Zero();
  Vector3d out = f;
  const double t = f.head<2>().norm();
  if (t > mu * f.z()) out.head<2>() *= mu * f.z() / t;
  return out;
}

TEST(ForceDistribution, ThePyramidIsTheFrictionConesInscribedOctagon) {
  const Vector3d n = Vector3d::UnitZ();
  EXPECT_TRUE(within_friction_pyramid({0.45, 0, 1}, n, kMu));  // an edge
  EXPECT_TRUE(within_friction_pyramid({0.2, -0.25, 1}, n, kMu));
  // A facet's middle lies at cos(pi/8) of the cone's radius: between, inside the cone only.
  const double facet = kMu * std::cos(M_PI / 8);
  const Vector3d mid(std::cos(M_PI / 8), std::sin(M_PI / 8), 0);
  EXPECT_TRUE(within_friction_pyramid(Vector3d(0, 0, 1) + 0.999 * facet * mid, n, kMu));
  EXPECT_FALSE(within_friction_pyramid(Vector3d(0, 0, 1) + 1.001 * facet * mid, n, kMu));
  EXPECT_FALSE(within_friction_pyramid({0.5, 0, 1}, n, kMu));  // outside the cone
  EXPECT_FALSE(within_friction_pyramid({0, 0, -1}, n, kMu));
  // About a tilted normal the diamond turns with it.
  const Vector3d tilted = Eigen::AngleAxisd(0.3, Vector3d::UnitY()) * n;
  EXPECT_TRUE(within_friction_pyramid(tilted * 100, tilted, kMu));
  EXPECT_FALSE(within_friction_pyramid(Vector3d(0, 0, 100), tilted, 0.2));
}

TEST(ForceDistribution, ForcesWithinTheirPyramidsAreKept) {
  const std::vector<Vector3d> desired = {{10, 5, 200}, {-20, 0, 210}, {0, 30, 190}, {5, -5, 220}};
  const auto feet = four_feet(desired);
  const auto f = constrained_stance_forces(feet, kMu);
  for (std::size_t i = 0; i < f.size(); ++i) EXPECT_EQ(f[i], desired[i]);
}

TEST(ForceDistribution, AFootAskedToPullPushesAndTheMomentIsKept) {
  // After a push to the left the trunk PD asks the right feet to pull (negative normal forces)
  // and the left ones to push hard and sideways: clipping drops the pull, and with it the roll
  // moment those feet were to make.
  const std::vector<Vector3d> desired = {
      {0, -180, 650}, {0, -180, -60}, {0, -180, 650}, {0, -180, -60}};
  const auto feet = four_feet(desired);
  const auto f = constrained_stance_forces(feet, kMu);
  std::vector<Vector3d> clip;
  for (const auto& d : desired) clip.push_back(clipped(d, kMu));
  for (std::size_t i = 0; i < f.size(); ++i) {
    EXPECT_TRUE(within_friction_pyramid(f[i], Vector3d::UnitZ(), kMu * (1 + 1e-9)))
        << "foot " << i << ": " << f[i].transpose();
  }
  const auto want = wrench(feet, desired);
  const double moment_error = (wrench(feet, f) - want).tail<3>().norm();
  const double clipped_moment_error = (wrench(feet, clip) - want).tail<3>().norm();
  EXPECT_LT(moment_error, 0.5 * clipped_moment_error)
      << "constrained " << moment_error << " N m, clipped " << clipped_moment_error << " N m";
}

TEST(ForceDistribution, TheSolutionIsTheBoundedLeastSquaresMinimum) {
  // Two feet, one asked to pull: the best within the pyramids is no worse than any feasible
  // perturbation of it (a first-order optimality check against finite moves).
  const std::vector<Vector3d> desired = {{30, 0, 300}, {0, 40, -50}};
  auto feet = four_feet({desired[0], desired[1]});
  const auto f = constrained_stance_forces(feet, kMu);
  const auto want = wrench(feet, desired);
  auto cost = [&](const std::vector<Vector3d>& x) {
    Eigen::Matrix<double, 6, 1> e = wrench(feet, x) - want;
    e.tail<3>() *= 10.0;
    double c = e.squaredNorm();
    for (std::size_t i = 0; i < x.size(); ++i) c += 1e-2 * (x[i] - desired[i]).squaredNorm();
    return c;
  };
  const double best = cost(f);
  for (int i = 0; i < 2; ++i)
    for (int k = 0; k < 3; ++k)
      for (double step : {-1.0, 1.0}) {
        auto x = f;
        x[i][k] += step;
        if (!within_friction_pyramid(x[i], Vector3d::UnitZ(), kMu)) continue;
        EXPECT_GE(cost(x), best * (1 - 1e-6))
            << "foot " << i << " axis " << k << " " << step << ": " << cost(x) << " < " << best
            << " at " << f[0].transpose() << " / " << f[1].transpose();
      }
}

// A state the simulation found non-finite gives the distribution NaNs: it returns what it was
// given (leg_torque clips it; the run's instability check ends the run), never throws.
TEST(ForceDistribution, NonFiniteInputIsReturnedAsItIs) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  auto feet = four_feet({{0, 0, 200}, {0, 0, -50}, {0, 0, 200}, {0, 0, 200}});
  feet[0].lever.x() = nan;
  std::vector<Vector3d> f;
  ASSERT_NO_THROW(f = constrained_stance_forces(feet, kMu));
  ASSERT_EQ(f.size(), 4u);
  EXPECT_EQ(f[1], Vector3d(0, 0, -50));
}

}  // namespace
