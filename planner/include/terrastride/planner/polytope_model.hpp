// Approximate force polytopes as functions of the foot position (Bratta et al. 2020, III-A),
// generalised to 3-D: the planner's constraint n^j(p)^T f <= d^j(p) without any Jacobian.
//
// Coordinates of a foot position p (base frame) relative to the leg's hip reference:
//   roll   gamma = atan2(p_y - h_y, -(p_z - h_z))      (0 in the paper's sagittal-only variant)
//   rolled frame: u = Rx(gamma)^T (p - h) = (a, 0, -(b + l0)), i.e. a = p_x - h_x and
//                 b = hypot(p_y - h_y, p_z - h_z) - l0   (paper: b = -(p_z - h_z))
//   leg length  l = hypot(a, b),  tilt  alpha = atan2(a, b)
// h is the roll-axis point and l0 the offset of the pitch "hip" along the rolled leg axis; on
// HyQ-like legs they are the HAA origin and the HAA->HFE offset, but they are fitted, not assumed.
//
// Facet j: n^j = Rx(gamma) Ry(-alpha) n_loc(theta^j, phi^j), offset d^j, with theta, phi, d
// interpolated linearly in l between reference polytopes at leg lengths l_1 < ... < l_K (and, in
// our variant, also linearly in alpha between reference tilts: a tensor grid of references;
// with one tilt reference this is exactly the paper's (11)-(16)). Outside the grid the end
// segments are extrapolated. n_loc is a unit vector in spherical angles about a per-facet pole
// axis chosen away from the facet's normal, so the angles are never singular.
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "terrastride/robot/robot_model.hpp"

namespace terrastride::planner {

// Thrown for missing, unreadable, invalid or stale polytope files; the message names the file.
class PolytopeFileError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

constexpr int kPolytopeFacets = 6;  // 2 per joint of a 3-DoF leg
constexpr int kPolytopeVertices = 8;

struct PolytopeFacets {
  std::array<Eigen::Vector3d, kPolytopeFacets> normals;
  std::array<double, kPolytopeFacets> offsets{};
};

// Leg coordinates of a foot position (see the header comment).
struct LegCoordinates {
  double gamma = 0.0, l = 0.0, alpha = 0.0;
};

class LegPolytopeModel {
 public:
  std::string leg_name;
  bool use_roll = true;                           // false: the paper's sagittal-only variant
  Eigen::Vector3d hip = Eigen::Vector3d::Zero();  // h
  double hip_offset = 0.0;                        // l0
  std::vector<double> l_knots;                    // K_l >= 2, increasing
  std::vector<double> alpha_knots;                // K_a >= 1, increasing
  std::array<int, kPolytopeFacets> poles{};  // pole axis (0 x, 1 y, 2 z) of each facet's angles
  // Reference values, node (i, m) = (l_knots[i], alpha_knots[m]) at index i * K_a + m, and per
  // node kPolytopeFacets triples (theta, phi, d). Facets 2i and 2i+1 bound joint i (+ and -
  // torque limit; HAA, HFE, KFE), as in robot::ForcePolytope.
  std::vector<double> nodes;

  int num_l() const { return static_cast<int>(l_knots.size()); }
  int num_alpha() const { return static_cast<int>(alpha_knots.size()); }
  double* node(int i, int m) { return &nodes[(i * num_alpha() + m) * 3 * kPolytopeFacets]; }
  const double* node(int i, int m) const {
    return &nodes[(i * num_alpha() + m) * 3 * kPolytopeFacets];
  }

  LegCoordinates coordinates(const Eigen::Vector3d& foot) const;
  PolytopeFacets facets(const Eigen::Vector3d& foot) const;

  // g_j = n^j(p)^T f - d^j(p) <= 0 for all facets; foot position and force in the base frame.
  // Optional analytic Jacobians: dg_dp(j, :) = dg_j/dp, dg_df(j, :) = dg_j/df = n^j.
  Eigen::Matrix<double, kPolytopeFacets, 1> constraint(
      const Eigen::Vector3d& foot, const Eigen::Vector3d& force,
      Eigen::Matrix<double, kPolytopeFacets, 3>* dg_dp = nullptr,
      Eigen::Matrix<double, kPolytopeFacets, 3>* dg_df = nullptr) const;

  // Vertices of the approximate polytope: vertex k takes facet 2i (bit i of k set) or 2i+1.
  std::array<Eigen::Vector3d, kPolytopeVertices> vertices(const Eigen::Vector3d& foot) const;

  // Throws std::invalid_argument naming the leg and the field when the layout is inconsistent.
  void validate() const;
};

struct RobotPolytopeModel {
  std::string robot;
  std::string variant;                 // "roll" (ours) or "sagittal" (the paper's)
  std::vector<LegPolytopeModel> legs;  // same order as the robot's legs
  // Fit figures stored for the record (training set); see polytope_fit.hpp.
  std::string fit_summary;

  const LegPolytopeModel& leg(const std::string& name) const;
};

// Fingerprint of everything in a leg that the force polytopes depend on (geometry, joint range,
// torque limits, nominal foot, range of motion): a changed robot file makes the fit stale.
std::string leg_fingerprint(const robot::LegModel& leg);

// data/robots/<robot>.polytopes.yaml next to the robot file.
std::string polytope_path_for(const robot::RobotModel& model);

// Writes atomically (temporary file + rename). Throws PolytopeFileError naming the path.
void save_polytope_model(const RobotPolytopeModel& model, const robot::RobotModel& robot_model,
                         const std::string& path);

// Loads the fitted parameters of `robot_model` from `path`. Fails with PolytopeFileError when the
// file is missing ("run terrastride polytopes fit"), malformed (names the field), for another
// robot, or stale (a leg's fingerprint differs from the robot file's).
RobotPolytopeModel load_polytope_model(const robot::RobotModel& robot_model,
                                       const std::string& path);
inline RobotPolytopeModel load_polytope_model(const robot::RobotModel& robot_model) {
  return load_polytope_model(robot_model, polytope_path_for(robot_model));
}

// load_polytope_model(robot_model), parsed once per file version and robot legs and then shared:
// every problem the planner builds needs it, and a planning-session step builds one many times a
// second (parsing the YAML file was a fifth of a pallet_15 step's problem building). The file is
// read again when its modification time or size changes (a refit) or for legs of other
// fingerprints; errors are thrown as by load_polytope_model and not cached. Thread-safe.
std::shared_ptr<const RobotPolytopeModel> shared_polytope_model(
    const robot::RobotModel& robot_model);

}  // namespace terrastride::planner
