// Plan execution in MuJoCo (simulation/include/terrastride/simulation/simulation.hpp): the model
// built from the robot and the terrain (MJCF, loaded), the options and plan checked, the public
// calls and the margin search. A run itself (stepping, controller, verdict) is
// simulation_run.cpp's.
#include "terrastride/simulation/simulation.hpp"

#include <mujoco/mujoco.h>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <Eigen/LU>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <ctime>
#include <functional>
#include <limits>
#include <map>
#include <memory>
#include <mutex>
#include <sstream>

#include "terrastride/collision/checks.hpp"
#include "terrastride/robot/leg_kinematics.hpp"
#include "simulation_model.hpp"

namespace terrastride::simulation {

using Eigen::Matrix3d;
using Eigen::Vector3d;
using namespace internal;

namespace internal {

std::string fmt(double v) {
  std::ostringstream s;
  s.precision(17);
  s << v;
  return s.str();
}
std::string fmt(const Vector3d& v) {
  return fmt(v.x()) + " " + fmt(v.y()) + " " + fmt(v.z());
}
std::string fmt_short(double v) {
  std::ostringstream s;
  s.precision(4);
  s << v;
  return s.str();
}

}  // namespace internal

namespace {

// A leg link's inertia about the base origin (base frame) at joint angles q.
struct LinkPose {
  Vector3d com;
  Matrix3d rotation;
};

std::array<LinkPose, 3> link_poses(const robot::LegModel& leg, const Vector3d& q) {
  // The chain of leg_kinematics.cpp (leg_frames): each link's frame and its centre of mass.
  const robot::LegFrames fr = robot::leg_frames(leg, q);
  std::array<LinkPose, 3> poses;
  for (int i = 0; i < 3; ++i)
    poses[i] = LinkPose{fr.origin[i] + fr.rotation[i] * leg.links[i].com, fr.rotation[i]};
  return poses;
}

// Joint angles that put each foot sphere's centre (nominal foot + r z) in place.
std::vector<Vector3d> nominal_joint_angles(const robot::RobotModel& model) {
  std::vector<Vector3d> q;
  for (const auto& leg : model.legs) {
    const auto ik =
        robot::inverse_kinematics(leg, leg.nominal_foot + Vector3d(0, 0, model.foot_radius));
    if (ik.status == robot::IkStatus::unreachable)
      throw SimulationError(model.source_file + ": nominal stance: " + ik.message);
    q.push_back(ik.q);
  }
  return q;
}

std::string full_inertia(const Matrix3d& i) {
  return fmt(i(0, 0)) + " " + fmt(i(1, 1)) + " " + fmt(i(2, 2)) + " " + fmt(i(0, 1)) + " " +
         fmt(i(0, 2)) + " " + fmt(i(1, 2));
}

// MuJoCo wants a strictly positive-definite inertia satisfying the triangle inequality: the rod
// links of the robot file have a near-zero axial inertia, kept as given but floored.
Matrix3d floor_inertia(const Matrix3d& i) {
  Matrix3d out = i;
  for (int k = 0; k < 3; ++k) out(k, k) = std::max(out(k, k), 1e-6);
  return out;
}

// Geom classes: the terrain collides with the robot; robot parts do not collide with each other
// (the planner does not model self-collision; the post-hoc checks do not either).
const char* kRobotGeom = "contype=\"1\" conaffinity=\"0\"";
const char* kTerrainGeom = "contype=\"0\" conaffinity=\"1\"";

std::string robot_body(const robot::RobotModel& model, double mass_scale, const Vector3d& pos,
                       const Eigen::Quaterniond& quat) {
  const TrunkInertia trunk = trunk_inertia(model);
  std::ostringstream x;
  x << "<body name=\"trunk\" pos=\"" << fmt(pos) << "\" quat=\"" << fmt(quat.w()) << " "
    << fmt(quat.x()) << " " << fmt(quat.y()) << " " << fmt(quat.z()) << "\">\n"
    << "<freejoint name=\"root\"/>\n"
    << "<inertial pos=\"" << fmt(trunk.com) << "\" mass=\"" << fmt(trunk.mass * mass_scale)
    << "\" fullinertia=\"" << full_inertia(trunk.inertia * mass_scale) << "\"/>\n"
    << "<site name=\"base\" pos=\"0 0 0\"/>\n";
  // The trunk's collision box is the robot file's (`trunk: none`: no trunk geometry).
  if (model.trunk)
    x << "<geom name=\"trunk\" type=\"box\" pos=\"" << fmt(model.trunk->center) << "\" size=\""
      << fmt(model.trunk->half_size()) << "\" " << kRobotGeom << "/>\n";
  for (const auto& leg : model.legs) {
    const std::string n = leg.name;
    const double r_foot = model.foot_radius;
    // The shin capsule stops short of the foot sphere's centre by the foot radius plus its own:
    // its end cap then stays above the sphere's lowest point for any shin pitch, so a shin contact
    // is a real contact of the lower leg, not the foot.
    const double shin_end = leg.l2 - (r_foot + leg.shin_radius);
    // The leg's general geometry (robot_model.hpp, LegModel): every body frame is parallel to the
    // trunk's at q = 0, so the offsets and axes go in as they are. The in-plane leg (HyQ) gives
    // (0, 0, -l) and the axes (-side, 0, 0), (0, 1, 0) and writes what it always wrote.
    const Vector3d& d0 = leg.joint_offset[0];
    const Vector3d& d1 = leg.joint_offset[1];
    const Vector3d& d2 = leg.joint_offset[2];
    const Vector3d shin_tip = d2 / leg.l2 * shin_end;
    const auto axis = [&](int j) {
      if (leg.shape == robot::LegShape::in_plane)
        return j == 0 ? std::to_string(-leg.side) + " 0 0" : std::string("0 1 0");
      return fmt(leg.joint_axis[j]);
    };
    x << "<body name=\"" << n << "_hip\" pos=\"" << fmt(leg.haa_origin) << "\">\n"
      << "<joint name=\"" << n << "_HAA\" type=\"hinge\" axis=\"" << axis(0) << "\" range=\""
      << fmt(leg.q_min[0]) << " " << fmt(leg.q_max[0]) << "\"/>\n"
      << "<inertial pos=\"" << fmt(leg.links[0].com) << "\" mass=\"" << fmt(leg.links[0].mass)
      << "\" fullinertia=\"" << full_inertia(floor_inertia(leg.links[0].inertia)) << "\"/>\n"
      << "<body name=\"" << n << "_upper\" pos=\"" << fmt(d0) << "\">\n"
      << "<joint name=\"" << n << "_HFE\" type=\"hinge\" axis=\"" << axis(1) << "\" range=\""
      << fmt(leg.q_min[1]) << " " << fmt(leg.q_max[1]) << "\"/>\n"
      << "<inertial pos=\"" << fmt(leg.links[1].com) << "\" mass=\"" << fmt(leg.links[1].mass)
      << "\" fullinertia=\"" << full_inertia(floor_inertia(leg.links[1].inertia)) << "\"/>\n"
      << "<geom name=\"" << n << "_thigh\" type=\"capsule\" fromto=\"0 0 0 " << fmt(d1)
      << "\" size=\"" << fmt(leg.thigh_radius) << "\" " << kRobotGeom << "/>\n"
      << "<body name=\"" << n << "_lower\" pos=\"" << fmt(d1) << "\">\n"
      << "<joint name=\"" << n << "_KFE\" type=\"hinge\" axis=\"" << axis(2) << "\" range=\""
      << fmt(leg.q_min[2]) << " " << fmt(leg.q_max[2]) << "\"/>\n"
      << "<inertial pos=\"" << fmt(leg.links[2].com) << "\" mass=\"" << fmt(leg.links[2].mass)
      << "\" fullinertia=\"" << full_inertia(floor_inertia(leg.links[2].inertia)) << "\"/>\n"
      << "<geom name=\"" << n << "_shin\" type=\"capsule\" fromto=\"0 0 0 " << fmt(shin_tip)
      << "\" size=\"" << fmt(leg.shin_radius) << "\" " << kRobotGeom << "/>\n"
      << "<geom name=\"" << n << "_foot\" type=\"sphere\" pos=\"" << fmt(d2)
      << "\" size=\"" << fmt(r_foot) << "\" " << kRobotGeom << "/>\n"
      << "<site name=\"" << n << "_foot\" pos=\"" << fmt(d2) << "\"/>\n"
      << "</body>\n</body>\n</body>\n";
  }
  x << "</body>\n";
  return x.str();
}

std::string actuators(const robot::RobotModel& model) {
  std::ostringstream x;
  x << "<actuator>\n";
  static const char* kJoints[3] = {"HAA", "HFE", "KFE"};
  for (const auto& leg : model.legs)
    for (int j = 0; j < 3; ++j)
      x << "<motor name=\"" << leg.name << "_" << kJoints[j] << "\" joint=\"" << leg.name << "_"
        << kJoints[j] << "\" gear=\"1\" ctrllimited=\"true\" ctrlrange=\""
        << fmt(-leg.torque_limit[j]) << " " << fmt(leg.torque_limit[j]) << "\"/>\n";
  x << "</actuator>\n";
  return x.str();
}

TerrainMjcf scene_mjcf(const terrain::Scene& scene) {
  TerrainMjcf t;
  std::ostringstream x;
  x << "<geom name=\"ground\" type=\"plane\" size=\"0 0 1\" pos=\"0 0 " << fmt(scene.ground_z())
    << "\" " << kTerrainGeom << "/>\n";
  // Every box, overhangs (shelves, treads overhead) too: a trunk driven into one meets it. Their
  // geoms are named apart so a contact report says which is which.
  int k = 0, overhead = 0;
  for (size_t i = 0; i < scene.boxes().size(); ++i) {
    const auto& b = scene.boxes()[i];
    const Vector3d c = 0.5 * (b.lo + b.hi), h = 0.5 * (b.hi - b.lo);
    const std::string name = scene.is_overhang(i) ? "overhang" + std::to_string(overhead++)
                                                  : "box" + std::to_string(k++);
    x << "<geom name=\"" << name << "\" type=\"box\" pos=\"" << fmt(c) << "\" size=\"" << fmt(h)
      << "\" " << kTerrainGeom << "/>\n";
  }
  t.geoms = x.str();
  t.terrain_geoms = 1 + static_cast<int>(scene.boxes().size());
  t.description =
      "scene " + scene.name() + " (" + std::to_string(scene.boxes().size()) + " boxes on a plane" +
      (overhead > 0 ? ", " + std::to_string(overhead) + " of them overhead)" : std::string(")"));
  return t;
}

// A scanned map as a MuJoCo heightfield over a plane at its lowest height. The heights are the
// surface the planner plans on: the smoothed `surface` layer (layers/surface.npy) when the map has
// one (scanned maps; the planner's field is its B-spline approximant), else the elevation
// (rasterised scenes, maps of earlier versions). Raw elevations would put the sensor noise the
// planner never saw under the feet. MuJoCo's heightfield vertices span [-rx, rx] x [-ry, ry]
// around the geom, rows along y, heights normalised to [0, 1] times the size's elevation: the
// grid (x-major, cell centres) is transposed into rows and its vertices put on the cell centres.
// Non-finite heights take the highest height of the map (conservative: more clearance needed,
// never a hole to step in); cells the map filled itself (observed 0) are counted with them.
TerrainMjcf map_mjcf(const terrain::TerrainMap& map) {
  const auto& g = map.grid();
  const auto& geo = g.geometry;
  if (geo.nx < 2 || geo.ny < 2)
    throw SimulationError("terrain map: a heightfield needs at least 2 x 2 cells");
  const bool has_surface = g.surface.size() == geo.size();
  const std::vector<float>& source = has_surface ? g.surface : g.elevation;
  if (source.size() != geo.size())
    throw SimulationError("terrain map: the height layer does not have one value per cell");
  float lo = std::numeric_limits<float>::infinity(), hi = -lo;
  for (float e : source)
    if (std::isfinite(e)) {
      lo = std::min(lo, e);
      hi = std::max(hi, e);
    }
  if (!std::isfinite(lo)) throw SimulationError("terrain map: no finite height");
  auto heights = std::make_shared<std::vector<float>>(geo.size());
  TerrainMjcf t;
  for (int i = 0; i < geo.nx; ++i)
    for (int j = 0; j < geo.ny; ++j) {
      const size_t cell = static_cast<size_t>(i) * geo.ny + j;
      float e = source[cell];
      const bool unobserved = !g.observed.empty() && g.observed[cell] == 0;
      if (!std::isfinite(e)) e = hi;
      if (!std::isfinite(source[cell]) || unobserved) ++t.filled_cells;
      (*heights)[static_cast<size_t>(j) * geo.nx + i] = e;  // row j (y), column i (x)
    }
  const double range = std::max(double(hi - lo), 1e-3);
  const double rx = 0.5 * geo.resolution * (geo.nx - 1), ry = 0.5 * geo.resolution * (geo.ny - 1);
  const Eigen::Vector2d centre =
      geo.origin + 0.5 * geo.resolution * Eigen::Vector2d(geo.nx, geo.ny);
  std::ostringstream a, x;
  a << "<hfield name=\"terrain\" nrow=\"" << geo.ny << "\" ncol=\"" << geo.nx << "\" size=\""
    << fmt(rx) << " " << fmt(ry) << " " << fmt(range) << " 0.1\"/>\n";
  x << "<geom name=\"ground\" type=\"plane\" size=\"0 0 1\" pos=\"0 0 " << fmt(lo - 1e-3) << "\" "
    << kTerrainGeom << "/>\n"
    << "<geom name=\"map\" type=\"hfield\" hfield=\"terrain\" pos=\"" << fmt(centre.x()) << " "
    << fmt(centre.y()) << " " << fmt(lo) << "\" " << kTerrainGeom << "/>\n";
  t.asset = a.str();
  t.geoms = x.str();
  t.heightfield = true;
  const float base = lo;
  t.after_load = [heights, base, range](mjModel* m) {
    const int adr = m->hfield_adr[0];
    const size_t n = heights->size();
    for (size_t k = 0; k < n; ++k)
      m->hfield_data[adr + k] = static_cast<float>(((*heights)[k] - base) / range);
  };
  std::ostringstream d;
  d << map.describe() << ": its " << (has_surface ? "smoothed surface" : "elevation") << " as a "
    << geo.nx << " x " << geo.ny << " heightfield (" << geo.resolution << " m cells, "
    << t.filled_cells << " filled cells)";
  t.description = d.str();
  return t;
}

// MuJoCo's contact and constraint buffers for this robot on this terrain, as [nconmax, njmax].
// A heightfield's are MuJoCo 2.2.2's defaults raised so a scan does not fill them (100 contacts
// filled up: a foot sphere or a shin meets several prisms): 1000 contacts, 3100 rows. 2.2.2
// allocates and clears dense njmax x njmax matrices (3100: 77 MB, 0.2 s of page faults per run,
// more than a 11 s plan's physics), so a scene's buffers hold what its geoms can make: 8 contacts
// per robot geom and terrain geom, 3 rows each (elliptic, condim 3), plus a row per joint limit.
// A run that fills either buffer says so in its verdict (dropped contacts).
std::pair<int, int> contact_buffers(const robot::RobotModel& model, const TerrainMjcf* terrain) {
  constexpr int kHeightfieldContacts = 1000, kHeightfieldRows = 3100;
  if (terrain && terrain->heightfield) return {kHeightfieldContacts, kHeightfieldRows};
  const int robot_geoms = (model.trunk ? 1 : 0) + 3 * static_cast<int>(model.legs.size());
  const int terrain_geoms = terrain ? std::max(terrain->terrain_geoms, 1) : 1;
  const int contacts = std::min(kHeightfieldContacts, 8 * robot_geoms * terrain_geoms);
  const int rows = std::min(kHeightfieldRows,
                            3 * contacts + 3 * static_cast<int>(model.legs.size()) + 16);
  return {contacts, rows};
}

}  // namespace

namespace internal {

std::string full_mjcf(const robot::RobotModel& model, const TerrainMjcf* terrain,
                      const SimulationOptions& o, const Vector3d& pos,
                      const Eigen::Quaterniond& quat) {
  const auto [nconmax, njmax] = contact_buffers(model, terrain);
  std::ostringstream x;
  // Elliptic cones with a high impratio: the default pyramid lets a loaded foot creep several
  // millimetres per stance, which the slip check would blame on the plan.
  x << "<mujoco model=\"" << model.name << "\">\n"
    << "<compiler angle=\"radian\" autolimits=\"true\"/>\n"
    << "<size nconmax=\"" << nconmax << "\" njmax=\"" << njmax << "\"/>\n"
    << "<option timestep=\"" << fmt(o.dt) << "\" gravity=\"0 0 " << fmt(-kGravity)
    << "\" cone=\"elliptic\" impratio=\"100\"/>\n"
    << "<default><geom solref=\"0.005 1\" friction=\"" << fmt(o.friction)
    << " 0.005 0.0001\" condim=\"3\"/></default>\n";
  if (terrain && !terrain->asset.empty()) x << "<asset>\n" << terrain->asset << "</asset>\n";
  x << "<worldbody>\n";
  if (terrain) x << terrain->geoms;
  x << robot_body(model, o.mass_scale, pos, quat) << "</worldbody>\n"
    << actuators(model) << "</mujoco>\n";
  return x.str();
}

std::unique_ptr<Model> load_model(const std::string& xml) {
  auto vfs = std::make_unique<mjVFS>();  // ~2 MB: not on the stack
  mj_defaultVFS(vfs.get());
  const char* name = "terrastride_model.xml";
  if (mj_makeEmptyFileVFS(vfs.get(), name, static_cast<int>(xml.size())) != 0)
    throw SimulationError("MuJoCo: cannot create the in-memory model file");
  const int idx = mj_findFileVFS(vfs.get(), name);
  std::memcpy(vfs->filedata[idx], xml.data(), xml.size());
  char error[1000] = "";
  auto model = std::make_unique<Model>();
  {
    // The XML parser and compiler of MuJoCo 2.2.2 are not documented as re-entrant; loading takes
    // milliseconds, so concurrent simulations (the service's workers) load one at a time.
    static std::mutex load_mutex;
    const std::lock_guard<std::mutex> lock(load_mutex);
    // MuJoCo's default warning handler prints and appends to MUJOCO_LOG.TXT in the working
    // directory (an unstable run wrote one wherever `simulate` ran). The warnings that matter are
    // counted in mjData::warning, which the run reads (became_unstable, the contact counts).
    mju_user_warning = [](const char*) {};
    model->m = mj_loadXML(name, vfs.get(), error, sizeof(error));
  }
  mj_deleteVFS(vfs.get());
  if (!model->m) throw SimulationError(std::string("MuJoCo refused the generated model: ") + error);
  model->d = mj_makeData(model->m);
  return model;
}

}  // namespace internal

namespace {

void validate_options(const SimulationOptions& o) {
  using L = SimulationLimits;
  if (!(o.dt >= L::kMinDt && o.dt <= L::kMaxDt))
    throw SimulationError("dt: must be in [" + fmt(L::kMinDt) + ", " + fmt(L::kMaxDt) + "] s");
  if (!(o.mass_scale > L::kMinMassScale && o.mass_scale < L::kMaxMassScale))
    throw SimulationError("mass scale: must be in (" + fmt(L::kMinMassScale) + ", " +
                          fmt(L::kMaxMassScale) + ")");
  if (!(o.friction > 0 && o.friction < L::kMaxFriction))
    throw SimulationError("friction: must be in (0, " + fmt(L::kMaxFriction) + ")");
  if (o.pushes.size() > L::kMaxPushes)
    throw SimulationError("pushes: at most " + std::to_string(L::kMaxPushes));
  for (std::size_t k = 0; k < o.pushes.size(); ++k) {
    const Push& p = o.pushes[k];
    const std::string at = "push " + std::to_string(k + 1) + ": ";
    if (!std::isfinite(p.t)) throw SimulationError(at + "its start time is not finite");
    if (!(p.duration >= 0 && p.duration <= L::kMaxPushDuration))
      throw SimulationError(at + "its duration must be in [0, " + fmt(L::kMaxPushDuration) + "] s");
    if (!(p.force.allFinite() && p.force.stableNorm() <= L::kMaxPushForce))
      throw SimulationError(at + "its force (" + fmt_short(p.force.stableNorm()) + " N) must be finite and at most " +
                            fmt_short(L::kMaxPushForce) + " N");
  }
  if (!(o.replan_every >= 0 && o.replan_every <= 100))
    throw SimulationError("replan every: must be within [0, 100] s (0 = open loop)");
  if (o.replan_every > 0) {
    if (o.replan_every < o.dt)
      throw SimulationError("replan every: must be at least the time step (" + fmt(o.dt) + " s)");
    if (!o.replanner) throw SimulationError("replan every: needs a re-planner");
    if (!(o.replan_latency >= 0 && o.replan_latency < o.replan_every))
      throw SimulationError("replan latency: must be within [0, replan every)");
    if (!std::isfinite(o.replan_from))
      throw SimulationError("replan from: must be a finite time (s)");
  }
}

void validate_plan(const robot::RobotModel& model, const planner::Trajectory& plan) {
  using L = SimulationLimits;
  try {
    collision::validate_trajectory(model, plan);
  } catch (const collision::TrajectoryError& e) {
    throw SimulationError(std::string("plan: ") + e.what());
  }
  if (plan.samples.size() < 2) throw SimulationError("plan: fewer than two samples");
  const double t0 = plan.samples.front().t, t1 = plan.samples.back().t;
  // 1 us of slack: a 120 s plan's sample times summed in steps may end 2e-11 s beyond 120 s.
  if (!(std::abs(t0) <= L::kMaxPlanDuration && t1 - t0 <= L::kMaxPlanDuration + 1e-6))
    throw SimulationError("plan: samples from t = " + fmt_short(t0) + " to " + fmt_short(t1) +
                          " s; a plan starts within " + fmt_short(L::kMaxPlanDuration) +
                          " s of 0 and lasts at most that long (what the planner plans)");
  const Vector3d origin = plan.samples.front().base.position;
  // stableNorm: the squares of 1e300 overflow.
  if (!(origin.stableNorm() <= L::kMaxPlanOrigin))
    throw SimulationError("plan: samples[0].base.position is " + fmt_short(origin.stableNorm()) +
                          " m from the origin, beyond " + fmt_short(L::kMaxPlanOrigin) + " m");
  const auto reach = [&](const Vector3d& p, std::size_t k, const std::string& what) {
    if (!((p - origin).stableNorm() <= L::kMaxPlanReach))
      throw SimulationError("plan: samples[" + std::to_string(k) + "]." + what + " is " +
                            fmt_short((p - origin).stableNorm()) + " m from the first base position, beyond " +
                            fmt_short(L::kMaxPlanReach) + " m");
  };
  for (std::size_t k = 0; k < plan.samples.size(); ++k) {
    const auto& s = plan.samples[k];
    reach(s.base.position, k, "base.position");
    for (std::size_t f = 0; f < s.feet.size(); ++f)
      reach(s.feet[f].position, k, "feet[" + std::to_string(f) + "].position");
  }
}

}  // namespace

void validate_simulation(const robot::RobotModel& model, const planner::Trajectory& plan,
                         const SimulationOptions& options) {
  validate_options(options);
  validate_plan(model, plan);
}

long long simulation_steps(const planner::Trajectory& plan, double dt) {
  if (plan.samples.size() < 2 || !(dt > 0)) return 0;
  const double span = plan.samples.back().t - plan.samples.front().t;
  // A millionth of a step of slack: times summed in steps carry rounding (120 s of 0.01 s steps
  // sum to 120.00000000002 s, which is 60000.00000001 steps of 2 ms, not 60001).
  return static_cast<long long>(std::ceil(span / dt - 1e-6));
}

TrunkInertia trunk_inertia(const robot::RobotModel& model) {
  const std::vector<Vector3d> q = nominal_joint_angles(model);
  double leg_mass = 0.0;
  Vector3d leg_moment = Vector3d::Zero();
  Matrix3d leg_inertia = Matrix3d::Zero();  // about the base origin
  for (size_t i = 0; i < model.legs.size(); ++i) {
    const auto& leg = model.legs[i];
    const auto poses = link_poses(leg, q[i]);
    for (int k = 0; k < 3; ++k) {
      const auto& link = leg.links[k];
      const Vector3d c = poses[k].com;
      leg_mass += link.mass;
      leg_moment += link.mass * c;
      leg_inertia += poses[k].rotation * link.inertia * poses[k].rotation.transpose() +
                     link.mass * (c.squaredNorm() * Matrix3d::Identity() - c * c.transpose());
    }
  }
  TrunkInertia t;
  t.mass = model.mass - leg_mass;
  if (t.mass <= 0)
    throw SimulationError(model.source_file + ": the legs' links weigh more than the body mass");
  t.com = -leg_moment / t.mass;
  t.inertia = model.inertia - leg_inertia -
              t.mass * (t.com.squaredNorm() * Matrix3d::Identity() - t.com * t.com.transpose());
  const Eigen::SelfAdjointEigenSolver<Matrix3d> eig(t.inertia);
  if (eig.eigenvalues().minCoeff() <= 0)
    throw SimulationError(model.source_file +
                          ": the body inertia minus the legs' share is not positive definite");
  return t;
}

std::string robot_mjcf(const robot::RobotModel& model, double mass_scale) {
  SimulationOptions o;
  o.mass_scale = mass_scale;
  return full_mjcf(model, nullptr, o, Vector3d::Zero(), Eigen::Quaterniond::Identity());
}

std::vector<std::vector<Vector3d>> mujoco_foot_positions(
    const robot::RobotModel& model, const std::vector<std::vector<Vector3d>>& q) {
  auto sim = load_model(robot_mjcf(model));
  std::vector<std::vector<Vector3d>> out;
  for (const auto& config : q) {
    if (config.size() != model.legs.size())
      throw SimulationError("one joint vector per leg expected");
    for (size_t i = 0; i < config.size(); ++i)
      for (int j = 0; j < 3; ++j) sim->d->qpos[7 + 3 * i + j] = config[i][j];
    mj_kinematics(sim->m, sim->d);
    std::vector<Vector3d> feet;
    for (const auto& leg : model.legs) {
      const int id = mj_name2id(sim->m, mjOBJ_SITE, (leg.name + "_foot").c_str());
      feet.emplace_back(sim->d->site_xpos[3 * id], sim->d->site_xpos[3 * id + 1],
                        sim->d->site_xpos[3 * id + 2]);
    }
    out.push_back(feet);
  }
  return out;
}

Vector3d mujoco_com(const robot::RobotModel& model, const std::vector<Vector3d>& q) {
  auto sim = load_model(robot_mjcf(model));
  for (size_t i = 0; i < q.size() && i < model.legs.size(); ++i)
    for (int j = 0; j < 3; ++j) sim->d->qpos[7 + 3 * i + j] = q[i][j];
  mj_forward(sim->m, sim->d);
  const int trunk = mj_name2id(sim->m, mjOBJ_BODY, "trunk");
  return Vector3d(sim->d->subtree_com[3 * trunk], sim->d->subtree_com[3 * trunk + 1],
                  sim->d->subtree_com[3 * trunk + 2]);
}

std::vector<Vector3d> nominal_stance(const robot::RobotModel& model) {
  return nominal_joint_angles(model);
}

SimulationReport simulate_plan(const robot::RobotModel& model, const planner::Trajectory& plan,
                               const terrain::Scene& scene, const SimulationOptions& options) {
  return simulate(model, plan, scene, scene_mjcf(scene), options);
}

SimulationReport simulate_plan(const robot::RobotModel& model, const planner::Trajectory& plan,
                               const terrain::TerrainMap& map, const SimulationOptions& options) {
  return simulate(model, plan, map, map_mjcf(map), options);
}

SimulationReport simulate_plan(const robot::RobotModel& model, const planner::Trajectory& plan,
                               const terrain::HeightField& terrain,
                               const SimulationOptions& options) {
  if (const auto* scene = dynamic_cast<const terrain::Scene*>(&terrain))
    return simulate_plan(model, plan, *scene, options);
  if (const auto* map = dynamic_cast<const terrain::TerrainMap*>(&terrain))
    return simulate_plan(model, plan, *map, options);
  throw SimulationError("terrain " + terrain.describe() +
                        ": only scenes and terrain maps can be simulated");
}

namespace {

// The largest amount a in [0, ceiling] that `run_at(a)` survives (verdict not "fail"), given that
// 0 does: doubling from `start` until a failure brackets it, then bisection to `tolerance`.
MarginSide search_margin(const std::function<SimulationReport(double)>& run_at, double start,
                         double ceiling, double tolerance) {
  MarginSide side;
  double lo = 0.0, hi = -1.0;
  for (double a = std::min(start, ceiling);; a = std::min(2 * a, ceiling)) {
    const SimulationReport r = run_at(a);
    if (r.verdict == "fail") {
      hi = a;
      side.failure = r.reasons.empty() ? "fail" : r.reasons.front();
      break;
    }
    lo = a;
    if (a >= ceiling) break;
  }
  while (hi >= 0 && hi - lo > tolerance) {
    const double mid = 0.5 * (lo + hi);
    const SimulationReport r = run_at(mid);
    if (r.verdict == "fail") {
      hi = mid;
      side.failure = r.reasons.empty() ? "fail" : r.reasons.front();
    } else {
      lo = mid;
    }
  }
  side.survived = lo;
  side.failed = hi;
  return side;
}

// The most runs search_margin makes: the doublings from `start` to `ceiling`, then the
// bisections of a bracket at most half the ceiling wide down to `tolerance`.
int search_max_runs(double start, double ceiling, double tolerance) {
  int runs = 1;
  for (double a = std::min(start, ceiling); a < ceiling; a = std::min(2 * a, ceiling)) ++runs;
  for (double width = ceiling; width > tolerance; width *= 0.5) ++runs;
  return runs;
}

}  // namespace

int margin_max_runs(const MarginOptions& margin) {
  int runs = 1 + 2 * search_max_runs(100.0, margin.push_force_max, margin.push_tolerance);
  if (margin.mass)
    runs += search_max_runs(0.1, margin.mass_scale_max - 1.0, margin.mass_tolerance) +
            search_max_runs(0.1, 1.0 - margin.mass_scale_min, margin.mass_tolerance);
  return runs;
}

MarginReport simulation_margin(const robot::RobotModel& model, const planner::Trajectory& plan,
                               const terrain::HeightField& terrain,
                               const SimulationOptions& options, const MarginOptions& margin) {
  if (!(margin.push_time_fraction >= 0 && margin.push_time_fraction < 1))
    throw SimulationError("margin: the push time fraction must be in [0, 1)");
  if (!(margin.push_duration > 0 && margin.push_duration <= 2))
    throw SimulationError("margin: the push duration must be in (0, 2] s");
  if (!(margin.push_force_max > 0 && margin.push_force_max <= 1e5) ||
      !(margin.push_tolerance > 0 && margin.push_tolerance < margin.push_force_max))
    throw SimulationError("margin: the push ceiling must be in (0, 1e5] N, the tolerance below it");
  if (!(margin.mass_scale_max > 1 && margin.mass_scale_min < 1 && margin.mass_scale_min > 0) ||
      !(margin.mass_tolerance > 0 && margin.mass_tolerance < 1))
    throw SimulationError("margin: mass scale limits must bracket 1, the tolerance in (0, 1)");
  if (plan.samples.size() < 2) throw SimulationError("plan: fewer than two samples");
  const auto wall0 = std::chrono::steady_clock::now();
  MarginReport r;
  r.options = margin;
  SimulationOptions base = options;
  base.record_dt = 0.0;
  auto run = [&](const SimulationOptions& o) {
    // Between runs too: a cancelled search must not start another (a run polls every 50 steps).
    if (o.stop_requested && o.stop_requested())
      throw SimulationCancelled("margin search stopped after " + std::to_string(r.runs) + " runs");
    ++r.runs;
    return simulate_plan(model, plan, terrain, o);
  };
  r.nominal_verdict = run(base).verdict;
  const double t0 = plan.samples.front().t, t1 = plan.samples.back().t;
  r.push_t = t0 + margin.push_time_fraction * (t1 - t0);
  r.push_duration = margin.push_duration;
  // The planned heading at the push: the nearest sample's yaw.
  const auto nearest =
      std::min_element(plan.samples.begin(), plan.samples.end(),
                       [&](const planner::TrajectorySample& a, const planner::TrajectorySample& b) {
                         return std::abs(a.t - r.push_t) < std::abs(b.t - r.push_t);
                       });
  const double yaw = nearest->base.euler_zyx[0];
  r.left = Vector3d(-std::sin(yaw), std::cos(yaw), 0.0);
  if (r.nominal_verdict != "fail") {
    for (const double sign : {1.0, -1.0}) {
      const MarginSide side = search_margin(
          [&](double force) {
            SimulationOptions o = base;
            o.pushes.push_back({r.push_t, sign * force * r.left, margin.push_duration});
            return run(o);
          },
          100.0, margin.push_force_max, margin.push_tolerance);
      (sign > 0 ? r.push_left : r.push_right) = side;
    }
    r.push_margin_N = std::min(r.push_left.survived, r.push_right.survived);
    r.push_margin_Ns = r.push_margin_N * margin.push_duration;
    r.push_at_ceiling = r.push_left.failed < 0 && r.push_right.failed < 0;
    if (margin.mass) {
      r.mass_searched = true;
      auto mass_side = [&](double sign, double ceiling) {
        MarginSide side = search_margin(
            [&](double error) {
              SimulationOptions o = base;
              o.mass_scale = base.mass_scale * (1.0 + sign * error);
              return run(o);
            },
            0.1, ceiling, margin.mass_tolerance);
        side.survived = 1.0 + sign * side.survived;
        if (side.failed >= 0) side.failed = 1.0 + sign * side.failed;
        return side;
      };
      r.mass_heavier = mass_side(1.0, margin.mass_scale_max - 1.0);
      r.mass_lighter = mass_side(-1.0, 1.0 - margin.mass_scale_min);
    }
  } else {
    r.mass_heavier.survived = r.mass_lighter.survived = 1.0;
  }
  r.wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - wall0).count();
  return r;
}

std::optional<ControllerOptions::ForceDistribution> force_distribution_named(
    const std::string& name) {
  if (name == "clipped") return ControllerOptions::ForceDistribution::clipped;
  if (name == "constrained") return ControllerOptions::ForceDistribution::constrained;
  return std::nullopt;
}

}  // namespace terrastride::simulation
