// Quadruped URDFs written by the tests, varied to stress the importer the way real robots differ:
// mesh feet, placeholder limits, reversed joint axes, knees forward or backward, other leg names
// and declaration orders, a base frame away from the centre of mass. The default is a Go2-sized
// robot (15 kg, 0.21 m thigh and shank, Go2's effort and velocity limits); every variant is a
// complete URDF any importer reads.
#pragma once

#include <array>
#include <cstdio>
#include <string>

namespace terrastride::test_support {

struct QuadrupedSpec {
  std::string robot = "quad";
  // Leg prefixes in the order LF, RF, LH, RH, and the order the legs are written (indices).
  std::array<std::string, 4> prefix{{"FL", "FR", "RL", "RR"}};
  std::array<int, 4> write_order{{0, 1, 2, 3}};
  std::string haa = "_hip_joint", hfe = "_thigh_joint", kfe = "_calf_joint", foot = "_foot";
  double base_mass = 7.0, hip_mass = 0.7, thigh_mass = 1.0, calf_mass = 0.25;
  double hip_x = 0.19, hip_y = 0.05, hip_lateral = 0.09, thigh = 0.21, calf = 0.21;
  double foot_radius = 0.022;
  bool mesh_feet = false;  // the foot link has a mesh collision and no sphere
  // Knees: +1 backward (Go2), -1 forward, per leg LF RF LH RH.
  std::array<int, 4> knee{{+1, +1, +1, +1}};
  bool reversed_axes = false;  // HFE and KFE turn about -y (angles and ranges negated)
  double effort_hip = 23.7, effort_knee = 45.43, velocity_hip = 30.1, velocity_knee = 15.7;
  double base_com_x = 0.0, base_com_z = 0.0;  // the base link's inertial origin
};

inline std::string num_text(double v) {
  char b[32];
  std::snprintf(b, sizeof b, "%.6g", v);
  return b;
}

inline std::string quadruped_urdf(const QuadrupedSpec& s) {
  std::string x = "<?xml version=\"1.0\"?>\n<robot name=\"" + s.robot + "\">\n";
  const auto inertial = [](double m, const std::string& xyz) {
    const std::string i = num_text(m * 0.002);
    return "<inertial><origin xyz=\"" + xyz + "\"/><mass value=\"" + num_text(m) +
           "\"/><inertia ixx=\"" + i + "\" ixy=\"0\" ixz=\"0\" iyy=\"" + i + "\" iyz=\"0\" izz=\"" + i +
           "\"/></inertial>";
  };
  x += "<link name=\"base\"><inertial><origin xyz=\"" + num_text(s.base_com_x) + " 0 " +
       num_text(s.base_com_z) + "\"/><mass value=\"" + num_text(s.base_mass) +
       "\"/><inertia ixx=\"0.03\" ixy=\"0\" ixz=\"0\" iyy=\"0.1\" iyz=\"0\" izz=\"0.11\"/></inertial>"
       "<collision><geometry><box size=\"0.38 0.094 0.114\"/></geometry></collision></link>\n";
  for (int w = 0; w < 4; ++w) {
    const int k = s.write_order[w];
    const std::string p = s.prefix[k];
    const bool left = k == 0 || k == 2, front = k < 2;
    const double sx = front ? s.hip_x : -s.hip_x, sy = left ? s.hip_y : -s.hip_y;
    const double lat = left ? s.hip_lateral : -s.hip_lateral;
    const double axis = s.reversed_axes ? -1.0 : 1.0;
    const auto joint = [&](const std::string& name, const std::string& parent,
                           const std::string& child, const std::string& xyz,
                           const std::string& ax, double lo, double hi, double effort,
                           double velocity) {
      return "<joint name=\"" + name + "\" type=\"revolute\"><parent link=\"" + parent +
             "\"/><child link=\"" + child + "\"/><origin xyz=\"" + xyz + "\"/><axis xyz=\"" + ax +
             "\"/><limit lower=\"" + num_text(lo) + "\" upper=\"" + num_text(hi) + "\" effort=\"" +
             num_text(effort) + "\" velocity=\"" + num_text(velocity) + "\"/></joint>\n";
    };
    // Knee backward: the KFE angle negative (about +y); forward: positive. Reversed axes negate.
    const double kb = s.knee[k] > 0 ? -1.0 : 1.0;
    const double k_lo = axis * kb > 0 ? 0.84 : -2.72, k_hi = axis * kb > 0 ? 2.72 : -0.84;
    const double h_lo = axis > 0 ? -1.57 : -3.49, h_hi = axis > 0 ? 3.49 : 1.57;
    x += "<link name=\"" + p + "_hip\">" + inertial(s.hip_mass, "0 0 0") + "</link>\n";
    x += "<link name=\"" + p + "_thigh\">" + inertial(s.thigh_mass, "0 0 " + num_text(-0.3 * s.thigh)) +
         "<collision><origin xyz=\"0 0 " + num_text(-s.thigh / 2) +
         "\"/><geometry><box size=\"" + num_text(s.thigh) + " 0.0245 0.034\"/></geometry></collision></link>\n";
    x += "<link name=\"" + p + "_calf\">" + inertial(s.calf_mass, "0 0 " + num_text(-0.4 * s.calf)) +
         "<collision><origin xyz=\"0 0 " + num_text(-s.calf / 2) +
         "\"/><geometry><cylinder length=\"" + num_text(s.calf * 0.6) +
         "\" radius=\"0.012\"/></geometry></collision></link>\n";
    x += "<link name=\"" + p + s.foot + "\">" + inertial(0.04, "0 0 0") +
         (s.mesh_feet ? "<collision><geometry><mesh filename=\"package://quad/foot.stl\"/></geometry></collision>"
                      : "<collision><geometry><sphere radius=\"" + num_text(s.foot_radius) +
                            "\"/></geometry></collision>") +
         "</link>\n";
    x += joint(p + s.haa, "base", p + "_hip", num_text(sx) + " " + num_text(sy) + " 0", "1 0 0", -1.05,
               1.05, s.effort_hip, s.velocity_hip);
    x += joint(p + s.hfe, p + "_hip", p + "_thigh", "0 " + num_text(lat) + " 0",
               "0 " + num_text(axis) + " 0", h_lo, h_hi, s.effort_hip, s.velocity_hip);
    x += joint(p + s.kfe, p + "_thigh", p + "_calf", "0 0 " + num_text(-s.thigh),
               "0 " + num_text(axis) + " 0", k_lo, k_hi, s.effort_knee, s.velocity_knee);
    x += "<joint name=\"" + p + s.foot + "_fixed\" type=\"fixed\"><parent link=\"" + p +
         "_calf\"/><child link=\"" + p + s.foot + "\"/><origin xyz=\"0 0 " + num_text(-s.calf) +
         "\"/></joint>\n";
  }
  return x + "</robot>\n";
}

}  // namespace terrastride::test_support
