// A solution as a Trajectory: the continuous-time solution sampled every dt, with each foot's
// phases and the contact timeline (which a re-plan reads back, timeline_of).
#include <algorithm>
#include <cmath>

#include "terrastride/planner/piece_math.hpp"
#include "terrastride/planner/planner.hpp"

namespace terrastride::planner {

namespace {

nlohmann::json timeline_json(const PhaseTimeline& tl, const std::vector<double>& events) {
  nlohmann::json c = nlohmann::json::array();
  for (const auto& foot : tl.contact) c.push_back(foot);
  nlohmann::json j = {{"events", events}, {"contact", c}};
  // Scaled like the first interval when the timing was optimised.
  if (tl.first_interval_elapsed > 0.0 && tl.num_intervals() > 0)
    j["first_interval_elapsed"] =
        tl.first_interval_elapsed * (events[1] - events[0]) / (tl.events[1] - tl.events[0]);
  bool swinging = false;
  for (double e : tl.swing_elapsed) swinging |= e > 0.0;
  if (swinging) j["swing_elapsed"] = tl.swing_elapsed;  // nominal times, as the clearance uses
  return j;
}

}  // namespace

Trajectory sample_solution(const SrbdProblem& problem, const std::vector<double>& x, double dt) {
  Trajectory tr;
  const auto& robot = problem.robot();
  tr.robot = robot.name;
  tr.robot_definition = robot.definition;
  tr.gait = problem.options().gait;
  tr.duration = problem.duration(x);
  tr.sample_dt = dt;
  for (const auto& leg : robot.legs) tr.feet.push_back(leg.name);
  const int n = static_cast<int>(std::floor(tr.duration / dt + 1e-9));
  for (int i = 0; i <= n + 1; ++i) {
    double t = std::min(i * dt, tr.duration);
    if (i == n + 1 && tr.duration - n * dt < 1e-9) break;
    const auto st = problem.evaluate(x, t);
    TrajectorySample s;
    s.t = t;
    s.base.position = st.pos;
    s.base.euler_zyx = st.euler;
    s.base.linear_velocity = st.vel;
    s.base.linear_acceleration = st.acc;
    euler_to_angular<double>(st.euler, st.euler_rate, st.euler_acc, &s.base.angular_velocity,
                             &s.base.angular_acceleration);
    for (std::size_t f = 0; f < st.foot_pos.size(); ++f) {
      FootState fs;
      fs.position = st.foot_pos[f];
      fs.velocity = st.foot_vel[f];
      fs.force = st.force[f];
      fs.contact = st.contact[f];
      s.feet.push_back(fs);
    }
    tr.samples.push_back(std::move(s));
  }
  // Phases per foot, at the solution's (possibly optimised) event times.
  const auto ev = problem.event_times(x);
  const auto& tl = problem.timeline();
  nlohmann::json phases = nlohmann::json::object();
  for (std::size_t f = 0; f < tl.feet.size(); ++f) {
    nlohmann::json list = nlohmann::json::array();
    for (int j = 0; j < tl.num_intervals(); ++j) {
      const bool c = tl.contact[f][j];
      if (!list.empty() && list.back()["contact"].get<bool>() == c)
        list.back()["end"] = ev[j + 1];
      else
        list.push_back({{"start", ev[j]}, {"end", ev[j + 1]}, {"contact", c}});
    }
    phases[tl.feet[f]] = list;
  }
  tr.extra["phases"] = phases;
  tr.extra["timeline"] = timeline_json(tl, ev);
  return tr;
}
}  // namespace terrastride::planner
