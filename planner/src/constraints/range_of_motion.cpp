// "range_of_motion" (baseline; TOWR's kinematic model): each foot within the box +-range_of_motion
// around its nominal position, in the base frame, at `rom_points` points of each segment (twice as
// many for a swinging foot, which moves fast). Rows in m.
#include <algorithm>
#include <vector>

#include "spline_variables.hpp"
#include "start_return.hpp"
#include "terrastride/planner/feasibility.hpp"
#include "terrastride/planner/constraints.hpp"
#include "terrastride/planner/nlp.hpp"

namespace terrastride::planner {

void add_range_of_motion(SrbdProblem& problem, int s) {
  const Layout& L = problem.layout();
  const robot::RobotModel& robot = problem.robot();
  const ProblemOptions& options = problem.options();
  const int S = L.num_segments;
  const int nf = static_cast<int>(robot.legs.size());
  const double frac = L.seg_fraction[s];
  // A measured start outside a foot's box (after a push): its excess as room at the points
  // after it (start_return.hpp); knot 0's rows keep the box (a violated one is a constant, left
  // out by add_piece). Likewise a session step's pinned end outside it, as room at the points
  // before it. Segments more than 2 s (the longest span the start_return setting accepts) from a
  // measured start or a pinned end get none, so they skip reading the settings.
  const double t_end = L.nominal_knot_time[S];
  const bool near_start = !problem.starts_at_rest() && L.nominal_knot_time[s] <= 2.0;
  const bool near_end = !problem.ends_at_rest() && t_end - L.nominal_knot_time[s + 1] <= 2.0;
  const double span = near_start || near_end
                          ? feasibility_options(robot, options.feasibility_settings).start_return
                          : 0.0;
  // The base's largest deceleration a start can count on: friction * g with its weight on its
  // feet (start_return.hpp, unavoidable_excess).
  const double decel = options.friction * kGravity;
  for (int f = 0; f < nf; ++f) {
    const Eigen::Vector3d nom = robot.legs[f].nominal_foot, box = robot.legs[f].range_of_motion;
    // Below / above the box at the start (s) and at the end (e).
    Eigen::Vector3d below_s = Eigen::Vector3d::Zero(), above_s = below_s, below_e = below_s,
                    above_e = below_s;
    // The foot's offset from its nominal position in the base frame, and how far it lies below /
    // above the box.
    auto offset_of = [&](const MeasuredFootPose& m) -> Eigen::Vector3d {
      return rotation_zyx<double>(m.euler).transpose() * (m.foot - m.base) - nom;
    };
    auto excess = [&](const Eigen::Vector3d& off, Eigen::Vector3d* below, Eigen::Vector3d* above) {
      *below = (-box - off).cwiseMax(0.0);
      *above = (off - box).cwiseMax(0.0);
    };
    MeasuredFootPose m;
    // A stance foot's offset at the start and its rate there (a start moving out of the box).
    Eigen::Vector3d off0 = Eigen::Vector3d::Zero(), rate0 = Eigen::Vector3d::Zero();
    bool moving = false;
    if (span > 0.0 && measured_foot_pose(problem, f, &m)) {
      off0 = offset_of(m);
      excess(off0, &below_s, &above_s);
      moving = measured_stance_offset_rate(problem, f, m, &rate0);
    }
    if (span > 0.0 && pinned_end_foot_pose(problem, f, &m))
      excess(offset_of(m), &below_e, &above_e);
    const int nr = std::max(1, options.rom_points) * (L.contact[f][s] ? 1 : 2);
    // The segment's end only in the last segment: the next segment's start covers it.
    for (const double sigma : L.segment_points(s, nr, s == S - 1)) {
      LocalVars lv;
      const HermiteLocal rp = add_base_position(lv, L, s, sigma, true);
      const HermiteLocal ep = add_base_euler(lv, L, s, sigma, true);
      const HermiteLocal fpl = add_foot_position(lv, L, f, s, sigma, true);
      const int dur = rp.needs_duration || ep.needs_duration || fpl.needs_duration
                          ? add_segment_duration(lv, L, s)
                          : -1;
      const double t = nominal_point_time(L, s, sigma);
      const double w = t > 0.0 ? start_return_weight(t, span) : 0.0;
      const double we = end_return_weight(t, t_end, span);
      std::vector<double> lo(3), hi(3);
      Eigen::Vector3d below = below_s, above = above_s;  // the start's, at t
      if (moving && w > 0.0)
        for (int i = 0; i < 3; ++i) {
          above[i] = unavoidable_excess(off0[i], rate0[i], box[i], t, decel);
          below[i] = unavoidable_excess(-off0[i], -rate0[i], box[i], t, decel);
        }
      for (int i = 0; i < 3; ++i) {
        lo[i] = -box[i] - std::max(below[i] * w, below_e[i] * we);
        hi[i] = box[i] + std::max(above[i] * w, above_e[i] * we);
      }
      problem.add_piece(make_piece("range_of_motion", lv, lo, hi, [=](const auto* x, auto* g) {
        using T = std::decay_t<decltype(*g)>;
        const T h = dur >= 0 ? T(x[dur] * frac) : T(1.0);
        Vec3<T> r, e, p;
        hermite<T>(sigma, h, x, rp, &r, nullptr, nullptr);
        hermite<T>(sigma, h, x, ep, &e, nullptr, nullptr);
        hermite<T>(sigma, h, x, fpl, &p, nullptr, nullptr);
        const Vec3<T> pb_ = rotation_zyx<T>(e).transpose() * (p - r);
        for (int i = 0; i < 3; ++i) g[i] = pb_[i] - nom[i];
      }));
    }
  }
}

}  // namespace terrastride::planner
