// A robot file (data/robots/*.yaml) from a URDF, read with Debian's urdfdom (docs/design.md §4.3,
// "Robots from URDF"): the four HAA-HFE-KFE leg chains ending in a foot sphere, fixed joints
// composed, fixed children's inertia lumped into the moving link, effort/velocity/range limits,
// the foot sphere radius and link radii from the collision primitives, and the SRBD mass and
// composite inertia at the nominal stance. What a URDF does not hold (nominal stance, range-of-
// motion box, shin model) gets stated defaults, listed in UrdfImport::defaults.
#pragma once

#include <array>
#include <cstddef>
#include <map>
#include <optional>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace terrastride::robot {

// The URDF cannot be imported; the message names the file and the joint or link at fault.
class UrdfImportError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

struct UrdfImportOptions {
  std::string name;                      // the robot's name in the file (required)
  std::vector<std::string> feet;         // foot link names; empty: every leg chain's sphere link
  std::optional<double> nominal_height;  // m, base above flat ground in the nominal stance
  // Joint ranges that replace the URDF's (by URDF joint name, degrees): required where the URDF's
  // are placeholders (a range wider than a full turn, or a continuous joint).
  std::map<std::string, std::pair<double, double>> joint_range_deg;
  // Effort (N m) and velocity (rad/s) limits that replace the URDF's, keyed by URDF joint name or
  // by joint kind ("haa", "hfe", "kfe": that joint of every leg; a joint's own name wins):
  // required where the URDF's are missing or placeholders (urdf_import.cpp, kPlaceholder*).
  std::map<std::string, double> effort;
  std::map<std::string, double> velocity;
  // The foot sphere's radius (m) for feet without a sphere collision (mesh feet): the foot link's
  // frame origin is then the sphere's centre. Also replaces the radius of sphere feet.
  std::optional<double> foot_radius;
  std::string command;  // how the file was made (recorded in its `source`)
};

struct UrdfImport {
  std::string yaml;                   // the robot file's text (load_robot reads it back)
  std::vector<std::string> defaults;  // values the URDF does not hold, with the default used
  std::vector<std::string> notes;     // what was read and from where
  // The robot file's base origin (the centre of mass at the nominal stance) in the URDF's base
  // frame; the axes are the URDF's. Recorded in the file's `source`.
  std::array<double, 3> base_origin_in_urdf{};
};

// What the import reads at most, refused beyond with the figure and the limit: urdfdom's XML
// parser recurses once per nested element (thousands deep overflow the stack), and every walk of
// the tree is bounded by its link count. A real quadruped's URDF is some 30-70 kB, 5 elements
// deep, 20-50 links.
struct UrdfLimits {
  static constexpr std::size_t kMaxBytes = 8u << 20;
  static constexpr int kMaxXmlDepth = 100;
  static constexpr std::size_t kMaxLinks = 1000;
  static constexpr std::size_t kMaxJoints = 1000;
};

// Reads `urdf_path` and returns the robot file; throws UrdfImportError.
UrdfImport import_urdf(const std::string& urdf_path, const UrdfImportOptions& options);

// The same from the URDF's text; `urdf_path` names it in errors and in the file's `source`.
UrdfImport import_urdf_text(const std::string& xml, const std::string& urdf_path,
                            const UrdfImportOptions& options);

}  // namespace terrastride::robot
