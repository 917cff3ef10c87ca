// Fail-fast checks, before the solve, that a request's end stance and start can exist at all.
//
// At the end of a plan every foot in contact stands still, at one point of its last stance, with
// the base at the goal: x, y and yaw as asked, pitch and roll as the problem fixes them (from the
// terrain under the nominal feet), height free. That foothold must lie in the leg's
// range-of-motion box around the nominal foot (base frame), on the terrain, where the terrain is
// planar within `foothold_planarity` over `clearance_probe` (the baseline constraints, constraints/). The
// check samples each foot's box on a grid and looks for such points; a goal none of whose
// footholds exists, or whose feet need incompatible base heights, is rejected in milliseconds
// instead of after seconds of iterations that end "infeasible" (gap scene, 1 m goal: 73).
// It only tests necessary conditions of the goal knot, with the box inflated by the grid step and
// box and planarity relaxed by the violation an "acceptable" solve may keep, so it never rejects
// a request the solver could solve.
#pragma once

#include <Eigen/Core>
#include <limits>
#include <optional>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "terrastride/planner/nlp.hpp"
#include "terrastride/robot/robot_model.hpp"
#include "terrastride/terrain/height_field.hpp"

namespace terrastride::planner {

// A request no plan can satisfy, found before the solve; what() names the foot, where and why.
// An std::invalid_argument, so the command line and the socket service report it as a bad input.
class UnreachableRequest : public std::invalid_argument {
 public:
  using std::invalid_argument::invalid_argument;
};

// Ipopt's default acceptable_constr_viol_tol (m for lengths): a solve can end "acceptable", which
// counts as success, with constraints violated up to this much.
constexpr double kAcceptableViolation = 0.01;

// One foot of a resting stance: the leg, and the foothold when it is fixed (a stance that began
// before the plan and never lifts); otherwise any reachable planar point of the terrain will do.
struct StanceFoot {
  int leg = 0;
  std::optional<Eigen::Vector3d> fixed_position;
};

// A resting base pose: x, y and the orientation fixed, the height within [z_min, z_max].
struct RestingStance {
  Eigen::Vector2d base_xy = Eigen::Vector2d::Zero();
  Eigen::Vector3d euler_zyx = Eigen::Vector3d::Zero();  // yaw, pitch, roll
  double base_z_min = -std::numeric_limits<double>::infinity();
  double base_z_max = std::numeric_limits<double>::infinity();
  std::vector<StanceFoot> feet;
  double planarity_tolerance = 0.01;  // m; <= 0: any terrain point will do
  double planarity_probe = 0.05;      // m
  double grid_step = 0.01;            // m, sampling of each foot's box
  // Constraint violation a solve may still end "acceptable" with (Ipopt's
  // acceptable_constr_viol_tol, 0.01 by default): boxes and planarity are relaxed by it, so that
  // no stance the solver could return is rejected.
  double violation_slack = kAcceptableViolation;
};

struct FootReach {
  std::string name;
  Eigen::Vector2d box_min = Eigen::Vector2d::Zero(), box_max = Eigen::Vector2d::Zero();  // world xy
  int in_box = 0;  // sampled terrain points inside the box for some base height
  int planar = 0;  // ... of which planar enough to stand on
  double terrain_min = 0.0, terrain_max = 0.0;  // terrain heights at the in-box points
  // Base heights for which some planar in-box point exists (disjoint, ascending).
  std::vector<std::pair<double, double>> base_heights;
};

struct StanceReach {
  bool reachable = true;
  std::string reason;  // when !reachable: which foot, where, why
  std::vector<FootReach> feet;
};

// Whether some base height lets every foot of `stance` stand on reachable planar ground.
StanceReach reach_stance(const robot::RobotModel& robot, const terrain::HeightField& terrain,
                         const RestingStance& stance);

// The end stance of `problem` (the feet in contact at its end, the base at its fixed goal pose),
// or nothing when the goal's x, y or orientation are left free (no goal given).
std::optional<RestingStance> end_stance(const SrbdProblem& problem);

// Throws UnreachableRequest when the end stance cannot exist, or when a foot of a plan from rest
// lies outside its range-of-motion box at the start (start values are fixed: no iteration can
// repair them). A measured start outside it (a re-plan's) is not rejected: the rows after it
// give it room back to the box.
void require_reachable(const SrbdProblem& problem);

}  // namespace terrastride::planner
