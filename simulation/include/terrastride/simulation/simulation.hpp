// Execution of a plan in MuJoCo as an independent judge: the robot model is generated
// in memory from the robot file, the terrain from the exact scene, and a tracking controller
// (leg gravity/Coriolis, planned forces, a trunk PD wrench spread over the stance feet, swing
// feed-forward and joint PD on the IK of the planned feet) follows the plan. A failure means the
// plan, not the controller: the verdict's thresholds are stated in SimulationThresholds.
//
// Conventions (docs/design.md): world frame, ZYX Euler angles, feet in the robot file's order, a
// plan's foot point is the contact point (the foot sphere's centre is foot + r n).
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstddef>
#include <functional>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "terrastride/planner/planning_session.hpp"
#include "terrastride/planner/request_limits.hpp"
#include "terrastride/planner/trajectory.hpp"
#include "terrastride/robot/robot_model.hpp"
#include "terrastride/terrain/scenes.hpp"
#include "terrastride/terrain/terrain_map.hpp"

namespace terrastride::simulation {

// A plan or option the simulation cannot run (the message names the input), or MuJoCo refusing
// the generated model.
class SimulationError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// The caller's stop_requested() said stop (a cancelled or late service request).
class SimulationCancelled : public SimulationError {
 public:
  using SimulationError::SimulationError;
};

// An external force on the trunk's origin (world frame) from `t` for `duration` seconds.
struct Push {
  double t = 0.0;
  Eigen::Vector3d force = Eigen::Vector3d::Zero();
  double duration = 0.0;
};

// What a simulated run accepts, whoever asks (`simulate`, the socket's simulate, the margin
// search); simulate_plan refuses the rest with SimulationError before it builds anything, and the
// CLI and the socket name their options by these same bounds.
struct SimulationLimits {
  static constexpr double kMinDt = 1e-4, kMaxDt = 0.01;  // s
  static constexpr double kMinMassScale = 0.1, kMaxMassScale = 10.0;  // exclusive
  static constexpr double kMaxFriction = 5.0;                        // exclusive, above 0
  // A push beyond this is no disturbance a legged robot meets (HyQ weighs 0.8 kN; the margin
  // search's ceiling is bounded by it too): 1e12 N made MuJoCo's state non-finite.
  static constexpr double kMaxPushForce = 1e5;  // N
  static constexpr std::size_t kMaxPushes = 100;
  // A plan lasts at most what the planner plans (planner::PlanLimits::kMaxDuration, 120 s): a
  // last sample at t = 1e9 overflowed the step count and "passed" after 0 steps. Its base and
  // feet stay within the planner's goal distance (plus 100 m) of its first base position, and
  // that within 1e6 m of the origin: a base at 1e300 m made the tracking error infinite.
  static constexpr double kMaxPlanDuration = planner::PlanLimits::kMaxDuration;
  static constexpr double kMaxPlanReach = planner::PlanLimits::kMaxGoalDistance + 100.0;  // m
  static constexpr double kMaxPlanOrigin = 1e6;                                          // m
  // A push lasts at most a plan's longest duration; it starts at a finite time.
  static constexpr double kMaxPushDuration = kMaxPlanDuration;  // s
  // A closed loop takes no re-plan within the plan's last this many seconds
  // (simulation_run.cpp, replan_if_due).
  static constexpr double kNoReplanTail = 0.1;  // s
};

// The verdict's thresholds (the defaults). Impulses and durations, not step counts, so the
// verdict does not depend on the time step.
struct SimulationThresholds {
  // Fall (fail): trunk this far below the plan, tilt error above this, or trunk/thigh contact.
  double fall_height_m = 0.15;
  double fall_tilt_rad = 30.0 * 3.14159265358979323846 / 180.0;
  // Any trunk or thigh contact impulse above this counts as the body on the terrain (N s); a
  // graze below it is numerical contact noise.
  double body_contact_impulse_Ns = 0.5;
  // Pass: all of these; otherwise warn.
  double position_rms_m = 0.02;
  double position_max_m = 0.06;
  double saturation_fraction = 0.01;  // of the simulated time with any joint at its limit
  double slip_m = 0.01;               // per stance, horizontal
  double touchdown_error_m = 0.03;    // contact point at touchdown vs the planned foothold
  double shin_impulse_Ns = 5.0;       // per leg over the whole plan
  // Impulse of any joint's end stop (N m s): MuJoCo enforces the ranges, so a plan that needs a
  // joint beyond its range shows here (not in the list; added for that reason).
  double joint_limit_impulse_Nms = 1.0;
};

// The tracking controller's PD gains.
struct ControllerGains {
  // Trunk PD wrench (N/m, N s/m, N m/rad, N m s/rad).
  double kp_position = 0.0, kd_position = 0.0;
  double kp_orientation = 0.0, kd_orientation = 0.0;
  // Joint PD in swing and stance (N m/rad, N m s/rad).
  double kp_swing = 0.0, kd_swing = 0.0;
  double kp_stance = 0.0, kd_stance = 0.0;
};

// The gains for a robot (controller_gains.cpp): each PD loop is a natural frequency and a damping
// ratio on the inertia it moves, so a 15 kg Go2 gets gains its own masses can carry at the time
// step, not HyQ's absolute numbers. The trunk's translation acts on the SRBD mass, its rotation on
// the smallest principal moment of the SRBD inertia, the joints on the smallest diagonal entry of
// a leg's joint-space inertia at the nominal stance (over all legs): the stiffest mode each
// scalar gain meets. The frequencies and ratios are HyQ's tuned gains (6000/1200, 1500/150,
// 400/10, 150/5 on 83 kg, 4.25 kg m^2 and its knee) to within 0.1 %.
ControllerGains controller_gains(const robot::RobotModel& model);

// Controller terms, all on by default; switches exist to measure what each term buys.
struct ControllerOptions {
  bool planned_forces = true;
  bool trunk_wrench = true;
  bool swing_feedforward = true;
  // Empty (the default): controller_gains(model). Given: these gains, whatever the robot.
  std::optional<ControllerGains> gains;
  // The wrench's foot forces are kept in a cone of mu * this (margin to the true cone).
  double cone_margin = 0.9;
  // How the stance feet share the trunk wrench. `clipped` (the default, on which every recorded
  // figure was measured): the least-norm forces that make it, each foot's sum with its planned
  // force then clipped into its cone; a foot asked to pull gives nothing, and what it was to
  // carry of the moment is lost (after a lateral push the trunk rolls over the other feet).
  // `constrained`: the forces nearest to those whose wrench is nearest to it with every foot
  // within its friction pyramid, the moment weighted first (a bounded least-squares problem,
  // simulation/src/force_distribution.hpp), as legged robots' balance controllers distribute
  // their contact forces. Equal to `clipped` while no foot would leave its pyramid.
  enum class ForceDistribution { clipped, constrained };
  ForceDistribution force_distribution = ForceDistribution::clipped;
};

// The force distribution named `name` ("clipped" or "constrained", as the CLI and the socket
// spell it); nullopt for any other name.
std::optional<ControllerOptions::ForceDistribution> force_distribution_named(
    const std::string& name);

// The robot's state as the simulator measures it (MuJoCo's), in plan.json's terms: world frame,
// the base origin, ZYX Euler angles, world-frame angular velocity, each foot's contact point
// (sphere centre - r n, as a plan's foot) and that point's velocity; feet in the robot's order.
struct MeasuredState {
  double t = 0.0;  // on the simulated plan's time axis (s)
  Eigen::Vector3d base_position = Eigen::Vector3d::Zero();
  Eigen::Vector3d base_euler_zyx = Eigen::Vector3d::Zero();
  Eigen::Vector3d base_linear_velocity = Eigen::Vector3d::Zero();
  Eigen::Vector3d base_angular_velocity = Eigen::Vector3d::Zero();
  std::vector<Eigen::Vector3d> foot_position, foot_velocity;
  std::vector<bool> foot_contact;  // touching the terrain (the plan's schedule decides stances)
};

// The measured state as the socket's plan.session.step "start_state" (and `plan --start-state`)
// takes it: {"base": {position, euler_zyx, linear_velocity, angular_velocity}, "feet": {NAME:
// {position, velocity}}} keyed by `feet` (docs/protocol.md). The in-process re-planner reads it
// back with planner::start_state_from_json, as the server does, so both map it the same way.
nlohmann::json start_state_json(const MeasuredState& state, const std::vector<std::string>& feet);

// What a re-planner returns: the plan from `start_time` (its samples from 0 = start_time on the
// simulated plan's axis, contact schedule the remaining one of that plan), or a failure (the
// controller keeps tracking the plan it has).
struct Replan {
  bool success = false;
  planner::Trajectory plan;
  double start_time = 0.0;
  std::string message;  // why not, when !success
  int iterations = -1;  // the planner's iterations, when it says (-1: unknown)
  // The planner answered with its current plan instead of a new one (its step's budget ran out,
  // "deadline", or its solve failed, "solve_failed"): plan is that plan from start_time.
  bool fallback = false;
  std::string fallback_reason;
  // The planning session's account of the step (capture step, touch-downs, fallback message),
  // when the re-planner is one; reported per step.
  nlohmann::json session;
};
using Replanner = std::function<Replan(const MeasuredState&)>;
// Makes a fresh re-planner (a new planning session) for each simulated run, so runs do not share
// a session's state (simulation_margin repeats the run).
using ReplannerFactory = std::function<Replanner()>;

struct SimulationOptions {
  double dt = 0.002;  // MuJoCo time step (s)
  std::vector<Push> pushes;
  double mass_scale = 1.0;  // trunk mass and inertia times this (an unplanned payload)
  double friction = 0.5;    // Coulomb friction of the terrain (the planner's mu)
  double record_dt = 0.01;  // per-sample output step (s); 0 = none
  SimulationThresholds thresholds;
  ControllerOptions controller;
  // Polled every 50 steps; true stops the run with SimulationCancelled (the service's
  // cancellation token; the module does not depend on the service).
  std::function<bool()> stop_requested;
  // Closed loop: every `replan_every` seconds of simulated time (from the plan's start while at
  // least 0.1 s of it remain) the measured state goes to a re-planner made by `replanner` for
  // this run, and the controller tracks the plan it returns from `replan_latency` seconds later
  // (the simulated time a real planner's answer would take to arrive; the simulation waits for
  // the planner, so this is the only way its compute time enters). 0 = open loop.
  double replan_every = 0.0;
  double replan_latency = 0.0;
  // The first re-plan is the first period at or after this time of the plan (s); before it the
  // controller tracks the plan open loop. A push benchmark starts re-planning shortly before its
  // push so that what it measures is the recovery, not the steps' drift over the whole run.
  double replan_from = 0.0;
  ReplannerFactory replanner;
};

// One recorded sample.
struct SimulationSample {
  double t = 0.0;
  Eigen::Vector3d base_position = Eigen::Vector3d::Zero();
  Eigen::Vector3d base_euler_zyx = Eigen::Vector3d::Zero();
  Eigen::Vector3d planned_position = Eigen::Vector3d::Zero();
  Eigen::Vector3d planned_euler_zyx = Eigen::Vector3d::Zero();
  std::vector<Eigen::Vector3d> joint_torque;  // per leg (HAA, HFE, KFE), as applied
  std::vector<bool> foot_contact;             // per foot, in contact with the terrain
  std::vector<bool> planned_contact;
  std::vector<Eigen::Vector3d> foot_force;     // per foot, terrain on foot, world (N)
  std::vector<Eigen::Vector3d> foot_position;  // per foot, contact point (sphere centre - r n)
  std::vector<double> shin_force;              // per leg, normal force magnitude sum (N)
  std::vector<double> thigh_force;
  double trunk_force = 0.0;
};

// One planned stance as executed.
struct StanceReport {
  int foot = 0;
  double t_start = 0.0, t_end = 0.0;  // planned
  bool touched_down = false;
  double touchdown_t = -1.0;
  double touchdown_error = 0.0;  // m, contact point at touchdown vs planned foothold
  // m, distance the foot's material contact point slid along the terrain in the stance (the path
  // length of its tangential velocity); rolling does not count.
  double slip = 0.0;
  // m, largest horizontal travel of the sphere's centre from touchdown: rolling of the sphere as
  // the shin turns (r times the angle), which the plan's point foot does not model, plus slip.
  double centre_drift = 0.0;
};

struct SimulationReport {
  std::string model_xml;  // the generated MJCF (for inspection)
  ControllerGains gains;  // the controller's, as used
  std::string terrain;    // what the robot walked on
  int filled_cells = 0;   // heightfield cells the map had hole-filled or had no elevation for
  double dt = 0.0;
  double duration = 0.0;  // simulated (s)
  double wall_s = 0.0;
  double realtime_factor = 0.0;  // simulated seconds per wall second
  double cpu_s = 0.0;            // CPU time of the run (a loaded machine inflates wall_s)
  double physics_wall_s = 0.0;   // of wall_s, in mj_step (the rest: controller and bookkeeping)
  int steps = 0;

  // Tracking.
  double position_rms = 0.0, position_max = 0.0, position_max_t = 0.0;
  double tilt_max = 0.0;         // rad, orientation error
  double height_drop_max = 0.0;  // m, largest trunk height below the plan
  // Torques.
  double saturation_fraction = 0.0;             // of the time with any joint clamped
  std::vector<Eigen::Vector3d> torque_max;      // per leg, largest |tau| applied
  std::vector<Eigen::Vector3d> saturated_time;  // per leg and joint (s)
  // Per leg and joint, time with the range's end stop pushing (s) and its impulse (N m s); the
  // joint with the largest impulse: its impulse and time.
  std::vector<Eigen::Vector3d> joint_limit_time, joint_limit_impulse;
  double joint_limit_impulse_max = 0.0, joint_limit_max_s = 0.0;
  // Contacts.
  std::vector<StanceReport> stances;
  double slip_max = 0.0, touchdown_error_max = 0.0, centre_drift_max = 0.0;
  int missed_touchdowns = 0;
  std::vector<double> shin_impulse, thigh_impulse;  // per leg (N s)
  double trunk_impulse = 0.0;
  double shin_impulse_max = 0.0;

  bool fell = false;
  double fall_t = -1.0;
  // MuJoCo found its state non-finite or diverging (a bad position, velocity or acceleration;
  // it resets the state then): the run stopped there and failed. Nothing after it was simulated.
  bool unstable = false;
  double unstable_t = -1.0;
  std::string verdict;               // pass, warn, fail (a fall or an unstable run)
  std::vector<std::string> reasons;  // why (empty for pass)
  SimulationThresholds thresholds;

  std::vector<SimulationSample> samples;

  // Closed loop (replan_every > 0): re-plans asked for, failed (the previous plan kept), the first
  // failure's message, and the re-planner's wall time per call (included in wall_s and cpu_s).
  // The tracking figures and the fall are judged against the plan being tracked at each instant;
  // reference_position_max is the largest base distance from the original plan, for comparison.
// A touchdown's error is against the foothold of the plan tracked at touchdown.
  int replans = 0;
  int replan_failures = 0;
  std::string replan_first_failure;
  std::vector<double> replan_wall_s;  // per call
  double replan_wall_median = 0.0, replan_wall_max = 0.0;
  // The calling thread's CPU time per call: the planner's own cost when it runs in process (a
  // loaded machine inflates the wall time); through a socket only the client's share.
  std::vector<double> replan_cpu_s;
  double replan_cpu_median = 0.0, replan_cpu_max = 0.0;
  // The planner's iterations per call where it reported them, and the times of the failed calls.
  std::vector<int> replan_iterations;
  int replan_iterations_median = 0, replan_iterations_max = 0;
  std::vector<double> replan_failure_times;
  // Per re-plan: when, its wall time, iterations (-1 unknown), and a fallback's reason ("" none).
  struct ReplanRecord {
    double t = 0.0, wall_s = 0.0;
    int iterations = -1;
    std::string fallback;
    nlohmann::json session;  // Replan::session
  };
  std::vector<ReplanRecord> replan_records;
  int replan_fallbacks = 0;
  double reference_position_max = 0.0;
};

// The MJCF of the robot alone (no terrain, no options), for tests and inspection.
std::string robot_mjcf(const robot::RobotModel& model, double mass_scale = 1.0);

// The trunk's mass, CoM (base frame) and inertia about that CoM: the SRBD body minus the legs in
// the nominal stance, so that the whole robot's CoM is at the base origin there.
struct TrunkInertia {
  double mass = 0.0;
  Eigen::Vector3d com = Eigen::Vector3d::Zero();
  Eigen::Matrix3d inertia = Eigen::Matrix3d::Zero();
};
TrunkInertia trunk_inertia(const robot::RobotModel& model);

// Foot sphere centres (base frame) of the generated model, per configuration and leg, at joint
// angles q[configuration][leg], computed by MuJoCo's own forward kinematics with the trunk at the
// origin; for comparison with the planner's FK.
std::vector<std::vector<Eigen::Vector3d>> mujoco_foot_positions(
    const robot::RobotModel& model, const std::vector<std::vector<Eigen::Vector3d>>& q);

// The whole robot's centre of mass (base frame) by MuJoCo at joint angles q (per leg).
Eigen::Vector3d mujoco_com(const robot::RobotModel& model, const std::vector<Eigen::Vector3d>& q);

// Joint angles of the nominal stance (foot spheres' centres at nominal foot + r z).
std::vector<Eigen::Vector3d> nominal_stance(const robot::RobotModel& model);

// Refuses (SimulationError naming the field) options outside SimulationLimits and a plan the
// checks would refuse (collision::validate_trajectory: robot, feet, finite increasing times,
// finite states) or that lasts or reaches beyond SimulationLimits. simulate_plan calls it first.
void validate_simulation(const robot::RobotModel& model, const planner::Trajectory& plan,
                         const SimulationOptions& options);

// MuJoCo steps of one run of `plan` at time step `dt` (its duration over dt, rounded up), for
// callers that bound a run's cost before they start it. The plan must have passed
// validate_simulation.
long long simulation_steps(const planner::Trajectory& plan, double dt);

// Runs the plan on `scene` (boxes with exact edges). Throws SimulationError naming the problem.
SimulationReport simulate_plan(const robot::RobotModel& model, const planner::Trajectory& plan,
                               const terrain::Scene& scene, const SimulationOptions& options);

// Runs the plan on a scanned map: the surface the planner plans on (the smoothed `surface`
// layer when the map has one, else its elevation) as a heightfield (vertices on the cell
// centres) over a plane at its lowest height; foot normals from the map's smooth field.
SimulationReport simulate_plan(const robot::RobotModel& model, const planner::Trajectory& plan,
                               const terrain::TerrainMap& map, const SimulationOptions& options);

// Either of the above by the terrain's type (a Scene or a TerrainMap, as the service's terrain
// sources hold them); SimulationError for any other height field.
SimulationReport simulate_plan(const robot::RobotModel& model, const planner::Trajectory& plan,
                               const terrain::HeightField& terrain,
                               const SimulationOptions& options);

// The in-process re-planner: for each run a planner::PlanningSession whose reference is
// `reference` (the simulated plan, with its "timeline"; PlanningSession's horizon and sample_dt),
// each call one session step from the measured state, mapped to the planner's start state as the
// socket's plan.session.step maps it (start_state_json, then planner::start_state_from_json). The
// robot and terrains must outlive every run; `options` as the reference was planned with. Each
// step has `budget` seconds (planner::StepLimits::budget, as the server's steps; 0 = none) or,
// with budget 0, `budget_iterations` solver iterations (StepLimits::iterations: answers that do
// not depend on the machine's load; 0 = none).
ReplannerFactory session_replanner(const robot::RobotModel& robot,
                                   const terrain::HeightField& plan_terrain,
                                   const terrain::HeightField& check_terrain,
                                   const planner::PlannerOptions& options,
                                   const planner::Trajectory& reference, double horizon,
                                   double sample_dt, double budget = 0.0,
                                   int budget_iterations = 0);

// Robustness margin (`terrastride simulate --margin`): the largest disturbance a plan survives,
// so two plans can be compared by how much they take. Survives = the verdict is not "fail" (no
// fall; warnings allowed), each search a bisection on that verdict (assumed monotone in the
// disturbance: a larger push or mass error is never easier).
// Push convention: a constant horizontal force on the trunk's origin, perpendicular to the
// planned heading (yaw) at the push's start, of `push_duration` seconds starting at
// `push_time_fraction` of the plan's duration; searched to the left and to the right, the margin
// being the smaller. Mass error: the trunk's mass and inertia scaled by K (the controller still
// uses the plan's forces): the largest K >= 1 (payload) and smallest K <= 1 it survives.
struct MarginOptions {
  double push_time_fraction = 0.5;
  double push_duration = 0.2;      // s
  double push_force_max = 4000.0;  // N, the search's ceiling (a margin there is "at least")
  double push_tolerance = 10.0;    // N, bisection stops when the bracket is this narrow
  bool mass = true;                // also search the mass error
  double mass_scale_max = 3.0, mass_scale_min = 0.3;  // the search's limits
  double mass_tolerance = 0.02;
};

struct MarginSide {
  double survived = 0.0;  // largest disturbance survived (N, or mass scale)
  double failed = -1.0;   // smallest that failed (< 0: none failed up to the search's limit)
  std::string failure;    // the verdict's first reason at `failed`
};

struct MarginReport {
  std::string nominal_verdict;               // without disturbance; "fail" leaves every margin at 0
  double push_t = 0.0, push_duration = 0.0;  // s
  Eigen::Vector3d left = Eigen::Vector3d::Zero();  // unit push direction to the left
  MarginSide push_left, push_right;
  double push_margin_N = 0.0;    // min of the two sides
  double push_margin_Ns = 0.0;   // its impulse (force times duration)
  bool push_at_ceiling = false;  // neither side failed up to push_force_max
  bool mass_searched = false;
  MarginSide mass_heavier, mass_lighter;  // survived/failed as mass scales
  int runs = 0;
  double wall_s = 0.0;
  MarginOptions options;
};

// The most runs simulation_margin makes with `margin` (the nominal run, each side's doubling and
// bisection at their longest): with the defaults 56. Its cost is at most this many times
// simulation_steps.
int margin_max_runs(const MarginOptions& margin);

// `options` are the simulation's (dt, friction, thresholds, controller; its pushes and mass
// scale are the nominal state every search adds to). Throws SimulationError as simulate_plan;
// options.stop_requested is polled within and between the runs (SimulationCancelled).
MarginReport simulation_margin(const robot::RobotModel& model, const planner::Trajectory& plan,
                               const terrain::HeightField& terrain,
                               const SimulationOptions& options, const MarginOptions& margin = {});

}  // namespace terrastride::simulation
