#include "terrastride/robot/robot_model.hpp"

#include <yaml-cpp/yaml.h>

#include <Eigen/Eigenvalues>

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iterator>
#include <filesystem>
#include <sstream>
#include <algorithm>

#ifndef TERRASTRIDE_SOURCE_DATA_DIR
#define TERRASTRIDE_SOURCE_DATA_DIR "data"
#endif

namespace terrastride::robot {
namespace {

constexpr double kDegToRad = M_PI / 180.0;

// Reads fields of one YAML mapping and reports errors as "<file>: <field.path>: problem".
class FieldReader {
 public:
  FieldReader(const std::string& file, const YAML::Node& node, std::string path)
      : file_(file), node_(node), path_(std::move(path)) {}

  [[noreturn]] void fail(const std::string& field, const std::string& problem) const {
    throw RobotFileError(file_ + ": field '" + join(field) + "': " + problem);
  }

  YAML::Node child(const std::string& field) const {
    if (!node_.IsMap()) throw RobotFileError(file_ + ": '" + path_ + "' must be a mapping");
    YAML::Node c = node_[field];
    if (!c) fail(field, "missing");
    return c;
  }
  FieldReader sub(const std::string& field) const {
    YAML::Node c = child(field);
    if (!c.IsMap()) fail(field, "must be a mapping");
    return FieldReader(file_, c, join(field));
  }
  bool has(const std::string& field) const { return node_.IsMap() && node_[field]; }

  double number(const std::string& field) const { return as_number(child(field), field); }
  double positive(const std::string& field) const {
    const double v = number(field);
    if (!(v > 0)) fail(field, "must be > 0 (got " + std::to_string(v) + ")");
    return v;
  }
  double non_negative(const std::string& field) const {
    const double v = number(field);
    if (!(v >= 0)) fail(field, "must be >= 0 (got " + std::to_string(v) + ")");
    return v;
  }
  std::string text(const std::string& field) const {
    YAML::Node c = child(field);
    if (!c.IsScalar()) fail(field, "must be a string");
    return c.as<std::string>();
  }
  Eigen::Vector3d vec3(const std::string& field) const {
    YAML::Node c = child(field);
    if (!c.IsSequence() || c.size() != 3) fail(field, "must be a list of 3 numbers");
    Eigen::Vector3d v;
    for (int i = 0; i < 3; ++i) v[i] = as_number(c[i], field + "[" + std::to_string(i) + "]");
    return v;
  }
  // [min, max] in degrees, returned in radians.
  std::pair<double, double> range_deg(const std::string& field) const {
    YAML::Node c = child(field);
    if (!c.IsSequence() || c.size() != 2) fail(field, "must be [min, max] in degrees");
    const double lo = as_number(c[0], field + "[0]"), hi = as_number(c[1], field + "[1]");
    if (!(lo < hi)) fail(field, "min must be below max");
    return {lo * kDegToRad, hi * kDegToRad};
  }
  const std::string& path() const { return path_; }
  const YAML::Node& node() const { return node_; }

 private:
  std::string join(const std::string& field) const {
    return path_.empty() ? field : path_ + "." + field;
  }
  double as_number(const YAML::Node& n, const std::string& field) const {
    if (!n.IsScalar()) fail(field, "must be a number");
    double v = 0;
    try {
      v = n.as<double>();
    } catch (const YAML::Exception&) {
      fail(field, "must be a number (got '" + n.Scalar() + "')");
    }
    if (!std::isfinite(v)) fail(field, "must be finite");
    return v;
  }

  std::string file_;
  YAML::Node node_;
  std::string path_;
};

Eigen::Matrix3d read_inertia(const FieldReader& r) {
  Eigen::Matrix3d inertia;
  const double ixx = r.positive("xx"), iyy = r.positive("yy"), izz = r.positive("zz");
  const double ixy = r.number("xy"), ixz = r.number("xz"), iyz = r.number("yz");
  inertia << ixx, ixy, ixz, ixy, iyy, iyz, ixz, iyz, izz;
  // A physical inertia is positive definite and satisfies the triangle inequalities.
  if (Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(inertia).eigenvalues().minCoeff() <= 0)
    r.fail("", "inertia matrix is not positive definite");
  return inertia;
}

LinkInertia read_link(const FieldReader& r) {
  LinkInertia link;
  link.mass = r.positive("mass");
  link.com = r.vec3("com");
  link.inertia = read_inertia(r.sub("inertia"));
  return link;
}

// `trunk: {size: [x, y, z], center: [x, y, z]}` or `trunk: none`. Required: a robot file that
// forgets its trunk must not be checked as if it had none.
std::optional<TrunkBox> read_trunk(const FieldReader& top) {
  const YAML::Node node = top.child("trunk");
  if (node.IsScalar() && node.Scalar() == "none") return std::nullopt;
  if (!node.IsMap())
    top.fail("trunk", "must be a mapping {size: [x, y, z], center: [x, y, z]} or 'none'");
  const FieldReader r = top.sub("trunk");
  TrunkBox box;
  box.size = r.vec3("size");
  for (int i = 0; i < 3; ++i)
    if (!(box.size[i] > 0))
      r.fail("size", "edge lengths must be > 0 (got " + std::to_string(box.size[i]) + ")");
  box.center = r.vec3("center");
  return box;
}

// The general leg geometry (robot_model.hpp, LegModel):
//   geometry: {haa_to_hfe: [x, y, z], hfe_to_kfe: [...], kfe_to_foot: [...],
//              axes: {haa: [x, y, z], hfe: [...], kfe: [...]}}
void read_general_geometry(const FieldReader& r, LegModel& leg) {
  const FieldReader g = r.sub("geometry");
  leg.joint_offset[0] = g.vec3("haa_to_hfe");
  leg.joint_offset[1] = g.vec3("hfe_to_kfe");
  leg.joint_offset[2] = g.vec3("kfe_to_foot");
  const FieldReader axes = g.sub("axes");
  static const char* kJoints[3] = {"haa", "hfe", "kfe"};
  for (int j = 0; j < 3; ++j) {
    const Eigen::Vector3d a = axes.vec3(kJoints[j]);
    if (!(std::abs(a.norm() - 1.0) < 1e-6)) axes.fail(kJoints[j], "must be a unit vector");
    leg.joint_axis[j] = a / a.norm();
  }
}

}  // namespace

void classify_leg_geometry(LegModel& leg, bool side_given) {
  const auto fail = [&](const std::string& what) {
    throw std::invalid_argument("leg " + leg.name + ": " + what);
  };
  for (int j = 0; j < 3; ++j) {
    if (!leg.joint_axis[j].allFinite() || !(std::abs(leg.joint_axis[j].norm() - 1.0) < 1e-6))
      fail("joint axis " + std::to_string(j) + " is not a unit vector");
    if (!leg.joint_offset[j].allFinite()) fail("joint offset " + std::to_string(j) + " is not finite");
  }
  if (!(leg.joint_offset[1].norm() > 0)) fail("the HFE -> KFE offset (thigh) has no length");
  if (!(leg.joint_offset[2].norm() > 0)) fail("the KFE -> foot offset (shank) has no length");
  const auto is = [](const Eigen::Vector3d& v, double x, double y, double z) {
    return v.x() == x && v.y() == y && v.z() == z;
  };
  const Eigen::Vector3d &a0 = leg.joint_axis[0], &a1 = leg.joint_axis[1], &a2 = leg.joint_axis[2];
  const bool haa_x = is(a0, 1, 0, 0) || is(a0, -1, 0, 0);
  const bool knee_y = (is(a1, 0, 1, 0) || is(a1, 0, -1, 0)) && (is(a2, 0, 1, 0) || is(a2, 0, -1, 0));
  bool straight_down = is(a1, 0, 1, 0) && is(a2, 0, 1, 0);
  for (int j = 0; j < 3; ++j) {
    const Eigen::Vector3d& d = leg.joint_offset[j];
    straight_down = straight_down && d.x() == 0 && d.y() == 0 && d.z() <= 0;
  }
  if (haa_x && straight_down) {
    leg.shape = LegShape::in_plane;
    const int side = a0.x() < 0 ? +1 : -1;
    if (side_given && side != leg.side)
      fail("side does not match the HAA axis (a left leg turns about -x, a right one about +x)");
    leg.side = side;
    leg.l0 = -leg.joint_offset[0].z();
    leg.l1 = -leg.joint_offset[1].z();
    leg.l2 = -leg.joint_offset[2].z();
    return;
  }
  leg.shape = haa_x && knee_y ? LegShape::lateral_offset : LegShape::general;
  if (!side_given) leg.side = leg.haa_origin.y() >= 0 ? +1 : -1;
  leg.l0 = std::max(0.0, -leg.joint_offset[0].z());
  leg.l1 = leg.joint_offset[1].norm();
  leg.l2 = leg.joint_offset[2].norm();
}

const LegModel& RobotModel::leg(const std::string& leg_name) const {
  const int i = leg_index(leg_name);
  if (i < 0) throw std::out_of_range("robot " + name + " has no leg '" + leg_name + "'");
  return legs[i];
}

int RobotModel::leg_index(const std::string& leg_name) const {
  for (size_t i = 0; i < legs.size(); ++i)
    if (legs[i].name == leg_name) return static_cast<int>(i);
  return -1;
}

namespace {
RobotModel read_robot(const YAML::Node& root, const std::string& path);
}  // namespace

RobotModel load_robot(const std::string& path) {
  // Read once as text: the model keeps the very bytes it was parsed from (RobotModel::definition).
  std::ifstream in(path, std::ios::binary);
  if (!in || std::filesystem::is_directory(path))
    throw RobotFileError(path + ": cannot open robot file");
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (in.bad()) throw RobotFileError(path + ": cannot read robot file");
  return parse_robot(text, path);
}

RobotModel parse_robot(const std::string& text, const std::string& label) {
  YAML::Node root;
  try {
    root = YAML::Load(text);
  } catch (const YAML::Exception& e) {
    throw RobotFileError(label + ": not valid YAML: " + e.what());
  }
  RobotModel robot = read_robot(root, label);
  robot.definition = text;
  return robot;
}

std::string robot_definition_hash(const std::string& text) {
  uint64_t h = 1469598103934665603ull;
  for (unsigned char ch : text) {
    h ^= ch;
    h *= 1099511628211ull;
  }
  char buf[17];
  std::snprintf(buf, sizeof buf, "%016llx", static_cast<unsigned long long>(h));
  return buf;
}

namespace {

// base_dof_free: which of x/y/z/yaw/pitch/roll the base moves in (all when absent).
void read_base_dof_free(const FieldReader& top, const std::string& path, RobotModel& robot) {
  if (!top.has("base_dof_free")) return;
  YAML::Node dofs = top.child("base_dof_free");
  static const char* kNames[6] = {"x", "y", "z", "yaw", "pitch", "roll"};
  if (!dofs.IsMap()) top.fail("base_dof_free", "must map x/y/z/yaw/pitch/roll to true/false");
  const FieldReader dr(path, dofs, "base_dof_free");
  for (int i = 0; i < 6; ++i) {
    YAML::Node d = dr.child(kNames[i]);
    try {
      robot.base_dof_free[i] = d.as<bool>();
    } catch (const YAML::Exception&) {
      dr.fail(kNames[i], "must be true or false");
    }
  }
}

// The trunk's collision box, which must clear the ground of the nominal stance.
void read_trunk_box(const FieldReader& top, RobotModel& robot) {
  robot.trunk = read_trunk(top);
  if (!robot.trunk) return;
  const double bottom = robot.trunk->center.z() - robot.trunk->half_size().z();
  if (!(bottom > -robot.nominal_base_height))
    top.fail("trunk", "its bottom (z = " + std::to_string(bottom) +
                          " m in the base frame) is not above the ground of the nominal stance "
                          "(z = -nominal_base_height = " +
                          std::to_string(-robot.nominal_base_height) + " m)");
}

// A leg's side and kinematic chain: the general `geometry`, or the in-plane l0/l1/l2; classified.
void read_leg_chain(const FieldReader& r, LegModel& leg) {
  const bool side_given = r.has("side");
  if (side_given) {
    const std::string side = r.text("side");
    if (side == "left") leg.side = +1;
    else if (side == "right") leg.side = -1;
    else r.fail("side", "must be 'left' or 'right' (got '" + side + "')");
  }
  if (r.has("geometry")) {
    // The general leg. The in-plane keys would say the same thing twice.
    for (const char* key : {"l0", "l1", "l2"})
      if (r.has(key))
        r.fail(key, "give either 'geometry' or l0/l1/l2, not both");
    read_general_geometry(r, leg);
  } else {
    // The in-plane leg (HyQ): l0, l1, l2 straight down, HAA about -side x, HFE and KFE about y.
    leg.l0 = r.non_negative("l0");
    leg.l1 = r.positive("l1");
    leg.l2 = r.positive("l2");
    if (!side_given) r.fail("side", "missing");
    leg.joint_axis = {Eigen::Vector3d(-leg.side, 0.0, 0.0), Eigen::Vector3d::UnitY(),
                      Eigen::Vector3d::UnitY()};
    leg.joint_offset = {Eigen::Vector3d(0.0, 0.0, -leg.l0), Eigen::Vector3d(0.0, 0.0, -leg.l1),
                        Eigen::Vector3d(0.0, 0.0, -leg.l2)};
  }
  try {
    classify_leg_geometry(leg, side_given);
  } catch (const std::invalid_argument& e) {
    r.fail(r.has("geometry") ? "geometry" : "l0", e.what());
  }
}

// The knee branch and the joint ranges, which must agree (or IK would always fail).
void read_leg_joint_ranges(const FieldReader& r, LegModel& leg) {
  const std::string knee = r.text("knee");
  if (knee == "backward") leg.knee_sign = -1;
  else if (knee == "forward") leg.knee_sign = +1;
  else r.fail("knee", "must be 'backward' or 'forward' (got '" + knee + "')");
  const FieldReader limits = r.sub("joint_range_deg");
  static const char* kJoints[3] = {"haa", "hfe", "kfe"};
  for (int j = 0; j < 3; ++j) {
    const auto [lo, hi] = limits.range_deg(kJoints[j]);
    leg.q_min[j] = lo;
    leg.q_max[j] = hi;
  }
  // The knee branch must agree with the KFE range, or IK would always fail.
  if (leg.shape == LegShape::in_plane) {
    if ((leg.knee_sign < 0 && leg.q_max[2] > 0) || (leg.knee_sign > 0 && leg.q_min[2] < 0))
      r.fail("joint_range_deg.kfe", "range does not match knee: " + knee);
  } else if (leg.shape == LegShape::lateral_offset) {
    // The straight leg's KFE angle: the closed form's knee branch starts there.
    const Eigen::Vector3d &d1 = leg.joint_offset[1], &d2 = leg.joint_offset[2];
    const double s2 = leg.joint_axis[2].y();
    const double straight =
        s2 * std::atan2(d1.x() * d2.z() - d1.z() * d2.x(), d1.x() * d2.x() + d1.z() * d2.z());
    const double lo = leg.knee_sign * (leg.q_min[2] - straight),
                 hi = leg.knee_sign * (leg.q_max[2] - straight);
    if (std::min(lo, hi) < -1e-9 || std::max(lo, hi) > 2 * M_PI)
      r.fail("joint_range_deg.kfe",
             "range does not lie on the knee's side (" + knee + ") of the straight leg (KFE = " +
                 std::to_string(straight * 180.0 / M_PI) + " deg)");
  }
}

// The leg's actuators (torque and velocity limits), links, nominal foot, range of motion and the
// shin's and thigh's collision shapes.
void read_leg_body(const FieldReader& r, LegModel& leg) {
  static const char* kJoints[3] = {"haa", "hfe", "kfe"};
  const FieldReader torque = r.sub("torque_limit");
  for (int j = 0; j < 3; ++j) leg.torque_limit[j] = torque.positive(kJoints[j]);
  if (r.has("velocity_limit")) {
    const FieldReader velocity = r.sub("velocity_limit");
    for (int j = 0; j < 3; ++j) leg.velocity_limit[j] = velocity.positive(kJoints[j]);
  }
  const FieldReader links = r.sub("links");
  leg.links[0] = read_link(links.sub("hip"));
  leg.links[1] = read_link(links.sub("upper"));
  leg.links[2] = read_link(links.sub("lower"));
  leg.nominal_foot = r.vec3("nominal_foot");
  leg.range_of_motion = r.vec3("range_of_motion");
  for (int j = 0; j < 3; ++j)
    if (!(leg.range_of_motion[j] > 0)) r.fail("range_of_motion", "half-sizes must be > 0");
  const FieldReader shin = r.sub("shin");
  leg.shin_length = shin.positive("length");
  leg.shin_angle = shin.number("angle_deg") * kDegToRad;
  leg.shin_radius = shin.positive("radius");
  leg.thigh_radius = r.sub("thigh").positive("radius");
}

// One leg, its keys merged over leg_model's.
LegModel read_leg(const FieldReader& r, const RobotModel& robot) {
  LegModel leg;
  leg.name = r.text("name");
  if (robot.leg_index(leg.name) >= 0) r.fail("name", "duplicate leg name '" + leg.name + "'");
  leg.haa_origin = r.vec3("haa_origin");
  read_leg_chain(r, leg);
  read_leg_joint_ranges(r, leg);
  leg.is_front = leg.haa_origin.x() >= 0;
  read_leg_body(r, leg);
  return leg;
}

RobotModel read_robot(const YAML::Node& root, const std::string& path) {
  if (!root.IsMap()) throw RobotFileError(path + ": robot file must be a YAML mapping");
  const FieldReader top(path, root, "");

  RobotModel robot;
  robot.source_file = path;
  robot.name = top.text("name");
  if (top.has("source")) {
    YAML::Emitter out;
    out << YAML::Flow << top.child("source");
    robot.source = out.c_str();
  }
  const FieldReader body = top.sub("body");
  robot.mass = body.positive("mass");
  robot.inertia = read_inertia(body.sub("inertia"));
  robot.nominal_base_height = top.positive("nominal_base_height");
  robot.foot_radius = top.non_negative("foot_radius");
  read_base_dof_free(top, path, robot);
  read_trunk_box(top, robot);

  // Shared leg description; each leg may override any of these keys.
  // (Optional: an imported robot file gives every key per leg.)
  const FieldReader legs_node =
      top.has("leg_model") ? top.sub("leg_model") : FieldReader(path, YAML::Node(YAML::NodeType::Map), "leg_model");
  YAML::Node list = top.child("legs");
  if (!list.IsSequence() || list.size() == 0) top.fail("legs", "must be a non-empty list");
  for (size_t k = 0; k < list.size(); ++k) {
    // Merge: leg-specific keys on top of leg_model.
    YAML::Node merged = YAML::Clone(legs_node.node());
    if (!list[k].IsMap()) top.fail("legs[" + std::to_string(k) + "]", "must be a mapping");
    for (const auto& kv : list[k]) merged[kv.first.as<std::string>()] = kv.second;
    const FieldReader r(path, merged, "legs[" + std::to_string(k) + "]");
    robot.legs.push_back(read_leg(r, robot));
  }
  return robot;
}
}  // namespace

std::string data_dir() {
  if (const char* env = std::getenv("TERRASTRIDE_DATA_DIR"); env && *env) return env;
  return TERRASTRIDE_SOURCE_DATA_DIR;
}

std::string robot_argument(const RobotModel& model) {
  namespace fs = std::filesystem;
  std::error_code ec;
  const fs::path shipped = fs::path(data_dir()) / "robots" / (model.name + ".yaml");
  if (fs::equivalent(shipped, model.source_file, ec)) return model.name;
  // A path the shell passes through as it is: relative paths gain ./ so that they read as paths
  // (resolve_robot_path takes a bare word for a shipped name).
  const std::string& p = model.source_file;
  if (!fs::is_regular_file(p, ec)) return model.name;  // e.g. a definition a plan carries
  if (p.find('/') == std::string::npos) return "./" + p;
  return p;
}

std::string resolve_robot_path(const std::string& name_or_path) {
  namespace fs = std::filesystem;
  if (name_or_path.find('/') != std::string::npos || fs::path(name_or_path).extension() == ".yaml")
    return name_or_path;
  const fs::path p = fs::path(data_dir()) / "robots" / (name_or_path + ".yaml");
  if (!fs::exists(p))
    throw RobotFileError("unknown robot '" + name_or_path + "': no file " + p.string());
  return p.string();
}

}  // namespace terrastride::robot
