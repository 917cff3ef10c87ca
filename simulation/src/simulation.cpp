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
  if (!(replanner_ && t >= next_replan_ - 1e-9 && t < t_end_ - 0.1 - 1e-3)) return;
  next_replan_ += o_.replan_every;
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
  const std::vector<Vector3d> delta = trunk_wrench_forces(b, ref, lever);
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

SimulationReport simulate(const robot::RobotModel& model, const planner::Trajectory& plan,
                          const terrain::HeightField& scene, const TerrainMjcf& terrain,
                          const SimulationOptions& o) {
  validate_simulation(model, plan, o);
  require_free_base(model);
  return SimulationRun(model, plan, scene, terrain, o).run();
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
