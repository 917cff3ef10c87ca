// Post-hoc checks of a planned motion against the real robot and the real terrain (docs/design.md
// §8; paper sections III-B and IV): joint torques from the leg dynamics, leg
// capsules against the scan's OctoMap with FCL, and stance footholds against the foothold-safety
// margin.
//
// Conventions. A plan's foot position is the foot point of the robot model's kinematics (the point
// that FK/IK place; on the terrain surface during stance, see nominal_base_height in the robot
// file). The foot is a sphere of radius foot_radius resting on that point. Forces are those the
// ground exerts on the foot, world frame, as in plan.json.
#pragma once

#include <Eigen/Core>
#include <map>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "terrastride/planner/trajectory.hpp"
#include "terrastride/robot/geometry.hpp"
#include "terrastride/robot/leg_kinematics.hpp"
#include "terrastride/robot/robot_model.hpp"
#include "terrastride/terrain/height_field.hpp"

// The checks take the terrain's OctoMap by reference or shared pointer only: callers that build or
// read one include <octomap/OcTree.h> (or collision/octree_terrain.hpp) themselves, and the many
// that only run checks do not parse OctoMap.
namespace octomap {
class OcTree;
}  // namespace octomap

namespace terrastride::collision {

// A trajectory the checks cannot interpret (feet that do not match the robot, non-finite numbers,
// times that do not increase); the message names the field ("samples[12].feet[2].position: ...").
class TrajectoryError : public std::invalid_argument {
 public:
  using std::invalid_argument::invalid_argument;
};

// ---- Leg kinematics along the trajectory (shared by the torque and the capsule checks) ----

enum class LegSampleStatus { ok, outside_joint_limits, unreachable };

struct LegSample {
  LegSampleStatus status = LegSampleStatus::unreachable;
  Eigen::Vector3d foot_base = Eigen::Vector3d::Zero();  // foot point in the base frame
  Eigen::Vector3d q = Eigen::Vector3d::Zero();          // valid unless unreachable
  Eigen::Vector3d qd = Eigen::Vector3d::Zero();
  Eigen::Vector3d qdd = Eigen::Vector3d::Zero();
  bool has_q() const { return status != LegSampleStatus::unreachable; }
};

struct LegIssue {
  int sample = -1;
  double t = 0.0;
  int leg = -1;
  std::string message;
};

struct TrajectoryKinematics {
  std::vector<double> time;
  // legs[leg][sample]
  std::vector<std::vector<LegSample>> legs;
  int unreachable_samples = 0;   // samples where some leg's foot is out of reach (IK failed)
  int joint_limit_samples = 0;   // samples where some leg needs a joint outside its range
  std::vector<LegIssue> issues;  // the first few IK failures / joint-limit excursions, with reasons
};

// Checks `trajectory` against `model` as every check reads it: its robot and feet, finite times
// that increase, finite base and foot states. Throws TrajectoryError naming the field. Shared by
// the checks (leg_kinematics) and the simulation (simulation.hpp), so both refuse the same plans.
void validate_trajectory(const robot::RobotModel& model, const planner::Trajectory& trajectory);

// Validates `trajectory` against `model` (throws TrajectoryError) and runs IK for every leg and
// sample. Joint velocities come from the foot velocity relative to the base, expressed in the base
// frame, through J^-1 (exact at each sample, no differencing error; plan.json carries velocities);
// joint accelerations are central differences of those velocities in time (plan.json carries no
// foot accelerations; the difference is second-order accurate, and at a 2-10 ms sample step its
// error is far below the torque limits). Near a kinematic singularity (J not invertible) q̇ falls
// back to a central difference of q.
TrajectoryKinematics leg_kinematics(const robot::RobotModel& model,
                                    const planner::Trajectory& trajectory);

// ---- Joint torques (paper (21)) ----

struct TorqueOptions {
  Eigen::Vector3d gravity = Eigen::Vector3d(0, 0, -9.81);  // world frame, m/s²
  // The legs ride on an accelerating base: the base's linear acceleration enters the leg dynamics
  // as an extra apparent gravity, g_eff = R^T (g - r̈_base). The base's rotation rate terms are left
  // out (small for the leg links at walking speeds; the fixed-base RNEA has no input for them).
  bool include_base_acceleration = true;
  double violation_tolerance = 1e-9;  // ratio > 1 + tolerance counts as a violation
};

struct LegTorqueSeries {
  std::string leg;
  std::vector<Eigen::Vector3d> tau;    // N m; NaN where IK failed
  std::vector<Eigen::Vector3d> ratio;  // |tau_i| / tau_lim_i; NaN where IK failed
  Eigen::Vector3d worst_ratio = Eigen::Vector3d::Zero();  // per joint HAA HFE KFE
  Eigen::Vector3i worst_sample = Eigen::Vector3i::Constant(-1);
  int violating_samples = 0;  // samples where a joint of this leg exceeds its limit
  // Joint speeds |q'_i| / q'_lim_i (legs whose robot file gives velocity limits; NaN elsewhere).
  std::vector<Eigen::Vector3d> velocity_ratio;
  Eigen::Vector3d worst_velocity_ratio = Eigen::Vector3d::Zero();
  int velocity_violating_samples = 0;
};

struct TorqueReport {
  std::vector<double> time;
  std::vector<LegTorqueSeries> legs;
  double ratio_max = 0.0;  // worst |tau|/tau_lim over all legs, joints and samples
  int worst_sample = -1, worst_leg = -1, worst_joint = -1;
  int violating_samples = 0;  // samples where any joint of any leg exceeds its limit
  // Energy proxy (J): the integral over the plan of sum over legs and joints of |tau_j q'_j|, the
  // mechanical work the motors do with no recuperation (samples where IK failed left out).
  double energy_proxy_J = 0.0;
  // Joint velocities against the robot file's velocity limits, beside the torques: checked only
  // when every leg has them (an imported robot always does; HyQ's file gives none).
  bool velocity_checked = false;
  double velocity_ratio_max = 0.0;  // worst |q'|/q'_lim
  int velocity_worst_sample = -1, velocity_worst_leg = -1, velocity_worst_joint = -1;
  int velocity_violating_samples = 0;
};

TorqueReport check_joint_torques(const robot::RobotModel& model,
                                 const planner::Trajectory& trajectory,
                                 const TrajectoryKinematics& kinematics,
                                 const TorqueOptions& options = {});

// ---- Leg capsules against the terrain's OctoMap (FCL) ----

struct ClearanceOptions {
  // The foot touches the ground in stance by design, and the lower leg ends in the foot, so the
  // shin capsule cannot run down to the foot point without "colliding" at every footstep. The
  // capsule's axis stops `shin_exclusion` short of the foot point: the foot sphere (2 r from the
  // contact point to its top), the shin's own radius (its end cap) and a quantisation margin, the
  // larger of `exclusion_margin` and the octree's voxel size (a scanned surface voxel may stand up
  // to one voxel above the true surface); robot::shin_exclusion, as the planner's shin sets. What
  // remains is the part of the leg the paper's shin constraint protects (knee and the points
  // between knee and foot). Negative = use 2 foot_radius + shin_radius + max(exclusion_margin,
  // voxel size). Coarse maps (5 cm voxels) exclude more of the shin and still read stance shins as
  // touching: map with 1-2 cm voxels.
  double shin_exclusion = -1.0;
  double exclusion_margin = robot::kShinExclusionMargin;
  // Distances beyond this are not resolved (reported as the cutoff). It bounds FCL's search, whose
  // cost grows with the number of voxels within that distance; 10 cm is well past where a
  // clearance matters for collision, so a thigh high above flat ground simply reads 0.1.
  double distance_cutoff = 0.1;
  // Per-sample distances below `exact_below` are always exact FCL results. Above it, a sample
  // whose capsule moved at most max(bound_tolerance, bound_relative (d - exact_below)) since the
  // last exact query d is reported by the certified lower bound d - motion (see
  // leg_clearance.cpp); that skips most queries along a smooth plan. Collisions are exact either
  // way; the per-leg minima are exact below `exact_below` and within that same allowance above it.
  // bound_tolerance = bound_relative = 0: query every sample.
  double exact_below = 0.01;
  double bound_tolerance = 0.002;
  double bound_relative = 0.1;
  // Links are queried as chains of capsules at most this long (the same union of points; tighter
  // bounding boxes, so FCL tests far fewer voxels; see leg_clearance.cpp).
  double piece_length = 0.1;
  bool check_thigh = true;  // thighs (HFE to knee, thigh_radius) as well as shins
  bool check_trunk = true;  // the robot file's trunk box (run_checks; robots with `trunk: none` skip)
  // Depth into occupied voxels that the map's quantisation explains: a voxel is occupied when a
  // measured point lies anywhere inside it, so a body may overlap it by up to one voxel edge
  // without touching the surface. A contact deeper than this is a certain collision even where
  // the certain solid has nothing (thin walls, which its one-cell erosion removes at coarse
  // cells). Negative: the octree's voxel edge plus the depth the map's sensor noise fills with
  // voxels (CertainSolid::noise_depth, 3 sigma; 0 on exact scenes).
  double deep_contact_depth = -1.0;
};

// The resolution-aware verdict of one body (capsule, trunk box) at one sample (see CertainSolid in
// octree_terrain.hpp): clear of every occupied voxel; touching occupied voxels but clear of the
// solid the map is certain of and no deeper into them than ClearanceOptions::deep_contact_depth
// (within the map's uncertainty: voxel quantisation, mixed pixels); or reaching into that certain
// solid or deeper into occupied voxels than the quantisation explains (a certain collision).
enum class ContactVerdict : char { clear = 0, uncertain = 1, certain = 2 };

struct LegClearanceSeries {
  std::string leg;
  // Distance to the occupied voxels (the map's own, conservative view).
  std::vector<double> shin_distance;   // m; <= 0 in collision (-penetration depth); NaN: no IK
  std::vector<double> thigh_distance;  // empty when the thigh is not checked
  // 1 where the distance is an FCL result, 0 where it is a lower bound (> exact_below).
  std::vector<char> shin_exact, thigh_exact;
  // Distance to the certain solid (<= 0: certain collision). Computed with FCL where the voxel
  // distance is below exact_below; elsewhere the voxel distance is repeated (a lower bound). With
  // no certain solid (ClearanceReport::certain_source empty) it equals the voxel distance.
  std::vector<double> shin_certain_distance, thigh_certain_distance;
  std::vector<ContactVerdict> shin_verdict, thigh_verdict;  // clear where NaN (no IK)
  double shin_min = 0.0, thigh_min = 0.0;
  int shin_min_sample = -1, thigh_min_sample = -1;
  double shin_certain_min = 0.0, thigh_certain_min = 0.0;
  // Samples touching an occupied voxel (certain + uncertain), and the certain ones among them.
  int shin_collision_samples = 0, thigh_collision_samples = 0;
  int shin_certain_samples = 0, thigh_certain_samples = 0;
  double first_collision_t = -1.0;          // first voxel contact; < 0: none
  double first_certain_collision_t = -1.0;  // first certain collision; < 0: none
};

struct ClearanceReport {
  std::vector<double> time;
  std::vector<LegClearanceSeries> legs;
  double shin_exclusion = 0.0;  // what was used (m)
  double shin_min_distance = 0.0;
  double thigh_min_distance = 0.0;
  int shin_collisions = 0;   // samples where any shin capsule touches an occupied voxel
  int thigh_collisions = 0;  // same for thighs
  double first_collision_t = -1.0;
  // The resolution-aware split of those samples: a certain collision of some shin (thigh), and
  // voxel contacts only within the map's uncertainty (shin_collisions = certain + uncertain).
  int shin_collisions_certain = 0, shin_contacts_uncertain = 0;
  int thigh_collisions_certain = 0, thigh_contacts_uncertain = 0;
  double shin_min_certain_distance = 0.0;  // min distance to the certain solid (m)
  double thigh_min_certain_distance = 0.0;
  double first_certain_collision_t = -1.0;
  // How the certain solid was made; empty: none was given, every voxel contact counts as certain.
  std::string certain_source;
  // Distances to the certain solid are resolved below this (ClearanceOptions::exact_below); a
  // minimum at or above it reads "at least this much".
  double certain_resolved_below = 0.0;
  double octree_resolution = 0.0;
  double deep_contact_depth = 0.0;  // voxel contacts deeper than this are certain (m)
  long fcl_queries = 0;      // capsule distance queries run (the rest were bounded, see options)
  long certain_queries = 0;  // capsule queries against the certain solid
};

struct CertainSolid;

// `certain`: the solid the map is certain of (octree_terrain.hpp); null = count every voxel contact
// as a certain collision (the voxel map alone cannot tell).
ClearanceReport check_leg_clearance(const robot::RobotModel& model,
                                    const planner::Trajectory& trajectory,
                                    const TrajectoryKinematics& kinematics,
                                    const octomap::OcTree& octree,
                                    const ClearanceOptions& options = {},
                                    const CertainSolid* certain = nullptr);

// ---- The trunk box against the terrain's OctoMap (FCL) ----

// The robot file's trunk box (robot::TrunkBox, fixed to the base) at every sample, checked as the
// leg capsules are: distance to the occupied voxels, to the certain solid, and the verdict.
struct TrunkClearanceReport {
  std::vector<double> time;
  std::vector<double> distance;          // m; <= 0 in collision (-penetration depth)
  std::vector<char> exact;               // 1: FCL result; 0: lower bound (> exact_below)
  std::vector<double> certain_distance;  // m; <= 0: reaches into the certain solid
  std::vector<ContactVerdict> verdict;
  double min_distance = 0.0, min_certain_distance = 0.0;
  int min_sample = -1;
  int collisions = 0;          // samples touching an occupied voxel (certain + uncertain)
  int collisions_certain = 0;  // certain collisions among them
  int contacts_uncertain = 0;
  double first_collision_t = -1.0, first_certain_collision_t = -1.0;  // < 0: none
  // The worst sample (smallest voxel distance): base position there, for messages.
  Eigen::Vector3d min_base = Eigen::Vector3d::Zero();
  double deep_contact_depth = 0.0;  // voxel contacts deeper than this are certain (m)
  std::string certain_source;
  double certain_resolved_below = 0.0;
  long fcl_queries = 0, certain_queries = 0;
  // The overhang the box's top meets at the worst sample, for messages ("" when it meets none):
  // see name_trunk_overhang.
  std::string overhang;
};

// Throws std::invalid_argument when `model` has no trunk (robot file `trunk: none`). Uses
// distance_cutoff, exact_below, bound_tolerance, bound_relative and deep_contact_depth of
// `options` as the leg check does (temporal coherence bounds by the largest corner motion).
TrunkClearanceReport check_trunk_clearance(const robot::RobotModel& model,
                                           const planner::Trajectory& trajectory,
                                           const octomap::OcTree& octree,
                                           const ClearanceOptions& options = {},
                                           const CertainSolid* certain = nullptr);

// Sets report->overhang when, at the worst sample, the top face of the trunk box stands within
// 2 cm of (or above) the underside of an overhang of `field` (HeightField::overhead): where, how
// high above the walkable surface, and how high the box's top reaches there.
void name_trunk_overhang(const robot::RobotModel& model, const planner::Trajectory& trajectory,
                         const terrain::HeightField& field, TrunkClearanceReport* report);

// ---- Stance footholds against the foothold-safety margin ----

struct Foothold {
  int leg = -1;
  int first_sample = -1, last_sample = -1;
  double t_start = 0.0, t_end = 0.0;
  Eigen::Vector3d position = Eigen::Vector3d::Zero();  // at the sample of the worst margin
  double margin = 0.0;  // worst signed margin over the stance (m); < 0 = unsafe
  bool safe() const { return margin >= 0.0; }
};

struct FootholdReport {
  double foot_radius = 0.0;
  std::vector<Foothold> footholds;  // one per stance phase per leg, in time order
  int unsafe = 0;
  double worst_margin = 0.0;  // +inf-like (1e9) when nothing unsafe is anywhere near
  int worst = -1;             // index into footholds
};

// A stance phase is a maximal run of samples with contact; its margin is the minimum of
// HeightField::safety_margin(x, y, foot_radius) over the run, so a foot sliding onto an edge
// counts.
FootholdReport check_footholds(const planner::Trajectory& trajectory,
                               const terrain::HeightField& field, double foot_radius);

// ---- Everything at once ----

struct CheckTerrain {
  const terrain::HeightField* field = nullptr;    // for footholds; null = footholds not checked
  std::shared_ptr<const octomap::OcTree> octree;  // for capsules; null = capsules not checked
  // What the capsule check may call a certain collision (octree_terrain.hpp). Null: derived by
  // run_checks from `field` (an exact scene's boxes, or a scanned map's height grid confirmed by
  // the OctoMap) over the trajectory's extent when it can, else every voxel contact counts.
  std::shared_ptr<const CertainSolid> certain;
  std::string description;
};

struct CheckOptions {
  TorqueOptions torque;
  ClearanceOptions clearance;
};

struct CheckReport {
  TrajectoryKinematics kinematics;
  TorqueReport torque;
  std::optional<ClearanceReport> clearance;
  std::optional<TrunkClearanceReport> trunk;  // with an OctoMap and a robot that has a trunk
  std::optional<FootholdReport> footholds;
  double wall_s = 0.0;

  // plan.json "checks" keys: torque_ratio_max, torque_violations, velocity_ratio_max and
  // velocity_violations (robots with velocity limits), shin_min_distance_m,
  // shin_collisions, unsafe_footholds, plus thigh_min_distance_m, thigh_collisions,
  // foothold_margin_min_m, ik_failures, joint_limit_violations; and the resolution-aware split of
  // the capsule contacts: shin_collisions_certain, shin_contacts_uncertain,
  // shin_min_certain_distance_m (thigh_* likewise); trunk_min_distance_m, trunk_collisions,
  // trunk_collisions_certain, trunk_contacts_uncertain, trunk_min_certain_distance_m when the
  // trunk was checked. shin_collisions and shin_min_distance_m keep
  // their meaning (contact with / distance to the occupied voxels); failures() and the report's
  // problems count certain collisions only. Checks that did not run are absent.
  std::map<std::string, double> keys() const;
  // One line per failed check, empty when all pass.
  std::vector<std::string> failures() const;
  bool passed() const { return failures().empty(); }
};

CheckReport run_checks(const robot::RobotModel& model, const planner::Trajectory& trajectory,
                       const CheckTerrain& terrain, const CheckOptions& options = {});

// The xy rectangle a trajectory's legs and trunk sweep (hips, knees, feet and the trunk box's
// corners at every sample), grown by `margin`: the region an analytic scene must be voxelised
// over.
void trajectory_extent(const robot::RobotModel& model, const planner::Trajectory& trajectory,
                       double margin, Eigen::Vector2d* lo, Eigen::Vector2d* hi);

// Base orientation from ZYX Euler angles (yaw, pitch, roll): R = Rz(yaw) Ry(pitch) Rx(roll), the
// planner's (robot/geometry.hpp).
using robot::rotation_zyx;

}  // namespace terrastride::collision
