// The Ceres fit of the force-polytope model on a small sample, and the committed fitted parameters
// (data/robots/*.polytopes.yaml) against the quality targets on held-out foot positions.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <string>

#include "terrastride/planner/polytope_fit.hpp"
#include "terrastride/planner/polytope_model.hpp"
#include "terrastride/robot/leg_kinematics.hpp"

namespace terrastride::planner {
namespace {

robot::RobotModel load(const std::string& name) {
  return robot::load_robot(std::string(TERRASTRIDE_TEST_DATA_DIR) + "/robots/" + name + ".yaml");
}

// Held-out positions: a seed the committed fit did not use (it used 1 + 7919 i).
constexpr uint64_t kHeldOutSeed = 424242;

TEST(PolytopeFit, SmallFitBeatsThePaperVariantOnHeldOutPositions) {
  const auto model = load("hyq");
  const auto& leg = model.legs[2];  // LH: knee forward
  PolytopeFitOptions opt;
  opt.samples = 240;
  opt.l_refs = 5;
  opt.alpha_refs = 2;
  opt.max_iterations = 30;
  const auto train = sample_leg_workspace(leg, opt.samples, 9);
  LegFitReport report;
  const LegPolytopeModel fitted = fit_leg_polytope(leg, train, opt, &report);
  EXPECT_LT(report.final_cost, 0.05 * report.initial_cost);
  EXPECT_LE(report.training.rho_out_max, opt.max_training_rho_out + 1e-9);
  // The fitted hip lands near the real joint geometry (HAA axis, HAA->HFE offset) it started from.
  EXPECT_LT((fitted.hip - leg.haa_origin).norm(), 0.02);
  EXPECT_NEAR(fitted.hip_offset, leg.l0, 0.02);

  const auto held_out = sample_leg_workspace(leg, 300, kHeldOutSeed);
  const PolytopeQuality ours = evaluate_polytope_quality(fitted, leg, held_out);
  const PolytopeQuality paper =
      evaluate_polytope_quality(paper_polytope_model(leg, train), leg, held_out);
  EXPECT_LE(ours.rho_out_median, 1.02);
  EXPECT_LE(ours.rho_out_max, 1.10);  // small sample, coarse grid: looser than the committed fit
  EXPECT_GE(ours.rho_in_median, 0.95);
  EXPECT_GT(paper.rho_out_median, ours.rho_out_median + 0.2);
}

TEST(PolytopeFit, HipCanBeHeldAtItsStart) {
  const auto model = load("monoped");
  const auto& leg = model.legs[0];
  PolytopeFitOptions opt;
  opt.l_refs = 4;
  opt.alpha_refs = 1;  // the paper's interpolation in l only, with the roll
  opt.fit_hip = false;
  opt.max_iterations = 20;
  const auto train = sample_leg_workspace(leg, 120, 4);
  const LegPolytopeModel fitted = fit_leg_polytope(leg, train, opt, nullptr);
  EXPECT_EQ(fitted.hip, leg.haa_origin);
  EXPECT_EQ(fitted.hip_offset, leg.l0);
  EXPECT_EQ(fitted.num_alpha(), 1);
  const auto q = evaluate_polytope_quality(fitted, leg, sample_leg_workspace(leg, 200, 77));
  EXPECT_LE(q.rho_out_median, 1.05);
}

TEST(PolytopeFit, BadInputIsRejectedWithTheLegName) {
  const auto model = load("hyq");
  const auto& leg = model.legs[0];
  EXPECT_THROW(sample_leg_workspace(leg, 0, 1), std::invalid_argument);
  PolytopeFitOptions opt;
  try {
    fit_leg_polytope(leg, sample_leg_workspace(leg, 10, 1), opt, nullptr);
    FAIL() << "expected an error";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("LF"), std::string::npos) << e.what();
  }
  opt.l_refs = 1;
  EXPECT_THROW(fit_leg_polytope(leg, sample_leg_workspace(leg, 100, 1), opt, nullptr),
               std::invalid_argument);
  // A box that lies wholly out of reach yields no feasible samples.
  robot::LegModel far = leg;
  far.nominal_foot.z() = -2.0;
  EXPECT_THROW(sample_leg_workspace(far, 5, 1), std::runtime_error);
}

// A quick fit of one leg: the copy tests need a model with real structure, not a good one.
PolytopeFitOptions quick_fit_options() {
  PolytopeFitOptions opt;
  opt.samples = 80;
  opt.l_refs = 4;
  opt.alpha_refs = 2;
  opt.max_iterations = 5;
  opt.rounds = 1;
  return opt;
}

Eigen::Vector3d mirrored(const LegCopy& c, const Eigen::Vector3d& v) {
  return Eigen::Vector3d(c.mirror_x * v.x(), c.mirror_y * v.y(), v.z());
}

// Every leg of the real quadrupeds is a mirror twin or translated copy of the first, and the
// copied model's facets at a foot position are exactly the mirrored facets of the source's at the
// mirrored position.
TEST(PolytopeCopy, TwinLegsAreFoundAndTheirModelIsTheMirroredSource) {
  for (const std::string name : {"go2", "hyq", "anymal_c"}) {
    const auto model = load(name);
    const auto& source = model.legs[0];
    const LegPolytopeModel fitted = fit_leg_polytope(
        source, sample_leg_workspace(source, 80, 3), quick_fit_options(), nullptr);
    for (size_t i = 1; i < model.legs.size(); ++i) {
      const auto& target = model.legs[i];
      const auto copy = find_leg_copy(source, target, sample_leg_workspace(target, 24, 5));
      ASSERT_TRUE(copy) << name << " " << target.name;
      const LegPolytopeModel m = copy_leg_polytope(fitted, source, target, *copy);
      EXPECT_EQ(m.leg_name, target.name);
      for (const auto& p : sample_leg_workspace(target, 40, 11)) {
        const Eigen::Vector3d p_source = source.haa_origin + mirrored(*copy, p - target.haa_origin);
        const PolytopeFacets ft = m.facets(p), fs = fitted.facets(p_source);
        for (int j = 0; j < kPolytopeFacets; ++j) {
          const int js = copy->source_facet[j];
          EXPECT_LT((ft.normals[j] - mirrored(*copy, fs.normals[js])).norm(), 1e-9)
              << name << " " << target.name << " facet " << j;
          EXPECT_NEAR(ft.offsets[j], fs.offsets[js], 1e-9 * std::abs(fs.offsets[js]));
        }
      }
    }
  }
  // The mirrors themselves: Go2's right front leg is its left front leg mirrored in y, HyQ's
  // left hind leg (knee forward) its left front leg mirrored in x.
  const auto go2 = load("go2");
  const auto rf = find_leg_copy(go2.legs[0], go2.legs[1], {});
  ASSERT_TRUE(rf);
  EXPECT_EQ(rf->mirror_x, 1);
  EXPECT_EQ(rf->mirror_y, -1);
  const auto hyq = load("hyq");
  const auto lh = find_leg_copy(hyq.legs[0], hyq.legs[2], {});
  ASSERT_TRUE(lh);
  EXPECT_EQ(lh->mirror_x, -1);
  EXPECT_EQ(lh->mirror_y, 1);
}

TEST(PolytopeCopy, LegsWithOtherTorquesOrLinksAreNotCopies) {
  const auto go2 = load("go2");
  const auto feet = sample_leg_workspace(go2.legs[1], 24, 5);
  robot::LegModel stronger = go2.legs[1];
  stronger.torque_limit[2] *= 1.1;
  EXPECT_FALSE(find_leg_copy(go2.legs[0], stronger, feet));
  robot::LegModel longer = go2.legs[1];
  longer.joint_offset[2] *= 1.05;  // a longer thigh (HFE -> KFE)
  robot::classify_leg_geometry(longer, true);
  EXPECT_FALSE(find_leg_copy(go2.legs[0], longer, feet));
  const auto hyq = load("hyq");
  EXPECT_FALSE(find_leg_copy(hyq.legs[0], go2.legs[0], sample_leg_workspace(go2.legs[0], 24, 5)));
}

TEST(PolytopeCopy, RobotFitCopiesTwinsOnlyWhenTheyFitAsWell) {
  auto go2 = load("go2");
  go2.legs[3].torque_limit[1] *= 1.2;  // RH is no twin any more
  PolytopeFitOptions opt = quick_fit_options();
  opt.copy_rho_in_tolerance = 1.0;  // accept every copy
  std::vector<LegFitReport> reports;
  const RobotPolytopeModel fitted = fit_robot_polytopes(go2, opt, &reports);
  ASSERT_EQ(reports.size(), 4u);
  EXPECT_TRUE(reports[0].copied_from.empty());
  EXPECT_GT(reports[0].iterations, 0);
  EXPECT_EQ(reports[1].copied_from, "LF mirrored in y");
  EXPECT_EQ(reports[1].iterations, 0);
  EXPECT_FALSE(reports[2].copied_from.empty());
  EXPECT_TRUE(reports[3].copied_from.empty());
  EXPECT_GT(reports[3].iterations, 0);
  for (size_t i = 0; i < 4; ++i) {
    EXPECT_EQ(fitted.legs[i].leg_name, go2.legs[i].name);
    EXPECT_LE(reports[i].training.rho_out_max, opt.max_training_rho_out + 1e-9) << i;
    // The report's figures are the leg's own, on its own training feet.
    const auto q = evaluate_polytope_quality(
        fitted.legs[i], go2.legs[i],
        sample_leg_workspace(go2.legs[i], opt.samples, opt.seed + 7919 * i, opt.box_scale));
    EXPECT_DOUBLE_EQ(q.rho_in_median, reports[i].training.rho_in_median) << i;
  }
  // A copy that must beat its source by a whole unit of rho_in never does: every leg is fitted,
  // the twins starting from their copies.
  opt.copy_rho_in_tolerance = -1.0;
  fit_robot_polytopes(go2, opt, &reports);
  for (const auto& r : reports) {
    EXPECT_TRUE(r.copied_from.empty()) << r.leg;
    EXPECT_GT(r.iterations, 0) << r.leg;
    EXPECT_LE(r.training.rho_out_max, opt.max_training_rho_out + 1e-9) << r.leg;
  }
  EXPECT_TRUE(reports[0].started_from.empty());
  EXPECT_EQ(reports[1].started_from, "LF mirrored in y");
  EXPECT_FALSE(reports[2].started_from.empty());
  EXPECT_TRUE(reports[3].started_from.empty());
}

// The committed parameters meet the quality targets of issue 5 on held-out positions; this fails
// if a refit (or a change of the model code) degrades them.
void check_committed(const std::string& robot_name, int samples_per_leg) {
  const auto model = load(robot_name);
  const RobotPolytopeModel fitted = load_polytope_model(model);  // also fails when stale
  std::vector<double> out_all;
  for (size_t i = 0; i < model.legs.size(); ++i) {
    const auto& leg = model.legs[i];
    const auto feet = sample_leg_workspace(leg, samples_per_leg, kHeldOutSeed + 31 * i);
    const LegPolytopeModel& m = fitted.leg(leg.name);
    std::vector<double> in;
    for (const auto& p : feet) {
      out_all.push_back(polytope_rho_out(m, leg, p));
      in.push_back(polytope_rho_in(m, leg, p));
      EXPECT_LE(out_all.back(), 1.05) << robot_name << " " << leg.name << " at " << p.transpose();
    }
    std::sort(in.begin(), in.end());
    // Conservative but not timid: the approximation keeps most of the exact polytope.
    EXPECT_GE(in[in.size() / 2], 0.95) << robot_name << " " << leg.name;
    EXPECT_GE(in.front(), 0.8) << robot_name << " " << leg.name;
  }
  std::sort(out_all.begin(), out_all.end());
  EXPECT_LE(out_all[out_all.size() / 2], 1.02) << robot_name;
  EXPECT_LE(out_all.back(), 1.05) << robot_name;
}

TEST(PolytopeCommitted, HyqMeetsTheTargetsOnHeldOutPositions) {
  check_committed("hyq", 1500);
}
TEST(PolytopeCommitted, MonopedMeetsTheTargetsOnHeldOutPositions) {
  check_committed("monoped", 1500);
}

TEST(PolytopeCommitted, PaperVariantIsFarWorseOnHyq) {
  // The comparison the issue asks for: the sagittal-only variant errs by tens of percent.
  const auto model = load("hyq");
  std::vector<double> out;
  for (const auto& leg : model.legs) {
    const auto paper = paper_polytope_model(leg, sample_leg_workspace(leg, 300, 3));
    for (const auto& p : sample_leg_workspace(leg, 300, kHeldOutSeed))
      out.push_back(polytope_rho_out(paper, leg, p));
  }
  std::sort(out.begin(), out.end());
  EXPECT_GT(out[out.size() / 2], 1.3);
  EXPECT_GT(out.back(), 2.0);
}

}  // namespace
}  // namespace terrastride::planner
