// Robot description shared by the planner, the force-polytope fit and the post-hoc checks.
// Robots are data (data/robots/*.yaml): nothing here is specific to HyQ.
#pragma once

#include <Eigen/Core>
#include <array>
#include <optional>
#include <cmath>
#include <stdexcept>
#include <string>
#include <vector>

namespace terrastride::robot {

// Thrown for unreadable or invalid robot files; the message names the file and the field.
class RobotFileError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// A rigid link of a leg: mass, centre of mass and inertia about that centre, both expressed in the
// frame of the joint that moves the link (at the joint, before the next joint's offset).
struct LinkInertia {
  double mass = 0.0;
  Eigen::Vector3d com = Eigen::Vector3d::Zero();
  Eigen::Matrix3d inertia = Eigen::Matrix3d::Zero();
};

enum class Joint { HAA = 0, HFE = 1, KFE = 2 };

// How the leg's inverse kinematics is solved, decided once from its geometry when the robot file
// is read (classify_leg_geometry):
//   in_plane:       HyQ's leg: HAA about +-x, HFE and KFE about +y, every offset straight down
//                   (-z). The formulas of docs/design.md §4.2, kept exactly as they were.
//   lateral_offset: HAA about +-x, HFE and KFE about +-y, any offsets (a lateral HAA->HFE offset
//                   as on Unitree legs, a forward hip offset, a lateral thigh, an angled shank as
//                   on ANYmal C): a closed form (geometry.hpp, lateral_offset_joint_angles).
//   general:        any other axes: a damped Newton solve from several starts (leg_kinematics.cpp).
enum class LegShape { in_plane, lateral_offset, general };

// One 3-DoF HAA-HFE-KFE leg. The general geometry (docs/design.md §4.2): at q = 0 every joint
// frame is parallel to the base frame; the HAA joint sits at haa_origin (base frame), and
// joint_offset[0..2] lead HAA -> HFE, HFE -> KFE and KFE -> foot centre at q = 0. Joint i turns
// everything after it by q_i about joint_axis[i] (unit, base frame at q = 0, carried along by
// the joints before it): foot = o + R0 (d0 + R1 (d1 + R2 d2)), R_i = Rot(joint_axis[i], q_i).
// HyQ's file gives the in-plane special case with l0, l1, l2 and side (docs/design.md §4.2):
//   v0 = (-L1 sin qH - L2 sin(qH+qK), 0, -L0 - L1 cos qH - L2 cos(qH+qK)),
//   foot = p_HAA + Rx(-side * qA) v0,
// i.e. joint_axis = (-side x, y, y), joint_offset = (-L0 z, -L1 z, -L2 z).
// side = +1 for a left leg, -1 for a right leg; knee_sign is the sign of the KFE angle measured
// from the straight leg: -1 for a knee bending backward (HyQ front legs, qK < 0), +1 forward.
struct LegModel {
  std::string name;
  Eigen::Vector3d haa_origin = Eigen::Vector3d::Zero();  // base frame
  std::array<Eigen::Vector3d, 3> joint_axis{
      {Eigen::Vector3d::UnitX(), Eigen::Vector3d::UnitY(), Eigen::Vector3d::UnitY()}};
  std::array<Eigen::Vector3d, 3> joint_offset{
      {Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero()}};
  LegShape shape = LegShape::in_plane;
  // Derived from the geometry (classify_leg_geometry): for the in-plane leg the file's numbers;
  // otherwise l0 = the HAA->HFE offset's downward part (the force polytopes' first guess of the
  // hip offset), l1 = |HFE->KFE| (thigh capsule), l2 = |KFE->foot| (shin capsule).
  double l0 = 0.0, l1 = 0.0, l2 = 0.0;
  int side = +1;
  int knee_sign = -1;
  Eigen::Vector3d q_min = Eigen::Vector3d::Zero();  // rad, HAA HFE KFE
  Eigen::Vector3d q_max = Eigen::Vector3d::Zero();
  Eigen::Vector3d torque_limit = Eigen::Vector3d::Zero();  // N m
  // rad/s; 0 where the robot file gives none (HyQ's does not). Recorded from URDF imports.
  Eigen::Vector3d velocity_limit = Eigen::Vector3d::Zero();
  std::array<LinkInertia, 3> links;                       // hip, upper leg, lower leg
  Eigen::Vector3d nominal_foot = Eigen::Vector3d::Zero();  // base frame
  Eigen::Vector3d range_of_motion = Eigen::Vector3d::Zero();  // half-size of the box b
  double shin_length = 0.0;  // s: distance foot contact point -> knee used by the shin model
  double shin_angle = 0.0;   // beta (rad), angle of the shin to the ground in the planner's model
  double shin_radius = 0.0;  // capsule radius of the lower leg for the post-hoc check
  double thigh_radius = 0.0; // capsule radius of the upper leg for the post-hoc check
  bool is_front = true;      // front legs have knee_sign -1 on HyQ; kept for reporting only
};

// Sets shape, l0, l1, l2 (and side for a leg not given one) from joint_axis and joint_offset;
// throws std::invalid_argument naming the leg when the geometry is not a leg (a zero axis, a
// zero-length thigh or shank). Called by load_robot and by the URDF importer.
void classify_leg_geometry(LegModel& leg, bool side_given);

// The trunk as one collision box, fixed to the base: full edge lengths along the base axes and
// the box centre in the base frame (the box is not turned relative to the base). HyQ's comes
// from its URDF's trunk collision mesh (data/robots/hyq.yaml says which numbers and where).
struct TrunkBox {
  Eigen::Vector3d size = Eigen::Vector3d::Zero();    // m, full lengths along base x, y, z
  Eigen::Vector3d center = Eigen::Vector3d::Zero();  // m, base frame
  Eigen::Vector3d half_size() const { return 0.5 * size; }
};

// The leg's nominal foot in the world for a base at `base` turned by `yaw` (no pitch or roll).
inline Eigen::Vector3d nominal_foot_world(const LegModel& leg, const Eigen::Vector3d& base,
                                          double yaw) {
  const Eigen::Vector3d& n = leg.nominal_foot;
  return base + Eigen::Vector3d(std::cos(yaw) * n.x() - std::sin(yaw) * n.y(),
                                std::sin(yaw) * n.x() + std::cos(yaw) * n.y(), n.z());
}

// A robot: the single rigid body of the SRBD model and its legs.
struct RobotModel {
  std::string name;
  std::string source_file;
  // Where the robot's numbers come from when the file says (`source:`, e.g. an imported URDF's
  // path, repository and commit), as one line of flow YAML; empty otherwise.
  std::string source;
  // The robot file's text as read, byte for byte: a plan carries it (plan.json "robot_file"), so
  // the plan is judged and simulated with the robot it was planned with. Empty for a robot built
  // in code.
  std::string definition;
  double mass = 0.0;                                  // total mass used by the SRBD model
  Eigen::Matrix3d inertia = Eigen::Matrix3d::Zero();  // base frame, about the CoM
  double foot_radius = 0.0;
  double nominal_base_height = 0.0;  // height of the base above flat ground in the nominal stance
  // Degrees of freedom of the base that the planner may move: all six for a free-floating robot,
  // only z for the monoped on its vertical slider.
  std::array<bool, 6> base_dof_free{{true, true, true, true, true, true}};  // x y z yaw pitch roll
  std::vector<LegModel> legs;
  // The trunk box; absent only when the robot file says `trunk: none` (the monoped, whose slider
  // carriage is not a body that can meet the terrain).
  std::optional<TrunkBox> trunk;

  bool has_trunk() const { return trunk.has_value(); }
  const LegModel& leg(const std::string& leg_name) const;
  int leg_index(const std::string& leg_name) const;  // -1 when absent
};

// Loads and validates a robot file. Every field is checked; errors name the file and the field.
RobotModel load_robot(const std::string& path);
// The same for a robot file's text; errors name `label` as the file.
RobotModel parse_robot(const std::string& text, const std::string& label);

// A content hash of a robot file's text (64-bit FNV-1a, 16 hex digits): names one definition in
// plan.json and in messages. Identity only; the plan carries the text itself.
std::string robot_definition_hash(const std::string& text);

// Finds data/robots/<name>.yaml: TERRASTRIDE_DATA_DIR if set, otherwise the data folder of the
// source tree the binary was built from. `name_or_path` may also be a path to a .yaml file.
std::string resolve_robot_path(const std::string& name_or_path);

// What to pass as --robot to name this robot in a command a user pastes: the name of a shipped
// robot (its file is data/robots/NAME.yaml), else the path of the file it was read from.
std::string robot_argument(const RobotModel& model);

// The shipped data folder (see resolve_robot_path).
std::string data_dir();

}  // namespace terrastride::robot
