// The interpolated force-polytope model: analytic derivatives against finite differences (also
// right next to a reference leg length where the interpolation changes segment), vertices, and
// the parameter files (round trip, missing, stale, malformed).
#include <gtest/gtest.h>

#include <sys/stat.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>
#include <thread>

#include "terrastride/planner/polytope_fit.hpp"
#include "terrastride/planner/polytope_model.hpp"
#include "terrastride/robot/leg_kinematics.hpp"

namespace terrastride::planner {
namespace {

using Eigen::Vector3d;
using Mat63 = Eigen::Matrix<double, kPolytopeFacets, 3>;
using Vec6 = Eigen::Matrix<double, kPolytopeFacets, 1>;  // not auto: expressions over temporaries

robot::RobotModel hyq() {
  return robot::load_robot(std::string(TERRASTRIDE_TEST_DATA_DIR) + "/robots/hyq.yaml");
}

// A model with non-trivial values everywhere: HyQ-like hip, 4 x 3 references, random angles and
// offsets, so every term of the derivative chain contributes.
LegPolytopeModel random_model(bool use_roll, int num_alpha, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  LegPolytopeModel m;
  m.leg_name = "LF";
  m.use_roll = use_roll;
  m.hip = Vector3d(0.37, 0.21, 0.0);
  m.hip_offset = use_roll ? 0.08 : 0.0;
  m.l_knots = {0.38, 0.47, 0.55, 0.68};
  m.alpha_knots = num_alpha == 1 ? std::vector<double>{0.0} : std::vector<double>{-0.6, 0.0, 0.6};
  m.poles = {0, 0, 1, 1, 1, 1};
  for (int n = 0; n < 4 * num_alpha; ++n) {
    for (int j = 0; j < kPolytopeFacets; ++j) {
      m.nodes.push_back((j % 2 ? M_PI : 0.0) + 0.4 * u(rng));  // theta
      m.nodes.push_back(0.3 * u(rng));                         // phi
      m.nodes.push_back(300 + 100 * u(rng));                   // d
    }
  }
  m.validate();
  return m;
}

// Foot position at leg coordinates (gamma, l, alpha) of a model: the inverse of coordinates().
Vector3d foot_at(const LegPolytopeModel& m, double gamma, double l, double alpha) {
  const double a = l * std::sin(alpha), b = l * std::cos(alpha);
  if (!m.use_roll) return m.hip + Vector3d(a, 0.1, -(b + m.hip_offset));
  const double rho = b + m.hip_offset;
  return m.hip + Vector3d(a, rho * std::sin(gamma), -rho * std::cos(gamma));
}

void expect_derivatives_match(const LegPolytopeModel& m, const Vector3d& p, const Vector3d& f) {
  Mat63 dg_dp, dg_df;
  const auto g = m.constraint(p, f, &dg_dp, &dg_df);
  const double h = 1e-6;
  for (int k = 0; k < 3; ++k) {
    Vector3d dp = Vector3d::Zero();
    dp[k] = h;
    const Vec6 fd_p = (m.constraint(p + dp, f) - m.constraint(p - dp, f)) / (2 * h);
    const Vec6 fd_f = (m.constraint(p, f + dp) - m.constraint(p, f - dp)) / (2 * h);
    for (int j = 0; j < kPolytopeFacets; ++j) {
      // g is O(1e3) N and its position derivative O(1e4) N/m: compare relative to that scale.
      EXPECT_NEAR(dg_dp(j, k), fd_p[j], 1e-5 * (1 + std::abs(fd_p[j])))
          << "dg" << j << "/dp" << k << " at p = " << p.transpose();
      EXPECT_NEAR(dg_df(j, k), fd_f[j], 1e-7) << "dg" << j << "/df" << k;
    }
  }
  const auto facets = m.facets(p);
  for (int j = 0; j < kPolytopeFacets; ++j) {
    EXPECT_NEAR(facets.normals[j].norm(), 1.0, 1e-12);
    EXPECT_NEAR(g[j], facets.normals[j].dot(f) - facets.offsets[j], 1e-9);
  }
}

TEST(PolytopeModel, DerivativesMatchFiniteDifferences) {
  const Vector3d f(40.0, -25.0, 380.0);
  for (bool roll : {true, false}) {
    for (int num_alpha : {1, 3}) {
      const LegPolytopeModel m = random_model(roll, num_alpha, 7 + num_alpha);
      std::mt19937_64 rng(3);
      std::uniform_real_distribution<double> ul(0.39, 0.67), ua(-0.55, 0.55), ug(-0.4, 0.4);
      for (int s = 0; s < 25; ++s) {
        SCOPED_TRACE("roll " + std::to_string(roll) + " alpha refs " + std::to_string(num_alpha));
        expect_derivatives_match(m, foot_at(m, ug(rng), ul(rng), ua(rng)), f);
      }
      // Extrapolated beyond the first and the last reference.
      expect_derivatives_match(m, foot_at(m, 0.1, 0.36, 0.2), f);
      expect_derivatives_match(m, foot_at(m, -0.1, 0.70, -0.7), f);
    }
  }
}

TEST(PolytopeModel, DerivativesOnBothSidesOfTheNominalReference) {
  // l_2 = 0.47 is where the interpolation switches from segment (l1, l2) to (l2, l3) (paper eq.
  // 10): each side has its own slope, and the constraint is continuous across the knot.
  const Vector3d f(-60.0, 30.0, 420.0);
  for (int num_alpha : {1, 3}) {
    const LegPolytopeModel m = random_model(true, num_alpha, 11);
    const double l2 = m.l_knots[1];
    for (double eps : {1e-4, 1e-3}) {
      expect_derivatives_match(m, foot_at(m, 0.15, l2 - eps, 0.25), f);
      expect_derivatives_match(m, foot_at(m, 0.15, l2 + eps, 0.25), f);
    }
    // Also on a tilt reference (alpha = 0) from both sides.
    if (num_alpha == 3) {
      expect_derivatives_match(m, foot_at(m, -0.2, 0.5, -1e-4), f);
      expect_derivatives_match(m, foot_at(m, -0.2, 0.5, 1e-4), f);
    }
    const auto below = m.constraint(foot_at(m, 0.15, l2 - 1e-9, 0.25), f);
    const auto above = m.constraint(foot_at(m, 0.15, l2 + 1e-9, 0.25), f);
    EXPECT_LT((below - above).cwiseAbs().maxCoeff(), 1e-4);
    // The slopes differ across the knot: the test above really straddles two segments.
    Mat63 d_below, d_above;
    m.constraint(foot_at(m, 0.15, l2 - 1e-4, 0.25), f, &d_below);
    m.constraint(foot_at(m, 0.15, l2 + 1e-4, 0.25), f, &d_above);
    EXPECT_GT((d_below - d_above).cwiseAbs().maxCoeff(), 1.0);
  }
}

TEST(PolytopeModel, VerticesLieOnTheirFacets) {
  const LegPolytopeModel m = random_model(true, 3, 5);
  const Vector3d p = foot_at(m, 0.1, 0.5, 0.1);
  const auto facets = m.facets(p);
  const auto verts = m.vertices(p);
  for (int k = 0; k < kPolytopeVertices; ++k) {
    for (int i = 0; i < 3; ++i) {
      const int j = ((k >> i) & 1) ? 2 * i : 2 * i + 1;
      EXPECT_NEAR(facets.normals[j].dot(verts[k]), facets.offsets[j], 1e-6);
    }
  }
}

TEST(PolytopeModel, PaperVariantIsExactAtItsNominalReference) {
  const auto model = hyq();
  for (const auto& leg : model.legs) {
    const auto feet = sample_leg_workspace(leg, 200, 5);
    const LegPolytopeModel paper = paper_polytope_model(leg, feet);
    EXPECT_FALSE(paper.use_roll);
    EXPECT_EQ(paper.num_l(), 3);
    // The nominal foot is the paper's l2 reference configuration: the model is exact there.
    EXPECT_NEAR(polytope_rho_out(paper, leg, leg.nominal_foot), 1.0, 1e-9) << leg.name;
    EXPECT_NEAR(polytope_rho_in(paper, leg, leg.nominal_foot), 1.0, 1e-9) << leg.name;
    // Away from it the sagittal-only model errs (the reason for the roll).
    const auto q = evaluate_polytope_quality(paper, leg, feet);
    EXPECT_GT(q.rho_out_max, 1.2) << leg.name;
    // The ablation step with the roll about the HAA axis is exact at the nominal foot too, and
    // far better than the sagittal-only model elsewhere.
    const LegPolytopeModel rolled = paper_polytope_model(leg, feet, true);
    EXPECT_TRUE(rolled.use_roll);
    EXPECT_NEAR(polytope_rho_out(rolled, leg, leg.nominal_foot), 1.0, 1e-9) << leg.name;
    EXPECT_LT(evaluate_polytope_quality(rolled, leg, feet).rho_out_median, q.rho_out_median);
  }
}

TEST(PolytopeModel, InvalidLayoutIsRejected) {
  LegPolytopeModel m = random_model(true, 3, 1);
  m.l_knots[2] = m.l_knots[1];
  EXPECT_THROW(m.validate(), std::invalid_argument);
  m = random_model(true, 3, 1);
  m.nodes.pop_back();
  try {
    m.validate();
    FAIL() << "expected an error";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("nodes"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("LF"), std::string::npos) << e.what();
  }
}

class PolytopeFile : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = std::filesystem::temp_directory_path() /
           ("terrastride_polytope_test_" + std::to_string(::getpid()));
    std::filesystem::create_directories(dir_);
    robot_ = hyq();
    model_.robot = "hyq";
    model_.variant = "roll";
    model_.fit_summary = "test";
    for (size_t i = 0; i < robot_.legs.size(); ++i) {
      LegPolytopeModel leg = random_model(true, 3, 100 + i);
      leg.leg_name = robot_.legs[i].name;
      model_.legs.push_back(leg);
    }
  }
  void TearDown() override { std::filesystem::remove_all(dir_); }
  std::string path(const std::string& name) const { return (dir_ / name).string(); }

  std::filesystem::path dir_;
  robot::RobotModel robot_;
  RobotPolytopeModel model_;
};

TEST_F(PolytopeFile, RoundTripKeepsEveryValue) {
  save_polytope_model(model_, robot_, path("p.yaml"));
  // No temporary is left beside it.
  for (const auto& e : std::filesystem::directory_iterator(dir_))
    EXPECT_EQ(e.path().filename(), "p.yaml");
  const RobotPolytopeModel back = load_polytope_model(robot_, path("p.yaml"));
  ASSERT_EQ(back.legs.size(), model_.legs.size());
  for (size_t i = 0; i < back.legs.size(); ++i) {
    const auto& a = model_.legs[i];
    const auto& b = back.legs[i];
    EXPECT_EQ(a.leg_name, b.leg_name);
    EXPECT_EQ(a.use_roll, b.use_roll);
    EXPECT_EQ(a.poles, b.poles);
    EXPECT_EQ(a.hip, b.hip);
    EXPECT_EQ(a.hip_offset, b.hip_offset);
    EXPECT_EQ(a.l_knots, b.l_knots);
    EXPECT_EQ(a.alpha_knots, b.alpha_knots);
    EXPECT_EQ(a.nodes, b.nodes);  // 17 significant digits: bit-exact
  }
}

// save_polytope_model writes as every output of terrastride does (perception's atomic writer): a
// symbolic link stays a link and its target gets the file, a FIFO is written through.
TEST_F(PolytopeFile, WritesThroughLinksAndFifos) {
  std::ofstream(path("target.yaml")) << "old";
  std::filesystem::create_symlink("target.yaml", path("link.yaml"));
  save_polytope_model(model_, robot_, path("link.yaml"));
  EXPECT_TRUE(std::filesystem::is_symlink(path("link.yaml")));
  EXPECT_EQ(load_polytope_model(robot_, path("target.yaml")).legs.size(), model_.legs.size());

  ASSERT_EQ(::mkfifo(path("p.fifo").c_str(), 0600), 0);
  std::string received;
  std::thread reader([&] {
    std::ifstream in(path("p.fifo"), std::ios::binary);
    received.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  });
  save_polytope_model(model_, robot_, path("p.fifo"));
  reader.join();
  EXPECT_TRUE(std::filesystem::is_fifo(path("p.fifo")));
  std::ifstream in(path("target.yaml"));
  const std::string saved((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  EXPECT_EQ(received, saved);
  // A missing folder is an error naming the path.
  try {
    save_polytope_model(model_, robot_, path("missing/p.yaml"));
    FAIL() << "expected an error";
  } catch (const PolytopeFileError& e) {
    EXPECT_NE(std::string(e.what()).find("missing/p.yaml"), std::string::npos) << e.what();
  }
}

TEST_F(PolytopeFile, MissingFileSaysHowToMakeIt) {
  try {
    load_polytope_model(robot_, path("absent.yaml"));
    FAIL() << "expected an error";
  } catch (const PolytopeFileError& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("absent.yaml"), std::string::npos) << msg;
    EXPECT_NE(msg.find("polytopes fit"), std::string::npos) << msg;
  }
}

TEST_F(PolytopeFile, ChangedRobotMakesTheFileStale) {
  save_polytope_model(model_, robot_, path("p.yaml"));
  robot::RobotModel changed = robot_;
  changed.legs[2].torque_limit[1] = 160.0;
  try {
    load_polytope_model(changed, path("p.yaml"));
    FAIL() << "expected an error";
  } catch (const PolytopeFileError& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("stale"), std::string::npos) << msg;
    EXPECT_NE(msg.find(robot_.legs[2].name), std::string::npos) << msg;
  }
  changed = robot_;
  changed.legs[0].l1 += 0.01;
  EXPECT_THROW(load_polytope_model(changed, path("p.yaml")), PolytopeFileError);
  changed = robot_;
  changed.name = "other";
  EXPECT_THROW(load_polytope_model(changed, path("p.yaml")), PolytopeFileError);
}

// The planner's shared copy (every problem build asks for it; a planning session builds one per
// step): parsed once, the same model while the file stays as it was, re-read after a refit
// (another modification time), errors thrown and not kept.
TEST_F(PolytopeFile, SharedModelIsParsedOnceAndFollowsTheFile) {
  robot_.source_file = path("robot.yaml");
  const std::string file = polytope_path_for(robot_);
  EXPECT_THROW(shared_polytope_model(robot_), PolytopeFileError);
  save_polytope_model(model_, robot_, file);
  const auto first = shared_polytope_model(robot_);
  ASSERT_TRUE(first);
  EXPECT_EQ(first->legs[0].nodes, model_.legs[0].nodes);
  EXPECT_EQ(shared_polytope_model(robot_).get(), first.get());

  RobotPolytopeModel refit = model_;
  refit.legs[0].hip_offset += 0.01;
  save_polytope_model(refit, robot_, file);
  // A later modification time whatever the file system's clock resolution.
  std::filesystem::last_write_time(
      file, std::filesystem::last_write_time(file) + std::chrono::seconds(2));
  const auto second = shared_polytope_model(robot_);
  EXPECT_NE(second.get(), first.get());
  EXPECT_EQ(second->legs[0].hip_offset, refit.legs[0].hip_offset);
  EXPECT_EQ(first->legs[0].hip_offset, model_.legs[0].hip_offset);  // a holder's copy stays

  // Legs the file was not fitted for: stale, as load_polytope_model says, every time.
  robot::RobotModel changed = robot_;
  changed.legs[1].torque_limit[0] += 10.0;
  EXPECT_THROW(shared_polytope_model(changed), PolytopeFileError);
  EXPECT_THROW(shared_polytope_model(changed), PolytopeFileError);
  EXPECT_EQ(shared_polytope_model(robot_).get(), second.get());
}

TEST_F(PolytopeFile, MalformedFieldIsNamed) {
  save_polytope_model(model_, robot_, path("p.yaml"));
  std::ifstream in(path("p.yaml"));
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const size_t at = text.find("hip_offset:");
  ASSERT_NE(at, std::string::npos);
  text.replace(at, std::string("hip_offset:").size(), "hip_offset: [1, 2]\n    x_hip_offset:");
  std::ofstream(path("bad.yaml")) << text;
  try {
    load_polytope_model(robot_, path("bad.yaml"));
    FAIL() << "expected an error";
  } catch (const PolytopeFileError& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("hip_offset"), std::string::npos) << msg;
    EXPECT_NE(msg.find("bad.yaml"), std::string::npos) << msg;
  }
  std::ofstream(path("junk.yaml")) << "robot: [unclosed\n";
  EXPECT_THROW(load_polytope_model(robot_, path("junk.yaml")), PolytopeFileError);
}

TEST(PolytopeFingerprint, DependsOnTheLegOnly) {
  const auto model = hyq();
  EXPECT_EQ(leg_fingerprint(model.legs[0]), leg_fingerprint(model.legs[0]));
  EXPECT_NE(leg_fingerprint(model.legs[0]), leg_fingerprint(model.legs[1]));
  auto leg = model.legs[0];
  leg.q_max[2] += 0.01;
  EXPECT_NE(leg_fingerprint(model.legs[0]), leg_fingerprint(leg));
}

}  // namespace
}  // namespace terrastride::planner
