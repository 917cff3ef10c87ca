// The URDF import's checks (urdf_checks.hpp).
#include "urdf_checks.hpp"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <map>
#include <set>
#include <vector>

namespace terrastride::robot::urdf_checks {
namespace {

// Magnitudes no legged robot's URDF reaches; within them every composition the import makes
// (frames down the tree, lumped inertias about the base) stays far from overflow.
constexpr double kMaxLength = 1e3;   // m: origins and primitive sizes
constexpr double kMaxMass = 1e5;     // kg per link
constexpr double kMaxInertia = 1e5;  // kg m^2 per entry
constexpr double kMaxLimit = 1e6;    // effort (N m or N), velocity (rad/s or m/s)

std::string num(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%g", v);
  return buf;
}

// TinyXML's element-name start: a letter, '_' or any byte of a multi-byte UTF-8 character.
bool name_start(unsigned char c) { return std::isalpha(c) || c == '_' || c >= 0x80; }

}  // namespace

XmlNesting xml_nesting(const std::string& xml, int limit) {
  XmlNesting deepest;
  int depth = 0;
  std::size_t line = 1, counted_to = 0;  // lines counted up to (not including) counted_to
  const std::size_t n = xml.size();
  const auto line_at = [&](std::size_t pos) {
    line += static_cast<std::size_t>(std::count(xml.begin() + counted_to, xml.begin() + pos, '\n'));
    counted_to = pos;
    return line;
  };
  // Past the first occurrence of `end` from `from`, or n (an unterminated construct: the XML
  // parser stops there too).
  const auto skip_past = [&](std::size_t from, const char* end) {
    const std::size_t at = xml.find(end, from);
    return at == std::string::npos ? n : at + std::char_traits<char>::length(end);
  };
  std::size_t i = 0;
  while ((i = xml.find('<', i)) != std::string::npos) {
    if (xml.compare(i, 4, "<!--") == 0) {
      i = skip_past(i + 4, "-->");
    } else if (xml.compare(i, 9, "<![CDATA[") == 0) {
      i = skip_past(i + 9, "]]>");
    } else if (xml.compare(i, 2, "</") == 0) {
      depth = std::max(0, depth - 1);
      i = skip_past(i + 2, ">");
    } else if (i + 1 < n && name_start(static_cast<unsigned char>(xml[i + 1]))) {
      // A start tag: to its '>' outside quoted attribute values (a quote opens a value only as
      // the first character after '=' and blanks, as TinyXML reads attributes).
      std::size_t j = i + 1;
      bool after_equals = false;
      for (; j < n && xml[j] != '>'; ++j) {
        const char c = xml[j];
        if (after_equals && (c == '"' || c == '\'')) {
          const std::size_t close = xml.find(c, j + 1);
          j = close == std::string::npos ? n - 1 : close;
          after_equals = false;
        } else if (c == '=') {
          after_equals = true;
        } else if (!std::isspace(static_cast<unsigned char>(c))) {
          after_equals = false;
        }
      }
      const bool empty = j < n && xml[j - 1] == '/';
      if (!empty && ++depth > deepest.depth) {
        deepest.depth = depth;
        deepest.line = line_at(i);
        if (depth > limit) return deepest;
      }
      i = j + 1;
    } else {
      // <!DOCTYPE ...>, <?xml ...?> and anything else TinyXML reads as an unknown: to the first
      // '>' (a quoted '>' in a declaration ends it later in TinyXML: scanning on from here only
      // sees more tags, never fewer).
      i = skip_past(i + 1, ">");
    }
  }
  return deepest;
}

void check_tree(const urdf::ModelInterface& model, std::size_t max_links, std::size_t max_joints) {
  if (model.links_.size() > max_links)
    throw Refusal(std::to_string(model.links_.size()) + " links, more than the " +
                  std::to_string(max_links) + " the import reads");
  if (model.joints_.size() > max_joints)
    throw Refusal(std::to_string(model.joints_.size()) + " joints, more than the " +
                  std::to_string(max_joints) + " the import reads");
  std::map<std::string, std::string> parent_joint;  // child link -> its joint
  for (const auto& [name, joint] : model.joints_) {
    if (joint->parent_link_name == joint->child_link_name)
      throw Refusal("joint '" + name + "' connects link '" + joint->child_link_name +
                    "' to itself (a URDF is a tree)");
    const auto [it, fresh] = parent_joint.emplace(joint->child_link_name, name);
    if (!fresh)
      throw Refusal("link '" + joint->child_link_name + "' is the child of two joints, '" +
                    it->second + "' and '" + name + "' (a URDF is a tree: one parent per link)");
  }
  // With one parent per link, a link the root does not reach lies on a cycle or below one: walk
  // up from it (at most one step per joint) to name the cycle.
  std::set<std::string> reached;
  std::vector<urdf::LinkConstSharedPtr> todo{model.getRoot()};
  while (!todo.empty() && todo.back()) {
    const urdf::LinkConstSharedPtr link = todo.back();
    todo.pop_back();
    if (!reached.insert(link->name).second) continue;
    for (const auto& child : link->child_links) todo.push_back(child);
  }
  for (const auto& [name, link] : model.links_) {
    if (reached.count(name)) continue;
    std::vector<std::string> chain{name};
    std::set<std::string> seen{name};
    for (std::size_t step = 0; step <= model.joints_.size(); ++step) {
      const auto up = parent_joint.find(chain.back());
      if (up == parent_joint.end()) break;
      const std::string parent = model.joints_.at(up->second)->parent_link_name;
      if (seen.count(parent)) {
        // The cycle from `parent` down, parent to child: each link after its joint.
        std::vector<std::string> cycle(std::find(chain.begin(), chain.end(), parent), chain.end());
        std::reverse(cycle.begin(), cycle.end());
        std::string joints, links = parent;
        for (const std::string& l : cycle) {
          joints += (joints.empty() ? "" : ", ") + parent_joint.at(l);
          links += " -> " + l;
        }
        throw Refusal("the joints " + joints + " form a cycle (links " + links + "): a URDF is a tree");
      }
      seen.insert(parent);
      chain.push_back(parent);
    }
    throw Refusal("link '" + name + "' is not connected to the root link '" +
                  model.getRoot()->name + "'");
  }
}

namespace {

void check_pose(const urdf::Pose& p, const std::string& what) {
  const double v[7] = {p.position.x, p.position.y, p.position.z, p.rotation.x,
                       p.rotation.y, p.rotation.z, p.rotation.w};
  for (double x : v)
    if (!std::isfinite(x)) throw Refusal(what + ": not finite");
  for (int k = 0; k < 3; ++k)
    if (std::abs(v[k]) > kMaxLength)
      throw Refusal(what + ": xyz " + num(v[k]) + " m, beyond " + num(kMaxLength) + " m");
}

void check_inertial(const urdf::Inertial& in, const std::string& link) {
  const std::string at = "link '" + link + "' inertial";
  check_pose(in.origin, at + " origin");
  if (!std::isfinite(in.mass) || in.mass < 0 || in.mass > kMaxMass)
    throw Refusal(at + ": mass " + num(in.mass) + " kg (must be in [0, " + num(kMaxMass) + "])");
  const double entries[6] = {in.ixx, in.iyy, in.izz, in.ixy, in.ixz, in.iyz};
  static const char* kNames[6] = {"ixx", "iyy", "izz", "ixy", "ixz", "iyz"};
  for (int k = 0; k < 6; ++k)
    if (!std::isfinite(entries[k]) || std::abs(entries[k]) > kMaxInertia)
      throw Refusal(at + ": inertia " + kNames[k] + " " + num(entries[k]) +
                    " (must be finite, at most " + num(kMaxInertia) + " kg m^2)");
  Eigen::Matrix3d i;
  i << in.ixx, in.ixy, in.ixz, in.ixy, in.iyy, in.iyz, in.ixz, in.iyz, in.izz;
  const Eigen::Vector3d eig = Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(i).eigenvalues();
  // Round-off of a URDF's rotated inertias leaves tiny negative eigenvalues on thin rods.
  if (eig.minCoeff() < -1e-9 * std::max(1e-12, eig.cwiseAbs().maxCoeff()))
    throw Refusal(at + ": the inertia is not positive semi-definite (principal moments " +
                  num(eig[0]) + ", " + num(eig[1]) + ", " + num(eig[2]) + " kg m^2)");
}

void check_size(double v, const std::string& what) {
  if (!std::isfinite(v) || !(v > 0) || v > kMaxLength)
    throw Refusal(what + " " + num(v) + " m (must be in (0, " + num(kMaxLength) + "])");
}

void check_collision(const urdf::Collision& c, const std::string& link) {
  const std::string at = "link '" + link + "' collision" + (c.name.empty() ? "" : " '" + c.name + "'");
  check_pose(c.origin, at + " origin");
  if (!c.geometry) return;
  switch (c.geometry->type) {
    case urdf::Geometry::SPHERE:
      check_size(static_cast<const urdf::Sphere&>(*c.geometry).radius, at + ": sphere radius");
      break;
    case urdf::Geometry::CYLINDER: {
      const auto& cy = static_cast<const urdf::Cylinder&>(*c.geometry);
      check_size(cy.radius, at + ": cylinder radius");
      check_size(cy.length, at + ": cylinder length");
      break;
    }
    case urdf::Geometry::BOX: {
      const auto& b = static_cast<const urdf::Box&>(*c.geometry);
      check_size(b.dim.x, at + ": box size x");
      check_size(b.dim.y, at + ": box size y");
      check_size(b.dim.z, at + ": box size z");
      break;
    }
    default:
      break;  // meshes are not read
  }
}

void check_joint(const urdf::Joint& j) {
  const std::string at = "joint '" + j.name + "'";
  check_pose(j.parent_to_joint_origin_transform, at + " origin");
  const double axis[3] = {j.axis.x, j.axis.y, j.axis.z};
  if (!std::isfinite(axis[0]) || !std::isfinite(axis[1]) || !std::isfinite(axis[2]) ||
      (j.type != urdf::Joint::FIXED && !(std::hypot(axis[0], axis[1], axis[2]) > 0)))
    throw Refusal(at + ": axis (" + num(axis[0]) + ", " + num(axis[1]) + ", " + num(axis[2]) +
                  ") is not a finite non-zero vector");
  if (!j.limits) return;
  const auto& l = *j.limits;
  if (!std::isfinite(l.lower) || !std::isfinite(l.upper))
    throw Refusal(at + ": limit lower " + num(l.lower) + ", upper " + num(l.upper) + ": not finite");
  if (!std::isfinite(l.effort) || std::abs(l.effort) > kMaxLimit)
    throw Refusal(at + ": limit effort " + num(l.effort) + " (must be finite, at most " +
                  num(kMaxLimit) + ")");
  if (!std::isfinite(l.velocity) || std::abs(l.velocity) > kMaxLimit)
    throw Refusal(at + ": limit velocity " + num(l.velocity) + " (must be finite, at most " +
                  num(kMaxLimit) + ")");
}

}  // namespace

void check_numbers(const urdf::ModelInterface& model) {
  for (const auto& [name, link] : model.links_) {
    if (link->inertial) check_inertial(*link->inertial, name);
    for (const auto& c : link->collision_array)
      if (c) check_collision(*c, name);
  }
  for (const auto& [name, joint] : model.joints_) check_joint(*joint);
}

}  // namespace terrastride::robot::urdf_checks
