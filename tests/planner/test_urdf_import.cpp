// URDF import (robot/urdf_import.hpp, `terrastride robot import`): the imported legs' forward
// kinematics against the URDF's own pose chain evaluated with urdfdom (joint origins composed,
// revolute joints turned about their axes) at random configurations, for Unitree Go2 and ANYmal C
// (../shared/robots); and the importer's errors, each naming the joint or link and writing nothing.
#include <gtest/gtest.h>
#include <unistd.h>
#include <urdf_parser/urdf_parser.h>
#include <yaml-cpp/yaml.h>

#include <Eigen/Geometry>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <random>
#include <string>

#include "terrastride/robot/leg_kinematics.hpp"
#include "terrastride/robot/robot_model.hpp"
#include "terrastride/robot/urdf_import.hpp"

namespace terrastride::robot {
namespace {

namespace fs = std::filesystem;

std::string shared_robot(const std::string& rel) {
  return std::string(TERRASTRIDE_SHARED_DIR) + "/robots/" + rel;
}

#define REQUIRE_SHARED_ROBOTS()                                                             \
  if (!fs::is_directory(std::string(TERRASTRIDE_SHARED_DIR) + "/robots"))                   \
  GTEST_SKIP() << "no " << TERRASTRIDE_SHARED_DIR                                           \
               << "/robots (the shared URDFs are not part of a user's clone)"

fs::path scratch(const std::string& tag) {
  const fs::path p = fs::temp_directory_path() /
                     ("terrastride_urdf_" + tag + "_" + std::to_string(::getpid()));
  fs::create_directories(p);
  return p;
}

Eigen::Isometry3d pose(const urdf::Pose& p) {
  Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
  t.translate(Eigen::Vector3d(p.position.x, p.position.y, p.position.z));
  t.rotate(Eigen::Quaterniond(p.rotation.w, p.rotation.x, p.rotation.y, p.rotation.z));
  return t;
}

// The foot sphere's centre in the root link's frame with the URDF joints at `q` (by name; others
// at 0): urdfdom's poses composed from the foot link up to the root.
Eigen::Vector3d urdf_foot(const urdf::ModelInterface& model, const std::string& foot_link,
                          const std::map<std::string, double>& q) {
  urdf::LinkConstSharedPtr link = model.getLink(foot_link);
  Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
  for (const auto& c : link->collision_array)
    if (c->geometry->type == urdf::Geometry::SPHERE) {
      t = pose(c->origin);
      break;
    }
  while (link->parent_joint) {
    const urdf::Joint& j = *link->parent_joint;
    Eigen::Isometry3d step = pose(j.parent_to_joint_origin_transform);
    if (j.type == urdf::Joint::REVOLUTE || j.type == urdf::Joint::CONTINUOUS) {
      const auto it = q.find(j.name);
      const double angle = it == q.end() ? 0.0 : it->second;
      step.rotate(Eigen::AngleAxisd(angle, Eigen::Vector3d(j.axis.x, j.axis.y, j.axis.z).normalized()));
    }
    t = step * t;
    link = model.getLink(j.parent_link_name);
  }
  return t.translation();
}

struct LegNames {
  std::string leg, haa, hfe, kfe, foot;
};

// The robot file's base origin in the URDF's base frame, from its `source`.
Eigen::Vector3d base_origin_in_urdf(const RobotModel& robot) {
  const YAML::Node source = YAML::Load(robot.source);
  const YAML::Node o = source["base_origin_in_urdf"];
  return Eigen::Vector3d(o[0].as<double>(), o[1].as<double>(), o[2].as<double>());
}

void expect_fk_is_the_urdf_chain(const std::string& urdf_path, const RobotModel& robot,
                                 const std::vector<LegNames>& names) {
  const Eigen::Vector3d origin = base_origin_in_urdf(robot);
  const urdf::ModelInterfaceSharedPtr model = urdf::parseURDFFile(urdf_path);
  ASSERT_TRUE(model);
  std::mt19937 rng(2026);
  std::uniform_real_distribution<double> u(0, 1);
  double worst = 0;
  for (const LegNames& n : names) {
    const LegModel& leg = robot.leg(n.leg);
    for (int k = 0; k < 500; ++k) {
      const Eigen::Vector3d q =
          leg.q_min + Eigen::Vector3d(u(rng), u(rng), u(rng)).cwiseProduct(leg.q_max - leg.q_min);
      const Eigen::Vector3d expected = urdf_foot(*model, n.foot, {{n.haa, q[0]}, {n.hfe, q[1]}, {n.kfe, q[2]}});
      worst = std::max(worst, (origin + foot_position(leg, q) - expected).norm());
    }
  }
  EXPECT_LT(worst, 1e-9) << robot.name;
}

std::vector<LegNames> go2_names() {
  std::vector<LegNames> v;
  for (const auto& [leg, urdf] : std::vector<std::pair<std::string, std::string>>{
           {"LF", "FL"}, {"RF", "FR"}, {"LH", "RL"}, {"RH", "RR"}})
    v.push_back({leg, urdf + "_hip_joint", urdf + "_thigh_joint", urdf + "_calf_joint", urdf + "_foot"});
  return v;
}

std::vector<LegNames> anymal_names() {
  std::vector<LegNames> v;
  for (const std::string leg : {"LF", "RF", "LH", "RH"})
    v.push_back({leg, leg + "_HAA", leg + "_HFE", leg + "_KFE", leg + "_FOOT"});
  return v;
}

UrdfImportOptions anymal_options() {
  UrdfImportOptions o;
  o.name = "anymal_c";
  for (const std::string leg : {"LF", "RF", "LH", "RH"}) {
    const bool front = leg[1] == 'F';
    o.joint_range_deg[leg + "_HFE"] = {-90, 90};
    o.joint_range_deg[leg + "_KFE"] = front ? std::make_pair(-150.0, -10.0) : std::make_pair(10.0, 150.0);
  }
  return o;
}

TEST(UrdfImport, Go2ForwardKinematicsIsTheUrdfChain) {
  REQUIRE_SHARED_ROBOTS();
  UrdfImportOptions o;
  o.name = "go2";
  const UrdfImport imp = import_urdf(shared_robot("go2/go2_description.urdf"), o);
  const RobotModel robot = parse_robot(imp.yaml, "go2 import");
  ASSERT_EQ(robot.legs.size(), 4u);
  for (const auto& leg : robot.legs) {
    EXPECT_EQ(leg.shape, LegShape::lateral_offset) << leg.name;
    EXPECT_EQ(leg.knee_sign, -1) << leg.name;  // all Go2 knees bend backward
  }
  EXPECT_NEAR(robot.foot_radius, 0.022, 1e-12);
  EXPECT_NEAR(std::abs(robot.leg("LF").joint_offset[0].y()), 0.0955, 1e-12);
  EXPECT_NEAR(robot.legs[0].torque_limit[2], 45.43, 1e-12);
  EXPECT_FALSE(imp.defaults.empty());  // nominal height, range of motion, shin model
  EXPECT_NE(robot.source.find("go2_description"), std::string::npos) << robot.source;
  expect_fk_is_the_urdf_chain(shared_robot("go2/go2_description.urdf"), robot, go2_names());
}

TEST(UrdfImport, AnymalForwardKinematicsIsTheUrdfChain) {
  REQUIRE_SHARED_ROBOTS();
  const UrdfImport imp = import_urdf(shared_robot("anymal_c/anymal.urdf"), anymal_options());
  const RobotModel robot = parse_robot(imp.yaml, "anymal import");
  ASSERT_EQ(robot.legs.size(), 4u);
  for (const auto& leg : robot.legs) EXPECT_EQ(leg.shape, LegShape::lateral_offset) << leg.name;
  EXPECT_NEAR(robot.foot_radius, 0.03, 1e-12);
  // The angled shank: the foot sits forward of (front legs) or behind the KFE joint at q = 0.
  EXPECT_GT(std::abs(robot.leg("LF").joint_offset[2].x()), 0.05);
  expect_fk_is_the_urdf_chain(shared_robot("anymal_c/anymal.urdf"), robot, anymal_names());
}

// The shipped files are what the import makes (their FK is the URDF chain too).
TEST(UrdfImport, ShippedFilesAreTheUrdfChain) {
  REQUIRE_SHARED_ROBOTS();
  const std::string data = TERRASTRIDE_TEST_DATA_DIR;
  if (!fs::exists(data + "/robots/go2.yaml")) GTEST_SKIP() << "no data/robots/go2.yaml yet";
  expect_fk_is_the_urdf_chain(shared_robot("go2/go2_description.urdf"), load_robot(data + "/robots/go2.yaml"), go2_names());
  expect_fk_is_the_urdf_chain(shared_robot("anymal_c/anymal.urdf"), load_robot(data + "/robots/anymal_c.yaml"), anymal_names());
}

// A small quadruped URDF: `legs` legs of three revolute joints; leg k has a foot sphere unless
// `no_sphere_leg` == k.
std::string quadruped_urdf(int legs, int no_sphere_leg = -1, bool placeholder = false) {
  std::string x = "<robot name=\"toy\">\n<link name=\"base\"><inertial><mass value=\"5\"/>"
                  "<inertia ixx=\"0.1\" ixy=\"0\" ixz=\"0\" iyy=\"0.2\" iyz=\"0\" izz=\"0.2\"/></inertial>"
                  "<collision><geometry><box size=\"0.4 0.2 0.1\"/></geometry></collision></link>\n";
  const char* names[4] = {"LF", "RF", "LH", "RH"};
  for (int k = 0; k < legs; ++k) {
    const std::string n = names[k];
    const double sx = n[1] == 'F' ? 0.2 : -0.2, sy = n[0] == 'L' ? 0.1 : -0.1;
    const auto link = [&](const std::string& name, const std::string& extra) {
      return "<link name=\"" + name + "\"><inertial><mass value=\"0.5\"/><inertia ixx=\"0.001\" ixy=\"0\" "
             "ixz=\"0\" iyy=\"0.001\" iyz=\"0\" izz=\"0.001\"/></inertial>" + extra + "</link>\n";
    };
    const auto joint = [&](const std::string& name, const std::string& parent, const std::string& child,
                           const std::string& xyz, const std::string& axis, const std::string& lo,
                           const std::string& hi) {
      return "<joint name=\"" + name + "\" type=\"revolute\"><parent link=\"" + parent + "\"/><child link=\"" +
             child + "\"/><origin xyz=\"" + xyz + "\"/><axis xyz=\"" + axis + "\"/><limit lower=\"" + lo +
             "\" upper=\"" + hi + "\" effort=\"20\" velocity=\"10\"/></joint>\n";
    };
    x += link(n + "_hip", "") + link(n + "_thigh", "") + link(n + "_calf", "");
    x += link(n + "_foot", k == no_sphere_leg ? "" : "<collision><geometry><sphere radius=\"0.02\"/></geometry></collision>");
    x += joint(n + "_HAA", "base", n + "_hip", std::to_string(sx) + " " + std::to_string(sy) + " 0", "1 0 0", "-0.8", "0.8");
    x += joint(n + "_HFE", n + "_hip", n + "_thigh", "0 " + std::to_string(sy * 0.5) + " 0", "0 1 0",
               placeholder ? "-9.42477796077" : "-1.5", placeholder ? "9.42477796077" : "1.5");
    x += joint(n + "_KFE", n + "_thigh", n + "_calf", "0 0 -0.2", "0 1 0", "-2.6", "-0.5");
    x += "<joint name=\"" + n + "_foot_fixed\" type=\"fixed\"><parent link=\"" + n + "_calf\"/><child link=\"" + n +
         "_foot\"/><origin xyz=\"0 0 -0.2\"/></joint>\n";
  }
  return x + "</robot>\n";
}

// Runs `terrastride robot import` on `urdf_text`; returns its exit status, stderr in *err.
int run_import(const std::string& tag, const std::string& urdf_text, std::string* err, fs::path* out,
               const std::string& extra = "") {
  const fs::path dir = scratch(tag);
  const fs::path urdf = dir / "robot.urdf";
  std::ofstream(urdf) << urdf_text;
  *out = dir / "robot.yaml";
  const std::string cmd = std::string(TERRASTRIDE_BINARY) + " robot import " + urdf.string() + " --out " +
                          out->string() + " " + extra + " >/dev/null 2>" + (dir / "err.txt").string();
  const int status = std::system(cmd.c_str());
  std::ifstream e(dir / "err.txt");
  err->assign((std::istreambuf_iterator<char>(e)), std::istreambuf_iterator<char>());
  return WEXITSTATUS(status);
}

TEST(UrdfImport, ToyQuadrupedImportsAndLoads) {
  std::string err;
  fs::path out;
  EXPECT_EQ(run_import("toy", quadruped_urdf(4), &err, &out), 0) << err;
  const RobotModel r = load_robot(out.string());
  EXPECT_EQ(r.legs.size(), 4u);
  EXPECT_EQ(r.name, "robot");
  EXPECT_NEAR(r.mass, 5 + 16 * 0.5, 1e-9);
  fs::remove_all(out.parent_path());
}

TEST(UrdfImport, ErrorsNameTheJointOrLinkAndWriteNothing) {
  struct Case {
    std::string tag, urdf, expect, extra;
  };
  const std::vector<Case> cases{
      {"malformed", "<robot name=\"x\"><link name=\"base\">", "not a valid URDF", ""},
      {"three_legs", quadruped_urdf(3), "found 3 leg chain(s)", ""},
      {"no_sphere", quadruped_urdf(4, 2), "LH_KFE", ""},
      {"no_sphere_named", quadruped_urdf(4), "foot link 'LH_calf' has no sphere collision",
       "--feet LF_foot,RF_foot,LH_calf,RH_foot"},
      {"placeholder", quadruped_urdf(4, -1, true), "joint 'LF_HFE' has the range [-540, 540] deg, a placeholder", ""},
      {"unknown_override", quadruped_urdf(4), "--joint-range names 'XX_HFE'", "--joint-range XX_HFE=-10:10"},
  };
  for (const Case& c : cases) {
    std::string err;
    fs::path out;
    EXPECT_EQ(run_import(c.tag, c.urdf, &err, &out, c.extra), 1) << c.tag << ": " << err;
    EXPECT_NE(err.find(c.expect), std::string::npos) << c.tag << ": " << err;
    EXPECT_FALSE(fs::exists(out)) << c.tag;
    fs::remove_all(out.parent_path());
  }
  // The placeholder ranges overridden: imported.
  std::string err;
  fs::path out;
  EXPECT_EQ(run_import("override", quadruped_urdf(4, -1, true), &err, &out,
                       "--joint-range LF_HFE,RF_HFE,LH_HFE,RH_HFE=-80:80"), 0) << err;
  EXPECT_TRUE(fs::exists(out));
  fs::remove_all(out.parent_path());
}

}  // namespace
}  // namespace terrastride::robot
