// The paper's hardware-feasibility constraint sets (Bratta et al. 2020, section III), appended to
// the SRBD problem on top of "baseline":
//  - "foot"     foot radius (III-B): every free stance foothold keeps the terrain's signed
//               foothold-safety margin for the robot's foot radius >= foot_margin;
//  - "shin"     shin collision (III-B, (19)-(20)): p_z + k s sin(beta) - h(p_knee,k) >= clearance
//               for points k along the modelled shin, over the whole stance;
//  - "polytope" force polytopes (III-A): n^j(p_b)^T f_b <= d^j(p_b) in the base frame, at every
//               force knot and at points inside each stance segment;
//  - "swing"    (beyond the paper) each component of a swing foot's acceleration within
//               +-swing_acceleration: the torque a swing leg needs to accelerate itself.
// "polytope" implies "swing": the joint-torque limits hold for stance legs (polytopes) and swing
// legs (acceleration) alike, as the post-hoc torque check judges them (tau = M q'' + c + g - J^T
// f). By default the shin and polytope rows of one stance segment are folded into one row each, a
// conservative smooth minimum/maximum (fewer rows: a cheaper KKT factorisation; see the options).
// "all" means foot, shin_ik and polytope (so swing too): the paper's fixed-angle shin model lets
// HyQ's real shin capsule into a pallet edge (pallet_10: 63 colliding samples, -57 mm), the IK
// shin does not (0 on both pallets) at the same cost; "shin" stays for the paper's comparison.
// Each set is built by one function in its own file, planner/src/constraints/SET.cpp, whose pieces
// are of kind SET, and is registered under SET (constraints.hpp).
#pragma once

#include <map>
#include <string>
#include <utility>
#include <vector>

#include "terrastride/planner/nlp.hpp"

namespace terrastride::planner {

struct FeasibilityOptions {
  // foot: required margin (m) beyond the foot radius. The planner sees the smoothed 2 cm
  // height-field's margin (a B-spline of a grid distance), the post-hoc check the exact scene's;
  // a few millimetres absorb the rasterisation difference.
  double foot_margin = 0.005;
  // shin: n points evenly spaced along the modelled shin from k_min = shin_exclusion / s to the
  // knee (k = 1). The paper checks the knee and two points; a step edge falling between two points
  // is only seen by the next one, so the shin line there can be lower than that point's
  // clearance by the spacing times tan(beta): 10 points keep that under ~1.5 cm on HyQ, 20 under
  // ~0.8 cm. Measured on pallet_15 "all" (shin_ik): 10 points, the real shin capsule cleared the
  // edge by 0.3 mm; 20 points, by 13 mm (merged rows: the row count is the same).
  // shin_exclusion (m along the shin from the foot): the foot sphere and the shin's end cap,
  // which stand on the ground by design (the post-hoc capsule check leaves out the same part:
  // 2 r_foot + r_shin + 1 cm, robot::shin_exclusion). Negative = that value.
  int shin_points = 20;
  double shin_exclusion = -1.0;
  // shin: required vertical gap (m) of each point above the terrain under it. Negative = the
  // shin capsule's radius over |cos(beta)|: a horizontal edge right below the shin's axis is then
  // at least one capsule radius away from it (perpendicular distance = gap |cos(beta)|).
  double shin_clearance = -1.0;
  // shin_ik: extra vertical gap (m) for the motion between the knots where the rows are imposed
  // (segment ends). Measured on pallet_15 "all" without it: the RH shin dipped 1 mm into the
  // edge between two knots (post-hoc capsule check, 2 ms samples).
  double shin_ik_margin = 0.005;
  // shin: points per stance segment at which the base yaw is taken (ends of segments always).
  int shin_yaw_points = 2;
  // shin: > 0 folds each stance segment's shin values (shin_points at each of its yaw points) into
  // ONE row, their soft minimum at this scale (m; feasibility::soft_min, <= the true minimum, so
  // the row implies every point's; at most scale * log(n) stricter: 7 mm for n = 30 points).
  // 0: one row per point. Measured (pallet_15 "all" on a loaded 2-core machine): rows
  // 21,744 -> 9,968 with polytope_softmax, solve 28 s user / 57 iterations -> 3.6 s / 22.
  double shin_softmin = 0.002;
  // shin_ik, thigh: each point of a link's axis also reads the terrain this far (m) beyond the
  // link's capsule radius to either side, across the base's heading (see
  // constraints/leg_capsule_clearance.hpp; the planner's smoothed terrain reaches a step's full
  // height within one 2 cm cell of its edge). Negative: the terrain under the axis only.
  double leg_probe_margin = 0.02;
  // shin_ik, thigh: the capsules the rows keep clear are the links' grown by this much (m), so the
  // margin is a distance from the link's surface, whatever its inclination (a vertical margin
  // shrinks to margin * cos(inclination) across a 55-degree hind shin). Why: executed in MuJoCo
  // (simulation::simulate_plan), a foot is a sphere that rolls as its shin turns during a stance,
  // so the shin is not where the planner's point foot puts it. Measured on the 11 s pallet_15
  // crawl with `all` and no growth: the RH foot's contact point crept 11 mm towards the pallet
  // over its 2.6 s stance (9 mm at the end, centre drift 17 mm at worst over the plan), and its
  // shin, 5 mm from the edge in the post-hoc check, met the edge for 6.1 N s (verdict warn,
  // limit 5 N s); eur_pallet the same (14 N s).
  double leg_capsule_margin = 0.003;
  // shin_ik, thigh: constraint points per segment where the terrain near the leg is tall (the
  // knots alone elsewhere for shin_ik, nothing for thigh). Measured on eur_pallet --goal 1.5,0,0
  // with the knots only (0.1 s apart): a swinging LH shin went 33 mm into the pallet between two.
  int leg_clearance_points = 3;
  // thigh: points along the thigh, HFE joint to knee.
  int thigh_points = 8;
  // trunk: required height (m) of the trunk box's bottom face above the terrain where the terrain
  // is tall (constraints/trunk.cpp); it covers the base's motion between knots.
  double trunk_margin = 0.02;
  // polytope: points per stance segment besides its two force knots (see constraints/polytope.cpp).
  int polytope_inner_points = 1;
  // polytope: > 0 folds each stance segment's facet rows (6 at each force knot and inner point)
  // into ONE row, their soft maximum at this scale (body weights; >= the true maximum, so the row
  // implies every facet row; at most scale * log(18) = 0.006 m g stricter). 0: 6 rows per point.
  double polytope_softmax = 0.002;
  // swing: bound on each world-frame component of a swing foot's acceleration (m/s^2). HyQ's
  // swing leg (about 3.5 kg of thigh and shin within 0.6 m of the HFE axis) needs some 40-60 N m
  // of its 150 N m at 100 m/s^2, leaving the rest for velocity and gravity terms and for the base's
  // own acceleration; the flat 2.4 s crawl's 0.33 m steps in 0.16 s need about 80 m/s^2.
  // A plan's default is its robot's (robot_swing_acceleration): HyQ's 100, Go2's 135, ANYmal
  // C's 35 (its 3 kg thigh on 80 N m motors); this value is the default without a robot.
  double swing_acceleration = 100.0;
  // joints: the joint angles keep this far (rad) inside their ranges at the spline's knots; it
  // covers the motion between knots.
  double joint_margin = 0.035;
  // joints: > 0 folds each knot's joint rows into ONE row, and each swing segment's three points'
  // into one, the soft maximum at this scale (rad) of (q_j - q_max_j + margin, q_min_j + margin -
  // q_j): >= the true maximum, so the row implies every joint's bound, and at most scale * log(n)
  // stricter when n values are equally close (a joint's two sides never both are). Off by
  // default (measured): at 0.005 rad pallet_15 'all' has 12,299 rows instead of
  // 14,035 and MUMPS's factor 0.98 M doubles instead of 1.14 M (-17 % CPU per factorisation;
  // the swing segments' merge is 0.14 M of it), but the iterations rose: the off-path suite's 25
  // clean requests 286 -> 308 (same exit codes, 25/0/11), its trots most (pallet_10 to 1,0.3,0.5
  // 7 -> 13), six 'all' plans 46 -> 54 (0.02 rad: 51). 0: a row per joint and point.
  double joints_softmax = 0.0;
  // joints: the joint-velocity rows (build_joint_velocity_rows) for a robot with velocity limits;
  // 1 on, 0 off. On: without them the imported robots' pallet_10 crawls exceed their URDF limits
  // by 3-11 % in swing. They do not yet serve every step: Go2's 1 m crawl over pallet_14 with
  // them ends infeasible (a foothold pushed onto the edge), without them at 1.05x the LH KFE limit.
  double joint_velocity = 1.0;
  // joints, range_of_motion: a re-plan whose measured start lies outside a joint range or a
  // range-of-motion box (after a push) gets its excess as room at the next knots, shrinking to
  // nothing over this span (s; constraints/start_return.hpp, docs/design.md §6.7). A session
  // step's pinned end outside them (a foothold slipped in a stance lasting to it) likewise at the
  // knots before it, growing over the same span up to the end. 0: none.
  // Measured on the pallet_15 `all` closed loop at 10 Hz, right push 450 N: 0.1 s
  // falls at 7.2 s, 0.25 s survives with 25 of 109 re-plans failed and 41.7 mm RMS, 0.5 s 18 and
  // 21.4 mm, 1 s 15 and 16.8 mm (left 300 N: 10 failed at each, pass only at 0.1 and 1 s).
  double start_return = 1.0;
  // force_ramp: bound on the rate of change of each contact force within a stance (N/s, the
  // norm of the force vector's change over a segment, divided by the segment's duration; 0 = no
  // bound). The force knots at touch-down and lift-off are zero (no variables, Layout), so a
  // foot loads and unloads at most at this rate: 2000 N/s is 20 N per 10 ms sample, a quarter of
  // HyQ's weight in 0.1 s.
  double force_rate_max = 2000.0;
  // The shape of the base and swing paths (constraints/monotone_progress.cpp,
  // lateral_corridor.cpp, swing_apex.cpp). Each bounds the splines' Bezier control points, so the
  // bound holds along the whole polynomial, not only at knots. 0 = off.
  // monotone_progress: 1 = the base never moves back along the start-to-goal line.
  int monotone_progress = 1;
  // lateral_corridor (m): the base within this distance of the start-to-goal line.
  double lateral_corridor = 0.02;
  // swing_apex_rise (m): a swing foot at most this far above the higher of its lift-off and
  // touch-down points, or of the terrain its guessed path passes where that is higher.
  double swing_apex_rise = 0.1;
  // replan_path_shape: 1 = the three path-shape families above also shape a problem that starts
  // from a given state (a re-plan: a planning session's step, `plan --init`); 0 = only plans that
  // start at rest (cold plans) carry them. Why (docs/design.md §6.4): a re-plan follows a plan
  // that already has the shape, and its end is pinned to it (a session's horizon) or is the goal;
  // a measured start that drifted ahead of or beside that plan cannot satisfy rows shaped for the
  // cold plan. See path_shape_applies (constraints/base_line.hpp).
  int replan_path_shape = 0;
};

void build_foot_set(SrbdProblem& problem, const FeasibilityOptions& options = {});
void build_shin_set(SrbdProblem& problem, const FeasibilityOptions& options = {});
// "shin_ik" (in "all"; beyond the paper): the shin inequality on the leg's real shin, foot to
// the knee from inverse kinematics at the base pose (see constraints/shin_ik.cpp).
void build_shin_ik_set(SrbdProblem& problem, const FeasibilityOptions& options = {});
// "thigh" (in "all"; beyond the paper): the same inequality on the thigh capsule, HFE joint to
// knee, where the terrain near the leg is tall (see constraints/thigh.cpp).
void build_thigh_set(SrbdProblem& problem, const FeasibilityOptions& options = {});
// "trunk" (in "all"; beyond the paper): the trunk box's bottom face above the terrain at the knots
// where the terrain near it is tall (see constraints/trunk.cpp). No rows for a robot without one.
void build_trunk_set(SrbdProblem& problem, const FeasibilityOptions& options = {});
void build_polytope_set(SrbdProblem& problem, const FeasibilityOptions& options = {});
void build_swing_set(SrbdProblem& problem, const FeasibilityOptions& options = {});
// "joints" (in "all"; beyond the paper): joint angles from IK within the joint ranges at every
// knot of the base spline (see constraints/joints.cpp).
void build_joints_set(SrbdProblem& problem, const FeasibilityOptions& options = {});
// Part of "joints" for a robot whose every leg has velocity limits (has_velocity_limits): the
// joint velocities within them at every knot and swing quarter point (piece kind
// "joint_velocity", constraints/joint_velocity.cpp); build_joints_set adds them.
bool has_velocity_limits(const robot::RobotModel& robot);
void build_joint_velocity_rows(SrbdProblem& problem);
// The joint velocities those rows bound, for a base (position, velocity, ZYX Euler angles and
// their rates) and a foot (position, velocity), all in the world frame.
template <class T>
Eigen::Matrix<T, 3, 1> joint_velocity_rows(
    const robot::LegModel& leg, const Eigen::Matrix<T, 3, 1>& base,
    const Eigen::Matrix<T, 3, 1>& base_vel, const Eigen::Matrix<T, 3, 1>& euler,
    const Eigen::Matrix<T, 3, 1>& euler_rate, const Eigen::Matrix<T, 3, 1>& foot,
    const Eigen::Matrix<T, 3, 1>& foot_vel);
// "force_ramp" (in "all"; beyond the paper): contact forces that load and unload continuously.
// The layout leaves out the force knots at touch-down and lift-off (zero force there); this adds
// the force rate bound force_rate_max per stance segment (see constraints/force_ramp.cpp).
void build_force_ramp_set(SrbdProblem& problem, const FeasibilityOptions& options = {});
// "monotone_progress", "lateral_corridor", "swing_apex" (in "all"): the base path's and
// the swing feet's shape, each on when its setting above is non-zero (no rows otherwise).
void build_monotone_progress_set(SrbdProblem& problem, const FeasibilityOptions& options = {});
void build_lateral_corridor_set(SrbdProblem& problem, const FeasibilityOptions& options = {});
void build_swing_apex_set(SrbdProblem& problem, const FeasibilityOptions& options = {});

// FeasibilityOptions from the defaults and NAME=VALUE settings (ProblemOptions::
// feasibility_settings, `terrastride plan --feasibility`); names are the fields' names. Throws
// std::invalid_argument naming the setting when the name is unknown or the value out of range.
FeasibilityOptions feasibility_options(const std::vector<std::pair<std::string, double>>& settings);
// The same over a robot's defaults (robot_feasibility_defaults): what a plan for that robot uses.
FeasibilityOptions feasibility_options(const robot::RobotModel& robot,
                                       const std::vector<std::pair<std::string, double>>& settings);

// The defaults that depend on the robot, the rest FeasibilityOptions{}'s: swing_acceleration.
FeasibilityOptions robot_feasibility_defaults(const robot::RobotModel& robot);

// The swing set's bound for a robot (m/s^2): 0.65 of the foot acceleration at which a swing leg
// reaches a joint's torque limit, rounded to 5 m/s^2. That acceleration is, at each leg's nominal
// stance and over the worst corner of the bound's box (every component at +-a), the least over
// joints i of (tau_max_i - |g_i(q)|) / sum_j |(M(q) J(q)^-1)_ij|: the torque the leg's own inertia
// asks for, gravity held. 0.65 is HyQ's 100 m/s^2 of its 154; it leaves a third of the torque
// for the velocity terms and the base's acceleration the bound does not see. Measured: ANYmal C's
// 'all' plan over pallet_21 needed its LF HFE at 1.31 x the limit with 100 m/s^2 (its swing leg
// saturates at 54). Throws std::invalid_argument naming the robot and leg when the nominal foot is
// out of reach or a joint's gravity torque alone exceeds its limit.
double robot_swing_acceleration(const robot::RobotModel& robot);
// The names feasibility_options() accepts.
std::vector<std::string> feasibility_option_names();

}  // namespace terrastride::planner
