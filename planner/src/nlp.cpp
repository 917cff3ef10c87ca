#include "terrastride/planner/nlp.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <mutex>
#include <Eigen/Cholesky>
#include <stdexcept>

#include "terrastride/planner/feasibility.hpp"
#include "terrastride/planner/foothold_planarity.hpp"
#include "terrastride/planner/piece_math.hpp"
#include "terrastride/planner/trajectory.hpp"

namespace terrastride::planner {

namespace {

std::map<std::string, ConstraintSetBuilder>& registry() {
  // The feasibility sets (feasibility.hpp) are there from the start: no static initialisers.
  static std::map<std::string, ConstraintSetBuilder> r = builtin_constraint_sets();
  return r;
}
std::mutex& registry_mutex() {
  static std::mutex m;
  return m;
}

// Swing-clearance profile: the fraction of h_min demanded at time t into a swing of duration T.
// 0 at lift-off and touch-down (the foot must be allowed to leave and reach the ground), 1 from
// `ramp` after lift-off to `ramp` before touch-down, sin^2 in between so that the lower bound it
// puts on the foot height has a bounded second derivative.
double clearance_profile(double t, double T, double ramp) {
  const double edge = std::min(t, T - t);
  const double tau = std::min(ramp, 0.5 * T);
  if (!(tau > 0.0)) return edge > 0.0 ? 1.0 : 0.0;
  const double s = std::sin(0.5 * M_PI * std::clamp(edge / tau, 0.0, 1.0));
  return s * s;
}

}  // namespace

void register_constraint_set(const std::string& name, ConstraintSetBuilder builder) {
  std::lock_guard<std::mutex> lock(registry_mutex());
  registry()[name] = std::move(builder);
}

std::vector<std::string> constraint_set_names() {
  std::lock_guard<std::mutex> lock(registry_mutex());
  std::vector<std::string> names{"baseline"};
  for (const auto& [k, v] : registry())
    if (k != "baseline") names.push_back(k);
  names.push_back("all");  // kAllFeasibilitySets, expanded in the SrbdProblem constructor
  return names;
}

SrbdProblem::~SrbdProblem() = default;

SrbdProblem::SrbdProblem(const robot::RobotModel& robot, const terrain::HeightField& terrain,
                         const PhaseTimeline& timeline, const ProblemOptions& options,
                         const StartState* start_state)
    : robot_(robot), terrain_(terrain), timeline_(timeline), options_(options) {
  if (timeline_.feet.size() != robot_.legs.size())
    throw std::invalid_argument("timeline has " + std::to_string(timeline_.feet.size()) +
                                " feet, robot " + robot_.name + " has " +
                                std::to_string(robot_.legs.size()) + " legs");
  if (timeline_.num_intervals() < 1) throw std::invalid_argument("empty phase timeline");
  if (!(options_.segment_dt > 0.0)) throw std::invalid_argument("segment_dt must be > 0");
  layout_ = make_layout(static_cast<int>(robot_.legs.size()), timeline_, options_, &variables_);
  build_initial_guess(start_state);
  build_baseline();
  std::vector<std::string> sets;  // "all" expanded, implied sets added, each set once
  for (const auto& name : options_.constraints)
    if (name == "all")
      sets.insert(sets.end(), std::begin(kAllFeasibilitySets), std::end(kAllFeasibilitySets));
    else
      sets.push_back(name);
  for (const auto& [set, implied] : kImpliedFeasibilitySets)
    if (std::find(sets.begin(), sets.end(), set) != sets.end()) sets.push_back(implied);
  for (std::size_t i = 0; i < sets.size(); ++i) {
    const std::string& name = sets[i];
    if (name == "baseline" || std::find(sets.begin(), sets.begin() + i, name) != sets.begin() + i)
      continue;
    ConstraintSetBuilder b;
    {
      std::lock_guard<std::mutex> lock(registry_mutex());
      auto it = registry().find(name);
      if (it != registry().end()) b = it->second;
    }
    if (!b) {
      std::string names;
      for (const auto& n : constraint_set_names()) names += (names.empty() ? "" : ", ") + n;
      throw std::invalid_argument("constraint set '" + name + "' is not available (available: " +
                                  names + ")");
    }
    b(*this);
  }
}

int SrbdProblem::num_free_variables() const {
  int n = 0;
  for (std::size_t i = 0; i < variables_.lower.size(); ++i)
    n += variables_.lower[i] < variables_.upper[i];
  return n;
}

void SrbdProblem::add_piece(std::unique_ptr<Piece> piece) {
  row_offset_.push_back(num_rows_);
  nz_offset_.push_back(nnz_);
  num_rows_ += piece->rows();
  nnz_ += piece->rows() * static_cast<int>(piece->vars.size());
  pieces_.push_back(std::move(piece));
}

// ---------------------------------------------------------------------------------------------
// Initial guess

void SrbdProblem::build_initial_guess(const StartState* start) {
  Layout& L = layout_;
  const int S = L.num_segments;
  const int nf = static_cast<int>(robot_.legs.size());
  const double T = timeline_.duration();
  variables_.initial.assign(variables_.lower.size(), 0.0);
  for (std::size_t j = 0; j < L.interval_var.size(); ++j)
    variables_.initial[L.interval_var[j]] = L.interval_nominal[j];

  // Start and goal poses. The base height follows the terrain under the nominal feet.
  auto base_height = [&](double x, double y, double yaw) {
    double h = 0.0;
    for (const auto& leg : robot_.legs) {
      const Eigen::Vector3d p = nominal_foot_world(leg, Eigen::Vector3d(x, y, 0.0), yaw);
      h += terrain_.height(p.x(), p.y());
    }
    return h / nf + robot_.nominal_base_height;
  };
  Eigen::Vector3d p_start, e_start(options_.start.z(), 0.0, 0.0), v_start = Eigen::Vector3d::Zero(),
      r_start = Eigen::Vector3d::Zero();
  if (start) {
    p_start = start->position;
    e_start = start->euler_zyx;
    v_start = start->linear_velocity;
    r_start = start->euler_rates;
  } else {
    p_start = Eigen::Vector3d(options_.start.x(), options_.start.y(),
                              base_height(options_.start.x(), options_.start.y(), e_start[0]));
  }
  Eigen::Vector3d goal_xyyaw = options_.has_goal ? options_.goal
                                                 : Eigen::Vector3d(p_start.x(), p_start.y(), e_start[0]);
  // Degrees of freedom the robot cannot move stay at their start value.
  if (!robot_.base_dof_free[0]) goal_xyyaw.x() = p_start.x();
  if (!robot_.base_dof_free[1]) goal_xyyaw.y() = p_start.y();
  if (!robot_.base_dof_free[3]) goal_xyyaw.z() = e_start[0];
  const Eigen::Vector3d p_goal(goal_xyyaw.x(), goal_xyyaw.y(),
                               base_height(goal_xyyaw.x(), goal_xyyaw.y(), goal_xyyaw.z()));
  // The goal's pitch and roll follow the plane fitted (least squares, in the yawed base frame)
  // through the terrain heights under the nominal feet. With the goal on a slope or a staircase a
  // level base cannot rest there: on the stairs scenario the front feet stand 0.24 m above the
  // hind feet at the goal, more than the range-of-motion box's 2 x 0.10 m allows at zero pitch.
  auto terrain_tilt = [&](double x, double y, double yaw) {
    double sxx = 0, sxh = 0, syy = 0, syh = 0, sx = 0, sy = 0, sh = 0;
    std::vector<double> heights;
    for (const auto& leg : robot_.legs) {
      const Eigen::Vector3d p = nominal_foot_world(leg, Eigen::Vector3d(x, y, 0.0), yaw);
      heights.push_back(terrain_.height(p.x(), p.y()));
      sx += leg.nominal_foot.x();
      sy += leg.nominal_foot.y();
      sh += heights.back();
    }
    const double mx = sx / nf, my = sy / nf, mh = sh / nf;
    for (int f = 0; f < nf; ++f) {
      const auto& leg = robot_.legs[f];
      const double h = heights[f] - mh;
      const double dx = leg.nominal_foot.x() - mx, dy = leg.nominal_foot.y() - my;
      sxx += dx * dx;
      sxh += dx * h;
      syy += dy * dy;
      syh += dy * h;
    }
    // R = Rz(yaw) Ry(pitch) Rx(roll): a positive pitch lowers the nose, a positive roll lifts
    // the left side.
    const double pitch = sxx > 1e-9 ? -std::atan(sxh / sxx) : 0.0;
    const double roll = syy > 1e-9 ? std::atan(syh / syy) : 0.0;
    return Eigen::Vector2d(pitch, roll);
  };
  const Eigen::Vector2d tilt_goal = terrain_tilt(goal_xyyaw.x(), goal_xyyaw.y(), goal_xyyaw.z());
  const Eigen::Vector3d e_goal(goal_xyyaw.z(), tilt_goal.x(), tilt_goal.y());

  // Progress from start to goal follows a minimum-jerk profile, s(u) = 10u^3 - 15u^4 + 6u^5, so
  // the guess leaves and reaches rest smoothly. (A linear ramp between resting end knots put
  // spikes of up to 8 m g into the first and last segments' accelerations.)
  auto progress = [T](double t, double* rate) {
    const double u = std::clamp(t / T, 0.0, 1.0), u2 = u * u;
    if (rate) *rate = 30.0 * u2 * (1.0 - u) * (1.0 - u) / T;
    return u2 * u * (10.0 - 15.0 * u + 6.0 * u2);
  };
  // The base height follows the terrain under the nominal feet, averaged over a window around t
  // (triangular weights): a foot crossing a step edge then lifts the guess gradually instead of
  // by a step between two knots.
  constexpr double kHeightWindow = 0.4;  // s, half width
  auto smoothed_height = [&](double t) {
    double sum = 0.0, weight = 0.0;
    constexpr int kSamples = 8;
    for (int i = -kSamples; i <= kSamples; ++i) {
      const double ti = std::clamp(t + kHeightWindow * i / kSamples, 0.0, T);
      const double w = 1.0 - std::abs(static_cast<double>(i)) / (kSamples + 1);
      const double u = progress(ti, nullptr);
      const Eigen::Vector3d p = (1 - u) * p_start + u * p_goal;
      sum += w * base_height(p.x(), p.y(), (1 - u) * e_start[0] + u * e_goal[0]);
      weight += w;
    }
    return sum / weight;
  };
  for (int k = 0; k <= S; ++k) {
    const double t = L.nominal_knot_time[k];
    double rate = 0.0;
    const double u = progress(t, &rate);
    const int b = L.base[k];
    const Eigen::Vector3d p = (1 - u) * p_start + u * p_goal;
    const Eigen::Vector3d e = (1 - u) * e_start + u * e_goal;
    const bool inner = k > 0 && k < S;
    constexpr double kDt = 1e-3;
    const double zb = k == 0 ? p_start.z() : smoothed_height(t);
    const double zd = inner ? (smoothed_height(t + kDt) - smoothed_height(t - kDt)) / (2 * kDt) : 0.0;
    for (int d = 0; d < 3; ++d) {
      variables_.initial[b + d] = d == 2 ? zb : p[d];
      variables_.initial[b + 3 + d] = d == 2 ? zd : rate * (p_goal[d] - p_start[d]);
      variables_.initial[b + 6 + d] = e[d];
      variables_.initial[b + 9 + d] = rate * (e_goal[d] - e_start[d]);
    }
  }
  // Start state and goal as bounds; fixed degrees of freedom held at their start value.
  auto fix = [&](int i, double v) {
    variables_.lower[i] = variables_.upper[i] = variables_.initial[i] = v;
  };
  {
    const int b = L.base[0];
    for (int d = 0; d < 3; ++d) {
      fix(b + d, p_start[d]);
      fix(b + 3 + d, v_start[d]);
      fix(b + 6 + d, e_start[d]);
      fix(b + 9 + d, r_start[d]);
    }
    const int g = L.base[S];
    if (options_.has_goal) {
      fix(g + 0, p_goal.x());
      fix(g + 1, p_goal.y());
      fix(g + 6, e_goal[0]);
    }
    fix(g + 7, e_goal[1]);
    fix(g + 8, e_goal[2]);
    for (int d = 0; d < 3; ++d) {
      fix(g + 3 + d, 0.0);
      fix(g + 9 + d, 0.0);
    }
  }
  for (int k = 0; k <= S; ++k) {
    const int b = L.base[k];
    for (int d = 0; d < 3; ++d) {
      if (!robot_.base_dof_free[d]) {
        fix(b + d, p_start[d]);
        fix(b + 3 + d, 0.0);
      }
      // euler order yaw, pitch, roll = dof 3, 4, 5
      if (!robot_.base_dof_free[3 + d]) {
        fix(b + 6 + d, e_start[d]);
        fix(b + 9 + d, 0.0);
      }
    }
  }

  // Footholds: nominal positions under the base at the middle of each stance, on the terrain.
  auto base_at = [&](double t, Eigen::Vector3d* pos, double* yaw) {
    int k = 0;
    while (k < S && L.nominal_knot_time[k + 1] < t) ++k;
    const int k1 = std::min(k + 1, S);
    const double t0 = L.nominal_knot_time[k], t1 = L.nominal_knot_time[k1];
    const double u = t1 > t0 ? std::clamp((t - t0) / (t1 - t0), 0.0, 1.0) : 0.0;
    *pos =
        (1 - u) * Eigen::Vector3d(variables_.initial[L.base[k]], variables_.initial[L.base[k] + 1],
                                  variables_.initial[L.base[k] + 2]) +
        u * Eigen::Vector3d(variables_.initial[L.base[k1]], variables_.initial[L.base[k1] + 1],
                            variables_.initial[L.base[k1] + 2]);
    *yaw = (1 - u) * variables_.initial[L.base[k] + 6] + u * variables_.initial[L.base[k1] + 6];
  };
  for (const auto& st : L.stances) {
    Eigen::Vector3d p;
    if (st.fixed) {
      if (start) {
        p = start->foot_position[st.foot];
      } else {
        p = nominal_foot_world(robot_.legs[st.foot], p_start, e_start[0]);
        p.z() = terrain_.height(p.x(), p.y());
      }
      for (int d = 0; d < 3; ++d) fix(st.pos_var + d, p[d]);
    } else {
      const double tm = 0.5 * (L.nominal_knot_time[st.first_seg] + L.nominal_knot_time[st.last_seg + 1]);
      Eigen::Vector3d b;
      double yaw;
      base_at(tm, &b, &yaw);
      p = nominal_foot_world(robot_.legs[st.foot], b, yaw);
      // Start from the nearest locally planar spot (see the foothold_planarity constraint), so
      // the solver does not begin with feet on step edges, and one at a height the leg can reach
      // from the guessed base (within 1.5 times the range-of-motion box's half-height of the
      // nominal foot height): a planar trench floor 0.30 m down under the nominal foot is no
      // foothold (gap scene, 1 m goal: the hind feet started there and the solve ended infeasible).
      const double probe = options_.clearance_probe, tol = 0.5 * options_.foothold_planarity;
      const auto& leg = robot_.legs[st.foot];
      auto usable = [&](double x, double y) {
        if (foothold_planarity_error(terrain_, x, y, probe) > tol) return false;
        const double below_base = terrain_.height(x, y) - b.z() - leg.nominal_foot.z();
        return std::abs(below_base) <= 1.5 * leg.range_of_motion.z();
      };
      if (probe > 0.0 && tol > 0.0 && !usable(p.x(), p.y())) {
        bool found = false;
        for (int r = 1; r <= 20 && !found; ++r)
          for (const auto& dir : {Eigen::Vector2d(1, 0), Eigen::Vector2d(-1, 0),
                                  Eigen::Vector2d(0, 1), Eigen::Vector2d(0, -1)}) {
            const Eigen::Vector2d q = p.head<2>() + 0.01 * r * dir;
            if (usable(q.x(), q.y())) {
              p.head<2>() = q;
              found = true;
              break;
            }
          }
      }
      p.z() = terrain_.height(p.x(), p.y());
      for (int d = 0; d < 3; ++d) variables_.initial[st.pos_var + d] = p[d];
    }
  }
  // Swing knots: straight line between the footholds, lifted by the clearance.
  for (const auto& sw : L.swings) {
    const int f = sw.foot;
    const int k0 = sw.first_seg, k1 = sw.last_seg + 1;
    Eigen::Vector3d pa, pb;
    const bool start_in_swing = L.foot_vel[f][k0] >= 0;  // knot 0 in swing
    if (start_in_swing) {
      pa = start ? start->foot_position[f]
                 : nominal_foot_world(robot_.legs[f], p_start, e_start[0]);
      if (!start) pa.z() = terrain_.height(pa.x(), pa.y());
    } else {
      pa = Eigen::Vector3d(variables_.initial[L.foot_pos[f][k0]],
                           variables_.initial[L.foot_pos[f][k0] + 1],
                           variables_.initial[L.foot_pos[f][k0] + 2]);
    }
    if (L.foot_vel[f][k1] < 0) {
      pb = Eigen::Vector3d(variables_.initial[L.foot_pos[f][k1]],
                           variables_.initial[L.foot_pos[f][k1] + 1],
                           variables_.initial[L.foot_pos[f][k1] + 2]);
    } else {
      Eigen::Vector3d b;
      double yaw;
      base_at(L.nominal_knot_time[k1], &b, &yaw);
      pb = nominal_foot_world(robot_.legs[f], b, yaw);
      pb.z() = terrain_.height(pb.x(), pb.y());
    }
    const double ta = L.nominal_knot_time[k0], tb = L.nominal_knot_time[k1];
    for (int k = k0; k <= k1; ++k) {
      if (L.foot_vel[f][k] < 0) continue;
      const double u = (L.nominal_knot_time[k] - ta) / (tb - ta);
      Eigen::Vector3d p = (1 - u) * pa + u * pb;
      // Above the highest terrain around the foot (the clearance constraint probes there too).
      double ground = std::max(pa.z(), pb.z());
      const double d = options_.clearance_probe;
      for (const auto& o : {Eigen::Vector2d(0, 0), Eigen::Vector2d(d, 0), Eigen::Vector2d(-d, 0),
                            Eigen::Vector2d(0, d), Eigen::Vector2d(0, -d)})
        ground = std::max(ground, terrain_.height(p.x() + o.x(), p.y() + o.y()));
      p.z() = std::max(p.z(), ground) + options_.swing_clearance * 1.5;
      Eigen::Vector3d v = (pb - pa) / (tb - ta);
      if (k == 0) {
        p = pa;
        v = start ? start->foot_velocity[f] : Eigen::Vector3d::Zero();
        for (int d = 0; d < 3; ++d) {
          fix(L.foot_pos[f][k] + d, p[d]);
          fix(L.foot_vel[f][k] + d, v[d]);
        }
        continue;
      }
      if (k == S) v.setZero();
      for (int d = 0; d < 3; ++d) {
        variables_.initial[L.foot_pos[f][k] + d] = p[d];
        variables_.initial[L.foot_vel[f][k] + d] = v[d];
      }
    }
  }
  guess_forces();
}

// Forces of the initial guess: at each knot, the forces of the feet in stance that best satisfy
// both neighbouring segments' linear and angular dynamics for the guessed base motion, nearest to
// the weight shared equally (a small regularised least-squares problem per knot), then held in
// the friction pyramid. Ipopt then starts near dynamic balance instead of 1-2 m g away from it.
void SrbdProblem::guess_forces() {
  const Layout& L = layout_;
  const int S = L.num_segments;
  const int nf = static_cast<int>(robot_.legs.size());
  const double mg = robot_.mass * kGravity, mu = options_.friction;
  const double fmax = options_.max_normal_force_factor * mg;
  const bool rot_free =
      robot_.base_dof_free[3] || robot_.base_dof_free[4] || robot_.base_dof_free[5];
  auto v3 = [&](int i) {
    return Eigen::Vector3d(variables_.initial[i], variables_.initial[i + 1],
                           variables_.initial[i + 2]);
  };
  // Angular rows are divided by this lever arm so that they weigh like the force rows.
  constexpr double kLever = 0.3;  // m
  constexpr double kRegularisation = 1e-3;
  for (int k = 0; k <= S; ++k) {
    std::vector<int> feet, vars;
    for (int f = 0; f < nf; ++f) {
      const int v = k < S && L.force[f][k][0] >= 0 ? L.force[f][k][0]
                    : k > 0                        ? L.force[f][k - 1][1]
                                                   : -1;
      if (v >= 0) {
        feet.push_back(f);
        vars.push_back(v);
      }
    }
    if (feet.empty()) continue;
    const int n = static_cast<int>(feet.size());
    Eigen::MatrixXd A = Eigen::MatrixXd::Zero(12, 3 * n);
    Eigen::VectorXd b = Eigen::VectorXd::Zero(12);
    int rows = 0;
    for (int side = 0; side < 2; ++side) {
      const int s = side == 0 ? k - 1 : k;  // the segment ending (0) or starting (1) at knot k
      if (s < 0 || s >= S) continue;
      const double sigma = side == 0 ? 1.0 : 0.0;
      const double h = variables_.initial[L.interval_var[L.seg_interval[s]]] * L.seg_fraction[s];
      const int b0 = L.base[s], b1 = L.base[s + 1];
      Eigen::Vector3d r, acc, e, ed, edd, w, wd;
      hermite<double>(sigma, h, v3(b0), v3(b0 + 3), v3(b1), v3(b1 + 3), &r, nullptr, &acc);
      hermite<double>(sigma, h, v3(b0 + 6), v3(b0 + 9), v3(b1 + 6), v3(b1 + 9), &e, &ed, &edd);
      euler_to_angular<double>(e, ed, edd, &w, &wd);
      const Eigen::Matrix3d R = rotation_zyx<double>(e);
      const Eigen::Matrix3d Iw = R * robot_.inertia * R.transpose();
      b.segment<3>(rows) = robot_.mass * acc + Eigen::Vector3d(0, 0, mg);
      if (rot_free) b.segment<3>(rows + 3) = (Iw * wd + w.cross(Iw * w)) / kLever;
      for (int i = 0; i < n; ++i) {
        if (!L.contact[feet[i]][s]) continue;
        A.block<3, 3>(rows, 3 * i).setIdentity();
        if (rot_free) {
          const Eigen::Vector3d lever = v3(L.foot_pos[feet[i]][k]) - r;
          Eigen::Matrix3d cross;  // lever x f as a matrix acting on f
          cross << 0, -lever.z(), lever.y(), lever.z(), 0, -lever.x(), -lever.y(), lever.x(), 0;
          A.block<3, 3>(rows + 3, 3 * i) = cross / kLever;
        }
      }
      rows += 6;
    }
    // Nearest to the equal share: min |A f - b|^2 + eps |f - f_equal|^2.
    Eigen::VectorXd f_equal = Eigen::VectorXd::Zero(3 * n);
    for (int i = 0; i < n; ++i) f_equal[3 * i + 2] = mg / n;
    const Eigen::MatrixXd At = A.topRows(rows).transpose();
    const Eigen::MatrixXd N =
        At * A.topRows(rows) + kRegularisation * Eigen::MatrixXd::Identity(3 * n, 3 * n);
    const Eigen::VectorXd f = N.ldlt().solve(At * b.head(rows) + kRegularisation * f_equal);
    for (int i = 0; i < n; ++i) {
      Eigen::Vector3d fi = f.segment<3>(3 * i);
      if (!fi.allFinite()) fi = f_equal.segment<3>(3 * i);
      fi.z() = std::clamp(fi.z(), 0.0, fmax);
      const double tangential = fi.head<2>().norm(), limit = mu * fi.z() / std::sqrt(2.0);
      if (tangential > limit) fi.head<2>() *= limit / tangential;
      for (int d = 0; d < 3; ++d) variables_.initial[vars[i] + d] = fi[d];
    }
  }
}

// ---------------------------------------------------------------------------------------------
// Baseline constraints

void SrbdProblem::build_baseline() {
  const Layout& L = layout_;
  const int S = L.num_segments;
  const int nf = static_cast<int>(robot_.legs.size());
  const double m = robot_.mass, mg = m * kGravity;
  const Eigen::Matrix3d inertia = robot_.inertia;
  const bool rot_free =
      robot_.base_dof_free[3] || robot_.base_dof_free[4] || robot_.base_dof_free[5];
  std::vector<int> lin_rows;
  for (int d = 0; d < 3; ++d)
    if (robot_.base_dof_free[d]) lin_rows.push_back(d);

  // Duration variable of segment s as a local index; the segment length is x[dur] * fraction.
  auto seg_duration = [&](LocalVars& lv, int s) { return lv.add(L.interval_var[L.seg_interval[s]]); };
  auto base_pos = [&](LocalVars& lv, int s, double sigma, bool value_only) {
    return add_hermite(lv, L.base[s], L.base[s] + 3, L.base[s + 1], L.base[s + 1] + 3, sigma,
                       value_only);
  };
  auto base_euler = [&](LocalVars& lv, int s, double sigma, bool value_only) {
    return add_hermite(lv, L.base[s] + 6, L.base[s] + 9, L.base[s + 1] + 6, L.base[s + 1] + 9,
                       sigma, value_only);
  };
  auto foot_spline = [&](LocalVars& lv, int f, int s, double sigma) {
    return add_hermite(lv, L.foot_pos[f][s], L.foot_vel[f][s], L.foot_pos[f][s + 1],
                       L.foot_vel[f][s + 1], sigma, true);
  };

  for (int s = 0; s < S; ++s) {
    const double frac = L.seg_fraction[s];
    // Linear dynamics at both ends of the segment: exact everywhere in it (see nlp.hpp).
    if (!lin_rows.empty())
      for (int side = 0; side < 2; ++side) {
        LocalVars lv;
        const double sigma = side;
        const HermiteLocal rp = base_pos(lv, s, sigma, false);
        const int dur = seg_duration(lv, s);
        std::vector<std::array<int, 3>> fl;
        for (int f = 0; f < nf; ++f)
          if (L.force[f][s][side] >= 0) fl.push_back(lv.add3(L.force[f][s][side]));
        std::vector<double> z(lin_rows.size(), 0.0);
        add_piece(make_piece("dynamics_linear", lv, z, z, [=](const auto* x, auto* g) {
          using T = std::decay_t<decltype(*g)>;
          const T h = x[dur] * frac;
          Vec3<T> a;
          hermite<T>(sigma, h, x, rp, nullptr, nullptr, &a);
          Vec3<T> r = m * a;
          r[2] += mg;
          for (const auto& fi : fl) r -= gather3(x, fi);
          for (std::size_t i = 0; i < lin_rows.size(); ++i) g[i] = r[lin_rows[i]] / mg;
        }));
      }
    // Angular dynamics at `angular_points` points (ends included).
    if (rot_free) {
      const int np = std::max(2, options_.angular_points);
      for (const double sigma : L.segment_points(s, np - 1, true)) {
        LocalVars lv;
        const HermiteLocal rp = base_pos(lv, s, sigma, true);
        const HermiteLocal ep = base_euler(lv, s, sigma, false);
        const int dur = seg_duration(lv, s);
        std::vector<std::array<int, 3>> fp, f0, f1;
        for (int f = 0; f < nf; ++f)
          if (L.contact[f][s]) {
            fp.push_back(lv.add3(L.foot_pos[f][s]));
            f0.push_back(sigma < 1.0 ? lv.add3(L.force[f][s][0]) : std::array<int, 3>{-1, -1, -1});
            f1.push_back(sigma > 0.0 ? lv.add3(L.force[f][s][1]) : std::array<int, 3>{-1, -1, -1});
          }
        const double scale = 1.0 / (0.1 * mg);
        // See angular_band. A cropped first segment's start was an interior point of the
        // previous plan's segment, so it keeps the band.
        const bool interior = (sigma > 0.0 && sigma < 1.0) || (s == 0 && L.first_segment_cropped > 0.0);
        const double band = interior ? options_.angular_band * scale : 0.0;
        add_piece(make_piece(
            "dynamics_angular", lv, std::vector<double>(3, -band), std::vector<double>(3, band),
            [=](const auto* x, auto* g) {
              using T = std::decay_t<decltype(*g)>;
              const T h = x[dur] * frac;
              Vec3<T> r, e, ed, edd, w, wd;
              hermite<T>(sigma, h, x, rp, &r, nullptr, nullptr);
              hermite<T>(sigma, h, x, ep, &e, &ed, &edd);
              euler_to_angular<T>(e, ed, edd, &w, &wd);
              const Eigen::Matrix<T, 3, 3> R = rotation_zyx<T>(e);
              const Eigen::Matrix<T, 3, 3> Iw = R * inertia.cast<T>() * R.transpose();
              const Vec3<T> Iww = Iw * w;
              Vec3<T> res = Iw * wd + w.cross(Iww);
              for (std::size_t i = 0; i < fp.size(); ++i) {
                const Vec3<T> f = (1.0 - sigma) * gather3(x, f0[i]) + sigma * gather3(x, f1[i]);
                res -= (gather3(x, fp[i]) - r).cross(f);
              }
              for (int i = 0; i < 3; ++i) g[i] = res[i] * scale;
            }));
      }
    }
    // Range of motion: foot in the box around its nominal position, in the base frame. Swing
    // feet move fast, so they get twice the points.
    for (int f = 0; f < nf; ++f) {
      const int nr = std::max(1, options_.rom_points) * (L.contact[f][s] ? 1 : 2);
      // The segment's end only in the last segment: the next segment's start covers it.
      for (const double sigma : L.segment_points(s, nr, s == S - 1)) {
        LocalVars lv;
        const HermiteLocal rp = base_pos(lv, s, sigma, true);
        const HermiteLocal ep = base_euler(lv, s, sigma, true);
        const HermiteLocal fpl = foot_spline(lv, f, s, sigma);
        const int dur = rp.needs_duration || ep.needs_duration || fpl.needs_duration
                            ? seg_duration(lv, s)
                            : -1;
        const Eigen::Vector3d nom = robot_.legs[f].nominal_foot, box = robot_.legs[f].range_of_motion;
        std::vector<double> lo{-box.x(), -box.y(), -box.z()}, hi{box.x(), box.y(), box.z()};
        add_piece(make_piece("range_of_motion", lv, lo, hi, [=](const auto* x, auto* g) {
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

  // Stance feet on the terrain.
  const terrain::HeightField* field = &terrain_;
  const double hmin = options_.swing_clearance, probe = options_.clearance_probe;
  for (const auto& st : L.stances) {
    if (st.fixed) continue;
    LocalVars lv;
    const auto p = lv.add3(st.pos_var);
    add_piece(make_piece("stance_height", lv, {0.0}, {0.0}, [=](const auto* x, auto* g) {
      g[0] = x[p[2]] - terrain_height(*field, x[p[0]], x[p[1]]);
    }));
  }

  // Footholds on locally planar terrain: |h(p + o) - h(p) - grad h(p) . o| <= tol at the four
  // probe offsets. Keeps feet off step edges, where the smoothed surface differs from the real
  // one and a lifting or landing foot would sweep through the edge.
  if (options_.foothold_planarity > 0.0 && probe > 0.0) {
    const double tol = options_.foothold_planarity;
    for (const auto& st : L.stances) {
      if (st.fixed) continue;
      LocalVars lv;
      const auto p = lv.add3(st.pos_var);
      std::vector<double> lo(4, -tol), hi(4, tol);
      add_piece(make_piece("foothold_planarity", lv, lo, hi, [=](const auto* x, auto* g) {
        foothold_planarity_residuals(*field, x[p[0]], x[p[1]], probe, g);
      }));
    }
  }

  // Friction pyramid and normal-force bounds at every force knot (linear in f for the fixed
  // foothold, so they hold along the whole linear force segment).
  const double mu = options_.friction;
  const double fmax = options_.max_normal_force_factor * mg;
  for (int f = 0; f < nf; ++f) {
    int last = -1;
    for (int s = 0; s < S; ++s)
      for (int side = 0; side < 2; ++side) {
        const int fv = L.force[f][s][side];
        if (fv < 0 || fv == last) continue;
        last = fv;
        LocalVars lv;
        const auto p = lv.add3(L.foot_pos[f][s]);
        const auto fi = lv.add3(fv);
        add_piece(make_piece(
            "friction", lv, {0.0, -kInf, -kInf, -kInf, -kInf}, {fmax / mg, 0.0, 0.0, 0.0, 0.0},
            [=](const auto* x, auto* g) {
              using T = std::decay_t<decltype(*g)>;
              Vec3<T> n, t1, t2;
              terrain_frame(*field, x[p[0]], x[p[1]], &n, &t1, &t2);
              const Vec3<T> force = gather3(x, fi) / mg;
              const T fn = n.dot(force), a = t1.dot(force), c = t2.dot(force);
              g[0] = fn;
              g[1] = a - mu * fn;
              g[2] = -a - mu * fn;
              g[3] = c - mu * fn;
              g[4] = -c - mu * fn;
            }));
      }
  }

  // Swing clearance: at `clearance_points` per segment, the foot must be h_min * profile above
  // the terrain under it AND above the terrain probed at +-probe in x and y around it. Probing
  // makes the bound conservative: between the points the foot moves less than the probe radius,
  // and a smoothed planning terrain underestimates a sharp step only near its edge.
  for (const auto& sw : L.swings) {
    const int f = sw.foot;
    const int np = std::max(1, options_.clearance_points);
    // Nominal times: with optimised timing the profile keeps its shape in swing fraction. A swing
    // under way at the start of a re-plan lifted off swing_elapsed before it.
    const double t0 = L.nominal_knot_time[sw.first_seg] -
                      (sw.first_seg == 0 ? timeline_.swing_elapsed_of(static_cast<std::size_t>(f)) : 0.0);
    const double swing_T = L.nominal_knot_time[sw.last_seg + 1] - t0;
    for (int s = sw.first_seg; s <= sw.last_seg; ++s)
      for (const double sigma : L.segment_points(s, np, false)) {
        if (s == sw.first_seg && sigma == 0.0) continue;  // lift-off knot
        const double t = L.nominal_knot_time[s] +
                         sigma * (L.nominal_knot_time[s + 1] - L.nominal_knot_time[s]) - t0;
        const double w = clearance_profile(t, swing_T, options_.clearance_ramp);
        LocalVars lv;
        const HermiteLocal fpl = foot_spline(lv, f, s, sigma);
        const int dur = fpl.needs_duration ? seg_duration(lv, s) : -1;
        const double frac = L.seg_fraction[s];
        const int nrow = probe > 0.0 ? 5 : 1;
        const double d = probe;
        std::vector<double> lo(nrow, hmin * w), hi(nrow, kInf);
        add_piece(make_piece("swing_clearance", lv, lo, hi, [=](const auto* x, auto* g) {
          using T = std::decay_t<decltype(*g)>;
          const T h = dur >= 0 ? T(x[dur] * frac) : T(1.0);
          Vec3<T> p;
          hermite<T>(sigma, h, x, fpl, &p, nullptr, nullptr);
          static const double ox[5] = {0, 1, -1, 0, 0}, oy[5] = {0, 0, 0, 1, -1};
          for (int i = 0; i < nrow; ++i)
            g[i] = p[2] - terrain_height(*field, p[0] + d * ox[i], p[1] + d * oy[i]);
        }));
      }
  }

  // Total duration fixed when the timing is optimised.
  if (options_.optimize_timing) {
    LocalVars lv;
    for (int v : L.interval_var) lv.add(v);
    const int n = static_cast<int>(L.interval_var.size());
    const double T = timeline_.duration();
    if (n <= kMaxPieceVars) {
      add_piece(make_piece("total_duration", lv, {T}, {T}, [=](const auto* x, auto* g) {
        using T_ = std::decay_t<decltype(*g)>;
        T_ sum = x[0];
        for (int i = 1; i < n; ++i) sum += x[i];
        g[0] = sum;
      }));
    } else {
      throw std::invalid_argument("too many gait intervals (" + std::to_string(n) +
                                  ") for timing optimisation; use fewer cycles");
    }
  }
}

// ---------------------------------------------------------------------------------------------
// Evaluation

void SrbdProblem::eval_constraints(const double* x, double* g) const {
  double xl[kMaxPieceVars];
  for (std::size_t i = 0; i < pieces_.size(); ++i) {
    const Piece& p = *pieces_[i];
    for (std::size_t k = 0; k < p.vars.size(); ++k) xl[k] = x[p.vars[k]];
    p.eval(xl, g + row_offset_[i]);
  }
}

void SrbdProblem::jacobian_structure(int* rows, int* cols) const {
  for (std::size_t i = 0; i < pieces_.size(); ++i) {
    const Piece& p = *pieces_[i];
    const int n = static_cast<int>(p.vars.size());
    int z = nz_offset_[i];
    for (int r = 0; r < p.rows(); ++r)
      for (int c = 0; c < n; ++c) {
        rows[z] = row_offset_[i] + r;
        cols[z] = p.vars[c];
        ++z;
      }
  }
}

void SrbdProblem::eval_jacobian(const double* x, double* values) const {
  double xl[kMaxPieceVars];
  double g[64];
  for (std::size_t i = 0; i < pieces_.size(); ++i) {
    const Piece& p = *pieces_[i];
    for (std::size_t k = 0; k < p.vars.size(); ++k) xl[k] = x[p.vars[k]];
    p.eval_jacobian(xl, g, values + nz_offset_[i]);
  }
}

std::vector<double> SrbdProblem::row_lower() const {
  std::vector<double> v;
  for (const auto& p : pieces_) v.insert(v.end(), p->lb.begin(), p->lb.end());
  return v;
}
std::vector<double> SrbdProblem::row_upper() const {
  std::vector<double> v;
  for (const auto& p : pieces_) v.insert(v.end(), p->ub.begin(), p->ub.end());
  return v;
}

double SrbdProblem::max_violation(const std::vector<double>& x) const {
  std::vector<double> g(num_rows_);
  eval_constraints(x.data(), g.data());
  return max_violation(x, g);
}

double SrbdProblem::max_violation(const std::vector<double>& x, const std::vector<double>& g) const {
  const auto lo = row_lower(), hi = row_upper();
  double v = 0.0;
  for (int i = 0; i < num_rows_; ++i) v = std::max({v, lo[i] - g[i], g[i] - hi[i]});
  for (std::size_t i = 0; i < x.size(); ++i)
    v = std::max({v, variables_.lower[i] - x[i], x[i] - variables_.upper[i]});
  return v;
}

std::map<std::string, double> SrbdProblem::violation_by_kind(const std::vector<double>& x) const {
  std::vector<double> g(num_rows_);
  eval_constraints(x.data(), g.data());
  std::map<std::string, double> out;
  for (std::size_t i = 0; i < pieces_.size(); ++i) {
    double& v = out[pieces_[i]->kind];
    for (int r = 0; r < pieces_[i]->rows(); ++r) {
      const double gi = g[row_offset_[i] + r];
      v = std::max({v, pieces_[i]->lb[r] - gi, gi - pieces_[i]->ub[r]});
    }
  }
  return out;
}

double SrbdProblem::duration(const std::vector<double>& x) const {
  double T = 0.0;
  for (int v : layout_.interval_var) T += x[v];
  return T;
}

std::vector<double> SrbdProblem::event_times(const std::vector<double>& x) const {
  std::vector<double> ev{0.0};
  for (int v : layout_.interval_var) ev.push_back(ev.back() + x[v]);
  return ev;
}

SrbdProblem::State SrbdProblem::evaluate(const std::vector<double>& x, double t) const {
  const Layout& L = layout_;
  const int S = L.num_segments;
  // Locate the segment (right-continuous: a knot belongs to the segment it starts).
  double t0 = 0.0;
  int s = 0;
  double h = x[L.interval_var[L.seg_interval[0]]] * L.seg_fraction[0];
  while (s < S - 1 && t >= t0 + h) {
    t0 += h;
    ++s;
    h = x[L.interval_var[L.seg_interval[s]]] * L.seg_fraction[s];
  }
  const double sigma = std::clamp((t - t0) / h, 0.0, 1.0);
  auto v3 = [&](int i) {
    return i < 0 ? Eigen::Vector3d::Zero().eval() : Eigen::Vector3d(x[i], x[i + 1], x[i + 2]);
  };
  State st;
  const int b0 = L.base[s], b1 = L.base[s + 1];
  hermite<double>(sigma, h, v3(b0), v3(b0 + 3), v3(b1), v3(b1 + 3), &st.pos, &st.vel, &st.acc);
  hermite<double>(sigma, h, v3(b0 + 6), v3(b0 + 9), v3(b1 + 6), v3(b1 + 9), &st.euler,
                  &st.euler_rate, &st.euler_acc);
  const int nf = static_cast<int>(robot_.legs.size());
  for (int f = 0; f < nf; ++f) {
    Eigen::Vector3d p, v;
    hermite<double>(sigma, h, v3(L.foot_pos[f][s]), v3(L.foot_vel[f][s]), v3(L.foot_pos[f][s + 1]),
                    v3(L.foot_vel[f][s + 1]), &p, &v, nullptr);
    st.foot_pos.push_back(p);
    st.foot_vel.push_back(v);
    st.contact.push_back(L.contact[f][s]);
    st.force.push_back(L.contact[f][s] ? ((1 - sigma) * v3(L.force[f][s][0]) +
                                          sigma * v3(L.force[f][s][1]))
                                             .eval()
                                       : Eigen::Vector3d::Zero().eval());
  }
  return st;
}

}  // namespace terrastride::planner
