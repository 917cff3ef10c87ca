#include "terrastride/planner/reachability.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>

#include "terrastride/planner/foothold_planarity.hpp"
#include "terrastride/planner/piece_math.hpp"

namespace terrastride::planner {

namespace {

using Interval = std::pair<double, double>;

std::string fmt(const char* format, double a) {
  char buf[64];
  std::snprintf(buf, sizeof buf, format, a);
  return buf;
}
std::string range(double a, double b) {
  return fmt("%.2f", a) + ".." + fmt("%.2f", b);
}

// Sorted, overlapping intervals merged.
std::vector<Interval> merged(std::vector<Interval> v) {
  std::sort(v.begin(), v.end());
  std::vector<Interval> out;
  for (const auto& iv : v)
    if (!out.empty() && iv.first <= out.back().second)
      out.back().second = std::max(out.back().second, iv.second);
    else
      out.push_back(iv);
  return out;
}

std::vector<Interval> intersected(const std::vector<Interval>& a, const std::vector<Interval>& b) {
  std::vector<Interval> out;
  for (const auto& p : a)
    for (const auto& q : b) {
      const double lo = std::max(p.first, q.first), hi = std::min(p.second, q.second);
      if (lo <= hi) out.push_back({lo, hi});
    }
  return merged(out);
}

std::string heights_text(const std::vector<Interval>& v) {
  std::string s;
  for (const auto& iv : v) s += (s.empty() ? "" : ", ") + range(iv.first, iv.second);
  return s + " m";
}

}  // namespace

StanceReach reach_stance(const robot::RobotModel& robot, const terrain::HeightField& terrain,
                         const RestingStance& stance) {
  StanceReach out;
  const Eigen::Matrix3d R = rotation_zyx<double>(stance.euler_zyx);
  // A foothold p and base height z fit the box when |R^T (p - (x, y, z)) - nominal| <= b per
  // axis; with a = R^T (p - (x, y, 0)) - nominal and c = R^T e_z that is |a - z c| <= b, an
  // interval of z per axis.
  const Eigen::Vector3d c = R.transpose().col(2);
  const double step = stance.grid_step;
  const Eigen::Vector3d base0(stance.base_xy.x(), stance.base_xy.y(), 0.0);
  auto base_heights_for = [&](const Eigen::Vector3d& p, const Eigen::Vector3d& nominal,
                              const Eigen::Vector3d& box, Interval* z) {
    const Eigen::Vector3d a = R.transpose() * (p - base0) - nominal;
    *z = {stance.base_z_min, stance.base_z_max};
    for (int i = 0; i < 3; ++i) {
      if (std::abs(c[i]) < 1e-12) {
        if (std::abs(a[i]) > box[i]) return false;
        continue;
      }
      const double t1 = (a[i] - box[i]) / c[i], t2 = (a[i] + box[i]) / c[i];
      z->first = std::max(z->first, std::min(t1, t2));
      z->second = std::min(z->second, std::max(t1, t2));
    }
    return z->first <= z->second;
  };
  const bool need_planar = stance.planarity_tolerance > 0.0 && stance.planarity_probe > 0.0;
  std::vector<Interval> common{{stance.base_z_min, stance.base_z_max}};
  for (const auto& foot : stance.feet) {
    const auto& leg = robot.legs.at(foot.leg);
    FootReach fr;
    fr.name = leg.name;
    // Sampling on a grid could step over a foothold the solver finds between two grid points:
    // the box is inflated by a grid step, so that the nearest sample (at most 0.71 steps away in
    // xy, and as much times the slope in height) still fits wherever that foothold fits. The
    // solver's own slack adds to that.
    const Eigen::Vector3d box =
        leg.range_of_motion + Eigen::Vector3d::Constant(step + stance.violation_slack);
    // The box's world xy extent (its height is free with the base height); reported uninflated.
    fr.box_min = Eigen::Vector2d::Constant(1e300);
    fr.box_max = Eigen::Vector2d::Constant(-1e300);
    for (int k = 0; k < 8; ++k) {
      const Eigen::Vector3d s((k & 1) ? 1 : -1, (k & 2) ? 1 : -1, (k & 4) ? 1 : -1);
      const Eigen::Vector2d corner =
          stance.base_xy + (R * (leg.nominal_foot + s.cwiseProduct(leg.range_of_motion))).head<2>();
      fr.box_min = fr.box_min.cwiseMin(corner);
      fr.box_max = fr.box_max.cwiseMax(corner);
    }
    std::vector<Interval> heights;
    fr.terrain_min = 1e300;
    fr.terrain_max = -1e300;
    auto consider = [&](const Eigen::Vector3d& p, bool check_planar) {
      Interval z;
      if (!base_heights_for(p, leg.nominal_foot, box, &z)) return;
      ++fr.in_box;
      fr.terrain_min = std::min(fr.terrain_min, p.z());
      fr.terrain_max = std::max(fr.terrain_max, p.z());
      if (check_planar && foothold_planarity_error(terrain, p.x(), p.y(), stance.planarity_probe) >
                              stance.planarity_tolerance + stance.violation_slack)
        return;
      ++fr.planar;
      heights.push_back(z);
    };
    if (foot.fixed_position) {
      consider(*foot.fixed_position, false);  // a fixed foothold has no planarity constraint
    } else {
      const Eigen::Vector2d lo = fr.box_min - Eigen::Vector2d::Constant(step),
                            hi = fr.box_max + Eigen::Vector2d::Constant(step);
      const int nx = static_cast<int>(std::ceil((hi.x() - lo.x()) / step)),
                ny = static_cast<int>(std::ceil((hi.y() - lo.y()) / step));
      for (int i = 0; i <= nx; ++i)
        for (int j = 0; j <= ny; ++j) {
          const double x = lo.x() + i * step, y = lo.y() + j * step;
          consider(Eigen::Vector3d(x, y, terrain.height(x, y)), need_planar);
        }
    }
    fr.base_heights = merged(heights);
    common = intersected(common, fr.base_heights);
    out.feet.push_back(std::move(fr));
  }
  if (!common.empty()) return out;

  out.reachable = false;
  const std::string planar_text = need_planar
                                      ? fmt("planar within %.3f m", stance.planarity_tolerance) +
                                            fmt(" over %.2f m", stance.planarity_probe)
                                      : std::string("on the terrain");
  for (const auto& fr : out.feet) {
    if (!fr.base_heights.empty()) continue;
    std::string why = "foot " + fr.name + " can reach no " +
                      (need_planar ? std::string("planar ground") : std::string("ground")) +
                      ": its range-of-motion box spans x " + range(fr.box_min.x(), fr.box_max.x()) +
                      ", y " + range(fr.box_min.y(), fr.box_max.y());
    if (fr.in_box == 0) {
      why += ", and no terrain point in it is within the box's height range";
    } else {
      why += "; none of the " + std::to_string(fr.in_box) + " points sampled there every " +
             fmt("%.0f cm", 100 * step) + " is " + planar_text;
      if (fr.terrain_max - fr.terrain_min > stance.planarity_tolerance)
        why += fmt("; the terrain heights there span %.2f m", fr.terrain_max - fr.terrain_min) +
               " (" + range(fr.terrain_min, fr.terrain_max) + " m)";
    }
    out.reason = why;
    return out;
  }
  // Every foot alone can stand, but not at one base height: list the heights each one needs.
  out.reason = "no base height lets every foot stand on reachable ground " + planar_text + ": ";
  for (std::size_t i = 0; i < out.feet.size(); ++i)
    out.reason += (i == 0 ? "foot " + out.feet[i].name + " needs the base at z "
                          : ", " + out.feet[i].name + " at z ") +
                  heights_text(out.feet[i].base_heights);
  return out;
}

std::optional<RestingStance> end_stance(const SrbdProblem& problem) {
  const Layout& L = problem.layout();
  const auto& lb = problem.lower();
  const auto& ub = problem.upper();
  const int S = L.num_segments, g = L.base[S];
  // x, y, yaw, pitch, roll of the last knot: the check needs them all fixed.
  for (int i : {g + 0, g + 1, g + 6, g + 7, g + 8})
    if (lb[i] != ub[i]) return std::nullopt;
  RestingStance st;
  st.base_xy = Eigen::Vector2d(lb[g], lb[g + 1]);
  st.euler_zyx = Eigen::Vector3d(lb[g + 6], lb[g + 7], lb[g + 8]);
  st.base_z_min = lb[g + 2] <= -kInf ? -std::numeric_limits<double>::infinity() : lb[g + 2];
  st.base_z_max = ub[g + 2] >= kInf ? std::numeric_limits<double>::infinity() : ub[g + 2];
  const auto& o = problem.options();
  st.planarity_tolerance = o.foothold_planarity;
  st.planarity_probe = o.clearance_probe;
  for (const auto& stance : L.stances) {
    if (stance.last_seg != S - 1) continue;  // ended before the goal
    StanceFoot f;
    f.leg = stance.foot;
    if (stance.fixed)
      f.fixed_position =
          Eigen::Vector3d(lb[stance.pos_var], lb[stance.pos_var + 1], lb[stance.pos_var + 2]);
    st.feet.push_back(f);
  }
  return st;
}

namespace {

// Where the base's orientation at a pose comes from, for messages: the terrain heights under the
// nominal feet (with the base's yaw only), which the goal's pitch and roll follow (initialization/base_guess.cpp).
std::string nominal_terrain_text(const robot::RobotModel& robot,
                                 const terrain::HeightField& terrain, const Eigen::Vector2d& xy,
                                 double yaw) {
  std::string s;
  for (const auto& leg : robot.legs) {
    const Eigen::Vector3d p =
        robot::nominal_foot_world(leg, Eigen::Vector3d(xy.x(), xy.y(), 0.0), yaw);
    s += (s.empty() ? "" : ", ") + leg.name + " " + fmt("%.2f", terrain.height(p.x(), p.y()));
  }
  return s + " m";
}

std::string pose_text(const Eigen::Vector2d& xy, double yaw) {
  return "(x " + fmt("%.2f", xy.x()) + ", y " + fmt("%.2f", xy.y()) + ", yaw " + fmt("%.2f", yaw) +
         ")";
}

}  // namespace

void require_reachable(const SrbdProblem& problem) {
  const robot::RobotModel& robot = problem.robot();
  const Layout& L = problem.layout();
  const auto& lb = problem.lower();
  // Start: base pose and every foot are fixed at the first knot, so each range-of-motion row
  // there is a constant. Only a violation beyond what Ipopt may still call "acceptable" is
  // rejected.
  constexpr double kStartSlack = kAcceptableViolation;
  // A measured start (a re-plan's) is what the robot is in, not a request: its excess is reported
  // and the rows after it give room back to the box (SrbdProblem::add_piece, start_return.hpp).
  if (problem.starts_at_rest()) {
    const int b = L.base[0];
    const Eigen::Vector3d r(lb[b], lb[b + 1], lb[b + 2]), e(lb[b + 6], lb[b + 7], lb[b + 8]);
    const Eigen::Matrix3d R = rotation_zyx<double>(e);
    for (std::size_t f = 0; f < robot.legs.size(); ++f) {
      const int pv = L.foot_pos[f][0];
      const Eigen::Vector3d p(lb[pv], lb[pv + 1], lb[pv + 2]);
      const auto& leg = robot.legs[f];
      const Eigen::Vector3d off = R.transpose() * (p - r) - leg.nominal_foot;
      for (int i = 0; i < 3; ++i) {
        const double excess = std::abs(off[i]) - leg.range_of_motion[i];
        if (excess <= kStartSlack) continue;
        static const char* axis = "xyz";
        throw UnreachableRequest(
            "at the start " + pose_text(r.head<2>(), e[0]) + " foot " + leg.name + " stands " +
            fmt("%.2f m", excess) + " outside its range-of-motion box along the base's " +
            std::string(1, axis[i]) + " axis (terrain under the nominal feet: " +
            nominal_terrain_text(robot, problem.terrain(), r.head<2>(), e[0]) +
            "); start where the terrain under the feet is level within " +
            fmt("%.2f m", leg.range_of_motion.z()) + " of their mean");
      }
    }
  }
  const auto stance = end_stance(problem);
  if (!stance) return;
  const StanceReach reach = reach_stance(robot, problem.terrain(), *stance);
  if (reach.reachable) return;
  const double deg = 180.0 / M_PI;
  throw UnreachableRequest(
      "at the goal " + pose_text(stance->base_xy, stance->euler_zyx[0]) + " " + reach.reason +
      " (base pitch " + fmt("%.1f", stance->euler_zyx[1] * deg) + " deg, roll " +
      fmt("%.1f", stance->euler_zyx[2] * deg) +
      " deg, fitted to the terrain under the nominal feet: " +
      nominal_terrain_text(robot, problem.terrain(), stance->base_xy, stance->euler_zyx[0]) +
      "); move the goal so that every foot's box covers planar ground at compatible heights");
}

}  // namespace terrastride::planner
