// Plan execution in MuJoCo (collision/include/terrastride/simulation/simulation.hpp).
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

namespace terrastride::simulation {
namespace {

using Eigen::Matrix3d;
using Eigen::Vector3d;

constexpr double kGravity = 9.81;

Matrix3d skew(const Vector3d& v) {
  Matrix3d s;
  s << 0, -v.z(), v.y(), v.z(), 0, -v.x(), -v.y(), v.x(), 0;
  return s;
}

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

std::string fmt(double v) {
  std::ostringstream s;
  s.precision(17);
  s << v;
  return s.str();
}
std::string fmt(const Vector3d& v) {
  return fmt(v.x()) + " " + fmt(v.y()) + " " + fmt(v.z());
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

// The terrain as MJCF: `asset` (inside <asset>) and `geoms` (world geoms), plus what to do with
// the loaded model (a heightfield's data is written after loading).
struct TerrainMjcf {
  std::string asset;
  std::string geoms;
  std::function<void(mjModel*)> after_load;
  int filled_cells = 0;
  std::string description;
  // Contact pairs a robot geom can make with the terrain geoms: a scene's few boxes and its plane
  // make at most 8 contacts per pair (box-box), a heightfield up to 50 per pair (prisms); 0: no
  // terrain (the robot alone).
  int terrain_geoms = 0;
  bool heightfield = false;
};

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

// The generated model, loaded through MuJoCo's virtual file system (2.2.2 has no
// mj_addBufferVFS: an empty VFS file is made and the text copied into it).
struct Model {
  mjModel* m = nullptr;
  mjData* d = nullptr;
  ~Model() {
    if (d) mj_deleteData(d);
    if (m) mj_deleteModel(m);
  }
};

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

// Spreads a trunk wrench (force, moment about the base) over the stance feet: the least-norm
// forces that produce it.
std::vector<Vector3d> spread_wrench(const Eigen::Matrix<double, 6, 1>& w,
                                    const std::vector<Vector3d>& lever) {
  const int n = static_cast<int>(lever.size());
  std::vector<Vector3d> out(n, Vector3d::Zero());
  if (n == 0) return out;
  Eigen::MatrixXd g(6, 3 * n);
  for (int i = 0; i < n; ++i) {
    g.block<3, 3>(0, 3 * i) = Matrix3d::Identity();
    g.block<3, 3>(3, 3 * i) = skew(lever[i]);
  }
  const Eigen::MatrixXd ggt = g * g.transpose() + 1e-6 * Eigen::MatrixXd::Identity(6, 6);
  const Eigen::VectorXd f = g.transpose() * ggt.ldlt().solve(w);
  for (int i = 0; i < n; ++i) out[i] = f.segment<3>(3 * i);
  return out;
}

// Projects a foot force into the cone |f_t| <= mu f_n about the normal n, with f_n >= 0.
Vector3d into_cone(const Vector3d& f, const Vector3d& n, double mu) {
  double fn = f.dot(n);
  if (fn <= 0) return Vector3d::Zero();
  Vector3d ft = f - fn * n;
  const double t = ft.norm();
  if (t > mu * fn) ft *= mu * fn / t;
  return fn * n + ft;
}

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
                                 next.fallback ? next.fallback_reason : std::string()});
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

std::string fmt_short(double v) {
  std::ostringstream s;
  s.precision(4);
  s << v;
  return s.str();
}

Vector3d terrain_normal(const terrain::HeightField& field, const Vector3d& p) {
  const auto s = field.sample(p.x(), p.y());
  return Vector3d(-s.gradient.x(), -s.gradient.y(), 1.0).normalized();
}

}  // namespace

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

namespace {

namespace {

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

}  // namespace

SimulationReport simulate(const robot::RobotModel& model, const planner::Trajectory& plan,
                          const terrain::HeightField& scene, const TerrainMjcf& terrain,
                          const SimulationOptions& o) {
  validate_simulation(model, plan, o);
  const int n_legs = static_cast<int>(model.legs.size());
  for (bool free : model.base_dof_free)
    if (!free)
      throw SimulationError("robot '" + model.name +
                            "': its base moves on restricted degrees of freedom (a slider); only "
                            "free-floating robots are simulated");
  const PlanView view(plan, n_legs);
  // Closed loop: the re-plan being tracked (its samples from 0 = `start` on the plan's axis) and
  // the one waiting for its latency; outside the tracked re-plan's span, the original plan.
  struct Tracked {
    std::unique_ptr<planner::Trajectory> plan;
    std::unique_ptr<PlanView> view;
    double start = 0.0, end = 0.0;
  };
  Tracked tracked, pending;
  double pending_from = 0.0;
  // The waiting re-plan becomes the tracked one once its latency has passed (at once without one).
  auto promote_pending = [&](double now) {
    if (!pending.view || now < pending_from - 1e-9) return;
    tracked = std::move(pending);
    pending = Tracked{};
  };
  const Replanner replanner = o.replan_every > 0 ? o.replanner() : Replanner();
  if (o.replan_every > 0 && !replanner) throw SimulationError("replan every: no re-planner made");
  // The plan the controller follows at t and the shift from the plan's axis to its own.
  auto view_for = [&](double t) -> std::pair<const PlanView*, double> {
    if (tracked.view && t >= tracked.start - 1e-9 && t <= tracked.end + 1e-9)
      return {tracked.view.get(), tracked.start};
    return {&view, 0.0};
  };
  auto plan_at = [&](double t) {
    const auto [v, shift] = view_for(t);
    return v->at(t - shift);
  };
  auto contact_at = [&](int i, double t) {
    const auto [v, shift] = view_for(t);
    return v->contact(i, t - shift);
  };
  const double r_foot = model.foot_radius;
  const double mu = o.friction;
  const ControllerOptions& c = o.controller;
  const ControllerGains g = c.gains ? *c.gains : controller_gains(model);

  // Initial state: the plan's first sample, legs by IK of its feet.
  const auto s0 = view.at(plan.samples.front().t);
  const Matrix3d rot0 = rotation_zyx(s0.euler);
  const Eigen::Quaterniond quat0(rot0);
  SimulationReport rep;
  rep.thresholds = o.thresholds;
  rep.gains = g;
  rep.dt = o.dt;
  rep.model_xml = full_mjcf(model, &terrain, o, s0.base_pos, quat0);
  rep.terrain = terrain.description;
  rep.filled_cells = terrain.filled_cells;
  auto sim = load_model(rep.model_xml);
  if (terrain.after_load) {
    terrain.after_load(sim->m);
    mj_forward(sim->m, sim->d);
  }
  mjModel* m = sim->m;
  mjData* d = sim->d;
  const int nv = m->nv;
  std::vector<mjtNum> jacp(3 * nv), full_m(nv * nv);

  std::vector<int> foot_site(n_legs), foot_geom(n_legs), shin_geom(n_legs), thigh_geom(n_legs);
  for (int i = 0; i < n_legs; ++i) {
    const std::string n = model.legs[i].name;
    foot_site[i] = mj_name2id(m, mjOBJ_SITE, (n + "_foot").c_str());
    foot_geom[i] = mj_name2id(m, mjOBJ_GEOM, (n + "_foot").c_str());
    shin_geom[i] = mj_name2id(m, mjOBJ_GEOM, (n + "_shin").c_str());
    thigh_geom[i] = mj_name2id(m, mjOBJ_GEOM, (n + "_thigh").c_str());
  }
  const int trunk_geom = mj_name2id(m, mjOBJ_GEOM, "trunk");
  const int trunk_body = mj_name2id(m, mjOBJ_BODY, "trunk");

  auto sphere_target = [&](const Vector3d& foot) {
    return Vector3d(foot + r_foot * terrain_normal(scene, foot));
  };
  // IK of the sphere centre over the planned foot point `foot` on a terrain of normal `n`.
  auto ik_in = [&](int i, const Vector3d& p_base, const Matrix3d& rot, const Vector3d& foot,
                   const Vector3d& n, const Vector3d& fallback) {
    const auto ik =
        robot::inverse_kinematics(model.legs[i], rot.transpose() * (foot + r_foot * n - p_base));
    return ik.status == robot::IkStatus::unreachable ? fallback : Vector3d(ik.q);
  };

  for (int k = 0; k < 3; ++k) d->qpos[k] = s0.base_pos[k];
  d->qpos[3] = quat0.w();
  d->qpos[4] = quat0.x();
  d->qpos[5] = quat0.y();
  d->qpos[6] = quat0.z();
  const Vector3d omega0_local = rot0.transpose() * s0.omega;
  for (int k = 0; k < 3; ++k) {
    d->qvel[k] = s0.base_vel[k];
    d->qvel[3 + k] = omega0_local[k];
  }
  std::vector<Vector3d> q_prev(n_legs);
  for (int i = 0; i < n_legs; ++i) {
    const auto ik = robot::inverse_kinematics(
        model.legs[i], rot0.transpose() * (sphere_target(s0.foot[i]) - s0.base_pos));
    if (ik.status == robot::IkStatus::unreachable)
      throw SimulationError("plan: first sample: " + ik.message);
    q_prev[i] = ik.q;
    for (int j = 0; j < 3; ++j) d->qpos[7 + 3 * i + j] = ik.q[j];
  }
  mj_forward(m, d);

  rep.torque_max.assign(n_legs, Vector3d::Zero());
  rep.saturated_time.assign(n_legs, Vector3d::Zero());
  rep.joint_limit_time.assign(n_legs, Vector3d::Zero());
  rep.joint_limit_impulse.assign(n_legs, Vector3d::Zero());
  rep.shin_impulse.assign(n_legs, 0.0);
  rep.thigh_impulse.assign(n_legs, 0.0);

  // Stances as executed.
  std::vector<std::vector<int>> stance_index(n_legs);
  for (int f = 0; f < n_legs; ++f)
    for (const auto& p : view.phases(f)) {
      if (!p.contact) continue;
      stance_index[f].push_back(static_cast<int>(rep.stances.size()));
      StanceReport s;
      s.foot = f;
      s.t_start = p.start;
      s.t_end = p.end;
      rep.stances.push_back(s);
    }
  std::vector<Vector3d> touchdown_point(rep.stances.size(), Vector3d::Zero());
  auto stance_at = [&](int f, double t) {
    for (int idx : stance_index[f])
      if (t >= rep.stances[idx].t_start && t < rep.stances[idx].t_end) return idx;
    return -1;
  };

  const double t0 = plan.samples.front().t;
  const double t_end = view.t_end();
  const int n_steps = static_cast<int>(simulation_steps(plan, o.dt));
  double sq_err_sum = 0.0, saturated_s = 0.0;
  double next_record = t0;
  double next_replan = t0 + o.replan_every;
  const auto wall0 = std::chrono::steady_clock::now();
  const double cpu0 = thread_cpu_seconds();
  std::vector<Vector3d> tau_applied(n_legs, Vector3d::Zero());

  for (int step = 0; step <= n_steps; ++step) {
    if (o.stop_requested && step % 50 == 0 && o.stop_requested())
      throw SimulationCancelled("simulation stopped at t = " + std::to_string(d->time + t0) + " s");
    const double t = d->time + t0;
    const Vector3d p(d->qpos[0], d->qpos[1], d->qpos[2]);
    const Matrix3d rot =
        Eigen::Quaterniond(d->qpos[3], d->qpos[4], d->qpos[5], d->qpos[6]).toRotationMatrix();
    const Vector3d v(d->qvel[0], d->qvel[1], d->qvel[2]);
    const Vector3d omega = rot * Vector3d(d->qvel[3], d->qvel[4], d->qvel[5]);

    // Contacts: per foot force (terrain on foot), shin/thigh/trunk normal force.
    std::vector<Vector3d> foot_force(n_legs, Vector3d::Zero());
    std::vector<bool> foot_contact(n_legs, false);
    std::vector<double> shin_f(n_legs, 0.0), thigh_f(n_legs, 0.0);
    double trunk_f = 0.0;
    for (int k = 0; k < d->ncon; ++k) {
      const mjContact& con = d->contact[k];
      mjtNum res[6];
      mj_contactForce(m, d, k, res);
      Eigen::Map<const Eigen::Matrix<mjtNum, 3, 3, Eigen::RowMajor>> frame(con.frame);
      // Force on geom2 (the normal points from geom1 to geom2); robot geoms take their side.
      const Vector3d f2 = frame.transpose() * Vector3d(res[0], res[1], res[2]);
      for (int i = 0; i < n_legs; ++i) {
        if (con.geom1 == foot_geom[i] || con.geom2 == foot_geom[i]) {
          foot_force[i] += con.geom2 == foot_geom[i] ? f2 : Vector3d(-f2);
          foot_contact[i] = true;
        }
        if (con.geom1 == shin_geom[i] || con.geom2 == shin_geom[i]) shin_f[i] += std::abs(res[0]);
        if (con.geom1 == thigh_geom[i] || con.geom2 == thigh_geom[i])
          thigh_f[i] += std::abs(res[0]);
      }
      if (con.geom1 == trunk_geom || con.geom2 == trunk_geom) trunk_f += std::abs(res[0]);
    }

    // Closed loop: the measured state to the re-planner; its plan tracked after the latency.
    promote_pending(t);
    // No re-plan within the plan's last 0.1 s: a re-plan to rest over that little cannot ramp the
    // forces down (every such step failed force_ramp in its first few ms). The 1 ms slack is for
    // durations that carry rounding: 3 crawl cycles of 3.6667 s end at 11.0001 s, and the step at
    // 10.9 s, 0.1001 s before that end, failed in every closed-loop run.
    if (replanner && t >= next_replan - 1e-9 && t < t_end - 0.1 - 1e-3) {
      next_replan += o.replan_every;
      MeasuredState ms;
      ms.t = t;
      ms.base_position = p;
      ms.base_euler_zyx = euler_zyx_of(rot);
      ms.base_linear_velocity = v;
      ms.base_angular_velocity = omega;
      ms.foot_contact = foot_contact;
      for (int i = 0; i < n_legs; ++i) {
        const Vector3d centre(d->site_xpos[3 * foot_site[i]], d->site_xpos[3 * foot_site[i] + 1],
                              d->site_xpos[3 * foot_site[i] + 2]);
        ms.foot_position.push_back(centre - r_foot * terrain_normal(scene, centre));
        mj_jacSite(m, d, jacp.data(), nullptr, foot_site[i]);
        Vector3d vel = Vector3d::Zero();
        for (int r = 0; r < 3; ++r)
          for (int k = 0; k < nv; ++k) vel[r] += jacp[r * nv + k] * d->qvel[k];
        ms.foot_velocity.push_back(vel);
      }
      const auto call0 = std::chrono::steady_clock::now();
      const double call_cpu0 = thread_cpu_seconds();
      Replan next = replanner(ms);
      record_replan(t, call0, call_cpu0, next, &rep);
      if (next.success) {
        try {
          if (next.plan.feet != plan.feet)
            throw SimulationError("its feet differ from the simulated plan's");
          Tracked n;
          n.plan = std::make_unique<planner::Trajectory>(std::move(next.plan));
          n.view = std::make_unique<PlanView>(*n.plan, n_legs);
          n.start = next.start_time;
          n.end = next.start_time + n.view->t_end();
          pending = std::move(n);
          pending_from = t + o.replan_latency;
        } catch (const SimulationError& e) {
          next.success = false;
          next.message = std::string("re-plan at t = ") + fmt(t) + " s: " + e.what();
        }
      }
      if (!next.success) {
        ++rep.replan_failures;
        rep.replan_failure_times.push_back(t);
        if (rep.replan_first_failure.empty())
          rep.replan_first_failure = next.message.empty() ? "re-plan failed" : next.message;
      }
      promote_pending(t);
    }
    const auto [plan_view, plan_shift] = view_for(t);
    const auto ps = plan_view->at(t - plan_shift);
    const Matrix3d rot_plan = rotation_zyx(ps.euler);
    if (replanner)
      rep.reference_position_max =
          std::max(rep.reference_position_max, (p - view.at(t).base_pos).norm());

    // Tracking errors.
    const double pos_err = (p - ps.base_pos).norm();
    const double tilt = Eigen::AngleAxisd(rot_plan.transpose() * rot).angle();
    const double drop = ps.base_pos.z() - p.z();
    sq_err_sum += pos_err * pos_err;
    if (pos_err > rep.position_max) {
      rep.position_max = pos_err;
      rep.position_max_t = t;
    }
    rep.tilt_max = std::max(rep.tilt_max, tilt);
    rep.height_drop_max = std::max(rep.height_drop_max, drop);
    double body_impulse = rep.trunk_impulse;
    for (int i = 0; i < n_legs; ++i) body_impulse = std::max(body_impulse, rep.thigh_impulse[i]);
    if (!rep.fell && (drop > o.thresholds.fall_height_m || tilt > o.thresholds.fall_tilt_rad ||
                      body_impulse > o.thresholds.body_contact_impulse_Ns)) {
      rep.fell = true;
      rep.fall_t = t;
      std::ostringstream why;
      why.precision(3);
      if (drop > o.thresholds.fall_height_m)
        why << "fall at t = " << t << " s: trunk " << drop << " m below the plan (limit "
            << o.thresholds.fall_height_m << ")";
      else if (tilt > o.thresholds.fall_tilt_rad)
        why << "fall at t = " << t << " s: orientation error " << tilt * 180 / M_PI
            << " deg (limit " << o.thresholds.fall_tilt_rad * 180 / M_PI << ")";
      else
        why << "fall at t = " << t << " s: trunk or thigh on the terrain (contact impulse "
            << body_impulse << " N s)";
      rep.reasons.push_back(why.str());
    }

    // Stance bookkeeping: touchdown error and slip of the sphere's contact point.
    for (int i = 0; i < n_legs; ++i) {
      const int idx = stance_at(i, t);
      if (idx < 0 || !foot_contact[i]) continue;
      const Vector3d centre(d->site_xpos[3 * foot_site[i]], d->site_xpos[3 * foot_site[i] + 1],
                            d->site_xpos[3 * foot_site[i] + 2]);
      const Vector3d contact_pt = centre - r_foot * terrain_normal(scene, centre);
      StanceReport& s = rep.stances[idx];
      if (!s.touched_down) {
        s.touched_down = true;
        s.touchdown_t = t;
        // The foothold of the plan tracked now (a re-plan may have moved it): within its span,
        // since beyond that the original plan's foothold would be compared.
        double t_foothold = 0.5 * (s.t_start + s.t_end);
        if (tracked.view && t >= tracked.start && t <= tracked.end)
          t_foothold = std::max(t, std::min(t_foothold, tracked.end));
        const Vector3d planned = plan_at(t_foothold).foot[i];
        s.touchdown_error = (contact_pt - planned).norm();
        touchdown_point[idx] = contact_pt;
      } else {
        s.centre_drift =
            std::max(s.centre_drift, (contact_pt - touchdown_point[idx]).head<2>().norm());
      }
      // Sliding: the velocity of the lower leg's material point at the contact, tangential part.
      const Vector3d n = terrain_normal(scene, centre);
      mj_jac(m, d, jacp.data(), nullptr, contact_pt.data(), m->site_bodyid[foot_site[i]]);
      Vector3d vel = Vector3d::Zero();
      for (int r = 0; r < 3; ++r)
        for (int k = 0; k < nv; ++k) vel[r] += jacp[r * nv + k] * d->qvel[k];
      s.slip += (vel - vel.dot(n) * n).norm() * o.dt;
    }

    // Record.
    if (o.record_dt > 0 && t >= next_record - 1e-9) {
      next_record += o.record_dt;
      SimulationSample smp;
      smp.t = t;
      smp.base_position = p;
      smp.base_euler_zyx = euler_zyx_of(rot);
      smp.planned_position = ps.base_pos;
      smp.planned_euler_zyx = ps.euler;
      smp.joint_torque = tau_applied;
      smp.foot_contact = foot_contact;
      smp.foot_force = foot_force;
      for (int i = 0; i < n_legs; ++i) {
        smp.planned_contact.push_back(contact_at(i, t));
        const Vector3d centre(d->site_xpos[3 * foot_site[i]], d->site_xpos[3 * foot_site[i] + 1],
                              d->site_xpos[3 * foot_site[i] + 2]);
        smp.foot_position.push_back(centre - r_foot * terrain_normal(scene, centre));
      }
      smp.shin_force = shin_f;
      smp.thigh_force = thigh_f;
      smp.trunk_force = trunk_f;
      rep.samples.push_back(std::move(smp));
    }
    if (step == n_steps || rep.fell) break;

    // Trunk PD wrench, spread over the planned stance feet within the friction cone.
    std::vector<int> stance;
    std::vector<Vector3d> lever;
    for (int i = 0; i < n_legs; ++i)
      if (contact_at(i, t)) {
        stance.push_back(i);
        lever.push_back(Vector3d(d->site_xpos[3 * foot_site[i]], d->site_xpos[3 * foot_site[i] + 1],
                                 d->site_xpos[3 * foot_site[i] + 2]) -
                        p);
      }
    std::vector<Vector3d> delta(stance.size(), Vector3d::Zero());
    if (c.trunk_wrench) {
      Eigen::Matrix<double, 6, 1> w;
      w.head<3>() = g.kp_position * (ps.base_pos - p) + g.kd_position * (ps.base_vel - v);
      w.tail<3>() = g.kp_orientation * rotation_vector(rot_plan * rot.transpose()) +
                    g.kd_orientation * (ps.omega - omega);
      if (!c.planned_forces) {
        // Without the plan's forces the wrench carries the weight.
        double mass = 0;
        for (int b = 1; b < m->nbody; ++b) mass += m->body_mass[b];
        w.head<3>() += mass * (ps.base_acc + Vector3d(0, 0, kGravity));
      }
      delta = spread_wrench(w, lever);
    }

    // The plan a moment before and after, for the swing feed-forward's joint rates.
    constexpr double h = 0.004;
    const auto pm = plan_view->at(t - h - plan_shift), pp = plan_view->at(t + h - plan_shift);
    const Matrix3d rot_m = rotation_zyx(pm.euler), rot_p = rotation_zyx(pp.euler);
    mj_fullM(m, full_m.data(), d->qM);
    bool saturated = false;
    for (int i = 0; i < n_legs; ++i) {
      const int dof = 6 + 3 * i;
      const auto& leg = model.legs[i];
      mj_jacSite(m, d, jacp.data(), nullptr, foot_site[i]);
      Matrix3d jac;
      for (int r = 0; r < 3; ++r)
        for (int k = 0; k < 3; ++k) jac(r, k) = jacp[r * nv + dof + k];
      Matrix3d mass;
      for (int r = 0; r < 3; ++r)
        for (int k = 0; k < 3; ++k) mass(r, k) = full_m[(dof + r) * nv + dof + k];
      Vector3d q, qd, bias;
      for (int j = 0; j < 3; ++j) {
        q[j] = d->qpos[7 + 3 * i + j];
        qd[j] = d->qvel[dof + j];
        bias[j] = d->qfrc_bias[dof + j];
      }
      // Desired joints: IK of the planned foot relative to the measured base; their rates from
      // the planned motion (finite differences of the IK along the planned base).
      const Vector3d n = terrain_normal(scene, ps.foot[i]);
      const Vector3d q_des = ik_in(i, p, rot, ps.foot[i], n, q_prev[i]);
      q_prev[i] = q_des;
      const Vector3d q0 = ik_in(i, ps.base_pos, rot_plan, ps.foot[i], n, q);
      const Vector3d qm = ik_in(i, pm.base_pos, rot_m, pm.foot[i], n, q0);
      const Vector3d qp = ik_in(i, pp.base_pos, rot_p, pp.foot[i], n, q0);
      const Vector3d qd_des = (qp - qm) / (2 * h);
      const Vector3d qdd_des = (qp - 2 * q0 + qm) / (h * h);
      const bool in_stance = contact_at(i, t);
      Vector3d tau = bias;
      if (in_stance) {
        Vector3d f = c.planned_forces ? ps.force[i] : Vector3d::Zero();
        const auto it = std::find(stance.begin(), stance.end(), i);
        f += delta[it - stance.begin()];
        f = into_cone(f, n, c.cone_margin * mu);
        tau -= jac.transpose() * f;
        tau += g.kp_stance * (q_des - q) + g.kd_stance * (qd_des - qd);
      } else {
        if (c.swing_feedforward) tau += mass * qdd_des;
        tau += g.kp_swing * (q_des - q) + g.kd_swing * (qd_des - qd);
      }
      for (int j = 0; j < 3; ++j) {
        const double lim = leg.torque_limit[j];
        if (std::abs(tau[j]) > lim) {
          saturated = true;
          rep.saturated_time[i][j] += o.dt;
          tau[j] = std::clamp(tau[j], -lim, lim);
        }
        rep.torque_max[i][j] = std::max(rep.torque_max[i][j], std::abs(tau[j]));
        d->ctrl[3 * i + j] = tau[j];
      }
      tau_applied[i] = tau;
    }
    if (saturated) saturated_s += o.dt;
    // End stops: MuJoCo's joint-limit constraints (joint k of the model is leg k/3 - 1's, the
    // free joint being 0); their torque times dt is the stop's impulse.
    for (int k = 0; k < d->nefc; ++k) {
      if (d->efc_type[k] != mjCNSTR_LIMIT_JOINT || d->efc_force[k] == 0) continue;
      const int jnt = d->efc_id[k] - 1;
      if (jnt < 0 || jnt >= 3 * n_legs) continue;
      rep.joint_limit_time[jnt / 3][jnt % 3] += o.dt;
      rep.joint_limit_impulse[jnt / 3][jnt % 3] += std::abs(d->efc_force[k]) * o.dt;
    }

    // Pushes on the trunk.
    for (int k = 0; k < 6; ++k) d->xfrc_applied[6 * trunk_body + k] = 0;
    for (const auto& push : o.pushes)
      if (t >= push.t && t < push.t + push.duration)
        for (int k = 0; k < 3; ++k) d->xfrc_applied[6 * trunk_body + k] += push.force[k];

    const auto step0 = std::chrono::steady_clock::now();
    mj_step(m, d);
    rep.physics_wall_s +=
        std::chrono::duration<double>(std::chrono::steady_clock::now() - step0).count();
    ++rep.steps;
    if (became_unstable(d)) {
      record_instability(d, t, &rep);
      break;
    }
    // Impulses of the step just taken (contact forces of the new state times dt).
    for (int k = 0; k < d->ncon; ++k) {
      const mjContact& con = d->contact[k];
      mjtNum res[6];
      mj_contactForce(m, d, k, res);
      const double impulse = std::abs(res[0]) * o.dt;
      for (int i = 0; i < n_legs; ++i) {
        if (con.geom1 == shin_geom[i] || con.geom2 == shin_geom[i]) rep.shin_impulse[i] += impulse;
        if (con.geom1 == thigh_geom[i] || con.geom2 == thigh_geom[i])
          rep.thigh_impulse[i] += impulse;
      }
      if (con.geom1 == trunk_geom || con.geom2 == trunk_geom) rep.trunk_impulse += impulse;
    }
  }
  rep.wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - wall0).count();
  rep.cpu_s = thread_cpu_seconds() - cpu0;
  rep.duration = rep.unstable ? rep.unstable_t - t0 : d->time;
  rep.realtime_factor = rep.wall_s > 0 ? rep.duration / rep.wall_s : 0.0;
  if (!rep.replan_wall_s.empty()) {
    median_and_max(rep.replan_wall_s, &rep.replan_wall_median, &rep.replan_wall_max);
    median_and_max(rep.replan_cpu_s, &rep.replan_cpu_median, &rep.replan_cpu_max);
  }
  if (!rep.replan_iterations.empty())
    median_and_max(rep.replan_iterations, &rep.replan_iterations_median,
                   &rep.replan_iterations_max);
  const int n_eval = rep.steps + 1;
  rep.position_rms = std::sqrt(sq_err_sum / n_eval);
  rep.saturation_fraction = rep.duration > 0 ? saturated_s / rep.duration : 0.0;
  for (const auto& s : rep.stances) {
    if (rep.fell && s.t_start > rep.fall_t) continue;
    if (!s.touched_down) {
      if (s.t_end - s.t_start > 0.05 && s.t_start < t0 + rep.duration) ++rep.missed_touchdowns;
      continue;
    }
    rep.slip_max = std::max(rep.slip_max, s.slip);
    rep.centre_drift_max = std::max(rep.centre_drift_max, s.centre_drift);
    rep.touchdown_error_max = std::max(rep.touchdown_error_max, s.touchdown_error);
  }
  for (double x : rep.shin_impulse) rep.shin_impulse_max = std::max(rep.shin_impulse_max, x);
  std::string limit_joint;
  static const char* kJoints[3] = {"HAA", "HFE", "KFE"};
  for (int i = 0; i < n_legs; ++i)
    for (int j = 0; j < 3; ++j)
      if (rep.joint_limit_impulse[i][j] > rep.joint_limit_impulse_max) {
        rep.joint_limit_impulse_max = rep.joint_limit_impulse[i][j];
        rep.joint_limit_max_s = rep.joint_limit_time[i][j];
        limit_joint = model.legs[i].name + " " + kJoints[j];
      }

  // Verdict. An unstable run judges nothing after its instability (stances it never reached,
  // torques of a limp robot): it fails with that reason alone.
  if (!rep.unstable) fail_non_finite_figures(t0, &rep);
  if (rep.unstable) {
    rep.verdict = "fail";
    return rep;
  }
  const auto& th = o.thresholds;
  std::ostringstream w;
  w.precision(3);
  auto warn = [&](bool bad, const std::string& what) {
    if (bad) rep.reasons.push_back(what);
  };
  auto str = [](double v, int prec = 3) {
    std::ostringstream s;
    s.precision(prec);
    s << v;
    return s.str();
  };
  warn(rep.position_rms > th.position_rms_m, "base position error RMS " + str(rep.position_rms) +
                                                 " m (limit " + str(th.position_rms_m) + ")");
  warn(rep.position_max > th.position_max_m, "base position error max " + str(rep.position_max) +
                                                 " m at t = " + str(rep.position_max_t) +
                                                 " s (limit " + str(th.position_max_m) + ")");
  warn(rep.saturation_fraction > th.saturation_fraction,
       "torque saturated " + str(100 * rep.saturation_fraction) + " % of the time (limit " +
           str(100 * th.saturation_fraction) + " %)");
  warn(rep.slip_max > th.slip_m,
       "foot slip " + str(rep.slip_max) + " m in a stance (limit " + str(th.slip_m) + ")");
  warn(rep.touchdown_error_max > th.touchdown_error_m,
       "touchdown error " + str(rep.touchdown_error_max) + " m (limit " +
           str(th.touchdown_error_m) + ")");
  warn(rep.missed_touchdowns > 0,
       std::to_string(rep.missed_touchdowns) + " planned stance(s) never touched the terrain");
  warn(rep.shin_impulse_max >= th.shin_impulse_Ns, "shin contact impulse " +
                                                       str(rep.shin_impulse_max) + " N s (limit " +
                                                       str(th.shin_impulse_Ns) + ")");
  warn(rep.joint_limit_impulse_max > th.joint_limit_impulse_Nms,
       limit_joint + " pressed against its range's end stop: " + str(rep.joint_limit_impulse_max) +
           " N m s over " + str(rep.joint_limit_max_s) + " s (limit " +
           str(th.joint_limit_impulse_Nms) + " N m s)");
  const int contacts_full = d->warning[mjWARN_CONTACTFULL].number;
  const int constraints_full = d->warning[mjWARN_CNSTRFULL].number;
  warn(contacts_full + constraints_full > 0,
       "MuJoCo's contact or constraint buffer was full in " +
           std::to_string(contacts_full + constraints_full) +
           " step(s): contacts were dropped, the physics is not faithful there");
  rep.verdict = rep.fell ? "fail" : (rep.reasons.empty() ? "pass" : "warn");
  return rep;
}

}  // namespace

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

}  // namespace terrastride::simulation
