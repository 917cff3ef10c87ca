// A run of a plan in MuJoCo (simulation.hpp's simulate_plan): the model loaded and put in the
// plan's first state, then stepped along the plan with the tracking controller (and the closed
// loop's re-plans), then summed up and judged. The model itself is built by simulation.cpp.
#include <mujoco/mujoco.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <ctime>
#include <memory>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include "force_distribution.hpp"
#include "simulation_model.hpp"
#include "terrastride/robot/leg_kinematics.hpp"
#include "terrastride/simulation/simulation.hpp"

namespace terrastride::simulation::internal {
namespace {

using Eigen::Matrix3d;
using Eigen::Vector3d;

Matrix3d rotation_zyx(const Vector3d& e) {
  return (Eigen::AngleAxisd(e[0], Vector3d::UnitZ()) * Eigen::AngleAxisd(e[1], Vector3d::UnitY()) *
          Eigen::AngleAxisd(e[2], Vector3d::UnitX()))
      .toRotationMatrix();
}

Vector3d euler_zyx_of(const Matrix3d& r) {
  // R = Rz(yaw) Ry(pitch) Rx(roll): r20 = -sin(pitch).
  const double pitch = std::asin(std::clamp(-r(2, 0), -1.0, 1.0));
  const double yaw = std::atan2(r(1, 0), r(0, 0));
  const double roll = std::atan2(r(2, 1), r(2, 2));
  return {yaw, pitch, roll};
}

// Rotation vector of a rotation matrix (axis times angle).
Vector3d rotation_vector(const Matrix3d& r) {
  const Eigen::AngleAxisd aa(r);
  return aa.axis() * aa.angle();
}

// The plan at any time: cubic Hermite on positions (with the sampled velocities), linear on the
// rest; contact from the plan's phases when it has them (exact switch times), else the samples.
class PlanView {
 public:
  PlanView(const planner::Trajectory& plan, int n_feet) : plan_(plan), n_feet_(n_feet) {
    if (plan.samples.size() < 2) throw SimulationError("plan: fewer than two samples");
    for (const auto& s : plan.samples)
      if (static_cast<int>(s.feet.size()) != n_feet)
        throw SimulationError("plan: samples do not have one entry per robot foot");
    phases_.resize(n_feet);
    if (plan.extra.contains("phases") && plan.extra["phases"].is_object()) {
      for (int f = 0; f < n_feet; ++f) {
        const std::string name = plan.feet[f];
        if (!plan.extra["phases"].contains(name)) continue;
        try {
          for (const auto& p : plan.extra["phases"][name])
            phases_[f].push_back({p.at("start").get<double>(), p.at("end").get<double>(),
                                  p.at("contact").get<bool>()});
        } catch (const nlohmann::json::exception& e) {
          throw SimulationError("plan: phases: " + name + ": " + e.what());
        }
      }
    }
    for (int f = 0; f < n_feet; ++f)
      if (phases_[f].empty()) phases_[f] = phases_from_samples(f);
  }

  struct Phase {
    double start, end;
    bool contact;
  };
  const std::vector<Phase>& phases(int f) const { return phases_[f]; }
  double t_end() const { return plan_.samples.back().t; }

  bool contact(int f, double t) const {
    for (const auto& p : phases_[f])
      if (t >= p.start && t < p.end) return p.contact;
    return phases_[f].back().contact;
  }

  struct State {
    Vector3d base_pos, base_vel, base_acc, euler, omega;
    std::vector<Vector3d> foot, foot_vel, foot_acc, force;
  };

  State at(double t) const {
    const auto& s = plan_.samples;
    t = std::clamp(t, s.front().t, s.back().t);
    size_t k =
        std::upper_bound(s.begin(), s.end(), t,
                         [](double v, const planner::TrajectorySample& a) { return v < a.t; }) -
        s.begin();
    k = std::clamp<size_t>(k, 1, s.size() - 1) - 1;
    const auto& a = s[k];
    const auto& b = s[k + 1];
    const double h = b.t - a.t;
    const double u = (t - a.t) / h;
    State st;
    hermite(a.base.position, a.base.linear_velocity, b.base.position, b.base.linear_velocity, h, u,
            &st.base_pos, &st.base_vel, &st.base_acc);
    // Euler angles across the +-pi seam: b's taken within pi of a's before interpolating.
    Vector3d eb = b.base.euler_zyx;
    for (int k = 0; k < 3; ++k)
      eb[k] -= 2 * M_PI * std::round((eb[k] - a.base.euler_zyx[k]) / (2 * M_PI));
    st.euler = lerp(a.base.euler_zyx, eb, u);
    st.omega = lerp(a.base.angular_velocity, b.base.angular_velocity, u);
    for (int f = 0; f < n_feet_; ++f) {
      Vector3d p, v, acc;
      hermite(a.feet[f].position, a.feet[f].velocity, b.feet[f].position, b.feet[f].velocity, h, u,
              &p, &v, &acc);
      st.foot.push_back(p);
      st.foot_vel.push_back(v);
      st.foot_acc.push_back(acc);
      st.force.push_back(lerp(a.feet[f].force, b.feet[f].force, u));
    }
    return st;
  }

 private:
  static Vector3d lerp(const Vector3d& a, const Vector3d& b, double u) { return a + u * (b - a); }

  static void hermite(const Vector3d& p0, const Vector3d& v0, const Vector3d& p1,
                      const Vector3d& v1, double h, double u, Vector3d* p, Vector3d* v,
                      Vector3d* acc) {
    const double u2 = u * u, u3 = u2 * u;
    *p = (2 * u3 - 3 * u2 + 1) * p0 + (u3 - 2 * u2 + u) * h * v0 + (-2 * u3 + 3 * u2) * p1 +
         (u3 - u2) * h * v1;
    *v = ((6 * u2 - 6 * u) * p0 + (3 * u2 - 4 * u + 1) * h * v0 + (-6 * u2 + 6 * u) * p1 +
          (3 * u2 - 2 * u) * h * v1) /
         h;
    *acc = ((12 * u - 6) * p0 + (6 * u - 4) * h * v0 + (-12 * u + 6) * p1 + (6 * u - 2) * h * v1) /
           (h * h);
  }

  std::vector<Phase> phases_from_samples(int f) const {
    std::vector<Phase> out;
    const auto& s = plan_.samples;
    for (size_t k = 0; k < s.size(); ++k) {
      const bool c = s[k].feet[f].contact;
      const double t0 = k == 0 ? s[0].t : 0.5 * (s[k - 1].t + s[k].t);
      if (out.empty() || out.back().contact != c) {
        if (!out.empty()) out.back().end = t0;
        out.push_back({t0, s.back().t, c});
      }
    }
    return out;
  }

  const planner::Trajectory& plan_;
  int n_feet_;
  std::vector<std::vector<Phase>> phases_;
};

// The median (the upper one of an even count) and the largest of a non-empty series.
template <class T>
void median_and_max(std::vector<T> values, T* median, T* max) {
  std::sort(values.begin(), values.end());
  *median = values[values.size() / 2];
  *max = values.back();
}

// CPU time of this thread: the speed figure that a loaded machine does not distort.
double thread_cpu_seconds() {
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return ts.tv_sec + 1e-9 * ts.tv_nsec;
}

// A re-plan's figures: its wall and CPU time, iterations and whether it fell back.
void record_replan(double t, std::chrono::steady_clock::time_point call0, double call_cpu0,
                   const Replan& next, SimulationReport* rep) {
  rep->replan_wall_s.push_back(
      std::chrono::duration<double>(std::chrono::steady_clock::now() - call0).count());
  rep->replan_cpu_s.push_back(thread_cpu_seconds() - call_cpu0);
  ++rep->replans;
  if (next.iterations >= 0) rep->replan_iterations.push_back(next.iterations);
  rep->replan_records.push_back({t, rep->replan_wall_s.back(), next.iterations,
                                 next.fallback ? next.fallback_reason : std::string(),
                                 next.session});
  if (next.fallback) ++rep->replan_fallbacks;
}

// MuJoCo 2.2.2 checks each step's positions, velocities and accelerations (mj_checkPos/Vel/Acc):
// a NaN or a magnitude beyond mjMAXVAL (1e10) is warned about and the state reset to the model's
// initial one (time 0), so the run would go on from there as if nothing had happened. A control
// beyond it is warned about and every control zeroed for the step: the robot goes limp.
bool became_unstable(const mjData* d) {
  return d->warning[mjWARN_BADQPOS].number + d->warning[mjWARN_BADQVEL].number +
             d->warning[mjWARN_BADQACC].number + d->warning[mjWARN_BADCTRL].number >
         0;
}
std::string unstable_what(const mjData* d) {
  if (d->warning[mjWARN_BADQPOS].number > 0) return "position";
  if (d->warning[mjWARN_BADQVEL].number > 0) return "velocity";
  if (d->warning[mjWARN_BADQACC].number > 0) return "acceleration";
  return "joint torque command";
}

Vector3d terrain_normal(const terrain::HeightField& field, const Vector3d& p) {
  const auto s = field.sample(p.x(), p.y());
  return Vector3d(-s.gradient.x(), -s.gradient.y(), 1.0).normalized();
}

// MuJoCo has reset the state (time 0, the model's initial pose) after a non-finite or diverging
// step at t: nothing after t was simulated, so nothing after it may be judged.
void record_instability(const mjData* d, double t, SimulationReport* rep) {
  rep->unstable = true;
  rep->unstable_t = t;
  rep->reasons.push_back("unstable simulation at t = " + fmt_short(t) +
                         " s: MuJoCo found a non-finite or diverging " + unstable_what(d) +
                         " (it resets the state or zeroes the controls then); the run stopped "
                         "there");
}

// Figures that are not finite judge nothing: the run is unstable (a failure, never a pass or a
// warning).
void fail_non_finite_figures(double t0, SimulationReport* rep) {
  const double figures[] = {rep->position_rms, rep->position_max, rep->tilt_max, rep->slip_max,
                            rep->touchdown_error_max, rep->shin_impulse_max,
                            rep->joint_limit_impulse_max, rep->trunk_impulse};
  if (std::all_of(std::begin(figures), std::end(figures),
                  [](double x) { return std::isfinite(x); }))
    return;
  rep->unstable = true;
  rep->unstable_t = t0 + rep->duration;
  rep->reasons.push_back("unstable simulation: its tracking or contact figures are not finite");
}

// Only free-floating robots are simulated: the generated model's base is a free joint.
void require_free_base(const robot::RobotModel& model) {
  for (bool free : model.base_dof_free)
    if (!free)
      throw SimulationError("robot '" + model.name +
                            "': its base moves on restricted degrees of freedom (a slider); only "
                            "free-floating robots are simulated");
}

// The closed loop's re-planner (none in open loop).
Replanner make_replanner(const SimulationOptions& o) {
  const Replanner replanner = o.replan_every > 0 ? o.replanner() : Replanner();
  if (o.replan_every > 0 && !replanner) throw SimulationError("replan every: no re-planner made");
  return replanner;
}

// The plan the controller follows. Closed loop: the re-plan being tracked (its samples from 0 =
// `start` on the plan's axis) and the one waiting for its latency; outside the tracked re-plan's
// span, the original plan.
class FollowedPlan {
 public:
  FollowedPlan(const planner::Trajectory& plan, int n_feet)
      : plan_(plan), n_feet_(n_feet), original_(plan, n_feet) {}

  const PlanView& original() const { return original_; }

  // The waiting re-plan becomes the tracked one once its latency has passed (at once without one).
  void promote_pending(double now) {
    if (!pending_.view || now < pending_from_ - 1e-9) return;
    tracked_ = std::move(pending_);
    pending_ = Tracked{};
  }

  // The plan the controller follows at t and the shift from the plan's axis to its own.
  std::pair<const PlanView*, double> view_for(double t) const {
    if (tracked_.view && t >= tracked_.start - 1e-9 && t <= tracked_.end + 1e-9)
      return {tracked_.view.get(), tracked_.start};
    return {&original_, 0.0};
  }
  PlanView::State at(double t) const {
    const auto [v, shift] = view_for(t);
    return v->at(t - shift);
  }
  bool contact(int i, double t) const {
    const auto [v, shift] = view_for(t);
    return v->contact(i, t - shift);
  }

  // When to compare a touchdown at t with the plan's foothold planned for `t_mid` (mid-stance):
  // within the tracked re-plan's span (a re-plan may have moved the foothold), since beyond that
  // the original plan's foothold would be compared.
  double foothold_time(double t, double t_mid) const {
    if (tracked_.view && t >= tracked_.start && t <= tracked_.end)
      return std::max(t, std::min(t_mid, tracked_.end));
    return t_mid;
  }

  // Queues a successful re-plan to be tracked from `from` (its latency passed); SimulationError
  // when it cannot be followed.
  void queue(Replan& next, double from) {
    if (next.plan.feet != plan_.feet)
      throw SimulationError("its feet differ from the simulated plan's");
    Tracked n;
    n.plan = std::make_unique<planner::Trajectory>(std::move(next.plan));
    n.view = std::make_unique<PlanView>(*n.plan, n_feet_);
    n.start = next.start_time;
    n.end = next.start_time + n.view->t_end();
    pending_ = std::move(n);
    pending_from_ = from;
  }

 private:
  struct Tracked {
    std::unique_ptr<planner::Trajectory> plan;
    std::unique_ptr<PlanView> view;
    double start = 0.0, end = 0.0;
  };
  const planner::Trajectory& plan_;
  int n_feet_;
  PlanView original_;
  Tracked tracked_, pending_;
  double pending_from_ = 0.0;
};

// The ids of the generated model's parts the run reads and drives.
struct ModelParts {
  std::vector<int> foot_site, foot_geom, shin_geom, thigh_geom;
  int trunk_geom = -1, trunk_body = -1;
};

ModelParts find_model_parts(const mjModel* m, const robot::RobotModel& model) {
  const int n_legs = static_cast<int>(model.legs.size());
  ModelParts parts;
  parts.foot_site.resize(n_legs);
  parts.foot_geom.resize(n_legs);
  parts.shin_geom.resize(n_legs);
  parts.thigh_geom.resize(n_legs);
  for (int i = 0; i < n_legs; ++i) {
    const std::string n = model.legs[i].name;
    parts.foot_site[i] = mj_name2id(m, mjOBJ_SITE, (n + "_foot").c_str());
    parts.foot_geom[i] = mj_name2id(m, mjOBJ_GEOM, (n + "_foot").c_str());
    parts.shin_geom[i] = mj_name2id(m, mjOBJ_GEOM, (n + "_shin").c_str());
    parts.thigh_geom[i] = mj_name2id(m, mjOBJ_GEOM, (n + "_thigh").c_str());
  }
  parts.trunk_geom = mj_name2id(m, mjOBJ_GEOM, "trunk");
  parts.trunk_body = mj_name2id(m, mjOBJ_BODY, "trunk");
  return parts;
}

// The measured trunk: position, rotation, linear and angular velocity (world frame).
struct BaseState {
  Vector3d p;
  Matrix3d rot;
  Vector3d v, omega;
};

BaseState measured_base(const mjData* d) {
  BaseState b;
  b.p = Vector3d(d->qpos[0], d->qpos[1], d->qpos[2]);
  b.rot = Eigen::Quaterniond(d->qpos[3], d->qpos[4], d->qpos[5], d->qpos[6]).toRotationMatrix();
  b.v = Vector3d(d->qvel[0], d->qvel[1], d->qvel[2]);
  b.omega = b.rot * Vector3d(d->qvel[3], d->qvel[4], d->qvel[5]);
  return b;
}

// Contacts of the current state: per foot force (terrain on foot), shin/thigh/trunk normal force.
struct ContactForces {
  std::vector<Vector3d> foot_force;
  std::vector<bool> foot_contact;
  std::vector<double> shin_f, thigh_f;
  double trunk_f = 0.0;
};

ContactForces measure_contacts(const mjModel* m, const mjData* d, const ModelParts& parts,
                               int n_legs) {
  ContactForces c;
  c.foot_force.assign(n_legs, Vector3d::Zero());
  c.foot_contact.assign(n_legs, false);
  c.shin_f.assign(n_legs, 0.0);
  c.thigh_f.assign(n_legs, 0.0);
  for (int k = 0; k < d->ncon; ++k) {
    const mjContact& con = d->contact[k];
    mjtNum res[6];
    mj_contactForce(m, d, k, res);
    Eigen::Map<const Eigen::Matrix<mjtNum, 3, 3, Eigen::RowMajor>> frame(con.frame);
    // Force on geom2 (the normal points from geom1 to geom2); robot geoms take their side.
    const Vector3d f2 = frame.transpose() * Vector3d(res[0], res[1], res[2]);
    for (int i = 0; i < n_legs; ++i) {
      if (con.geom1 == parts.foot_geom[i] || con.geom2 == parts.foot_geom[i]) {
        c.foot_force[i] += con.geom2 == parts.foot_geom[i] ? f2 : Vector3d(-f2);
        c.foot_contact[i] = true;
      }
      if (con.geom1 == parts.shin_geom[i] || con.geom2 == parts.shin_geom[i])
        c.shin_f[i] += std::abs(res[0]);
      if (con.geom1 == parts.thigh_geom[i] || con.geom2 == parts.thigh_geom[i])
        c.thigh_f[i] += std::abs(res[0]);
    }
    if (con.geom1 == parts.trunk_geom || con.geom2 == parts.trunk_geom)
      c.trunk_f += std::abs(res[0]);
  }
  return c;
}

// The plan's references at one control step: now, a moment before and after (the swing
// feed-forward's joint rates), and the rotations of each.
struct PlanReference {
  PlanView::State now, before, after;
  Matrix3d rot, rot_before, rot_after;
};

// The time around a control step over which the plan is differentiated (swing joint rates).
constexpr double kRateStep = 0.004;

// One run of a plan in MuJoCo: the model built from the robot, the terrain and the plan's first
// state (constructor), then stepped along the plan with the tracking controller (run), then
// summed up and judged (the returned report).
class SimulationRun {
 public:
  SimulationRun(const robot::RobotModel& model, const planner::Trajectory& plan,
                const terrain::HeightField& scene, const TerrainMjcf& terrain,
                const SimulationOptions& o);
  SimulationReport run();

 private:
  // Model building.
  void load(const TerrainMjcf& terrain, const PlanView::State& s0, const Matrix3d& rot0);
  void set_initial_state(const PlanView::State& s0, const Matrix3d& rot0);
  void prepare_report();

  // Stepping.
  void step_through_plan();
  void replan_if_due(double t, const BaseState& b, const ContactForces& contacts);
  MeasuredState measured_state(double t, const BaseState& b,
                               const ContactForces& contacts);
  void follow_replan(double t, Replan& next);
  void track(double t, const BaseState& b, const PlanReference& ref);
  void track_stances(double t, const ContactForces& contacts);
  void record_sample(double t, const BaseState& b, const PlanReference& ref,
                     const ContactForces& contacts);
  void record_joint_limits();
  void apply_pushes(double t);
  bool step_physics(double t);
  void add_body_impulses();

  // Controller.
  PlanReference plan_reference(double t) const;
  void control(double t, const BaseState& b, const PlanReference& ref);
  std::vector<Vector3d> trunk_wrench_forces(const BaseState& b, const PlanReference& ref,
                                            const std::vector<Vector3d>& lever) const;
  void constrain_stance_forces(const PlanReference& ref, const std::vector<int>& stance,
                               const std::vector<Vector3d>& lever,
                               std::vector<Vector3d>* delta) const;
  Vector3d leg_torque(int i, double t, const BaseState& b, const PlanReference& ref,
                      const std::vector<int>& stance, const std::vector<Vector3d>& delta);
  bool apply_torque(int i, Vector3d tau);
  Vector3d ik_in(int i, const Vector3d& p_base, const Matrix3d& rot, const Vector3d& foot,
                 const Vector3d& n, const Vector3d& fallback) const;

  // Verdict.
  void summarise();
  std::string worst_end_stop();
  void judge();

  Vector3d foot_centre(int i) const {
    const int s = parts_.foot_site[i];
    return Vector3d(d_->site_xpos[3 * s], d_->site_xpos[3 * s + 1], d_->site_xpos[3 * s + 2]);
  }
  // The terrain point under a foot sphere's centre.
  Vector3d contact_point(const Vector3d& centre) const {
    return centre - r_foot_ * terrain_normal(scene_, centre);
  }
  // The velocity J qdot of a point whose translation Jacobian is in jacp_.
  Vector3d jacobian_velocity() const {
    Vector3d vel = Vector3d::Zero();
    for (int r = 0; r < 3; ++r)
      for (int k = 0; k < nv_; ++k) vel[r] += jacp_[r * nv_ + k] * d_->qvel[k];
    return vel;
  }

  const robot::RobotModel& model_;
  const planner::Trajectory& plan_;
  const terrain::HeightField& scene_;
  const SimulationOptions& o_;
  const int n_legs_;
  FollowedPlan followed_;
  const Replanner replanner_;
  const double r_foot_;
  const double mu_;
  const ControllerOptions& c_;
  const ControllerGains g_;

  SimulationReport rep_;
  std::unique_ptr<Model> sim_;
  mjModel* m_ = nullptr;
  mjData* d_ = nullptr;
  int nv_ = 0;
  std::vector<mjtNum> jacp_, full_m_;
  ModelParts parts_;
  std::vector<Vector3d> q_prev_;

  // Stances as executed: each foot's stances in rep_.stances and where each touched down.
  std::vector<std::vector<int>> stance_index_;
  std::vector<Vector3d> touchdown_point_;

  double t0_ = 0.0, t_end_ = 0.0;
  int n_steps_ = 0;
  double sq_err_sum_ = 0.0, saturated_s_ = 0.0;
  double next_record_ = 0.0, next_replan_ = 0.0;
  std::vector<Vector3d> tau_applied_;
};

// --- Model building ---

SimulationRun::SimulationRun(const robot::RobotModel& model, const planner::Trajectory& plan,
                             const terrain::HeightField& scene, const TerrainMjcf& terrain,
                             const SimulationOptions& o)
    : model_(model),
      plan_(plan),
      scene_(scene),
      o_(o),
      n_legs_(static_cast<int>(model.legs.size())),
      followed_(plan, n_legs_),
      replanner_(make_replanner(o)),
      r_foot_(model.foot_radius),
      mu_(o.friction),
      c_(o.controller),
      g_(o.controller.gains ? *o.controller.gains : controller_gains(model)) {
  // Initial state: the plan's first sample, legs by IK of its feet.
  const auto s0 = followed_.original().at(plan.samples.front().t);
  const Matrix3d rot0 = rotation_zyx(s0.euler);
  load(terrain, s0, rot0);
  set_initial_state(s0, rot0);
  prepare_report();
}

void SimulationRun::load(const TerrainMjcf& terrain, const PlanView::State& s0,
                         const Matrix3d& rot0) {
  const Eigen::Quaterniond quat0(rot0);
  rep_.thresholds = o_.thresholds;
  rep_.gains = g_;
  rep_.dt = o_.dt;
  rep_.model_xml = full_mjcf(model_, &terrain, o_, s0.base_pos, quat0);
  rep_.terrain = terrain.description;
  rep_.filled_cells = terrain.filled_cells;
  sim_ = load_model(rep_.model_xml);
  if (terrain.after_load) {
    terrain.after_load(sim_->m);
    mj_forward(sim_->m, sim_->d);
  }
  m_ = sim_->m;
  d_ = sim_->d;
  nv_ = m_->nv;
  jacp_.resize(3 * nv_);
  full_m_.resize(nv_ * nv_);
  parts_ = find_model_parts(m_, model_);
}

void SimulationRun::set_initial_state(const PlanView::State& s0, const Matrix3d& rot0) {
  const Eigen::Quaterniond quat0(rot0);
  for (int k = 0; k < 3; ++k) d_->qpos[k] = s0.base_pos[k];
  d_->qpos[3] = quat0.w();
  d_->qpos[4] = quat0.x();
  d_->qpos[5] = quat0.y();
  d_->qpos[6] = quat0.z();
  const Vector3d omega0_local = rot0.transpose() * s0.omega;
  for (int k = 0; k < 3; ++k) {
    d_->qvel[k] = s0.base_vel[k];
    d_->qvel[3 + k] = omega0_local[k];
  }
  q_prev_.resize(n_legs_);
  for (int i = 0; i < n_legs_; ++i) {
    const Vector3d sphere = s0.foot[i] + r_foot_ * terrain_normal(scene_, s0.foot[i]);
    const auto ik =
        robot::inverse_kinematics(model_.legs[i], rot0.transpose() * (sphere - s0.base_pos));
    if (ik.status == robot::IkStatus::unreachable)
      throw SimulationError("plan: first sample: " + ik.message);
    q_prev_[i] = ik.q;
    for (int j = 0; j < 3; ++j) d_->qpos[7 + 3 * i + j] = ik.q[j];
  }
  mj_forward(m_, d_);
}

void SimulationRun::prepare_report() {
  rep_.torque_max.assign(n_legs_, Vector3d::Zero());
  rep_.saturated_time.assign(n_legs_, Vector3d::Zero());
  rep_.joint_limit_time.assign(n_legs_, Vector3d::Zero());
  rep_.joint_limit_impulse.assign(n_legs_, Vector3d::Zero());
  rep_.shin_impulse.assign(n_legs_, 0.0);
  rep_.thigh_impulse.assign(n_legs_, 0.0);
  // Stances as executed.
  stance_index_.resize(n_legs_);
  for (int f = 0; f < n_legs_; ++f)
    for (const auto& p : followed_.original().phases(f)) {
      if (!p.contact) continue;
      stance_index_[f].push_back(static_cast<int>(rep_.stances.size()));
      StanceReport s;
      s.foot = f;
      s.t_start = p.start;
      s.t_end = p.end;
      rep_.stances.push_back(s);
    }
  touchdown_point_.assign(rep_.stances.size(), Vector3d::Zero());
  t0_ = plan_.samples.front().t;
  t_end_ = followed_.original().t_end();
  n_steps_ = static_cast<int>(simulation_steps(plan_, o_.dt));
  next_record_ = t0_;
  next_replan_ = t0_ + o_.replan_every;
  tau_applied_.assign(n_legs_, Vector3d::Zero());
}

SimulationReport SimulationRun::run() {
  const auto wall0 = std::chrono::steady_clock::now();
  const double cpu0 = thread_cpu_seconds();
  step_through_plan();
  rep_.wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - wall0).count();
  rep_.cpu_s = thread_cpu_seconds() - cpu0;
  summarise();
  judge();
  return std::move(rep_);
}

// --- Stepping ---

void SimulationRun::step_through_plan() {
  for (int step = 0; step <= n_steps_; ++step) {
    if (o_.stop_requested && step % 50 == 0 && o_.stop_requested())
      throw SimulationCancelled("simulation stopped at t = " + std::to_string(d_->time + t0_) +
                                " s");
    const double t = d_->time + t0_;
    const BaseState b = measured_base(d_);
    const ContactForces contacts = measure_contacts(m_, d_, parts_, n_legs_);
    // Closed loop: the measured state to the re-planner; its plan tracked after the latency.
    followed_.promote_pending(t);
    replan_if_due(t, b, contacts);
    const PlanReference ref = plan_reference(t);
    if (replanner_)
      rep_.reference_position_max = std::max(
          rep_.reference_position_max, (b.p - followed_.original().at(t).base_pos).norm());
    track(t, b, ref);
    track_stances(t, contacts);
    record_sample(t, b, ref, contacts);
    if (step == n_steps_ || rep_.fell) break;
    control(t, b, ref);
    record_joint_limits();
    apply_pushes(t);
    if (!step_physics(t)) break;
    add_body_impulses();
  }
}

void SimulationRun::replan_if_due(double t, const BaseState& b, const ContactForces& contacts) {
  // No re-plan within the plan's last 0.1 s: a re-plan to rest over that little cannot ramp the
  // forces down (every such step failed force_ramp in its first few ms). The 1 ms slack is for
  // durations that carry rounding: 3 crawl cycles of 3.6667 s end at 11.0001 s, and the step at
  // 10.9 s, 0.1001 s before that end, failed in every closed-loop run.
  if (!(replanner_ && t >= next_replan_ - 1e-9 &&
        t < t_end_ - SimulationLimits::kNoReplanTail - 1e-3))
    return;
  next_replan_ += o_.replan_every;
  if (t < o_.replan_from - 1e-9) return;  // the plan is tracked open loop until then
  const MeasuredState ms = measured_state(t, b, contacts);
  const auto call0 = std::chrono::steady_clock::now();
  const double call_cpu0 = thread_cpu_seconds();
  Replan next = replanner_(ms);
  record_replan(t, call0, call_cpu0, next, &rep_);
  follow_replan(t, next);
  followed_.promote_pending(t);
}

MeasuredState SimulationRun::measured_state(double t, const BaseState& b,
                                            const ContactForces& contacts) {
  MeasuredState ms;
  ms.t = t;
  ms.base_position = b.p;
  ms.base_euler_zyx = euler_zyx_of(b.rot);
  ms.base_linear_velocity = b.v;
  ms.base_angular_velocity = b.omega;
  ms.foot_contact = contacts.foot_contact;
  for (int i = 0; i < n_legs_; ++i) {
    ms.foot_position.push_back(contact_point(foot_centre(i)));
    mj_jacSite(m_, d_, jacp_.data(), nullptr, parts_.foot_site[i]);
    ms.foot_velocity.push_back(jacobian_velocity());
  }
  return ms;
}

// A successful re-plan is tracked after the latency; a failed one (or one that cannot be
// followed) is counted, the first failure's message kept.
void SimulationRun::follow_replan(double t, Replan& next) {
  if (next.success) {
    try {
      followed_.queue(next, t + o_.replan_latency);
    } catch (const SimulationError& e) {
      next.success = false;
      next.message = std::string("re-plan at t = ") + fmt(t) + " s: " + e.what();
    }
  }
  if (!next.success) {
    ++rep_.replan_failures;
    rep_.replan_failure_times.push_back(t);
    if (rep_.replan_first_failure.empty())
      rep_.replan_first_failure = next.message.empty() ? "re-plan failed" : next.message;
  }
}

// Tracking errors, and the fall that ends the run: the trunk too far below the plan, tilted too
// far, or the body on the terrain.
void SimulationRun::track(double t, const BaseState& b, const PlanReference& ref) {
  const auto& ps = ref.now;
  const double pos_err = (b.p - ps.base_pos).norm();
  const double tilt = Eigen::AngleAxisd(ref.rot.transpose() * b.rot).angle();
  const double drop = ps.base_pos.z() - b.p.z();
  sq_err_sum_ += pos_err * pos_err;
  if (pos_err > rep_.position_max) {
    rep_.position_max = pos_err;
    rep_.position_max_t = t;
  }
  rep_.tilt_max = std::max(rep_.tilt_max, tilt);
  rep_.height_drop_max = std::max(rep_.height_drop_max, drop);
  double body_impulse = rep_.trunk_impulse;
  for (int i = 0; i < n_legs_; ++i) body_impulse = std::max(body_impulse, rep_.thigh_impulse[i]);
  const auto& th = o_.thresholds;
  if (rep_.fell || !(drop > th.fall_height_m || tilt > th.fall_tilt_rad ||
                     body_impulse > th.body_contact_impulse_Ns))
    return;
  rep_.fell = true;
  rep_.fall_t = t;
  std::ostringstream why;
  why.precision(3);
  if (drop > th.fall_height_m)
    why << "fall at t = " << t << " s: trunk " << drop << " m below the plan (limit "
        << th.fall_height_m << ")";
  else if (tilt > th.fall_tilt_rad)
    why << "fall at t = " << t << " s: orientation error " << tilt * 180 / M_PI << " deg (limit "
        << th.fall_tilt_rad * 180 / M_PI << ")";
  else
    why << "fall at t = " << t << " s: trunk or thigh on the terrain (contact impulse "
        << body_impulse << " N s)";
  rep_.reasons.push_back(why.str());
}

// Stance bookkeeping: touchdown error and slip of the sphere's contact point.
void SimulationRun::track_stances(double t, const ContactForces& contacts) {
  const auto stance_at = [&](int f) {
    for (int idx : stance_index_[f])
      if (t >= rep_.stances[idx].t_start && t < rep_.stances[idx].t_end) return idx;
    return -1;
  };
  for (int i = 0; i < n_legs_; ++i) {
    const int idx = stance_at(i);
    if (idx < 0 || !contacts.foot_contact[i]) continue;
    const Vector3d centre = foot_centre(i);
    const Vector3d contact_pt = contact_point(centre);
    StanceReport& s = rep_.stances[idx];
    if (!s.touched_down) {
      s.touched_down = true;
      s.touchdown_t = t;
      const double t_foothold = followed_.foothold_time(t, 0.5 * (s.t_start + s.t_end));
      const Vector3d planned = followed_.at(t_foothold).foot[i];
      s.touchdown_error = (contact_pt - planned).norm();
      touchdown_point_[idx] = contact_pt;
    } else {
      s.centre_drift =
          std::max(s.centre_drift, (contact_pt - touchdown_point_[idx]).head<2>().norm());
    }
    // Sliding: the velocity of the lower leg's material point at the contact, tangential part.
    const Vector3d n = terrain_normal(scene_, centre);
    mj_jac(m_, d_, jacp_.data(), nullptr, contact_pt.data(), m_->site_bodyid[parts_.foot_site[i]]);
    const Vector3d vel = jacobian_velocity();
    s.slip += (vel - vel.dot(n) * n).norm() * o_.dt;
  }
}

void SimulationRun::record_sample(double t, const BaseState& b, const PlanReference& ref,
                                  const ContactForces& contacts) {
  if (!(o_.record_dt > 0 && t >= next_record_ - 1e-9)) return;
  next_record_ += o_.record_dt;
  SimulationSample smp;
  smp.t = t;
  smp.base_position = b.p;
  smp.base_euler_zyx = euler_zyx_of(b.rot);
  smp.planned_position = ref.now.base_pos;
  smp.planned_euler_zyx = ref.now.euler;
  smp.joint_torque = tau_applied_;
  smp.foot_contact = contacts.foot_contact;
  smp.foot_force = contacts.foot_force;
  for (int i = 0; i < n_legs_; ++i) {
    smp.planned_contact.push_back(followed_.contact(i, t));
    smp.foot_position.push_back(contact_point(foot_centre(i)));
  }
  smp.shin_force = contacts.shin_f;
  smp.thigh_force = contacts.thigh_f;
  smp.trunk_force = contacts.trunk_f;
  rep_.samples.push_back(std::move(smp));
}

// End stops: MuJoCo's joint-limit constraints (joint k of the model is leg k/3 - 1's, the free
// joint being 0); their torque times dt is the stop's impulse.
void SimulationRun::record_joint_limits() {
  for (int k = 0; k < d_->nefc; ++k) {
    if (d_->efc_type[k] != mjCNSTR_LIMIT_JOINT || d_->efc_force[k] == 0) continue;
    const int jnt = d_->efc_id[k] - 1;
    if (jnt < 0 || jnt >= 3 * n_legs_) continue;
    rep_.joint_limit_time[jnt / 3][jnt % 3] += o_.dt;
    rep_.joint_limit_impulse[jnt / 3][jnt % 3] += std::abs(d_->efc_force[k]) * o_.dt;
  }
}

// Pushes on the trunk.
void SimulationRun::apply_pushes(double t) {
  const int trunk = parts_.trunk_body;
  for (int k = 0; k < 6; ++k) d_->xfrc_applied[6 * trunk + k] = 0;
  for (const auto& push : o_.pushes)
    if (t >= push.t && t < push.t + push.duration)
      for (int k = 0; k < 3; ++k) d_->xfrc_applied[6 * trunk + k] += push.force[k];
}

// One physics step; false when it went unstable (the run stops there).
bool SimulationRun::step_physics(double t) {
  const auto step0 = std::chrono::steady_clock::now();
  mj_step(m_, d_);
  rep_.physics_wall_s +=
      std::chrono::duration<double>(std::chrono::steady_clock::now() - step0).count();
  ++rep_.steps;
  if (became_unstable(d_)) {
    record_instability(d_, t, &rep_);
    return false;
  }
  return true;
}

// Impulses of the step just taken (contact forces of the new state times dt).
void SimulationRun::add_body_impulses() {
  for (int k = 0; k < d_->ncon; ++k) {
    const mjContact& con = d_->contact[k];
    mjtNum res[6];
    mj_contactForce(m_, d_, k, res);
    const double impulse = std::abs(res[0]) * o_.dt;
    for (int i = 0; i < n_legs_; ++i) {
      if (con.geom1 == parts_.shin_geom[i] || con.geom2 == parts_.shin_geom[i])
        rep_.shin_impulse[i] += impulse;
      if (con.geom1 == parts_.thigh_geom[i] || con.geom2 == parts_.thigh_geom[i])
        rep_.thigh_impulse[i] += impulse;
    }
    if (con.geom1 == parts_.trunk_geom || con.geom2 == parts_.trunk_geom)
      rep_.trunk_impulse += impulse;
  }
}

// --- Controller ---

PlanReference SimulationRun::plan_reference(double t) const {
  const auto [view, shift] = followed_.view_for(t);
  PlanReference ref;
  ref.now = view->at(t - shift);
  ref.rot = rotation_zyx(ref.now.euler);
  ref.before = view->at(t - kRateStep - shift);
  ref.after = view->at(t + kRateStep - shift);
  ref.rot_before = rotation_zyx(ref.before.euler);
  ref.rot_after = rotation_zyx(ref.after.euler);
  return ref;
}

// The joint torques of every leg for the step from t: the trunk wrench spread over the planned
// stance feet, the planned forces, joint PD and the swing feed-forward, clamped to the limits.
void SimulationRun::control(double t, const BaseState& b, const PlanReference& ref) {
  std::vector<int> stance;
  std::vector<Vector3d> lever;
  for (int i = 0; i < n_legs_; ++i)
    if (followed_.contact(i, t)) {
      stance.push_back(i);
      lever.push_back(foot_centre(i) - b.p);
    }
  std::vector<Vector3d> delta = trunk_wrench_forces(b, ref, lever);
  if (c_.force_distribution == ControllerOptions::ForceDistribution::constrained)
    constrain_stance_forces(ref, stance, lever, &delta);
  mj_fullM(m_, full_m_.data(), d_->qM);
  bool saturated = false;
  for (int i = 0; i < n_legs_; ++i)
    saturated = apply_torque(i, leg_torque(i, t, b, ref, stance, delta)) || saturated;
  if (saturated) saturated_s_ += o_.dt;
}

// Trunk PD wrench, spread over the planned stance feet (at `lever` from the base): each stance
// foot's share.
std::vector<Vector3d> SimulationRun::trunk_wrench_forces(const BaseState& b,
                                                         const PlanReference& ref,
                                                         const std::vector<Vector3d>& lever) const {
  if (!c_.trunk_wrench) return std::vector<Vector3d>(lever.size(), Vector3d::Zero());
  const auto& ps = ref.now;
  Eigen::Matrix<double, 6, 1> w;
  w.head<3>() = g_.kp_position * (ps.base_pos - b.p) + g_.kd_position * (ps.base_vel - b.v);
  w.tail<3>() = g_.kp_orientation * rotation_vector(ref.rot * b.rot.transpose()) +
                g_.kd_orientation * (ps.omega - b.omega);
  if (!c_.planned_forces) {
    // Without the plan's forces the wrench carries the weight.
    double mass = 0;
    for (int k = 1; k < m_->nbody; ++k) mass += m_->body_mass[k];
    w.head<3>() += mass * (ps.base_acc + Vector3d(0, 0, kGravity));
  }
  return spread_wrench(w, lever);
}

// The constrained distribution (ControllerOptions::force_distribution): each stance foot's share
// `delta` becomes what its planned force needs to reach the constrained force, so that
// leg_torque's cone clip leaves it as it is (the pyramid lies within the cone of the same mu).
void SimulationRun::constrain_stance_forces(const PlanReference& ref,
                                            const std::vector<int>& stance,
                                            const std::vector<Vector3d>& lever,
                                            std::vector<Vector3d>* delta) const {
  std::vector<StanceFoot> feet(stance.size());
  for (std::size_t k = 0; k < stance.size(); ++k) {
    const int i = stance[k];
    const Vector3d planned = c_.planned_forces ? ref.now.force[i] : Vector3d::Zero();
    feet[k] = {planned + (*delta)[k], lever[k], terrain_normal(scene_, ref.now.foot[i])};
  }
  const std::vector<Vector3d> f = constrained_stance_forces(feet, c_.cone_margin * mu_);
  for (std::size_t k = 0; k < stance.size(); ++k) (*delta)[k] += f[k] - feet[k].desired;
}

// IK of the sphere centre over the planned foot point `foot` on a terrain of normal `n`.
Vector3d SimulationRun::ik_in(int i, const Vector3d& p_base, const Matrix3d& rot,
                              const Vector3d& foot, const Vector3d& n,
                              const Vector3d& fallback) const {
  const auto ik =
      robot::inverse_kinematics(model_.legs[i], rot.transpose() * (foot + r_foot_ * n - p_base));
  return ik.status == robot::IkStatus::unreachable ? fallback : Vector3d(ik.q);
}

// Leg i's torque before the limits: gravity/Coriolis, in stance the planned force plus its share
// of the trunk wrench within the friction cone, joint PD towards the IK of the planned foot, and
// in swing the feed-forward of the planned joint accelerations.
Vector3d SimulationRun::leg_torque(int i, double t, const BaseState& b, const PlanReference& ref,
                                   const std::vector<int>& stance,
                                   const std::vector<Vector3d>& delta) {
  const int dof = 6 + 3 * i;
  mj_jacSite(m_, d_, jacp_.data(), nullptr, parts_.foot_site[i]);
  Matrix3d jac;
  for (int r = 0; r < 3; ++r)
    for (int k = 0; k < 3; ++k) jac(r, k) = jacp_[r * nv_ + dof + k];
  Matrix3d mass;
  for (int r = 0; r < 3; ++r)
    for (int k = 0; k < 3; ++k) mass(r, k) = full_m_[(dof + r) * nv_ + dof + k];
  Vector3d q, qd, bias;
  for (int j = 0; j < 3; ++j) {
    q[j] = d_->qpos[7 + 3 * i + j];
    qd[j] = d_->qvel[dof + j];
    bias[j] = d_->qfrc_bias[dof + j];
  }
  // Desired joints: IK of the planned foot relative to the measured base; their rates from the
  // planned motion (finite differences of the IK along the planned base).
  const auto& ps = ref.now;
  const auto &pm = ref.before, &pp = ref.after;
  const Vector3d n = terrain_normal(scene_, ps.foot[i]);
  const Vector3d q_des = ik_in(i, b.p, b.rot, ps.foot[i], n, q_prev_[i]);
  q_prev_[i] = q_des;
  const Vector3d q0 = ik_in(i, ps.base_pos, ref.rot, ps.foot[i], n, q);
  const Vector3d qm = ik_in(i, pm.base_pos, ref.rot_before, pm.foot[i], n, q0);
  const Vector3d qp = ik_in(i, pp.base_pos, ref.rot_after, pp.foot[i], n, q0);
  constexpr double h = kRateStep;
  const Vector3d qd_des = (qp - qm) / (2 * h);
  const Vector3d qdd_des = (qp - 2 * q0 + qm) / (h * h);
  Vector3d tau = bias;
  if (followed_.contact(i, t)) {
    Vector3d f = c_.planned_forces ? ps.force[i] : Vector3d::Zero();
    const auto it = std::find(stance.begin(), stance.end(), i);
    f += delta[it - stance.begin()];
    f = into_cone(f, n, c_.cone_margin * mu_);
    tau -= jac.transpose() * f;
    tau += g_.kp_stance * (q_des - q) + g_.kd_stance * (qd_des - qd);
  } else {
    if (c_.swing_feedforward) tau += mass * qdd_des;
    tau += g_.kp_swing * (q_des - q) + g_.kd_swing * (qd_des - qd);
  }
  return tau;
}

// Clamps leg i's torque to its limits and commands it; true when a joint saturated.
bool SimulationRun::apply_torque(int i, Vector3d tau) {
  bool saturated = false;
  for (int j = 0; j < 3; ++j) {
    const double lim = model_.legs[i].torque_limit[j];
    if (std::abs(tau[j]) > lim) {
      saturated = true;
      rep_.saturated_time[i][j] += o_.dt;
      tau[j] = std::clamp(tau[j], -lim, lim);
    }
    rep_.torque_max[i][j] = std::max(rep_.torque_max[i][j], std::abs(tau[j]));
    d_->ctrl[3 * i + j] = tau[j];
  }
  tau_applied_[i] = tau;
  return saturated;
}

// --- Verdict ---

// The run's figures from what the steps accumulated.
void SimulationRun::summarise() {
  rep_.duration = rep_.unstable ? rep_.unstable_t - t0_ : d_->time;
  rep_.realtime_factor = rep_.wall_s > 0 ? rep_.duration / rep_.wall_s : 0.0;
  if (!rep_.replan_wall_s.empty()) {
    median_and_max(rep_.replan_wall_s, &rep_.replan_wall_median, &rep_.replan_wall_max);
    median_and_max(rep_.replan_cpu_s, &rep_.replan_cpu_median, &rep_.replan_cpu_max);
  }
  if (!rep_.replan_iterations.empty())
    median_and_max(rep_.replan_iterations, &rep_.replan_iterations_median,
                   &rep_.replan_iterations_max);
  const int n_eval = rep_.steps + 1;
  rep_.position_rms = std::sqrt(sq_err_sum_ / n_eval);
  rep_.saturation_fraction = rep_.duration > 0 ? saturated_s_ / rep_.duration : 0.0;
  for (const auto& s : rep_.stances) {
    if (rep_.fell && s.t_start > rep_.fall_t) continue;
    if (!s.touched_down) {
      if (s.t_end - s.t_start > 0.05 && s.t_start < t0_ + rep_.duration) ++rep_.missed_touchdowns;
      continue;
    }
    rep_.slip_max = std::max(rep_.slip_max, s.slip);
    rep_.centre_drift_max = std::max(rep_.centre_drift_max, s.centre_drift);
    rep_.touchdown_error_max = std::max(rep_.touchdown_error_max, s.touchdown_error);
  }
  for (double x : rep_.shin_impulse) rep_.shin_impulse_max = std::max(rep_.shin_impulse_max, x);
}

// The end stop pressed hardest (its impulse and time go into the report); its joint's name.
std::string SimulationRun::worst_end_stop() {
  std::string limit_joint;
  static const char* kJoints[3] = {"HAA", "HFE", "KFE"};
  for (int i = 0; i < n_legs_; ++i)
    for (int j = 0; j < 3; ++j)
      if (rep_.joint_limit_impulse[i][j] > rep_.joint_limit_impulse_max) {
        rep_.joint_limit_impulse_max = rep_.joint_limit_impulse[i][j];
        rep_.joint_limit_max_s = rep_.joint_limit_time[i][j];
        limit_joint = model_.legs[i].name + " " + kJoints[j];
      }
  return limit_joint;
}

// Verdict. An unstable run judges nothing after its instability (stances it never reached,
// torques of a limp robot): it fails with that reason alone.
void SimulationRun::judge() {
  const std::string limit_joint = worst_end_stop();
  if (!rep_.unstable) fail_non_finite_figures(t0_, &rep_);
  if (rep_.unstable) {
    rep_.verdict = "fail";
    return;
  }
  const auto& th = o_.thresholds;
  auto warn = [&](bool bad, const std::string& what) {
    if (bad) rep_.reasons.push_back(what);
  };
  auto str = [](double v) {
    std::ostringstream s;
    s.precision(3);
    s << v;
    return s.str();
  };
  const SimulationReport& r = rep_;
  warn(r.position_rms > th.position_rms_m, "base position error RMS " + str(r.position_rms) +
                                               " m (limit " + str(th.position_rms_m) + ")");
  warn(r.position_max > th.position_max_m, "base position error max " + str(r.position_max) +
                                               " m at t = " + str(r.position_max_t) +
                                               " s (limit " + str(th.position_max_m) + ")");
  warn(r.saturation_fraction > th.saturation_fraction,
       "torque saturated " + str(100 * r.saturation_fraction) + " % of the time (limit " +
           str(100 * th.saturation_fraction) + " %)");
  warn(r.slip_max > th.slip_m,
       "foot slip " + str(r.slip_max) + " m in a stance (limit " + str(th.slip_m) + ")");
  warn(r.touchdown_error_max > th.touchdown_error_m,
       "touchdown error " + str(r.touchdown_error_max) + " m (limit " +
           str(th.touchdown_error_m) + ")");
  warn(r.missed_touchdowns > 0,
       std::to_string(r.missed_touchdowns) + " planned stance(s) never touched the terrain");
  warn(r.shin_impulse_max >= th.shin_impulse_Ns, "shin contact impulse " +
                                                     str(r.shin_impulse_max) + " N s (limit " +
                                                     str(th.shin_impulse_Ns) + ")");
  warn(r.joint_limit_impulse_max > th.joint_limit_impulse_Nms,
       limit_joint + " pressed against its range's end stop: " + str(r.joint_limit_impulse_max) +
           " N m s over " + str(r.joint_limit_max_s) + " s (limit " +
           str(th.joint_limit_impulse_Nms) + " N m s)");
  const int contacts_full = d_->warning[mjWARN_CONTACTFULL].number;
  const int constraints_full = d_->warning[mjWARN_CNSTRFULL].number;
  warn(contacts_full + constraints_full > 0,
       "MuJoCo's contact or constraint buffer was full in " +
           std::to_string(contacts_full + constraints_full) +
           " step(s): contacts were dropped, the physics is not faithful there");
  rep_.verdict = rep_.fell ? "fail" : (rep_.reasons.empty() ? "pass" : "warn");
}

}  // namespace

SimulationReport simulate(const robot::RobotModel& model, const planner::Trajectory& plan,
                          const terrain::HeightField& scene, const TerrainMjcf& terrain,
                          const SimulationOptions& o) {
  validate_simulation(model, plan, o);
  require_free_base(model);
  return SimulationRun(model, plan, scene, terrain, o).run();
}

}  // namespace terrastride::simulation::internal
