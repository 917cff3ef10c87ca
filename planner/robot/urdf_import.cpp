// URDF -> robot file (urdf_import.hpp). urdfdom parses the XML and builds the link tree; this file
// walks it at q = 0, composes the fixed joints into the general leg geometry of robot_model.hpp
// (joint origins as offsets in the base frame, joint axes in the base frame: every joint frame is
// then parallel to the base, as LegModel wants), lumps inertias and reads collision primitives.
#include "terrastride/robot/urdf_import.hpp"

#include <console_bridge/console.h>
#include <urdf_parser/urdf_parser.h>

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <functional>
#include <map>
#include <optional>
#include <set>
#include <sstream>

#include "terrastride/robot/leg_kinematics.hpp"
#include "terrastride/robot/robot_model.hpp"
#include "urdf_checks.hpp"

namespace terrastride::robot {
namespace {

using Eigen::Isometry3d;
using Eigen::Matrix3d;
using Eigen::Vector3d;

constexpr double kRadToDeg = 180.0 / M_PI;

// urdfdom reports parse errors through console_bridge: collected here, so that the error names
// what urdfdom found instead of printing it to stderr.
class CollectingHandler : public console_bridge::OutputHandler {
 public:
  void log(const std::string& text, console_bridge::LogLevel level, const char*, int) override {
    if (level >= console_bridge::CONSOLE_BRIDGE_LOG_WARN) messages.push_back(text);
  }
  std::vector<std::string> messages;
};

Isometry3d to_eigen(const urdf::Pose& p) {
  Isometry3d t = Isometry3d::Identity();
  t.translate(Vector3d(p.position.x, p.position.y, p.position.z));
  t.rotate(Eigen::Quaterniond(p.rotation.w, p.rotation.x, p.rotation.y, p.rotation.z));
  return t;
}

// A link's place in the tree at q = 0: its frame in the base frame and the movable joints on the
// way from the base.
struct LinkInfo {
  urdf::LinkConstSharedPtr link;
  Isometry3d frame = Isometry3d::Identity();
  std::vector<urdf::JointConstSharedPtr> movable;
};

bool is_revolute(const urdf::Joint& j) {
  return j.type == urdf::Joint::REVOLUTE || j.type == urdf::Joint::CONTINUOUS;
}

// A collision primitive's points that bound it (box corners, cylinder rims, sphere poles), in the
// base frame; meshes have none.
std::vector<Vector3d> primitive_points(const Isometry3d& link_frame, const urdf::Collision& c) {
  std::vector<Vector3d> pts;
  if (!c.geometry) return pts;
  const Isometry3d t = link_frame * to_eigen(c.origin);
  switch (c.geometry->type) {
    case urdf::Geometry::BOX: {
      const auto& b = static_cast<const urdf::Box&>(*c.geometry);
      for (int k = 0; k < 8; ++k)
        pts.push_back(t * Vector3d((k & 1 ? 0.5 : -0.5) * b.dim.x, (k & 2 ? 0.5 : -0.5) * b.dim.y,
                                   (k & 4 ? 0.5 : -0.5) * b.dim.z));
      break;
    }
    case urdf::Geometry::CYLINDER: {
      const auto& cy = static_cast<const urdf::Cylinder&>(*c.geometry);
      for (int k = 0; k < 32; ++k) {
        const double a = 2 * M_PI * k / 32;
        for (double z : {-0.5 * cy.length, 0.5 * cy.length})
          pts.push_back(t * Vector3d(cy.radius * std::cos(a), cy.radius * std::sin(a), z));
      }
      break;
    }
    case urdf::Geometry::SPHERE: {
      const auto& s = static_cast<const urdf::Sphere&>(*c.geometry);
      for (int k = 0; k < 3; ++k)
        for (double sg : {-1.0, 1.0}) pts.push_back(t * (sg * s.radius * Vector3d::Unit(k)));
      break;
    }
    default:
      break;
  }
  return pts;
}

// The radius of a capsule along the link direction `dir` that holds the primitive's cross-
// section, when the primitive is elongated along the link (its long axis within 30 degrees of
// it); nullopt otherwise (a drive's disc at a joint, a housing across the link).
std::optional<double> along_link_radius(const Isometry3d& link_frame, const urdf::Collision& c,
                                        const Vector3d& dir) {
  if (!c.geometry) return std::nullopt;
  const Isometry3d t = link_frame * to_eigen(c.origin);
  const Matrix3d r = t.rotation();
  const double cos_max = std::cos(30.0 * M_PI / 180.0);
  if (c.geometry->type == urdf::Geometry::CYLINDER) {
    const auto& cy = static_cast<const urdf::Cylinder&>(*c.geometry);
    if (std::abs(r.col(2).dot(dir)) >= cos_max && cy.length >= 2 * cy.radius) return cy.radius;
    return std::nullopt;
  }
  if (c.geometry->type == urdf::Geometry::BOX) {
    const auto& b = static_cast<const urdf::Box&>(*c.geometry);
    const double dims[3] = {b.dim.x, b.dim.y, b.dim.z};
    const int longest = static_cast<int>(std::max_element(dims, dims + 3) - dims);
    if (std::abs(r.col(longest).dot(dir)) < cos_max) return std::nullopt;
    double sq = 0;
    for (int k = 0; k < 3; ++k)
      if (k != longest) sq += dims[k] * dims[k];
    return 0.5 * std::sqrt(sq);
  }
  return std::nullopt;
}

// Mass, centre of mass and inertia (about the centre of mass) of several bodies, base frame.
struct Lump {
  double mass = 0.0;
  Vector3d first_moment = Vector3d::Zero();
  Matrix3d inertia_at_origin = Matrix3d::Zero();  // about the base origin
  std::vector<std::string> links;
  void add(double m, const Vector3d& com, const Matrix3d& inertia_com) {
    mass += m;
    first_moment += m * com;
    inertia_at_origin += inertia_com + m * (com.squaredNorm() * Matrix3d::Identity() - com * com.transpose());
  }
  Vector3d com() const { return first_moment / mass; }
  Matrix3d inertia_about(const Vector3d& p) const {
    // Parallel axis: from the origin to the centre of mass, then to p.
    const Vector3d c = com();
    const Matrix3d at_com =
        inertia_at_origin - mass * (c.squaredNorm() * Matrix3d::Identity() - c * c.transpose());
    const Vector3d d = c - p;
    return at_com + mass * (d.squaredNorm() * Matrix3d::Identity() - d * d.transpose());
  }
  Matrix3d inertia_com() const { return inertia_about(com()); }
};

void add_link_inertial(Lump* lump, const LinkInfo& info) {
  lump->links.push_back(info.link->name);
  const auto& in = info.link->inertial;
  if (!in || !(in->mass > 0)) return;
  const Isometry3d t = info.frame * to_eigen(in->origin);
  Matrix3d i;
  i << in->ixx, in->ixy, in->ixz, in->ixy, in->iyy, in->iyz, in->ixz, in->iyz, in->izz;
  lump->add(in->mass, t.translation(), t.rotation() * i * t.rotation().transpose());
}

// The shortest text that reads back as the same double (round-off below 1e-12 of the URDF's
// compositions, such as 6e-15 m, written as 0: far below the 1e-9 m the import is tested to).
std::string num(double v) {
  if (std::abs(v) < 1e-12) v = 0.0;
  char buf[40];
  const auto res = std::to_chars(buf, buf + sizeof buf, v);
  return std::string(buf, res.ptr);
}
std::string short_num(double v) {
  char buf[40];
  std::snprintf(buf, sizeof buf, "%.6g", v == 0.0 ? 0.0 : v);
  return buf;
}
std::string vec(const Vector3d& v) { return "[" + num(v.x()) + ", " + num(v.y()) + ", " + num(v.z()) + "]"; }
std::string inertia_yaml(const Matrix3d& i) {
  return "{xx: " + num(i(0, 0)) + ", yy: " + num(i(1, 1)) + ", zz: " + num(i(2, 2)) +
         ", xy: " + num(i(0, 1)) + ", xz: " + num(i(0, 2)) + ", yz: " + num(i(1, 2)) + "}";
}

// An axis within 1e-10 of a coordinate axis is that axis (a URDF's rpy of 1.57079632679 is pi/2
// to 5e-12 rad): the closed-form inverse kinematics then applies (robot_model.hpp, LegShape).
Vector3d snap_axis(Vector3d a) {
  a.normalize();
  for (int k = 0; k < 3; ++k) {
    if (std::abs(a[k]) < 1e-10) a[k] = 0.0;
    if (std::abs(std::abs(a[k]) - 1.0) < 1e-10) a[k] = a[k] > 0 ? 1.0 : -1.0;
  }
  return a / a.norm();
}


// Text for a double-quoted YAML scalar.
std::string quoted(std::string s) {
  std::string out;
  for (char ch : s) {
    if (ch == '"' || ch == '\\') out += '\\';
    out += ch;
  }
  return out;
}

struct LegChain {
  std::string name;  // LF, RF, LH, RH
  std::array<urdf::JointConstSharedPtr, 3> joints;
  std::array<Isometry3d, 3> joint_frame;  // base frame at q = 0
  std::string foot_link;
  Vector3d foot_center = Vector3d::Zero();
  double foot_radius = 0.0;
  std::array<Lump, 3> links;
  std::array<std::vector<std::pair<Isometry3d, urdf::CollisionSharedPtr>>, 3> collisions;
};

std::string joint_list(const std::vector<urdf::JointConstSharedPtr>& joints) {
  std::string s;
  for (const auto& j : joints) s += (s.empty() ? "" : ", ") + j->name;
  return s;
}

}  // namespace

namespace {

// Every link at q = 0 with the movable joints above it, in depth-first pre-order (children in the
// URDF's order). Iterative: a tree of kMaxLinks links in one chain must not exhaust the stack;
// check_tree made it a tree, so each link is visited once.
std::vector<LinkInfo> walk_tree(const urdf::ModelInterface& model,
                                const std::function<void(const std::string&)>& fail) {
  std::vector<LinkInfo> infos;
  std::vector<LinkInfo> todo(1);
  todo.back().link = model.getRoot();
  while (!todo.empty()) {
    LinkInfo here = std::move(todo.back());
    todo.pop_back();
    const auto& joints = here.link->child_joints;
    for (auto it = joints.rbegin(); it != joints.rend(); ++it) {
      const urdf::JointConstSharedPtr& joint = *it;
      const urdf::LinkConstSharedPtr child = model.getLink(joint->child_link_name);
      if (!child) continue;
      LinkInfo next;
      next.link = child;
      next.frame = here.frame * to_eigen(joint->parent_to_joint_origin_transform);
      next.movable = here.movable;
      if (joint->type != urdf::Joint::FIXED) {
        if (!is_revolute(*joint))
          fail("joint '" + joint->name + "' is neither revolute nor fixed (a leg has three revolute joints)");
        next.movable.push_back(joint);
      }
      todo.push_back(std::move(next));
    }
    infos.push_back(std::move(here));
  }
  return infos;
}

// urdfdom's model of `xml`, after the nesting pre-scan; its tree and numbers checked.
urdf::ModelInterfaceSharedPtr parse_checked(const std::string& xml,
                                            const std::function<void(const std::string&)>& fail) {
  if (xml.size() > UrdfLimits::kMaxBytes)
    fail(std::to_string(xml.size()) + " bytes, more than the " + std::to_string(UrdfLimits::kMaxBytes) +
         " a URDF may have");
  // urdfdom's XML parser recurses once per nested element: refused before it sees the text.
  const urdf_checks::XmlNesting nesting = urdf_checks::xml_nesting(xml, UrdfLimits::kMaxXmlDepth);
  if (nesting.depth > UrdfLimits::kMaxXmlDepth)
    fail("XML elements nested " + std::to_string(nesting.depth) + " deep at line " +
         std::to_string(nesting.line) + ", more than the limit of " +
         std::to_string(UrdfLimits::kMaxXmlDepth) + " (a URDF nests some 5 deep)");
  try {
    urdf_checks::check_joint_cycles(xml);
  } catch (const urdf_checks::Refusal& e) {
    fail(e.what());
  }
  CollectingHandler handler;
  console_bridge::useOutputHandler(&handler);
  urdf::ModelInterfaceSharedPtr model;
  try {
    model = urdf::parseURDF(xml);
  } catch (const std::exception& e) {
    handler.messages.push_back(e.what());
  }
  console_bridge::restorePreviousOutputHandler();
  if (!model) {
    std::string why;
    for (const auto& m : handler.messages) why += (why.empty() ? "" : "; ") + m;
    fail("not a valid URDF (urdfdom: " + (why.empty() ? std::string("no reason given") : why) + ")");
  }
  if (!model->getRoot()) fail("the URDF has no root link");
  try {
    urdf_checks::check_tree(*model, UrdfLimits::kMaxLinks, UrdfLimits::kMaxJoints);
  } catch (const urdf_checks::Refusal& e) {
    // urdfdom's links hold their children by shared_ptr: a cycle it accepted would keep itself
    // alive (leaked) once the model goes.
    for (auto& named : model->links_) {
      named.second->child_links.clear();
      named.second->child_joints.clear();
    }
    fail(e.what());
  }
  try {
    urdf_checks::check_numbers(*model);
  } catch (const urdf_checks::Refusal& e) {
    fail(e.what());
  }
  return model;
}

// The file's bytes, refused beyond UrdfLimits::kMaxBytes without reading further (a FIFO or
// /dev/zero has no size to ask for first).
std::string read_bounded(const std::string& path, const std::function<void(const std::string&)>& fail) {
  std::ifstream in(path, std::ios::binary);
  if (!in) fail("cannot open the file");
  std::string xml(UrdfLimits::kMaxBytes + 1, '\0');
  in.read(&xml[0], static_cast<std::streamsize>(xml.size()));
  xml.resize(static_cast<std::size_t>(in.gcount()));
  if (in.bad()) fail("cannot read the file");
  if (xml.size() > UrdfLimits::kMaxBytes)
    fail("more than " + std::to_string(UrdfLimits::kMaxBytes) + " bytes, the most a URDF may have");
  return xml;
}

}  // namespace

UrdfImport import_urdf(const std::string& urdf_path, const UrdfImportOptions& options) {
  const auto fail = [&](const std::string& what) -> void {
    throw UrdfImportError(urdf_path + ": " + what);
  };
  if (options.name.empty()) fail("no robot name given");
  return import_urdf_text(read_bounded(urdf_path, fail), urdf_path, options);
}

namespace {

using Fail = std::function<void(const std::string&)>;

// The four leg chains: their joints, frames at q = 0, foot sphere and name (LF, RF, LH, RH, by
// where the HAA joint sits), in that order.
std::vector<LegChain> find_legs(const std::vector<LinkInfo>& infos, const UrdfImportOptions& options,
                                const Fail& fail) {
  // Feet: the named links, or every link three revolute joints down that has a sphere collision.
  const auto sphere_of = [](const urdf::Link& l) -> urdf::CollisionSharedPtr {
    for (const auto& c : l.collision_array)
      if (c && c->geometry && c->geometry->type == urdf::Geometry::SPHERE) return c;
    return nullptr;
  };
  std::vector<const LinkInfo*> feet;
  if (!options.feet.empty()) {
    for (const std::string& name : options.feet) {
      const auto it = std::find_if(infos.begin(), infos.end(),
                                   [&](const LinkInfo& i) { return i.link->name == name; });
      if (it == infos.end()) fail("--feet: no link '" + name + "'");
      if (it->movable.size() != 3)
        fail("--feet: link '" + name + "' lies " + std::to_string(it->movable.size()) +
             " revolute joints below the base (" + joint_list(it->movable) + "), a leg's foot lies 3");
      if (!sphere_of(*it->link) && !options.foot_radius)
        fail("foot link '" + name + "' has no sphere collision (the foot sphere's radius and centre come from it): "
             "give the radius with --foot-radius METRES (the link's frame origin is then the sphere's centre)");
      feet.push_back(&*it);
    }
  } else {
    std::set<std::string> chains_with_foot;
    for (const LinkInfo& i : infos)
      if (i.movable.size() == 3 && sphere_of(*i.link)) {
        feet.push_back(&i);
        chains_with_foot.insert(i.movable[2]->name);
      }
    // Mesh feet with --foot-radius: the chain's leaf link fixed below the KFE joint's link (a
    // foot frame of its own; the KFE link's own frame sits at the knee).
    if (options.foot_radius)
      for (const LinkInfo& i : infos)
        if (i.movable.size() == 3 && !chains_with_foot.count(i.movable[2]->name) &&
            i.link->child_joints.empty() && i.link->name != i.movable[2]->child_link_name) {
          feet.push_back(&i);
          chains_with_foot.insert(i.movable[2]->name);
        }
    // Chains of three revolute joints without any foot below them: named.
    for (const LinkInfo& i : infos)
      if (i.movable.size() == 3 && !chains_with_foot.count(i.movable[2]->name)) {
        fail("the leg chain " + joint_list(i.movable) + " ends without a foot: no link below joint '" +
             i.movable[2]->name + "' has a sphere collision" +
             (options.foot_radius ? " or is a foot link fixed below it" : "") +
             " (name the foot links with --foot-link LINK,LINK,LINK,LINK and give --foot-radius METRES "
             "for feet without a sphere)");
      }
  }
  if (feet.size() != 4) {
    std::string found;
    for (const LinkInfo* f : feet) found += (found.empty() ? "" : "; ") + f->link->name + " (" + joint_list(f->movable) + ")";
    std::set<std::string> other;
    for (const LinkInfo& i : infos)
      if (!i.movable.empty() && i.movable.size() != 3 && i.link->child_joints.empty())
        other.insert("link '" + i.link->name + "' after " + std::to_string(i.movable.size()) +
                     " revolute joint(s) (" + joint_list(i.movable) + ")");
    std::string others;
    for (const auto& o : other) others += (others.empty() ? "" : "; ") + o;
    fail("found " + std::to_string(feet.size()) +
         " leg chain(s) of three revolute joints ending in a foot sphere" +
         (found.empty() ? "" : " [" + found + "]") + ", a quadruped needs four" +
         (others.empty() ? "" : "; other chains: " + others));
  }

  // Name the legs by where their HAA joints sit: front/hind by x, left/right by y.
  std::vector<LegChain> legs;
  for (const LinkInfo* f : feet) {
    LegChain leg;
    for (int k = 0; k < 3; ++k) leg.joints[k] = f->movable[k];
    for (const LinkInfo& i : infos)
      for (int k = 0; k < 3; ++k)
        if (i.link->name == leg.joints[k]->child_link_name)
          leg.joint_frame[k] = i.frame;  // the child's frame is the joint's frame at q = 0
    const urdf::CollisionSharedPtr sphere = sphere_of(*f->link);
    leg.foot_link = f->link->name;
    if (sphere) {
      leg.foot_center = (f->frame * to_eigen(sphere->origin)).translation();
      leg.foot_radius = options.foot_radius ? *options.foot_radius
                                            : static_cast<const urdf::Sphere&>(*sphere->geometry).radius;
    } else {
      // A mesh foot: its link's frame origin is the sphere's centre, the radius is given.
      leg.foot_center = f->frame.translation();
      leg.foot_radius = *options.foot_radius;
      if ((leg.foot_center - leg.joint_frame[2].translation()).norm() < 1e-6)
        fail("foot link '" + leg.foot_link + "' has its frame at joint '" + leg.joints[2]->name +
             "' (the knee), not at the foot: name a link whose frame is the foot's centre with --foot-link");
    }
    const Vector3d haa = leg.joint_frame[0].translation();
    if (haa.x() == 0 || haa.y() == 0)
      fail("joint '" + leg.joints[0]->name + "' sits on the base's x or y axis: cannot tell front/hind and left/right");
    leg.name = std::string(haa.y() > 0 ? "L" : "R") + (haa.x() > 0 ? "F" : "H");
    for (const LegChain& other : legs)
      if (other.name == leg.name)
        fail("joints '" + other.joints[0]->name + "' and '" + leg.joints[0]->name + "' both sit at the " + leg.name + " corner");
    legs.push_back(leg);
  }
  std::sort(legs.begin(), legs.end(), [](const LegChain& a, const LegChain& b) {
    const auto order = [](const std::string& n) {
      return std::string("LF RF LH RH").find(n);
    };
    return order(a.name) < order(b.name);
  });

  return legs;
}

// Per leg, the joints' ranges (overrides applied, placeholders refused), effort and velocity.
struct JointLimits {
  std::array<double, 3> lo{}, hi{}, effort{}, velocity{};
  std::array<bool, 3> effort_given{}, velocity_given{};  // from --effort / --velocity
};

// A limit given on the command line for joint `j` (k-th of its leg: haa, hfe, kfe): by the
// joint's name, else by its kind; *used records which key served.
std::optional<double> given_limit(const std::map<std::string, double>& given, const urdf::Joint& j,
                                  int k, std::set<std::string>* used) {
  static const char* kKinds[3] = {"haa", "hfe", "kfe"};
  for (const std::string& key : {j.name, std::string(kKinds[k])}) {
    const auto it = given.find(key);
    if (it != given.end()) {
      used->insert(key);
      return it->second;
    }
  }
  return std::nullopt;
}
std::vector<JointLimits> read_limits(const std::vector<LegChain>& legs, const UrdfImportOptions& options,
                                     UrdfImport& out, const Fail& fail) {
  // Joint limits, with overrides; placeholders refused.
  std::set<std::string> used_overrides, used_effort, used_velocity;
  std::vector<JointLimits> limits(legs.size());
  for (size_t l = 0; l < legs.size(); ++l)
    for (int k = 0; k < 3; ++k) {
      const urdf::Joint& j = *legs[l].joints[k];
      if (const auto e = given_limit(options.effort, j, k, &used_effort)) {
        if (!(*e > 0) || !std::isfinite(*e)) fail("--effort " + j.name + ": must be a finite number > 0 (N m)");
        limits[l].effort[k] = *e;
        limits[l].effort_given[k] = true;
      } else if (!j.limits || !(j.limits->effort > 0)) {
        fail("joint '" + j.name + "' has no effort limit (the torque limit of the force polytopes): give it with --effort " +
             j.name + "=N_M");
      } else {
        limits[l].effort[k] = j.limits->effort;
      }
      if (const auto v = given_limit(options.velocity, j, k, &used_velocity)) {
        if (!(*v > 0) || !std::isfinite(*v)) fail("--velocity " + j.name + ": must be a finite number > 0 (rad/s)");
        limits[l].velocity[k] = *v;
        limits[l].velocity_given[k] = true;
      } else if (!j.limits || !(j.limits->velocity > 0)) {
        fail("joint '" + j.name + "' has no velocity limit (the joint speed the checks and the planner hold): give it with --velocity " +
             j.name + "=RAD_PER_S");
      } else {
        limits[l].velocity[k] = j.limits->velocity;
      }
      const auto ov = options.joint_range_deg.find(j.name);
      if (ov != options.joint_range_deg.end()) {
        used_overrides.insert(j.name);
        if (!(ov->second.first < ov->second.second))
          fail("--joint-range " + j.name + ": min must be below max");
        if (!(std::abs(ov->second.first) <= 360 && std::abs(ov->second.second) <= 360))
          fail("--joint-range " + j.name + ": min and max must be within [-360, 360] degrees");
        limits[l].lo[k] = ov->second.first / kRadToDeg;
        limits[l].hi[k] = ov->second.second / kRadToDeg;
        out.notes.push_back("joint '" + j.name + "': range [" + short_num(ov->second.first) + ", " +
                            short_num(ov->second.second) + "] deg given (the URDF says [" +
                            short_num(j.limits->lower * kRadToDeg) + ", " + short_num(j.limits->upper * kRadToDeg) + "])");
        continue;
      }
      const double lo = j.limits->lower, hi = j.limits->upper;
      if (j.type == urdf::Joint::CONTINUOUS)
        fail("joint '" + j.name + "' is continuous (no range): give its range with --joint-range " + j.name + "=MIN:MAX (degrees)");
      if (!(hi > lo) || hi - lo >= 2 * M_PI || std::abs(lo) > 2 * M_PI || std::abs(hi) > 2 * M_PI)
        fail("joint '" + j.name + "' has the range [" + short_num(lo * kRadToDeg) + ", " + short_num(hi * kRadToDeg) +
             "] deg, a placeholder (wider than a full turn or empty), not the joint's stops: give its range with --joint-range " +
             j.name + "=MIN:MAX (degrees)");
      limits[l].lo[k] = lo;
      limits[l].hi[k] = hi;
    }
  for (const auto& [name, range] : options.joint_range_deg)
    if (!used_overrides.count(name)) fail("--joint-range names '" + name + "', which is not a leg joint");
  for (const auto& [name, value] : options.effort)
    if (!used_effort.count(name)) fail("--effort names '" + name + "', which is not a leg joint (nor haa, hfe, kfe)");
  for (const auto& [name, value] : options.velocity)
    if (!used_velocity.count(name)) fail("--velocity names '" + name + "', which is not a leg joint (nor haa, hfe, kfe)");

  return limits;
}

// Placeholder efforts and velocities (1000 N m, 1000 rad/s are common in research URDFs), judged
// against the robot's own size: the weight m g and the stretched leg's length L (thigh + shank).
// Real quadrupeds' joints hold 0.3-0.8 m g L (HyQ 0.26, ANYmal C 0.27, Go2's knee 0.72) and turn
// the stretched leg's foot at 4-17 m/s (ANYmal C 4.5, Go2's hip 12.8): an effort above
// kPlaceholderEffort m g L, or a velocity whose foot speed v L exceeds kPlaceholderFootSpeed, is
// not the motor's. Limits given with --effort / --velocity are taken as they are.
constexpr double kPlaceholderEffort = 3.0;        // times m g L
constexpr double kPlaceholderFootSpeed = 25.0;    // m/s
void refuse_placeholder_limits(const std::vector<LegChain>& legs, const std::vector<JointLimits>& limits,
                               const std::vector<LegModel>& models, double mass, const Fail& fail) {
  static const char* kKinds[3] = {"haa", "hfe", "kfe"};
  for (size_t l = 0; l < legs.size(); ++l) {
    const double reach = models[l].l1 + models[l].l2;
    const double effort_cap = kPlaceholderEffort * mass * 9.81 * reach;
    const double velocity_cap = kPlaceholderFootSpeed / reach;
    for (int k = 0; k < 3; ++k) {
      const std::string& name = legs[l].joints[k]->name;
      if (!limits[l].effort_given[k] && limits[l].effort[k] > effort_cap)
        fail("joint '" + name + "' has the effort limit " + short_num(limits[l].effort[k]) +
             " N m, a placeholder: it would hold " + short_num(limits[l].effort[k] / (mass * 9.81 * reach)) +
             " times the robot's weight (" + short_num(mass) + " kg) at the end of its stretched leg (" +
             short_num(reach) + " m), more than " + short_num(kPlaceholderEffort) +
             ": give the motor's with --effort " + name + "=N_M (or --effort " + kKinds[k] + "=N_M for every leg)");
      if (!limits[l].velocity_given[k] && limits[l].velocity[k] > velocity_cap)
        fail("joint '" + name + "' has the velocity limit " + short_num(limits[l].velocity[k]) +
             " rad/s, a placeholder: it would move the stretched leg's foot (" + short_num(reach) + " m) at " +
             short_num(limits[l].velocity[k] * reach) + " m/s, more than " + short_num(kPlaceholderFootSpeed) +
             " m/s: give the motor's with --velocity " + name + "=RAD_PER_S (or --velocity " + kKinds[k] +
             "=RAD_PER_S for every leg)");
    }
  }
}

// The legs' general geometry (robot_model.hpp) with their limits and knees; *foot_radius the
// largest foot sphere.
std::vector<LegModel> leg_models(const std::vector<LegChain>& legs, const std::vector<JointLimits>& limits,
                                 UrdfImport& out, const Fail& fail, double* foot_radius_out) {
  std::vector<LegModel> models(legs.size());
  // The legs' geometry: joint origins and axes at q = 0 in the base frame.
  double foot_radius = 0;
  for (size_t l = 0; l < legs.size(); ++l) {
    const LegChain& c = legs[l];
    LegModel& m = models[l];
    m.name = c.name;
    m.haa_origin = c.joint_frame[0].translation();
    for (int k = 0; k < 3; ++k) {
      const urdf::Vector3& a = c.joints[k]->axis;
      m.joint_axis[k] = snap_axis(c.joint_frame[k].rotation() * Vector3d(a.x, a.y, a.z));
    }
    m.joint_offset[0] = c.joint_frame[1].translation() - c.joint_frame[0].translation();
    m.joint_offset[1] = c.joint_frame[2].translation() - c.joint_frame[1].translation();
    m.joint_offset[2] = c.foot_center - c.joint_frame[2].translation();
    for (int k = 0; k < 3; ++k) {
      m.q_min[k] = limits[l].lo[k];
      m.q_max[k] = limits[l].hi[k];
      m.torque_limit[k] = limits[l].effort[k];
      m.velocity_limit[k] = limits[l].velocity[k];
    }
    try {
      classify_leg_geometry(m, false);
    } catch (const std::invalid_argument& e) {
      fail(std::string(e.what()) + " (joints " + c.joints[0]->name + ", " + c.joints[1]->name + ", " + c.joints[2]->name + ")");
    }
    // The knee bends to one side of the straight leg over the whole KFE range.
    if (m.shape != LegShape::general) {
      const Vector3d &d1 = m.joint_offset[1], &d2 = m.joint_offset[2];
      const double straight =
          m.joint_axis[2].y() * std::atan2(d1.x() * d2.z() - d1.z() * d2.x(), d1.x() * d2.x() + d1.z() * d2.z());
      const double lo = m.q_min[2] - straight, hi = m.q_max[2] - straight;
      if (lo < 0 && hi > 0)
        fail("joint '" + c.joints[2]->name + "': its range [" + short_num(m.q_min[2] * kRadToDeg) + ", " +
             short_num(m.q_max[2] * kRadToDeg) + "] deg holds the straight leg (" + short_num(straight * kRadToDeg) +
             " deg): the knee would bend both ways; give its range with --joint-range " + c.joints[2]->name + "=MIN:MAX");
      m.knee_sign = hi <= 0 ? -1 : +1;
    }
    foot_radius = std::max(foot_radius, c.foot_radius);
    out.notes.push_back("leg " + c.name + ": joints " + c.joints[0]->name + ", " + c.joints[1]->name + ", " +
                        c.joints[2]->name + ", foot '" + c.foot_link + "' (sphere r = " + short_num(c.foot_radius) +
                        " m); " + (m.shape == LegShape::general ? "general axes (numeric IK)" : "closed-form IK"));
  }

  *foot_radius_out = foot_radius;
  return models;
}

// What the robot file is written from.
struct ImportedRobot {
  std::vector<LegChain> legs;
  std::vector<LegModel> models;
  std::vector<double> thigh_radius, shin_radius;
  double height = 0.0, foot_radius = 0.0;
  std::vector<Vector3d> q_nominal;
  Lump body;
  Vector3d shift = Vector3d::Zero(), trunk_lo = Vector3d::Zero(), trunk_hi = Vector3d::Zero();
};

// Link radii from the collision primitives along each link, the nominal stance.
void radii_and_stance(ImportedRobot& r, const UrdfImportOptions& options, UrdfImport& out, const Fail& fail) {
  const std::vector<LegChain>& legs = r.legs;
  std::vector<LegModel>& models = r.models;
  // Link radii from the collision primitives along each link; stated defaults where none.
  std::vector<double>& thigh_radius = r.thigh_radius;
  std::vector<double>& shin_radius = r.shin_radius;
  thigh_radius.assign(legs.size(), 0.0);
  shin_radius.assign(legs.size(), 0.0);
  for (size_t l = 0; l < legs.size(); ++l) {
    const LegModel& m = models[l];
    for (int k : {1, 2}) {
      const Vector3d dir = m.joint_offset[k].normalized();
      double r = 0;
      for (const auto& [frame, c] : legs[l].collisions[k])
        if (const auto rr = along_link_radius(frame, *c, dir)) r = std::max(r, *rr);
      const double fallback = 0.06 * (m.l1 + m.l2);
      if (!(r > 0)) {
        r = fallback;
        out.defaults.push_back("leg " + m.name + ": no collision primitive along its " + (k == 1 ? "thigh" : "shank") +
                               ": capsule radius " + short_num(r) + " m (6 % of the leg's length)");
      }
      (k == 1 ? thigh_radius : shin_radius)[l] = r;
    }
  }

  // The nominal stance: each foot under its HFE joint, at the foot's lateral place of q = 0.
  double leg_drop = 0;
  for (const LegModel& m : models) leg_drop = std::max(leg_drop, -(foot_position(m, Vector3d::Zero()) - m.haa_origin).z());
  double& height = r.height;
  if (options.nominal_height) {
    height = *options.nominal_height;
    if (!(height > 0) || !std::isfinite(height)) fail("--nominal-height must be a finite number > 0");
  } else {
    height = 0.75 * leg_drop;
    out.defaults.push_back("nominal base height " + short_num(height) +
                           " m (75 % of the feet's drop below the HAA joints at q = 0, " + short_num(leg_drop) +
                           " m; --nominal-height to change)");
  }
  out.defaults.push_back("nominal feet: under the HFE joints at q = 0, at the feet's lateral place of q = 0, z = -nominal height");
  std::vector<Vector3d>& q_nominal = r.q_nominal;
  q_nominal.assign(legs.size(), Vector3d::Zero());
  for (size_t l = 0; l < legs.size(); ++l) {
    LegModel& m = models[l];
    const Vector3d hfe = m.haa_origin + m.joint_offset[0];
    m.nominal_foot = Vector3d(hfe.x(), foot_position(m, Vector3d::Zero()).y(), -height);
    const IkResult ik = inverse_kinematics(m, m.nominal_foot);
    if (!ik.ok())
      fail("nominal stance at height " + short_num(height) + " m: " + ik.message + " (--nominal-height to change)");
    q_nominal[l] = ik.q;
  }

}

// The trunk box: the base's collision primitives' bounding box, or a stated default.
void trunk_box(ImportedRobot& r, const std::vector<Vector3d>& trunk_points,
               const std::vector<std::string>& skipped_meshes, UrdfImport& out) {
  const std::vector<LegModel>& models = r.models;
  Vector3d& trunk_lo = r.trunk_lo;
  Vector3d& trunk_hi = r.trunk_hi;
  // The trunk box: the bounding box of the base's collision primitives.
  if (!trunk_points.empty()) {
    trunk_lo = trunk_hi = trunk_points.front();
    for (const Vector3d& p : trunk_points) {
      trunk_lo = trunk_lo.cwiseMin(p);
      trunk_hi = trunk_hi.cwiseMax(p);
    }
    out.notes.push_back("trunk box: the bounding box of the base's collision boxes, cylinders and spheres" +
                        std::string(skipped_meshes.empty() ? "" : " (meshes left out)"));
  } else {
    trunk_lo = trunk_hi = models[0].haa_origin;
    for (const LegModel& m : models) {
      trunk_lo = trunk_lo.cwiseMin(m.haa_origin);
      trunk_hi = trunk_hi.cwiseMax(m.haa_origin);
    }
    trunk_lo.z() = -0.05;
    trunk_hi.z() = 0.05;
    out.defaults.push_back("trunk box: the base has no collision primitive: the box spanning the HAA joints, 0.1 m high");
  }

}

// The robot file's text.
std::string robot_yaml(const ImportedRobot& r, const UrdfImport& out, const UrdfImportOptions& options,
                       const std::string& urdf_path, const std::string& urdf_robot,
                       const std::string& xml, const Fail& fail) {
  const std::vector<LegChain>& legs = r.legs;
  const std::vector<LegModel>& models = r.models;
  const Lump& body = r.body;
  const Vector3d& shift = r.shift;
  const double height = r.height, foot_radius = r.foot_radius;
  const Vector3d &trunk_lo = r.trunk_lo, &trunk_hi = r.trunk_hi;
  const std::vector<Vector3d>& q_nominal = r.q_nominal;
  const std::vector<double> &thigh_radius = r.thigh_radius, &shin_radius = r.shin_radius;
  // The robot file.
  std::ostringstream y;
  y << "# " << options.name << ", imported from a URDF by `terrastride robot import` (docs/design.md §4.3).\n"
    << "# Geometry, limits, inertias, foot sphere and link radii come from the URDF; the stated defaults\n"
    << "# below (nominal stance, range-of-motion box, shin model) do not: the URDF does not hold them.\n";
  for (const auto& d : out.defaults) y << "#   default: " << d << "\n";
  for (const auto& n : out.notes) y << "#   " << n << "\n";
  y << "name: " << options.name << "\n"
    << "source: {urdf: \"" << quoted(urdf_path) << "\", urdf_robot: \"" << quoted(urdf_robot) << "\", fnv1a64: \"" << robot_definition_hash(xml)
    << "\", base_origin_in_urdf: " << vec(shift)
    << (options.command.empty() ? "" : ", command: \"" + quoted(options.command) + "\"") << "}\n"
    << "body:\n"
    << "  mass: " << num(body.mass) << "   # kg, all links (SRBD)\n"
    << "  inertia: " << inertia_yaml(body.inertia_com()) << "   # about the centre of mass, nominal stance\n"
    << "nominal_base_height: " << num(height + shift.z()) << "   # the centre of mass above the ground\n"
    << "foot_radius: " << num(foot_radius) << "\n"
    << "trunk:\n"
    << "  size: " << vec(trunk_hi - trunk_lo) << "\n"
    << "  center: " << vec(0.5 * (trunk_hi + trunk_lo) - shift) << "\n"
    << "legs:\n";
  static const char* kJoints[3] = {"haa", "hfe", "kfe"};
  static const char* kLinks[3] = {"hip", "upper", "lower"};
  for (size_t l = 0; l < legs.size(); ++l) {
    const LegModel& m = models[l];
    const LegChain& c = legs[l];
    y << "  - name: " << m.name << "   # joints " << c.joints[0]->name << ", " << c.joints[1]->name << ", "
      << c.joints[2]->name << "; foot " << c.foot_link << "\n"
      << "    knee: " << (m.knee_sign < 0 ? "backward" : "forward") << "\n"
      << "    haa_origin: " << vec(m.haa_origin - shift) << "\n"
      << "    geometry:\n"
      << "      haa_to_hfe: " << vec(m.joint_offset[0]) << "\n"
      << "      hfe_to_kfe: " << vec(m.joint_offset[1]) << "\n"
      << "      kfe_to_foot: " << vec(m.joint_offset[2]) << "   # to the foot sphere's centre\n"
      << "      axes: {haa: " << vec(m.joint_axis[0]) << ", hfe: " << vec(m.joint_axis[1]) << ", kfe: "
      << vec(m.joint_axis[2]) << "}\n"
      << "    joint_range_deg: {";
    for (int k = 0; k < 3; ++k)
      y << (k ? ", " : "") << kJoints[k] << ": [" << num(m.q_min[k] * kRadToDeg) << ", " << num(m.q_max[k] * kRadToDeg) << "]";
    y << "}\n    torque_limit: {";
    for (int k = 0; k < 3; ++k) y << (k ? ", " : "") << kJoints[k] << ": " << num(m.torque_limit[k]);
    y << "}\n";
    if (m.velocity_limit.minCoeff() > 0) {
      y << "    velocity_limit: {";
      for (int k = 0; k < 3; ++k) y << (k ? ", " : "") << kJoints[k] << ": " << num(m.velocity_limit[k]);
      y << "}\n";
    }
    y << "    links:\n";
    for (int k = 0; k < 3; ++k) {
      const Lump& link = c.links[k];
      if (!(link.mass > 0))
        fail("leg " + m.name + ": the links moved by joint '" + c.joints[k]->name + "' have no mass");
      const Vector3d joint_q0 = k == 0 ? m.haa_origin
                                       : (k == 1 ? Vector3d(m.haa_origin + m.joint_offset[0])
                                                 : Vector3d(m.haa_origin + m.joint_offset[0] + m.joint_offset[1]));
      y << "      " << kLinks[k] << ": {mass: " << num(link.mass) << ", com: " << vec(link.com() - joint_q0)
        << ", inertia: " << inertia_yaml(link.inertia_com()) << "}\n";
    }
    const double reach = m.l1 + m.l2;
    y << "    nominal_foot: " << vec(m.nominal_foot - shift) << "\n"
      << "    range_of_motion: " << vec(Vector3d(0.25, 0.20, 0.10) * (reach / 0.691)) << "\n";
    const LegFrames fr = leg_frames(m, q_nominal[l]);
    const Vector3d shank = fr.origin[2] - fr.foot;
    const double beta = std::atan2(shank.z(), shank.x()) * kRadToDeg;
    y << "    shin: {length: " << num(0.88 * m.l2) << ", angle_deg: " << num(beta) << ", radius: " << num(shin_radius[l])
      << "}\n"
      << "    thigh: {radius: " << num(thigh_radius[l]) << "}\n";
  }
  return y.str();
}

}  // namespace

UrdfImport import_urdf_text(const std::string& xml, const std::string& urdf_path,
                            const UrdfImportOptions& options) {
  UrdfImport out;
  const Fail fail = [&](const std::string& what) -> void {
    throw UrdfImportError(urdf_path + ": " + what);
  };
  if (options.name.empty()) fail("no robot name given");
  if (options.foot_radius && !(*options.foot_radius > 0 && *options.foot_radius < 1))
    fail("--foot-radius must be a number of metres in (0, 1)");
  const urdf::ModelInterfaceSharedPtr model = parse_checked(xml, fail);
  const urdf::LinkConstSharedPtr root = model->getRoot();
  const std::vector<LinkInfo> infos = walk_tree(*model, fail);
  out.notes.push_back("base link '" + root->name + "' (the URDF's root)");

  ImportedRobot r;
  r.legs = find_legs(infos, options, fail);
  std::vector<LegChain>& legs = r.legs;

  // Links: the base (no revolute joint above) and each leg's three moving links (everything
  // fixed below joint k, up to the next revolute joint), inertia lumped, collisions kept.
  Lump base;
  std::vector<Vector3d> trunk_points;
  std::vector<std::string> skipped_meshes;
  for (const LinkInfo& i : infos) {
    if (i.movable.empty()) {
      add_link_inertial(&base, i);
      for (const auto& c : i.link->collision_array) {
        const auto pts = primitive_points(i.frame, *c);
        if (pts.empty()) skipped_meshes.push_back(i.link->name);
        trunk_points.insert(trunk_points.end(), pts.begin(), pts.end());
      }
      continue;
    }
    bool placed = false;
    for (LegChain& leg : legs) {
      if (i.movable[0] != leg.joints[0]) continue;
      const int k = static_cast<int>(i.movable.size()) - 1;
      if (k > 2 || (k >= 1 && i.movable[1] != leg.joints[1]) || (k == 2 && i.movable[2] != leg.joints[2]))
        fail("joint '" + i.movable.back()->name + "' branches off leg " + leg.name +
             "'s chain: a leg is one chain of three revolute joints");
      add_link_inertial(&leg.links[k], i);
      for (const auto& c : i.link->collision_array) leg.collisions[k].push_back({i.frame, c});
      placed = true;
    }
    if (!placed) fail("link '" + i.link->name + "' moves with joint '" + i.movable[0]->name + "', which is not a leg's HAA joint");
  }
  if (!(base.mass > 0)) fail("the base link '" + root->name + "' and the links fixed to it have no mass");

  const std::vector<JointLimits> limits = read_limits(legs, options, out, fail);
  r.models = leg_models(legs, limits, out, fail, &r.foot_radius);
  const std::vector<LegModel>& models = r.models;
  const double foot_radius = r.foot_radius;
  radii_and_stance(r, options, out, fail);
  const std::vector<Vector3d>& q_nominal = r.q_nominal;

  // The SRBD body: every link, legs at the nominal stance; inertia about the centre of mass.
  Lump& body = r.body;
  body = base;
  for (size_t l = 0; l < legs.size(); ++l) {
    const LegFrames fr = leg_frames(models[l], q_nominal[l]);
    for (int k = 0; k < 3; ++k) {
      const Lump& link = legs[l].links[k];
      if (!(link.mass > 0)) continue;
      // The link turns with its joint: its inertia about its centre turned by fr.rotation[k].
      const Vector3d com_q0 = link.com();
      const Vector3d joint_q0 = k == 0 ? models[l].haa_origin
                                       : (k == 1 ? Vector3d(models[l].haa_origin + models[l].joint_offset[0])
                                                 : Vector3d(models[l].haa_origin + models[l].joint_offset[0] + models[l].joint_offset[1]));
      const Vector3d com_q = fr.origin[k] + fr.rotation[k] * (com_q0 - joint_q0);
      body.add(link.mass, com_q, fr.rotation[k] * link.inertia_com() * fr.rotation[k].transpose());
    }
  }
  // The SRBD model puts the centre of mass at the base origin (the planner's dynamics and the
  // simulator's trunk = body - legs both rely on it): the robot file's base frame is the URDF's
  // base frame moved to the centre of mass at the nominal stance (axes unchanged). On Go2 the
  // legs are 55 % of the mass, so the difference matters: left in the URDF's frame, the trunk
  // that makes the body's centre the origin would sit 14 cm up, with an unphysical inertia.
  refuse_placeholder_limits(legs, limits, models, body.mass, fail);
  r.shift = body.com();
  const Vector3d& shift = r.shift;
  out.base_origin_in_urdf = {shift.x(), shift.y(), shift.z()};
  out.notes.push_back("SRBD: mass " + short_num(body.mass) + " kg (" + std::to_string(infos.size()) +
                      " links); its centre of mass at the nominal stance, (" + short_num(shift.x()) + ", " +
                      short_num(shift.y()) + ", " + short_num(shift.z()) +
                      ") m in the URDF's base frame, is the robot file's base origin");

  trunk_box(r, trunk_points, skipped_meshes, out);

  // Defaults the URDF does not hold: range of motion and the shin model.
  out.defaults.push_back("range of motion: HyQ's box (0.25, 0.20, 0.10 m for 0.691 m of thigh and shank) scaled by the leg's thigh + shank");
  out.defaults.push_back("shin model: s = 0.88 x the KFE-foot length (HyQ's 0.30 of 0.341), angle = the shank's angle to the ground at the nominal stance");
  if (foot_radius != legs[0].foot_radius || foot_radius != legs[3].foot_radius)
    out.notes.push_back("the feet's sphere radii differ: the largest, " + short_num(foot_radius) + " m, is used");

  out.yaml = robot_yaml(r, out, options, urdf_path, model->getName(), xml, fail);
  // Read back with the robot-file reader: what is written loads.
  try {
    parse_robot(out.yaml, "the imported robot file");
  } catch (const RobotFileError& e) {
    fail(std::string("the imported robot does not load: ") + e.what());
  }
  return out;
}

}  // namespace terrastride::robot
