// The URDF import's checks (urdf_checks.hpp).
#include "urdf_checks.hpp"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <map>
#include <set>
#include <string_view>
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

// Calls on_start(begin, end, depth, empty) for each start tag, by TinyXML's lexical rules: the
// tag is xml[begin, end) ('<' to '>'), depth 1 the root element, `empty` for <.../>; stops when
// it returns false.
template <class OnStart>
void scan_start_tags(const std::string& xml, OnStart&& on_start) {
  int depth = 0;
  const std::size_t n = xml.size();
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
      if (!on_start(i, std::min(j + 1, n), depth + 1, empty)) return;
      if (!empty) ++depth;
      i = j + 1;
    } else {
      // <!DOCTYPE ...>, <?xml ...?> and anything else TinyXML reads as an unknown: to the first
      // '>' (a quoted '>' in a declaration ends it later in TinyXML: scanning on from here only
      // sees more tags, never fewer).
      i = skip_past(i + 1, ">");
    }
  }
}

// A start tag's element name.
std::string tag_name(const std::string& xml, std::size_t begin, std::size_t end) {
  std::size_t k = begin + 1;
  while (k < end && !std::isspace(static_cast<unsigned char>(xml[k])) && xml[k] != '/' && xml[k] != '>') ++k;
  return xml.substr(begin + 1, k - begin - 1);
}

// The raw (not entity-decoded: names equal as written are equal to urdfdom too) value of
// attribute `key` in a start tag, "" when absent. Searched within the tag only.
std::string tag_attribute(const std::string& xml, std::size_t begin, std::size_t end,
                          const std::string& key) {
  const std::string_view tag(xml.data() + begin, end - begin);
  for (std::size_t k = tag.find(key, 1); k != std::string_view::npos; k = tag.find(key, k + 1)) {
    if (!std::isspace(static_cast<unsigned char>(tag[k - 1]))) continue;
    std::size_t v = k + key.size();
    while (v < tag.size() && std::isspace(static_cast<unsigned char>(tag[v]))) ++v;
    if (v >= tag.size() || tag[v] != '=') continue;
    ++v;
    while (v < tag.size() && std::isspace(static_cast<unsigned char>(tag[v]))) ++v;
    if (v >= tag.size() || (tag[v] != '"' && tag[v] != '\'')) return "";
    const std::size_t close = tag.find(tag[v], v + 1);
    if (close == std::string_view::npos) return "";
    return std::string(tag.substr(v + 1, close - v - 1));
  }
  return "";
}

}  // namespace

XmlNesting xml_nesting(const std::string& xml, int limit) {
  XmlNesting deepest;
  std::size_t line = 1, counted_to = 0;  // lines counted up to (not including) counted_to
  scan_start_tags(xml, [&](std::size_t begin, std::size_t, int depth, bool empty) {
    if (empty || depth <= deepest.depth) return true;
    line += static_cast<std::size_t>(std::count(xml.begin() + counted_to, xml.begin() + begin, '\n'));
    counted_to = begin;
    deepest = {depth, line};
    return depth <= limit;
  });
  return deepest;
}

void check_joint_cycles(const std::string& xml) {
  // The root element's <joint> children with their first <parent> and <child> link.
  struct Edge {
    std::string joint, child;
  };
  std::map<std::string, std::vector<Edge>> children;  // parent link -> its joints
  std::string joint, parent, child;
  std::size_t joints = 0;
  const auto close_joint = [&] {
    if (!joint.empty() && !parent.empty() && !child.empty()) {
      if (parent == child)
        throw Refusal("joint '" + joint + "' connects link '" + child + "' to itself (a URDF is a tree)");
      children[parent].push_back({joint, child});
      ++joints;
    }
    joint.clear();
    parent.clear();
    child.clear();
  };
  bool is_robot = false;
  scan_start_tags(xml, [&](std::size_t begin, std::size_t end, int depth, bool) {
    const std::string name = tag_name(xml, begin, end);
    if (depth == 1) is_robot = name == "robot";
    if (!is_robot) return false;
    if (depth == 2) close_joint();
    if (depth == 2 && name == "joint") joint = tag_attribute(xml, begin, end, "name");
    // urdfdom reads a joint's first <parent> and <child>.
    if (depth == 3 && !joint.empty() && name == "parent" && parent.empty())
      parent = tag_attribute(xml, begin, end, "link");
    if (depth == 3 && !joint.empty() && name == "child" && child.empty())
      child = tag_attribute(xml, begin, end, "link");
    return joints <= 100000;
  });
  close_joint();
  // Depth-first from every link, iteratively: a joint to a link on the current path closes a
  // cycle, named from that link round.
  std::map<std::string, int> state;  // 1 on the path, 2 done
  for (const auto& start : children) {
    if (state[start.first]) continue;
    std::vector<std::pair<std::string, std::size_t>> path{{start.first, 0}};
    std::vector<std::string> via;  // via[k]: the joint from path[k] to path[k + 1]
    state[start.first] = 1;
    while (!path.empty()) {
      auto& [link, next] = path.back();
      const auto it = children.find(link);
      if (it == children.end() || next >= it->second.size()) {
        state[link] = 2;
        path.pop_back();
        if (!via.empty()) via.pop_back();
        continue;
      }
      const Edge edge = it->second[next++];
      if (state[edge.child] == 1) {
        std::size_t k = 0;
        while (path[k].first != edge.child) ++k;
        std::string joint_names, link_names = edge.child;
        for (std::size_t m = k; m < path.size(); ++m) {
          joint_names += (joint_names.empty() ? "" : ", ") + (m + 1 < path.size() ? via[m] : edge.joint);
          link_names += " -> " + (m + 1 < path.size() ? path[m + 1].first : edge.child);
        }
        throw Refusal("the joints " + joint_names + " form a cycle (links " + link_names +
                      "): a URDF is a tree");
      }
      if (state[edge.child] == 0) {
        state[edge.child] = 1;
        via.push_back(edge.joint);
        path.push_back({edge.child, 0});
      }
    }
  }
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
