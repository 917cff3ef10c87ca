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

#include "support/quadruped_urdf.hpp"
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
  EXPECT_EQ(run_import("toy", quadruped_urdf(4), &err, &out, "--no-fit"), 0) << err;
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
                       "--joint-range LF_HFE,RF_HFE,LH_HFE,RH_HFE=-80:80 --no-fit"), 0) << err;
  EXPECT_TRUE(fs::exists(out));
  fs::remove_all(out.parent_path());
}

// `urdf_text` with `extra` inserted before its closing </robot>.
std::string with_extra(const std::string& urdf_text, const std::string& extra) {
  const size_t end = urdf_text.rfind("</robot>");
  return urdf_text.substr(0, end) + extra + urdf_text.substr(end);
}

// `urdf_text` with the first occurrence of `from` replaced by `to`.
std::string replaced(std::string urdf_text, const std::string& from, const std::string& to) {
  const size_t at = urdf_text.find(from);
  EXPECT_NE(at, std::string::npos) << from;
  if (at != std::string::npos) urdf_text.replace(at, from.size(), to);
  return urdf_text;
}

std::string nested(int depth, const std::string& open = "<a>", const std::string& close = "</a>") {
  std::string x;
  for (int k = 0; k < depth; ++k) x += open;
  for (int k = 0; k < depth; ++k) x += close;
  return x;
}

struct RefusalCase {
  std::string tag, urdf, expect;
};

// Each case: exit status 1, stderr holding `expect` (and the file's name), no robot file.
void expect_refused(const std::vector<RefusalCase>& cases) {
  for (const RefusalCase& c : cases) {
    std::string err;
    fs::path out;
    EXPECT_EQ(run_import(c.tag, c.urdf, &err, &out), 1) << c.tag << ": " << err;
    EXPECT_NE(err.find(c.expect), std::string::npos) << c.tag << ": " << err;
    EXPECT_NE(err.find("robot.urdf"), std::string::npos) << c.tag << ": " << err;
    EXPECT_FALSE(fs::exists(out)) << c.tag;
    fs::remove_all(out.parent_path());
  }
}

// urdfdom's XML parser recursed once per element: 5000 nested elements crashed the import
// (segfault after 9 s). The nesting is measured before urdfdom sees the text.
TEST(UrdfImport, DeepXmlNestingIsRefusedBeforeParsing) {
  const std::string toy = quadruped_urdf(4);
  expect_refused({
      {"nested_5000", with_extra(toy, nested(5000)), "XML elements nested 101 deep"},
      {"nested_101", with_extra(toy, nested(100)), "limit of 100"},
      // Attributes with '>' and '/>' inside quotes do not end a tag early.
      {"nested_quoted", with_extra(toy, nested(3000, "<a b=\"x/>\" c = '>'>", "</a>")), "limit of 100"},
      // Unclosed: the opening tags alone are the recursion.
      {"nested_open", with_extra(toy, nested(10000).substr(0, 3 * 10000)), "limit of 100"},
      // A document that is only nesting.
      {"nested_bare", nested(100000, "<robot>", "</robot>"), "at line 1, more than the limit of 100"},
  });
  // The same elements in a comment, CDATA or empty tags are no nesting: imported.
  for (const std::string& extra :
       {"<!--" + nested(5000) + "-->", "<gazebo><![CDATA[" + nested(5000) + "]]></gazebo>",
        std::string("<gazebo>") + [] {
          std::string x;
          for (int k = 0; k < 5000; ++k) x += "<a b='>'/>";
          return x;
        }() + "</gazebo>",
        nested(90, "<gazebo>", "</gazebo>")}) {
    std::string err;
    fs::path out;
    EXPECT_EQ(run_import("nested_ok", with_extra(toy, extra), &err, &out, "--no-fit"), 0)
        << extra.substr(0, 60) << ": " << err;
    fs::remove_all(out.parent_path());
  }
}

TEST(UrdfImport, OversizedFileIsRefused) {
  // 9 MiB of comment in an otherwise fine URDF: refused by size, before anything is parsed.
  const std::string big = with_extra(quadruped_urdf(4), "<!--" + std::string(9u << 20, ' ') + "-->");
  expect_refused({{"oversized", big, "the most a URDF may have"}});
  UrdfImportOptions o;
  o.name = "toy";
  try {
    import_urdf_text(big, "big.urdf", o);
    ADD_FAILURE() << "imported";
  } catch (const UrdfImportError& e) {
    EXPECT_NE(std::string(e.what()).find("big.urdf: " + std::to_string(big.size()) + " bytes"), std::string::npos)
        << e.what();
  }
}

std::string joint_xml(const std::string& name, const std::string& parent, const std::string& child,
                      const std::string& type = "fixed") {
  return "<joint name=\"" + name + "\" type=\"" + type + "\"><parent link=\"" + parent + "\"/><child link=\"" +
         child + "\"/><origin xyz=\"0 0 0.01\"/><axis xyz=\"0 1 0\"/><limit lower=\"-1\" upper=\"1\" "
         "effort=\"1\" velocity=\"1\"/></joint>\n";
}

// A joint cycle made the import's tree walk run until std::bad_alloc (3.2 GB): each shape is
// refused, naming the joints or links.
TEST(UrdfImport, JointCyclesAreRefusedByName) {
  const std::string toy = quadruped_urdf(4);
  std::string ring;  // a loop of 12 links off the tree
  for (int k = 0; k < 12; ++k) ring += "<link name=\"ring" + std::to_string(k) + "\"/>";
  for (int k = 0; k < 12; ++k)
    ring += joint_xml("ring_joint" + std::to_string(k), "ring" + std::to_string(k), "ring" + std::to_string((k + 1) % 12));
  std::string chain_loop;  // a chain of 30 links whose last joint goes back to the third
  for (int k = 0; k < 30; ++k) chain_loop += "<link name=\"c" + std::to_string(k) + "\"/>";
  chain_loop += joint_xml("c_root", "base", "c0");
  for (int k = 1; k < 30; ++k)
    chain_loop += joint_xml("c_joint" + std::to_string(k), "c" + std::to_string(k - 1), "c" + std::to_string(k));
  chain_loop += joint_xml("c_back", "c29", "c2", "revolute");
  expect_refused({
      // The calf's child joint goes back to the hip.
      {"child_is_ancestor", with_extra(toy, joint_xml("LF_back", "LF_calf", "LF_hip", "revolute")),
       "the joints LF_back, LF_HFE, LF_KFE form a cycle (links LF_calf -> LF_hip -> LF_thigh -> LF_calf)"},
      {"two_parents", with_extra(toy, joint_xml("RF_extra", "base", "RH_thigh")),
       "link 'RH_thigh' is the child of two joints"},
      {"self_loop", with_extra(toy, joint_xml("LH_self", "LH_calf", "LH_calf", "revolute")),
       "joint 'LH_self' connects link 'LH_calf' to itself"},
      {"ring_off_the_tree", with_extra(toy, ring), "form a cycle"},
      {"ring_joints_named", with_extra(toy, ring), "ring_joint0, ring_joint1"},
      {"long_loop", with_extra(toy, chain_loop), "form a cycle (links c2 -> c3 -> c4 -> c5"},
      {"long_loop_back", with_extra(toy, chain_loop), "c28 -> c29 -> c2)"},
      // Through the root: named before urdfdom (which finds no root link and leaks the cycle).
      {"through_root", with_extra(toy, joint_xml("back_to_base", "LF_foot", "base")),
       "form a cycle (links "},
      {"through_root_named", with_extra(toy, joint_xml("back_to_base", "LF_foot", "base")),
       "back_to_base, LF_HAA"},
      {"two_link_robot", "<robot name=\"r\"><link name=\"a\"/><link name=\"b\"/>" + joint_xml("ab", "a", "b") +
                             joint_xml("ba", "b", "a") + "</robot>",
       "the joints ab, ba form a cycle (links a -> b -> a)"},
      {"hanging", with_extra(toy, ring + "<link name=\"hang\"/>" + joint_xml("hang_joint", "ring3", "hang")),
       "form a cycle"},
      // Off the tree without a cycle: a second root (urdfdom names it).
      {"unreached", with_extra(toy, "<link name=\"x\"/><link name=\"y\"/>" + joint_xml("xy", "x", "y") +
                                         joint_xml("base_y", "base", "y")),
       "Two root links found: [base] and [x]"},
      // A cycle the import's own checks would have found after urdfdom refused the file for
      // another reason (a joint without its parent): refused by the cycle, before urdfdom.
      {"cycle_and_malformed", replaced(with_extra(toy, joint_xml("LH_self", "LH_calf", "LH_calf")),
                                       "<parent link=\"RF_hip\"/>", "parent link=\"RF_hip\"/>"),
       "joint 'LH_self' connects link 'LH_calf' to itself"},
  });
}

// A negative base mass imported (Go2 weighed 9.2 kg instead of 16.1 kg), as did infinite or
// indefinite inertias and zero foot spheres: each refused by link or joint name and field.
TEST(UrdfImport, NumbersOutOfRangeAreRefusedByLinkOrJoint) {
  const std::string toy = quadruped_urdf(4);
  const std::string calf = "<link name=\"LH_calf\"><inertial><mass value=\"0.5\"/>";
  expect_refused({
      {"base_mass_negative", replaced(toy, "<mass value=\"5\"/>", "<mass value=\"-5\"/>"),
       "link 'base' inertial: mass -5 kg"},
      {"leg_mass_negative", replaced(toy, calf, "<link name=\"LH_calf\"><inertial><mass value=\"-0.5\"/>"),
       "link 'LH_calf' inertial: mass -0.5 kg"},
      {"mass_huge", replaced(toy, "<mass value=\"5\"/>", "<mass value=\"1e300\"/>"), "link 'base' inertial: mass 1e+300"},
      {"inertia_huge", replaced(toy, "ixx=\"0.1\"", "ixx=\"1e308\""), "link 'base' inertial: inertia ixx 1e+308"},
      {"inertia_indefinite", replaced(toy, "ixx=\"0.1\" ixy=\"0\"", "ixx=\"0.1\" ixy=\"0.5\""),
       "link 'base' inertial: the inertia is not positive semi-definite"},
      {"inertia_negative", replaced(toy, "iyy=\"0.2\"", "iyy=\"-0.2\""), "not positive semi-definite"},
      {"inertial_origin_huge", replaced(toy, "<inertial><mass value=\"5\"/>",
                                         "<inertial><origin xyz=\"1e300 0 0\"/><mass value=\"5\"/>"),
       "link 'base' inertial origin: xyz 1e+300"},
      {"foot_radius_zero", replaced(toy, "<sphere radius=\"0.02\"/>", "<sphere radius=\"0\"/>"),
       "link 'LF_foot' collision: sphere radius 0 m"},
      {"foot_radius_negative", replaced(toy, "<sphere radius=\"0.02\"/>", "<sphere radius=\"-0.02\"/>"),
       "sphere radius -0.02 m"},
      {"box_zero", replaced(toy, "<box size=\"0.4 0.2 0.1\"/>", "<box size=\"0.4 0 0.1\"/>"),
       "link 'base' collision: box size y 0 m"},
      {"joint_origin_huge", replaced(toy, "<origin xyz=\"0 0 -0.2\"/>", "<origin xyz=\"0 0 -1e300\"/>"),
       "joint 'LF_KFE' origin: xyz -1e+300"},
      {"joint_axis_zero", replaced(toy, "<axis xyz=\"0 1 0\"/>", "<axis xyz=\"0 0 0\"/>"),
       "joint 'LF_HFE': axis (0, 0, 0) is not a finite non-zero vector"},
      {"effort_huge", replaced(toy, "effort=\"20\"", "effort=\"1e300\""), "joint 'LF_HAA': limit effort 1e+300"},
      {"velocity_huge", replaced(toy, "velocity=\"10\"", "velocity=\"1e300\""), "joint 'LF_HAA': limit velocity 1e+300"},
  });
  // Placeholder-range overrides and the nominal height: finite.
  std::string err;
  fs::path out;
  EXPECT_EQ(run_import("override_inf", toy, &err, &out, "--joint-range LF_HFE=-inf:inf"), 1) << err;
  EXPECT_NE(err.find("--joint-range LF_HFE"), std::string::npos) << err;
  fs::remove_all(out.parent_path());
  EXPECT_EQ(run_import("height_inf", toy, &err, &out, "--nominal-height inf"), 1) << err;
  EXPECT_NE(err.find("--nominal-height"), std::string::npos) << err;
  EXPECT_FALSE(fs::exists(out));
  fs::remove_all(out.parent_path());
}

// The fuzz target's seeds (tests/fuzz/corpus_urdf) go through the import: each either imports
// or is refused with UrdfImportError, none crashes.
TEST(UrdfImport, FuzzCorpusReplay) {
  const fs::path corpus = fs::path(TERRASTRIDE_SOURCE_DIR) / "tests/fuzz/corpus_urdf";
  ASSERT_TRUE(fs::is_directory(corpus)) << corpus;
  int files = 0, imported = 0;
  for (const auto& entry : fs::directory_iterator(corpus)) {
    std::ifstream in(entry.path(), std::ios::binary);
    const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    UrdfImportOptions o;
    o.name = "fuzz";
    ++files;
    try {
      import_urdf_text(bytes, entry.path().filename().string(), o);
      ++imported;
    } catch (const UrdfImportError&) {
    }
  }
  EXPECT_GE(files, 10);
  EXPECT_GE(imported, 1);  // the toy quadruped
}

// Limits are real or refused: placeholder and missing efforts and velocities are refused by
// joint name with the flag that supplies real ones, and the flags (by joint or joint kind) make
// the import go through. The criteria (urdf_import.cpp): an effort above 3 m g L, a velocity
// above 25 m/s / L, for the robot's weight m g and its stretched leg's length L.
TEST(UrdfImport, PlaceholderEffortsAndVelocitiesAreRefusedByJoint) {
  using test_support::QuadrupedSpec;
  QuadrupedSpec effort;
  effort.effort_knee = 1000;  // 15.4 kg, 0.42 m: 1000 N m holds 15.8 times its weight
  QuadrupedSpec velocity;
  velocity.velocity_hip = 1000;
  QuadrupedSpec missing;
  missing.velocity_knee = 0;  // urdfdom's "not given"
  const struct {
    std::string tag, urdf, expect;
  } cases[] = {
      {"effort", test_support::quadruped_urdf(effort),
       "joint 'FL_calf_joint' has the effort limit 1000 N m, a placeholder"},
      {"effort_fix", test_support::quadruped_urdf(effort), "--effort FL_calf_joint=N_M"},
      {"velocity", test_support::quadruped_urdf(velocity),
       "joint 'FL_hip_joint' has the velocity limit 1000 rad/s, a placeholder"},
      {"velocity_fix", test_support::quadruped_urdf(velocity), "--velocity haa=RAD_PER_S"},
      {"missing", test_support::quadruped_urdf(missing),
       "joint 'FL_calf_joint' has no velocity limit"},
  };
  for (const auto& c : cases) {
    std::string err;
    fs::path out;
    EXPECT_EQ(run_import(c.tag, c.urdf, &err, &out), 1) << c.tag << ": " << err;
    EXPECT_NE(err.find(c.expect), std::string::npos) << c.tag << ": " << err;
    EXPECT_FALSE(fs::exists(out)) << c.tag;
    fs::remove_all(out.parent_path());
  }
  // Given: by kind for every leg, and by name (a name wins over its kind).
  std::string err;
  fs::path out;
  ASSERT_EQ(run_import("effort_given", test_support::quadruped_urdf(effort), &err, &out,
                       "--effort kfe=45 --effort FL_calf_joint=44 --no-fit"),
            0)
      << err;
  const RobotModel r = load_robot(out.string());
  EXPECT_DOUBLE_EQ(r.leg("LF").torque_limit[2], 44);
  EXPECT_DOUBLE_EQ(r.leg("RH").torque_limit[2], 45);
  EXPECT_DOUBLE_EQ(r.leg("RH").velocity_limit[2], 15.7);
  fs::remove_all(out.parent_path());
  EXPECT_EQ(run_import("velocity_given", test_support::quadruped_urdf(missing), &err, &out,
                       "--velocity FL_calf_joint,FR_calf_joint,RL_calf_joint,RR_calf_joint=15 --no-fit"),
            0)
      << err;
  EXPECT_DOUBLE_EQ(load_robot(out.string()).leg("LH").velocity_limit[2], 15);
  fs::remove_all(out.parent_path());
  EXPECT_EQ(run_import("bad_kind", test_support::quadruped_urdf(effort), &err, &out, "--effort knee=45"), 1);
  EXPECT_NE(err.find("--effort names 'knee'"), std::string::npos) << err;
  fs::remove_all(out.parent_path());
}

// Mesh feet (no sphere collision): refused with the flag that names the radius; with
// --foot-radius the foot links' frames are the spheres' centres, found without naming them, or
// named with --foot-link.
TEST(UrdfImport, MeshFeetTakeTheRadiusGiven) {
  test_support::QuadrupedSpec mesh;
  mesh.mesh_feet = true;
  const std::string urdf = test_support::quadruped_urdf(mesh);
  std::string err;
  fs::path out;
  EXPECT_EQ(run_import("mesh", urdf, &err, &out), 1) << err;
  EXPECT_NE(err.find("--foot-radius METRES"), std::string::npos) << err;
  EXPECT_NE(err.find("FL_calf_joint"), std::string::npos) << err;
  fs::remove_all(out.parent_path());
  for (const std::string extra :
       {"--foot-radius 0.023", "--foot-radius 0.023 --foot-link FL_foot,FR_foot,RL_foot,RR_foot"}) {
    ASSERT_EQ(run_import("mesh_r", urdf, &err, &out, extra + " --no-fit"), 0) << extra << ": " << err;
    const RobotModel r = load_robot(out.string());
    EXPECT_DOUBLE_EQ(r.foot_radius, 0.023);
    // The foot sphere's centre is the foot link's origin, 0.21 m below the knee at q = 0.
    EXPECT_NEAR(r.leg("LF").joint_offset[2].norm(), 0.21, 1e-9) << extra;
    fs::remove_all(out.parent_path());
  }
  EXPECT_EQ(run_import("mesh_bad", urdf, &err, &out, "--foot-radius 0"), 1);
  EXPECT_NE(err.find("--foot-radius must be"), std::string::npos) << err;
  fs::remove_all(out.parent_path());
}

}  // namespace
}  // namespace terrastride::robot
