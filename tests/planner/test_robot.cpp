// Robot model: FK/IK, Jacobian, leg dynamics, exact force polytopes, robot-file validation.
#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <filesystem>
#include <fstream>
#include <random>

#include "terrastride/robot/geometry.hpp"
#include "terrastride/robot/leg_kinematics.hpp"
#include "terrastride/robot/robot_model.hpp"

using namespace terrastride::robot;

namespace {

RobotModel hyq() { return load_robot(std::string(TERRASTRIDE_TEST_DATA_DIR) + "/robots/hyq.yaml"); }

// The leg's branch of IK covers configurations whose foot lies below the HFE joint in the leg's
// plane (r > 0 in the IK of docs/design.md §4.2); folded configurations with the foot above it
// are reached by a different HAA angle, outside the branch, and are skipped by the round trip.
bool on_ik_branch(const LegModel& leg, const Vector3& q) {
  return leg.l0 + leg.l1 * std::cos(q[1]) + leg.l2 * std::cos(q[1] + q[2]) > 1e-3;
}

}  // namespace

TEST(RobotModel, LoadsHyqWithDesignValues) {
  const RobotModel r = hyq();
  EXPECT_EQ(r.name, "hyq");
  ASSERT_EQ(r.legs.size(), 4u);
  EXPECT_EQ(r.legs[0].name, "LF");
  EXPECT_EQ(r.legs[3].name, "RH");
  EXPECT_DOUBLE_EQ(r.mass, 83.0);
  EXPECT_DOUBLE_EQ(r.inertia(0, 2), 0.193);
  EXPECT_DOUBLE_EQ(r.legs[1].haa_origin.y(), -0.207);
  EXPECT_EQ(r.legs[0].knee_sign, -1);
  EXPECT_EQ(r.legs[2].knee_sign, +1);
  EXPECT_NEAR(r.legs[2].shin_angle, 37 * M_PI / 180, 1e-12);
  EXPECT_NEAR(r.legs[0].q_min[2], -140 * M_PI / 180, 1e-12);
  EXPECT_DOUBLE_EQ(r.legs[0].torque_limit[0], 120.0);
}

TEST(LegKinematics, DesignCheckValue) {
  const RobotModel r = hyq();
  const Vector3 foot = foot_position(r.leg("LF"), Vector3(-0.2, 0.75, -1.5));
  EXPECT_NEAR(foot.x(), 0.367, 5e-4);
  EXPECT_NEAR(foot.y(), 0.323, 5e-4);
  EXPECT_NEAR(foot.z(), -0.574, 5e-4);
}

TEST(LegKinematics, FkIkRoundTripOverWholeJointRange) {
  const RobotModel r = hyq();
  for (const LegModel& leg : r.legs) {
    int tested = 0;
    double worst = 0;
    constexpr int kSteps = 24;
    for (int a = 0; a <= kSteps; ++a)
      for (int h = 0; h <= kSteps; ++h)
        for (int k = 0; k <= kSteps; ++k) {
          const Vector3 t(a / double(kSteps), h / double(kSteps), k / double(kSteps));
          const Vector3 q = leg.q_min + t.cwiseProduct(leg.q_max - leg.q_min);
          if (!on_ik_branch(leg, q)) continue;
          const Vector3 foot = foot_position(leg, q);
          const IkResult ik = inverse_kinematics(leg, foot);
          ASSERT_TRUE(ik.ok()) << leg.name << " q=" << q.transpose() << ": " << ik.message;
          worst = std::max(worst, (foot_position(leg, ik.q) - foot).norm());
          EXPECT_LT((ik.q - q).norm(), 1e-6) << leg.name << " q=" << q.transpose();
          ++tested;
        }
    EXPECT_LT(worst, 1e-9) << leg.name;
    EXPECT_GT(tested, kSteps * kSteps * kSteps / 2) << leg.name;
  }
}

TEST(LegKinematics, IkReportsUnreachableAndOutOfRange) {
  const RobotModel r = hyq();
  const LegModel& lf = r.leg("LF");
  IkResult far = inverse_kinematics(lf, lf.haa_origin + Vector3(0, 0, -1.2));
  EXPECT_EQ(far.status, IkStatus::unreachable);
  EXPECT_NE(far.message.find("LF"), std::string::npos);
  EXPECT_NE(far.message.find("out of reach"), std::string::npos);
  // Foot far inward: needs HAA beyond its +25 deg limit.
  IkResult inward = inverse_kinematics(lf, lf.haa_origin + Vector3(0, -0.4, -0.4));
  EXPECT_EQ(inward.status, IkStatus::outside_joint_limits);
  EXPECT_NE(inward.message.find("HAA"), std::string::npos);
  EXPECT_EQ(inverse_kinematics(lf, Vector3(NAN, 0, 0)).status, IkStatus::unreachable);
}

TEST(LegKinematics, NominalStanceIsReachableForEveryLeg) {
  const RobotModel r = hyq();
  for (const LegModel& leg : r.legs) {
    const IkResult ik = inverse_kinematics(leg, leg.nominal_foot);
    ASSERT_TRUE(ik.ok()) << ik.message;
    EXPECT_EQ(ik.q[2] > 0, leg.knee_sign > 0) << leg.name;  // right knee branch
    // The face centres of the range-of-motion box are reachable. Its lower outer corners are
    // not (HyQ's box is not inside the workspace there), so the planner cannot rely on the box
    // alone for reachability and the post-hoc checks run IK on every sample.
    int unreachable_corners = 0;
    for (int axis = 0; axis < 3; ++axis)
      for (int sign : {-1, 1}) {
        const Vector3 p = leg.nominal_foot + sign * leg.range_of_motion[axis] * Vector3::Unit(axis);
        EXPECT_NE(inverse_kinematics(leg, p).status, IkStatus::unreachable) << leg.name;
      }
    for (int c = 0; c < 8; ++c) {
      const Vector3 s((c & 1) ? 1 : -1, (c & 2) ? 1 : -1, (c & 4) ? 1 : -1);
      const Vector3 p = leg.nominal_foot + s.cwiseProduct(leg.range_of_motion);
      if (inverse_kinematics(leg, p).status == IkStatus::unreachable) ++unreachable_corners;
    }
    EXPECT_EQ(unreachable_corners, 1) << leg.name << ": the lower outward corner away from the body";
  }
}

TEST(LegKinematics, JacobianMatchesFiniteDifferences) {
  const RobotModel r = hyq();
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(0, 1);
  for (const LegModel& leg : r.legs)
    for (int trial = 0; trial < 50; ++trial) {
      const Vector3 q = leg.q_min + Vector3(u(rng), u(rng), u(rng)).cwiseProduct(leg.q_max - leg.q_min);
      const Matrix3 jac = foot_jacobian(leg, q);
      for (int j = 0; j < 3; ++j) {
        const double h = 1e-6;
        const Vector3 dq = Vector3::Unit(j) * h;
        const Vector3 fd = (foot_position(leg, q + dq) - foot_position(leg, q - dq)) / (2 * h);
        EXPECT_LT((jac.col(j) - fd).norm(), 1e-8) << leg.name << " column " << j;
      }
    }
}

namespace {

// Second, independent formulation of the leg dynamics: the Lagrangian L = T - V built from the
// link poses by finite differences of FK-like geometry, differentiated numerically.
struct LinkPose {
  Vector3 com;
  Matrix3 rotation;
};

std::array<LinkPose, 3> link_poses(const LegModel& leg, const Vector3& q) {
  const Matrix3 r0 = Eigen::AngleAxisd(-leg.side * q[0], Vector3::UnitX()).toRotationMatrix();
  const Matrix3 r1 = r0 * Eigen::AngleAxisd(q[1], Vector3::UnitY()).toRotationMatrix();
  const Matrix3 r2 = r1 * Eigen::AngleAxisd(q[2], Vector3::UnitY()).toRotationMatrix();
  const Vector3 o0 = leg.haa_origin, o1 = o0 + r0 * Vector3(0, 0, -leg.l0),
                o2 = o1 + r1 * Vector3(0, 0, -leg.l1);
  return {{{o0 + r0 * leg.links[0].com, r0}, {o1 + r1 * leg.links[1].com, r1},
           {o2 + r2 * leg.links[2].com, r2}}};
}

double lagrangian(const LegModel& leg, const Vector3& q, const Vector3& qd, const Vector3& g) {
  const double h = 1e-6;
  const auto p0 = link_poses(leg, q - qd * h), p1 = link_poses(leg, q + qd * h);
  const auto p = link_poses(leg, q);
  double kinetic = 0, potential = 0;
  for (int i = 0; i < 3; ++i) {
    const Vector3 v = (p1[i].com - p0[i].com) / (2 * h);
    // Angular velocity from the rotation's time derivative: [w]x = Rdot R^T.
    const Matrix3 w_hat = (p1[i].rotation - p0[i].rotation) / (2 * h) * p[i].rotation.transpose();
    const Vector3 w(w_hat(2, 1), w_hat(0, 2), w_hat(1, 0));
    const Matrix3 inertia = p[i].rotation * leg.links[i].inertia * p[i].rotation.transpose();
    kinetic += 0.5 * leg.links[i].mass * v.squaredNorm() + 0.5 * w.dot(inertia * w);
    potential -= leg.links[i].mass * g.dot(p[i].com);
  }
  return kinetic - potential;
}

}  // namespace

TEST(LegDynamics, InverseDynamicsMatchesLagrangian) {
  const RobotModel r = hyq();
  const Vector3 g(0.3, -0.5, -9.7);  // tilted base: gravity not along -z
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(-1, 1);
  for (const LegModel& leg : r.legs)
    for (int trial = 0; trial < 10; ++trial) {
      const Vector3 q = 0.5 * (leg.q_min + leg.q_max) + 0.3 * Vector3(u(rng), u(rng), u(rng));
      const Vector3 qd = 3 * Vector3(u(rng), u(rng), u(rng));
      const Vector3 qdd = 20 * Vector3(u(rng), u(rng), u(rng));
      // tau = d/dt dL/dqd - dL/dq along q(t) = q + qd t + qdd t^2 / 2, by central differences.
      const double e = 1e-4, dt = 1e-4;
      auto dl_dqd = [&](const Vector3& qq, const Vector3& vv) {
        Vector3 out;
        for (int j = 0; j < 3; ++j)
          out[j] = (lagrangian(leg, qq, vv + Vector3::Unit(j) * e, g) -
                    lagrangian(leg, qq, vv - Vector3::Unit(j) * e, g)) / (2 * e);
        return out;
      };
      Vector3 dl_dq;
      for (int j = 0; j < 3; ++j)
        dl_dq[j] = (lagrangian(leg, q + Vector3::Unit(j) * e, qd, g) -
                    lagrangian(leg, q - Vector3::Unit(j) * e, qd, g)) / (2 * e);
      const Vector3 ddt = (dl_dqd(q + qd * dt + 0.5 * qdd * dt * dt, qd + qdd * dt) -
                           dl_dqd(q - qd * dt + 0.5 * qdd * dt * dt, qd - qdd * dt)) / (2 * dt);
      const Vector3 tau_lagrange = ddt - dl_dq;
      const Vector3 tau_rnea = inverse_dynamics(leg, q, qd, qdd, g);
      EXPECT_LT((tau_lagrange - tau_rnea).norm(), 2e-3 * (1 + tau_rnea.norm()))
          << leg.name << "\nrnea " << tau_rnea.transpose() << "\nlagrange " << tau_lagrange.transpose();
    }
}

TEST(LegDynamics, TermsAreConsistent) {
  const RobotModel r = hyq();
  const LegModel& leg = r.leg("RH");
  const Vector3 q(-0.1, -0.7, 1.4), qd(0.5, -2.0, 3.0), qdd(4, -6, 9), g(0, 0, -9.81);
  const LegDynamicsTerms t = dynamics_terms(leg, q, qd, g);
  EXPECT_LT((t.mass_matrix - t.mass_matrix.transpose()).norm(), 1e-12);
  EXPECT_GT(Eigen::SelfAdjointEigenSolver<Matrix3>(t.mass_matrix).eigenvalues().minCoeff(), 0);
  EXPECT_LT((t.mass_matrix * qdd + t.coriolis + t.gravity - inverse_dynamics(leg, q, qd, qdd, g)).norm(), 1e-10);
  // Coriolis work vanishes in the sense qd^T (Mdot - 2C) qd = 0, so qd^T c = 1/2 qd^T Mdot qd.
  const double h = 1e-6;
  const Matrix3 mdot = (dynamics_terms(leg, q + qd * h, qd, g).mass_matrix -
                        dynamics_terms(leg, q - qd * h, qd, g).mass_matrix) / (2 * h);
  EXPECT_NEAR(qd.dot(t.coriolis), 0.5 * qd.dot(mdot * qd), 1e-6);
  // A static contact force that balances gravity needs tau = g - J^T f.
  const Vector3 f(10, -20, 300);
  EXPECT_LT((joint_torques(leg, q, Vector3::Zero(), Vector3::Zero(), f, g) -
             (t.gravity - foot_jacobian(leg, q).transpose() * f)).norm(), 1e-10);
}

TEST(ForcePolytope, VerticesSaturateEveryJoint) {
  const RobotModel r = hyq();
  for (const LegModel& leg : r.legs) {
    const IkResult ik = inverse_kinematics(leg, leg.nominal_foot);
    ASSERT_TRUE(ik.ok());
    const ForcePolytope p = exact_force_polytope(leg, ik.q);
    const Matrix3 jt = foot_jacobian(leg, ik.q).transpose();
    for (const Vector3& v : p.vertices) {
      const Vector3 tau = jt * v;
      for (int i = 0; i < 3; ++i) EXPECT_NEAR(std::abs(tau[i]), leg.torque_limit[i], 1e-9);
      EXPECT_NEAR(p.torque_ratio(v), 1.0, 1e-12);
      // Each vertex lies on three facets and inside the other three.
      int active = 0;
      for (int j = 0; j < 6; ++j) {
        const double s = p.normals[j].dot(v) - p.offsets[j];
        EXPECT_LE(s, 1e-9);
        if (std::abs(s) < 1e-9) ++active;
      }
      EXPECT_EQ(active, 3);
    }
    // A force twice a vertex is outside, half of it inside.
    EXPECT_NEAR(p.torque_ratio(2 * p.vertices[3]), 2.0, 1e-12);
    EXPECT_NEAR(p.torque_ratio(0.5 * p.vertices[3]), 0.5, 1e-12);
  }
}

namespace {
std::string write_temp(const std::string& name, const std::string& text) {
  const auto path = std::filesystem::temp_directory_path() / ("terrastride_" + name + ".yaml");
  std::ofstream(path) << text;
  return path.string();
}
std::string hyq_text() {
  std::ifstream in(std::string(TERRASTRIDE_TEST_DATA_DIR) + "/robots/hyq.yaml");
  return std::string(std::istreambuf_iterator<char>(in), {});
}
std::string load_error(const std::string& path) {
  try {
    load_robot(path);
  } catch (const RobotFileError& e) {
    return e.what();
  }
  return "";
}
std::string replaced(std::string text, const std::string& from, const std::string& to) {
  const size_t pos = text.find(from);
  EXPECT_NE(pos, std::string::npos) << from;
  return text.replace(pos, from.size(), to);
}
}  // namespace

TEST(RobotModel, FileErrorsNameFileAndField) {
  EXPECT_NE(load_error("/nonexistent/robot.yaml").find("/nonexistent/robot.yaml: cannot open"),
            std::string::npos);
  const std::string bad_yaml = write_temp("bad_yaml", "name: [unclosed\n");
  EXPECT_NE(load_error(bad_yaml).find("not valid YAML"), std::string::npos);

  const std::string no_mass = write_temp("no_mass", replaced(hyq_text(), "mass: 83.0", "weight: 83.0"));
  const std::string e1 = load_error(no_mass);
  EXPECT_NE(e1.find(no_mass), std::string::npos) << e1;
  EXPECT_NE(e1.find("'body.mass': missing"), std::string::npos) << e1;

  const std::string neg = write_temp("neg", replaced(hyq_text(), "l1: 0.35", "l1: -0.35"));
  EXPECT_NE(load_error(neg).find("'legs[0].l1': must be > 0"), std::string::npos) << load_error(neg);

  const std::string text_num = write_temp("text", replaced(hyq_text(), "hfe: 150.0", "hfe: lots"));
  EXPECT_NE(load_error(text_num).find("torque_limit.hfe': must be a number (got 'lots')"),
            std::string::npos) << load_error(text_num);

  const std::string side = write_temp("side", replaced(hyq_text(), "side: right", "side: middle"));
  EXPECT_NE(load_error(side).find("'legs[1].side': must be 'left' or 'right'"), std::string::npos);

  const std::string knee = write_temp("knee", replaced(hyq_text(), "kfe: [20, 140]", "kfe: [-140, -20]"));
  EXPECT_NE(load_error(knee).find("does not match knee"), std::string::npos) << load_error(knee);

  const std::string range = write_temp("range", replaced(hyq_text(), "haa: [-70, 25]", "haa: [25, -70]"));
  EXPECT_NE(load_error(range).find("min must be below max"), std::string::npos);

  const std::string vec = write_temp("vec", replaced(hyq_text(), "[0.3735, 0.207, 0.0]", "[0.3735, 0.207]"));
  EXPECT_NE(load_error(vec).find("'legs[0].haa_origin': must be a list of 3 numbers"), std::string::npos);

  const std::string inertia = write_temp("inertia", replaced(hyq_text(), "xz: 0.193", "xz: 9.0"));
  EXPECT_NE(load_error(inertia).find("not positive definite"), std::string::npos);
}

TEST(RobotModel, HyqTrunkIsTheBoundingBoxOfItsUrdfCollisionMesh) {
  const RobotModel m = hyq();
  ASSERT_TRUE(m.has_trunk());
  // iit-DLSLab/hyq-description meshes/trunk/trunk.dae: x +-0.5, y +-0.2413, z +-0.09 shifted 1 cm up.
  EXPECT_NEAR(m.trunk->size.x(), 1.0, 1e-12);
  EXPECT_NEAR(m.trunk->size.y(), 0.4826, 1e-12);
  EXPECT_NEAR(m.trunk->size.z(), 0.18, 1e-12);
  EXPECT_NEAR(m.trunk->center.z(), 0.01, 1e-12);
  // The box holds the HAA joints and sits well above the nominal feet.
  for (const auto& leg : m.legs) {
    const Eigen::Vector3d d = (leg.haa_origin - m.trunk->center).cwiseAbs();
    EXPECT_TRUE((d.array() <= m.trunk->half_size().array()).all()) << leg.name;
    EXPECT_GT(m.trunk->center.z() - m.trunk->half_size().z(), leg.nominal_foot.z() + 0.4);
  }
  // Corners: bit 0 x, bit 1 y, bit 2 z; the world corners follow the base pose.
  const Eigen::Vector3d c7 = trunk_corner_in_base(*m.trunk, 7), c0 = trunk_corner_in_base(*m.trunk, 0);
  EXPECT_TRUE(c7.isApprox(Eigen::Vector3d(0.5, 0.2413, 0.10), 1e-12));
  EXPECT_TRUE(c0.isApprox(Eigen::Vector3d(-0.5, -0.2413, -0.08), 1e-12));
  const Eigen::Vector3d base(1, 2, 0.58), yaw90(M_PI / 2, 0, 0);
  const Eigen::Vector3d w = trunk_corner_world<double>(*m.trunk, 7, base, yaw90);
  EXPECT_TRUE(w.isApprox(Eigen::Vector3d(1 - 0.2413, 2 + 0.5, 0.68), 1e-9)) << w.transpose();
}

TEST(RobotModel, TrunkFieldErrorsNameFileAndField) {
  const std::string trunk_block =
      "trunk:\n  size: [1.0, 0.4826, 0.18]    # m, full edge lengths along base x, y, z\n"
      "  center: [0.0, 0.0, 0.01]     # m, base frame\n";
  const std::string missing = write_temp("no_trunk", replaced(hyq_text(), trunk_block, ""));
  const std::string e1 = load_error(missing);
  EXPECT_NE(e1.find(missing), std::string::npos) << e1;
  EXPECT_NE(e1.find("'trunk': missing"), std::string::npos) << e1;

  const std::string no_size = write_temp(
      "trunk_no_size", replaced(hyq_text(), "size: [1.0, 0.4826, 0.18]", "sise: [1.0, 0.4826, 0.18]"));
  EXPECT_NE(load_error(no_size).find("'trunk.size': missing"), std::string::npos) << load_error(no_size);

  const std::string flat = write_temp(
      "trunk_flat", replaced(hyq_text(), "size: [1.0, 0.4826, 0.18]", "size: [1.0, 0.0, 0.18]"));
  EXPECT_NE(load_error(flat).find("'trunk.size': edge lengths must be > 0"), std::string::npos)
      << load_error(flat);

  const std::string short_center = write_temp(
      "trunk_center", replaced(hyq_text(), "center: [0.0, 0.0, 0.01]", "center: [0.0, 0.01]"));
  EXPECT_NE(load_error(short_center).find("'trunk.center': must be a list of 3 numbers"),
            std::string::npos) << load_error(short_center);

  const std::string word = write_temp("trunk_word", replaced(hyq_text(), trunk_block, "trunk: box\n"));
  EXPECT_NE(load_error(word).find("'trunk': must be a mapping"), std::string::npos) << load_error(word);

  const std::string low = write_temp(
      "trunk_low", replaced(hyq_text(), "center: [0.0, 0.0, 0.01]", "center: [0.0, 0.0, -0.55]"));
  EXPECT_NE(load_error(low).find("'trunk': its bottom"), std::string::npos) << load_error(low);
}

TEST(RobotModel, MonopedLoadsWithSliderDof) {
  const RobotModel m = load_robot(std::string(TERRASTRIDE_TEST_DATA_DIR) + "/robots/monoped.yaml");
  ASSERT_EQ(m.legs.size(), 1u);
  EXPECT_FALSE(m.base_dof_free[0]);
  EXPECT_TRUE(m.base_dof_free[2]);
  EXPECT_TRUE(inverse_kinematics(m.legs[0], m.legs[0].nominal_foot).ok());
  EXPECT_FALSE(m.has_trunk());  // `trunk: none`: the slider carriage is not a body
}
