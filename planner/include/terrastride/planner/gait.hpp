// Gaits as data (data/gaits/*.yaml) and the phase timeline they produce for a plan.
#pragma once

#include <map>
#include <stdexcept>
#include <string>
#include <vector>

namespace terrastride::robot {
struct RobotModel;
}

namespace terrastride::planner {

// Unreadable or invalid gait file, or a gait that does not fit the robot; names file and field.
class GaitError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

struct Gait {
  std::string name;
  std::string source_file;
  double cycle_duration = 1.0;  // s, default length of one cycle
  double lead_in = 0.0;         // all-stance time before the first cycle, fraction of a cycle
  double lead_out = 0.0;        // all-stance time after the last cycle, fraction of a cycle
  // Swing windows [start, end] per leg name, fractions of a cycle.
  std::map<std::string, std::vector<std::pair<double, double>>> swing;
};

Gait load_gait(const std::string& path);

// Gait files give their times in HyQ's seconds. Another robot walks the same gait dynamically
// similar to HyQ (equal Froude number v^2 / (g h)): its times scale by sqrt(h / h_HyQ), h the
// nominal base height (HyQ 0.58 m: 1 exactly; Go2 0.298 m: 0.717; ANYmal C 0.404 m: 0.834), and
// since a stride is the range-of-motion box, which scales with the leg (default_cycles), the feet
// keep HyQ's speeds relative to leg length over time scaled so. A `--duration` replaces it.
constexpr double kGaitReferenceBaseHeight = 0.58;  // m, HyQ's nominal base height
double gait_time_scale(const robot::RobotModel& robot);
// The gait with its cycle_duration scaled by gait_time_scale (the gait itself for scale 1).
Gait timed_for_robot(const Gait& gait, const robot::RobotModel& robot);

// The fewest feet the gait stands on at once while any stands (a flight phase aside).
int fewest_stance_feet(const Gait& gait, const std::vector<std::string>& feet);
// Refuses a robot that cannot carry its weight in the gait, before any solve: at the nominal
// stance, its weight shared by the fewest feet the gait stands on (legs' own weight included),
// a joint needing more torque than its limit. The message names the robot, leg, joint, torque
// and limit. Returns the worst |tau| / limit.
double require_weight_bearable(const Gait& gait, const robot::RobotModel& robot);
// The gait a plan from rest walks: `name_or_path` loaded, timed_for_robot, and
// require_weight_bearable (a robot too weak for it is refused here, not after a solve that
// cannot succeed).
Gait gait_for_robot(const std::string& name_or_path, const robot::RobotModel& robot);
// data/gaits/<name>.yaml (TERRASTRIDE_DATA_DIR honoured), or a path to a .yaml file.
std::string resolve_gait_path(const std::string& name_or_path);
// The gait names in the data folder (data/gaits/NAME.yaml), sorted.
std::vector<std::string> gait_names();

// The contact schedule of a whole plan: the merged switch times of all feet (events) and, per
// interval between consecutive events, which feet are in stance. Every plan piece (base, feet,
// forces) has knots on these events, so contact never changes inside a polynomial piece.
struct PhaseTimeline {
  std::vector<std::string> feet;
  std::vector<double> events;              // 0 = e_0 < e_1 < ... < e_N = duration
  std::vector<std::vector<bool>> contact;  // [foot][interval]
  // A cropped timeline's first interval is the tail of one that began this long before t = 0. The
  // planner then keeps that interval's segment knots (at the same absolute times), so that a plan
  // warm-started from a shifted previous plan can reproduce it exactly.
  double first_interval_elapsed = 0.0;
  // Per foot (empty: all 0): a foot in swing at t = 0 lifted off this long before. The swing
  // clearance demanded along a swing follows its time since lift-off, so a re-plan must demand
  // what the previous plan did (a swing restarted at the crop point demanded a full step height
  // of a foot already coming down: the flat 2.4 s crawl re-planned at 0.1 s ended infeasible).
  std::vector<double> swing_elapsed;
  double swing_elapsed_of(std::size_t foot) const {
    return foot < swing_elapsed.size() ? swing_elapsed[foot] : 0.0;
  }
  double duration() const { return events.empty() ? 0.0 : events.back(); }
  int num_intervals() const { return static_cast<int>(events.size()) - 1; }
  // Per foot, the phases as [start, end, contact] triples (consecutive intervals merged).
  struct Phase {
    double start, end;
    bool contact;
  };
  std::vector<Phase> phases(int foot) const;
  // The part of the timeline from t0 on, shifted so that it starts at 0.
  PhaseTimeline cropped(double t0) const;
};

// Builds the timeline of `cycles` cycles lasting `duration` seconds in total (duration <= 0: the
// gait's default cycle_duration times cycles, plus lead-in/out). `feet` are the robot's legs;
// every leg needs an entry in the gait and every gait entry a leg.
PhaseTimeline make_timeline(const Gait& gait, const std::vector<std::string>& feet, int cycles,
                            double duration);

// Refuses, before any solve, a walk whose swings need a joint faster than the robot file's velocity
// limit (robots with velocity limits on every leg; others: 0). Each foot must cover `distance` (m,
// start to goal) in its swings, while the base moves at the average speed distance / duration: a
// swing carries the foot distance (1 - swing time / duration) / swings forward relative to the
// base. The joint travel of that step, from half a step behind the nominal foot to half a step
// ahead (inverse kinematics at both), over the swing time is the least average speed the joint
// needs; its peak cannot be lower. The lift is left out: the base may rise instead of the swing
// leg folding (counted as a 5 cm lift, it refused Go2 with 1 rad/s knees on its default crawl,
// for which a plan within 0.96 of that limit exists); so are turns and terrain. The estimate
// stays below what a plan needs (Go2 with 8 rad/s knees trotting 1 m in 1.6 s: 0.086 of the
// limit, where its plan peaks at 0.93): it refuses what no plan can do. The message names the
// gait, leg, joint, needed speed and limit, and the fix: the least --duration (the needed speed
// scales with 1 / duration) or more --cycles. Returns the worst needed / limit.
double require_joint_speeds_reachable(const PhaseTimeline& timeline, const std::string& gait_name,
                                      const robot::RobotModel& robot, double distance);

// The gait with its lead-in lengthened, if need be, so that the timeline's second lift-off (the
// second distinct time at which a foot lifts off) comes no earlier than `second_lift_off` s; the
// total `duration` is kept (duration <= 0: the cycle is kept and the plan grows longer). Unchanged
// when the second lift-off is that late already, when the duration leaves no room for it, or
// when the lead-in would shorten the cycle below half of the gait's (the gait would not be the
// same gait). With optimised timing this is the initial schedule: the solver may shorten the
// lead-in's intervals as any other (down to half each, Layout), so the floor is not guaranteed.
// A plan from rest with force ramps needs this (plan_motion; docs/design.md §6.4 "Path shape").
Gait with_rest_lead_in(const Gait& gait, const std::vector<std::string>& feet, int cycles,
                       double duration, double second_lift_off);

}  // namespace terrastride::planner
