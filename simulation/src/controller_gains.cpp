// The tracking controller's gains for a robot (simulation.hpp, controller_gains): each PD loop is
// a natural frequency w and a damping ratio z on the inertia I it moves, kp = I w^2 and
// kd = 2 z I w. HyQ's hand-tuned absolute gains made a 15 kg Go2 fall in the first
// second: 150 N m s/rad of trunk orientation damping on Go2's 0.18 kg m^2 roll inertia is
// kd dt / I = 1.6 per 2 ms step, and 10 N m s/rad of swing damping on its 5e-3 kg m^2 knee is 4:
// an explicit PD step beyond 1 overshoots and grows. The same frequencies and ratios on each
// robot's own inertias keep every loop's kd dt / I where HyQ's is: the gains follow the robot's
// mass and inertias (its legs' inertias follow their lengths).
//
// The frequencies stay HyQ's although a smaller robot's plans are faster (gait_time_scale: Go2's
// times are 0.717 of HyQ's). Measured on the `all` plans of a 1 m crawl (flat, pallet_10), with
// every loop's frequency scaled by 1 / gait_time_scale (Go2 x 1.39, ANYmal C x 1.20): tracking RMS
// changed by -1 to -6 % (Go2 5.0 -> 5.0 and 6.9 -> 6.6 mm) but the stance feet slipped more
// (Go2 1.2 -> 3.8 and 4.5 -> 5.4 mm, ANYmal C 3.7 -> 9.3 mm on flat, near the 10 mm verdict
// limit): stiffer loops push the feet harder. The contact model needs no scaling either: MuJoCo's
// soft contact (solref 5 ms, elliptic cones, simulation.cpp) is a time constant and a friction
// coefficient, independent of the robot's size, and scales its stiffness with each contact's
// effective mass.
#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <limits>

#include "terrastride/simulation/simulation.hpp"
#include "terrastride/robot/leg_kinematics.hpp"

namespace terrastride::simulation {
namespace {

// HyQ's tuned gains as frequencies (rad/s) and damping ratios, on its 83 kg, the smallest principal
// moment of its SRBD inertia (4.2534 kg m^2) and the smallest diagonal entry of its legs'
// joint-space inertia at the nominal stance (the knee, 0.034211 kg m^2):
//   trunk position    6000 N/m,      1200 N s/m:      w = 8.50,  z = 0.850
//   trunk orientation 1500 N m/rad,  150 N m s/rad:   w = 18.78, z = 0.939
//   swing joints      400 N m/rad,   10 N m s/rad:    w = 108.1, z = 1.352
//   stance joints     150 N m/rad,   5 N m s/rad:     w = 66.22, z = 1.104
// Rounded so: HyQ's gains come out within 0.1 % of the tuned ones (test_simulation).
constexpr double kPositionFrequency = 8.50, kPositionDamping = 0.850;
constexpr double kOrientationFrequency = 18.78, kOrientationDamping = 0.939;
constexpr double kSwingFrequency = 108.1, kSwingDamping = 1.352;
constexpr double kStanceFrequency = 66.22, kStanceDamping = 1.104;

struct Pd {
  double kp = 0.0, kd = 0.0;
};
Pd pd(double inertia, double frequency, double damping) {
  return {inertia * frequency * frequency, 2.0 * damping * inertia * frequency};
}

// The smallest diagonal entry of any leg's joint-space inertia at the nominal stance: the joint
// the scalar joint gains move fastest (a knee, on every shipped robot).
double smallest_joint_inertia(const robot::RobotModel& model) {
  const std::vector<Eigen::Vector3d> q = nominal_stance(model);
  double smallest = std::numeric_limits<double>::infinity();
  for (size_t i = 0; i < model.legs.size(); ++i) {
    const Eigen::Matrix3d m =
        robot::dynamics_terms(model.legs[i], q[i], Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero())
            .mass_matrix;
    smallest = std::min(smallest, m.diagonal().minCoeff());
  }
  return smallest;
}

}  // namespace

ControllerGains controller_gains(const robot::RobotModel& model) {
  if (!(model.mass > 0)) throw SimulationError("robot '" + model.name + "': no mass");
  const double roll_like =
      Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(model.inertia, Eigen::EigenvaluesOnly)
          .eigenvalues()
          .minCoeff();
  if (!(roll_like > 0))
    throw SimulationError("robot '" + model.name + "': its body inertia is not positive definite");
  const double joint = smallest_joint_inertia(model);
  if (!(joint > 0 && std::isfinite(joint)))
    throw SimulationError("robot '" + model.name +
                          "': a leg joint moves no inertia at the nominal stance (link masses?)");
  ControllerGains g;
  const Pd position = pd(model.mass, kPositionFrequency, kPositionDamping);
  const Pd orientation = pd(roll_like, kOrientationFrequency, kOrientationDamping);
  const Pd swing = pd(joint, kSwingFrequency, kSwingDamping);
  const Pd stance = pd(joint, kStanceFrequency, kStanceDamping);
  g.kp_position = position.kp;
  g.kd_position = position.kd;
  g.kp_orientation = orientation.kp;
  g.kd_orientation = orientation.kd;
  g.kp_swing = swing.kp;
  g.kd_swing = swing.kd;
  g.kp_stance = stance.kp;
  g.kd_stance = stance.kd;
  return g;
}

}  // namespace terrastride::simulation
