#include "terrastride/planner/gait.hpp"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <iomanip>
#include <sstream>

#include "terrastride/planner/request_limits.hpp"
#include "terrastride/robot/leg_kinematics.hpp"
#include "terrastride/robot/robot_model.hpp"

namespace terrastride::planner {

namespace {

double read_number(const YAML::Node& node, const std::string& file, const std::string& field) {
  try {
    const double v = node.as<double>();
    if (!std::isfinite(v)) throw GaitError(file + ": " + field + ": not a finite number");
    return v;
  } catch (const YAML::Exception&) {
    throw GaitError(file + ": " + field + ": expected a number");
  }
}

// A name (the gait's, a leg's): a YAML scalar. yaml-cpp's own "bad conversion" names neither the
// file nor the field.
std::string read_text(const YAML::Node& node, const std::string& file, const std::string& field) {
  if (!node.IsScalar()) throw GaitError(file + ": " + field + ": expected a name (text)");
  return node.Scalar();
}

}  // namespace

Gait load_gait(const std::string& path) {
  YAML::Node root;
  try {
    root = YAML::LoadFile(path);
  } catch (const YAML::BadFile&) {
    throw GaitError(path + ": cannot read gait file");
  } catch (const YAML::Exception& e) {
    throw GaitError(path + ": not valid YAML: " + e.what());
  }
  if (!root.IsMap()) throw GaitError(path + ": expected a mapping at the top level");
  Gait g;
  g.source_file = path;
  g.name = root["name"] ? read_text(root["name"], path, "name")
                        : std::filesystem::path(path).stem().string();
  if (root["cycle_duration"]) {
    g.cycle_duration = read_number(root["cycle_duration"], path, "cycle_duration");
    if (g.cycle_duration <= 0.0) throw GaitError(path + ": cycle_duration: must be > 0");
  }
  if (root["lead_in"]) g.lead_in = read_number(root["lead_in"], path, "lead_in");
  if (root["lead_out"]) g.lead_out = read_number(root["lead_out"], path, "lead_out");
  if (g.lead_in < 0.0 || g.lead_out < 0.0) throw GaitError(path + ": lead_in/lead_out: must be >= 0");
  const YAML::Node swing = root["swing"];
  if (!swing || !swing.IsMap() || swing.size() == 0)
    throw GaitError(path + ": swing: expected a mapping from leg name to swing windows");
  for (const auto& kv : swing) {
    const std::string leg = read_text(kv.first, path, "swing (a leg's name)");
    const std::string field = "swing." + leg;
    if (!kv.second.IsSequence()) throw GaitError(path + ": " + field + ": expected a list");
    std::vector<std::pair<double, double>> windows;
    for (std::size_t i = 0; i < kv.second.size(); ++i) {
      const YAML::Node w = kv.second[i];
      const std::string wf = field + "[" + std::to_string(i) + "]";
      if (!w.IsSequence() || w.size() != 2) throw GaitError(path + ": " + wf + ": expected [start, end]");
      const double a = read_number(w[0], path, wf), b = read_number(w[1], path, wf);
      if (!(a >= 0.0 && a < b && b <= 1.0))
        throw GaitError(path + ": " + wf + ": need 0 <= start < end <= 1");
      windows.emplace_back(a, b);
    }
    std::sort(windows.begin(), windows.end());
    for (std::size_t i = 1; i < windows.size(); ++i)
      if (windows[i].first < windows[i - 1].second)
        throw GaitError(path + ": " + field + ": swing windows overlap");
    g.swing[leg] = windows;
  }
  return g;
}

double gait_time_scale(const robot::RobotModel& robot) {
  const double h = robot.nominal_base_height;
  if (!(h > 0.0) || !std::isfinite(h))
    throw GaitError("robot '" + robot.name + "': nominal_base_height must be > 0 to time a gait");
  return std::sqrt(h / kGaitReferenceBaseHeight);  // HyQ: sqrt(1) = 1 exactly
}

Gait timed_for_robot(const Gait& gait, const robot::RobotModel& robot) {
  Gait timed = gait;
  timed.cycle_duration *= gait_time_scale(robot);
  return timed;
}

int fewest_stance_feet(const Gait& gait, const std::vector<std::string>& feet) {
  std::vector<double> cuts{0.0, 1.0};
  for (const auto& [leg, windows] : gait.swing)
    for (const auto& [a, b] : windows) {
      cuts.push_back(a);
      cuts.push_back(b);
    }
  std::sort(cuts.begin(), cuts.end());
  int fewest = static_cast<int>(feet.size());
  for (std::size_t k = 0; k + 1 < cuts.size(); ++k) {
    if (cuts[k + 1] - cuts[k] < 1e-12) continue;
    const double mid = 0.5 * (cuts[k] + cuts[k + 1]);
    int standing = 0;
    for (const auto& f : feet) {
      bool swinging = false;
      const auto it = gait.swing.find(f);
      if (it != gait.swing.end())
        for (const auto& [a, b] : it->second) swinging = swinging || (mid > a && mid < b);
      standing += !swinging;
    }
    if (standing > 0) fewest = std::min(fewest, standing);
  }
  return fewest;
}

double require_weight_bearable(const Gait& gait, const robot::RobotModel& robot) {
  std::vector<std::string> feet;
  for (const auto& leg : robot.legs) feet.push_back(leg.name);
  const int n = fewest_stance_feet(gait, feet);
  if (n < 1 || !(robot.mass > 0.0)) return 0.0;
  constexpr double kG = 9.81;
  const Eigen::Vector3d gravity(0.0, 0.0, -kG), load(0.0, 0.0, robot.mass * kG / n);
  static const char* kJoint[3] = {"HAA", "HFE", "KFE"};
  double worst = 0.0;
  for (const auto& leg : robot.legs) {
    if (!(leg.torque_limit.minCoeff() > 0.0)) continue;
    // The foot sphere's centre above the nominal contact point, as the simulator stands it.
    const auto ik =
        robot::inverse_kinematics(leg, leg.nominal_foot + Eigen::Vector3d(0, 0, robot.foot_radius));
    if (ik.status == robot::IkStatus::unreachable) continue;  // the reachability check names it
    const Eigen::Vector3d zero = Eigen::Vector3d::Zero();
    const Eigen::Vector3d tau = robot::joint_torques(leg, ik.q, zero, zero, load, gravity);
    for (int j = 0; j < 3; ++j) {
      const double ratio = std::abs(tau[j]) / leg.torque_limit[j];
      worst = std::max(worst, ratio);
      if (ratio > 1.0) {
        std::ostringstream m;
        m << "robot '" << robot.name << "' cannot carry its weight in the " << gait.name
          << " gait: on " << n << " feet at its nominal stance (" << robot.mass * kG / n
          << " N each) leg " << leg.name << "'s " << kJoint[j] << " needs " << std::abs(tau[j])
          << " N m and its limit is " << leg.torque_limit[j]
          << " N m (the robot file's torque_limit: give the motor's with `robot import "
             "--effort`; a straighter nominal stance, `robot import --nominal-height`, needs less)";
        throw RequestError("robot", m.str());
      }
    }
  }
  return worst;
}

double require_joint_speeds_reachable(const PhaseTimeline& timeline, const std::string& gait_name,
                                      const robot::RobotModel& robot, double distance) {
  const double duration = timeline.duration();
  if (!(distance > 0.0) || !(duration > 0.0)) return 0.0;
  for (const auto& leg : robot.legs)
    if (!(leg.velocity_limit.minCoeff() > 0.0)) return 0.0;  // the robot file gives none
  static const char* kJoint[3] = {"HAA", "HFE", "KFE"};
  // The joint furthest beyond its limit: the --duration that serves it serves every joint.
  double worst = 0.0, worst_needed = 0.0, worst_step = 0.0, worst_swing = 0.0;
  int worst_leg = -1, worst_joint = -1;
  for (std::size_t f = 0; f < robot.legs.size() && f < timeline.feet.size(); ++f) {
    const robot::LegModel& leg = robot.legs[f];
    int swings = 0;
    double swing_time = 0.0;
    for (const auto& phase : timeline.phases(static_cast<int>(f)))
      if (!phase.contact) {
        ++swings;
        swing_time += phase.end - phase.start;
      }
    if (swings == 0) continue;
    const double step = distance * (1.0 - swing_time / duration) / swings;
    // The foot sphere's centre over the nominal contact point, as the planner's rows place it.
    const Eigen::Vector3d centre = leg.nominal_foot + Eigen::Vector3d(0, 0, robot.foot_radius);
    const auto back = robot::inverse_kinematics(leg, centre - Eigen::Vector3d(step / 2, 0, 0));
    const auto front = robot::inverse_kinematics(leg, centre + Eigen::Vector3d(step / 2, 0, 0));
    // A step beyond the leg's reach: the reachability check names it.
    if (back.status == robot::IkStatus::unreachable || front.status == robot::IkStatus::unreachable)
      continue;
    for (int j = 0; j < 3; ++j) {
      const double needed = std::abs(front.q[j] - back.q[j]) * swings / swing_time;
      const double ratio = needed / leg.velocity_limit[j];
      if (ratio > worst) {
        worst = ratio;
        worst_needed = needed;
        worst_step = step;
        worst_swing = swing_time / swings;
        worst_leg = static_cast<int>(f);
        worst_joint = j;
      }
    }
  }
  if (worst > 1.0) {
    const robot::LegModel& leg = robot.legs[worst_leg];
    std::ostringstream m;
    m.precision(3);
    m << "robot '" << robot.name << "' cannot swing its legs fast enough in the " << gait_name
      << " gait: leg " << leg.name << " moves its foot " << worst_step
      << " m ahead of the base in " << worst_swing << " s per swing (" << distance << " m in " << duration << " s), which needs " << kJoint[worst_joint]
      << " to turn at " << worst_needed << " rad/s on average, above its limit of "
      << leg.velocity_limit[worst_joint]
      << " rad/s (the robot file's velocity_limit); plan a slower walk: --duration " << std::fixed
      << std::setprecision(1) << std::ceil(10.0 * duration * worst) / 10.0
      << " s at least, or more --cycles (shorter steps)";
    throw RequestError("duration", m.str());
  }
  return worst;
}

Gait gait_for_robot(const std::string& name_or_path, const robot::RobotModel& robot) {
  Gait gait = timed_for_robot(load_gait(resolve_gait_path(name_or_path)), robot);
  require_weight_bearable(gait, robot);
  return gait;
}

std::string resolve_gait_path(const std::string& name_or_path) {
  namespace fs = std::filesystem;
  if (name_or_path.find('/') != std::string::npos ||
      (name_or_path.size() > 5 && name_or_path.substr(name_or_path.size() - 5) == ".yaml")) {
    if (!fs::exists(name_or_path)) throw GaitError(name_or_path + ": no such gait file");
    return name_or_path;
  }
  const fs::path dir = fs::path(robot::data_dir()) / "gaits";
  const fs::path p = dir / (name_or_path + ".yaml");
  if (fs::exists(p)) return p.string();
  std::string names;
  for (const auto& n : gait_names()) names += (names.empty() ? "" : ", ") + n;
  throw GaitError("gait '" + name_or_path + "': unknown (gaits in " + dir.string() + ": " + names +
                  ")");
}

std::vector<std::string> gait_names() {
  namespace fs = std::filesystem;
  const fs::path dir = fs::path(robot::data_dir()) / "gaits";
  std::vector<std::string> names;
  std::error_code ec;
  if (fs::is_directory(dir, ec))
    for (const auto& e : fs::directory_iterator(dir, ec))
      if (e.path().extension() == ".yaml") names.push_back(e.path().stem().string());
  std::sort(names.begin(), names.end());
  return names;
}

PhaseTimeline make_timeline(const Gait& gait, const std::vector<std::string>& feet, int cycles,
                            double duration) {
  if (cycles < 1) throw GaitError("cycles: must be >= 1 (got " + std::to_string(cycles) + ")");
  for (const auto& [leg, w] : gait.swing)
    if (std::find(feet.begin(), feet.end(), leg) == feet.end())
      throw GaitError(gait.source_file + ": swing." + leg + ": the robot has no such leg");
  for (const auto& f : feet)
    if (!gait.swing.count(f))
      throw GaitError(gait.source_file + ": swing: no entry for the robot's leg " + f);
  const double units = gait.lead_in + cycles + gait.lead_out;  // in cycles
  const double cycle = duration > 0.0 ? duration / units : gait.cycle_duration;
  const double total = cycle * units;
  // Swing intervals in absolute time, per foot.
  std::vector<std::vector<std::pair<double, double>>> sw(feet.size());
  std::vector<double> ev{0.0, total};
  for (std::size_t f = 0; f < feet.size(); ++f) {
    for (int c = 0; c < cycles; ++c)
      for (const auto& [a, b] : gait.swing.at(feet[f])) {
        double ta = (gait.lead_in + c + a) * cycle, tb = (gait.lead_in + c + b) * cycle;
        // A swing ending exactly where the next cycle's swing starts is one longer swing.
        if (!sw[f].empty() && std::abs(sw[f].back().second - ta) < 1e-9 * total)
          sw[f].back().second = tb;
        else
          sw[f].emplace_back(ta, tb);
      }
    for (const auto& [a, b] : sw[f]) {
      ev.push_back(a);
      ev.push_back(b);
    }
  }
  std::sort(ev.begin(), ev.end());
  PhaseTimeline tl;
  tl.feet = feet;
  const double tol = 1e-9 * std::max(1.0, total);
  for (double e : ev)
    if (tl.events.empty() || e - tl.events.back() > tol) tl.events.push_back(e);
  tl.events.back() = total;
  const int n = tl.num_intervals();
  tl.contact.assign(feet.size(), std::vector<bool>(n, true));
  for (std::size_t f = 0; f < feet.size(); ++f)
    for (int j = 0; j < n; ++j) {
      const double mid = 0.5 * (tl.events[j] + tl.events[j + 1]);
      for (const auto& [a, b] : sw[f])
        if (mid > a && mid < b) tl.contact[f][j] = false;
    }
  return tl;
}

Gait with_rest_lead_in(const Gait& gait, const std::vector<std::string>& feet, int cycles,
                       double duration, double second_lift_off) {
  const PhaseTimeline tl = make_timeline(gait, feet, cycles, duration);
  const double tol = 1e-9 * std::max(1.0, tl.duration());
  std::vector<double> lift_offs;
  for (std::size_t f = 0; f < feet.size(); ++f)
    for (const auto& ph : tl.phases(static_cast<int>(f)))
      if (!ph.contact) lift_offs.push_back(ph.start);
  std::sort(lift_offs.begin(), lift_offs.end());
  lift_offs.erase(std::unique(lift_offs.begin(), lift_offs.end(),
                              [&](double a, double b) { return b - a <= tol; }),
                  lift_offs.end());
  if (lift_offs.size() < 2 || lift_offs[1] >= second_lift_off - tol) return gait;
  // The second lift-off lies a2 cycles after the lead-in; lengthening the lead-in moves every
  // switch by the same number of cycles, so the same lift-off stays second.
  const double units = gait.lead_in + cycles + gait.lead_out;
  const double cycle = tl.duration() / units;
  const double a2 = lift_offs[1] / cycle - gait.lead_in;
  double lead_in;
  if (duration > 0.0) {
    // (L + a2) * duration / (L + cycles + lead_out) = second_lift_off
    if (duration <= second_lift_off) return gait;
    lead_in = (second_lift_off * (cycles + gait.lead_out) - a2 * duration) /
              (duration - second_lift_off);
  } else {
    lead_in = second_lift_off / gait.cycle_duration - a2;
  }
  // A duration barely longer than second_lift_off would pack every cycle into what is left
  // (crawl, 3 cycles in 0.5 s: 7 ms swings instead of 33 ms); such a schedule is not the gait any
  // more, so a lead-in that would shorten the cycle below half of what it was is not applied.
  if (duration > 0.0 && lead_in > gait.lead_in) {
    const double new_cycle = duration / (lead_in + cycles + gait.lead_out);
    if (new_cycle < 0.5 * cycle) return gait;
  }
  Gait out = gait;
  out.lead_in = std::max(gait.lead_in, lead_in);
  return out;
}

std::vector<PhaseTimeline::Phase> PhaseTimeline::phases(int foot) const {
  std::vector<Phase> out;
  for (int j = 0; j < num_intervals(); ++j) {
    const bool c = contact[foot][j];
    if (!out.empty() && out.back().contact == c)
      out.back().end = events[j + 1];
    else
      out.push_back({events[j], events[j + 1], c});
  }
  return out;
}

PhaseTimeline PhaseTimeline::cropped(double t0) const {
  if (!(t0 >= 0.0 && t0 < duration()))
    throw GaitError("start time " + std::to_string(t0) + " s is outside the plan [0, " +
                    std::to_string(duration()) + ")");
  PhaseTimeline out;
  out.feet = feet;
  out.contact.assign(feet.size(), {});
  out.events.push_back(0.0);
  const double tol = 1e-6;
  for (int j = 0; j < num_intervals(); ++j) {
    if (events[j + 1] <= t0 + tol) continue;
    if (out.events.size() == 1) {
      const double begun = t0 - events[j] + (j == 0 ? first_interval_elapsed : 0.0);
      out.first_interval_elapsed = begun > tol ? begun : 0.0;
    }
    if (out.events.size() == 1) {
      // Feet in swing at t0: time since their lift-off (in an earlier interval, or before this
      // timeline began).
      out.swing_elapsed.assign(feet.size(), 0.0);
      for (std::size_t f = 0; f < feet.size(); ++f) {
        if (contact[f][j]) continue;
        int first = j;
        while (first > 0 && !contact[f][first - 1]) --first;
        const double since = t0 - events[first] + (first == 0 ? swing_elapsed_of(f) : 0.0);
        out.swing_elapsed[f] = since > tol ? since : 0.0;
      }
    }
    out.events.push_back(events[j + 1] - t0);
    for (std::size_t f = 0; f < feet.size(); ++f) out.contact[f].push_back(contact[f][j]);
  }
  return out;
}

}  // namespace terrastride::planner
