// The feasibility constraint sets (foot radius, shin, force polytopes): every piece's Jacobian
// against central finite differences on a curved terrain with a varying safety margin, the
// pieces' values against the formulas evaluated independently, and the set registry ("all").
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <random>
#include <set>

#include "terrastride/planner/feasibility.hpp"
#include "terrastride/planner/gait.hpp"
#include "terrastride/planner/nlp.hpp"
#include "terrastride/planner/polytope_model.hpp"
#include "terrastride/robot/leg_kinematics.hpp"
#include "terrastride/robot/robot_model.hpp"
#include "../../planner/src/constraints/feasibility_common.hpp"
#include "piece_derivatives.hpp"
#include "test_robots.hpp"
#include "test_terrains.hpp"

namespace terrastride::planner {
namespace {

using testing::count_kinds;
using testing::feet_of;
using testing::hyq;

// The tanh step with a safety margin that varies smoothly in x and y (so the foot piece's
// gradient chain is exercised): m = 0.03 + 0.05 sin(4x) cos(3y) - r.
class MarginStep : public testing::TanhStep {
 public:
  using TanhStep::TanhStep;
  terrain::MarginSample safety_margin(double x, double y, double r) const override {
    terrain::MarginSample m;
    m.margin = 0.03 + 0.05 * std::sin(4 * x) * std::cos(3 * y) - r;
    m.gradient = Eigen::Vector2d(0.2 * std::cos(4 * x) * std::cos(3 * y),
                                 -0.15 * std::sin(4 * x) * std::sin(3 * y));
    return m;
  }
};

// Central differences of each piece of the given kinds; returns the number of pieces checked.
int check_pieces(const SrbdProblem& p, const std::set<std::string>& kinds, unsigned seed,
                 double noise_size) {
  return testing::check_piece_derivatives(
      p, seed, noise_size, [&](const Piece& piece) { return kinds.count(piece.kind) > 0; });
}

TEST(FeasibilityDerivatives, HyqPiecesMatchFiniteDifferences) {
  const auto r = hyq();
  MarginStep terrain(0.1, 0.5, 0.05, 0.01);
  PlannerOptions o;
  o.has_goal = true;
  o.goal = Eigen::Vector3d(0.4, 0.05, 0.3);  // a turn, so the yaw paths are exercised
  o.optimize_timing = true;                  // duration variables in the inner points
  o.constraints = {"all", "shin"};
  const PhaseTimeline tl = make_timeline(load_gait(resolve_gait_path("crawl")), feet_of(r), 1, 2.0);
  SrbdProblem p(r, terrain, tl, o);
  const auto kinds = count_kinds(p);
  ASSERT_GT(kinds.count("foot"), 0u);
  ASSERT_GT(kinds.count("shin"), 0u);
  ASSERT_GT(kinds.count("polytope"), 0u);
  for (unsigned seed : {1u, 2u, 3u})
    EXPECT_GT(check_pieces(p, {"foot", "shin", "polytope"}, seed, 0.02), 0);
}

TEST(FeasibilityDerivatives, ShinKinematicPiecesMatchFiniteDifferences) {
  const auto r = hyq();
  MarginStep terrain(0.1, 0.5, 0.05, 0.01);
  PlannerOptions o;
  o.has_goal = true;
  o.goal = Eigen::Vector3d(0.4, 0.05, 0.3);
  o.constraints = {"shin_ik"};
  const PhaseTimeline tl = make_timeline(load_gait(resolve_gait_path("crawl")), feet_of(r), 1, 2.0);
  SrbdProblem p(r, terrain, tl, o);
  ASSERT_GT(count_kinds(p)["shin_ik"], 0);
  for (unsigned seed : {1u, 2u}) EXPECT_GT(check_pieces(p, {"shin_ik"}, seed, 0.02), 0);
}

// The shin_ik knee is the robot's own IK knee: at a stance knot, the piece's first row (t = t0
// along foot -> knee) and last row (the knee) match robot::knee_position at the IK solution.
TEST(FeasibilityValues, ShinKinematicKneeIsTheIkKnee) {
  const auto r = hyq();
  testing::FlatField flat;
  PlannerOptions o;
  const PhaseTimeline tl = make_timeline(load_gait(resolve_gait_path("crawl")), feet_of(r), 1, 2.0);
  SrbdProblem p(r, flat, tl, o);
  FeasibilityOptions fo;
  fo.shin_clearance = 0.0;  // rows are plain heights above the flat ground
  fo.shin_softmin = 0.0;    // one row per point
  build_shin_ik_set(p, fo);
  std::vector<double> x = p.initial_guess();
  std::mt19937 rng(3);
  std::normal_distribution<double> noise(0.0, 0.01);
  for (std::size_t i = 0; i < x.size(); ++i)
    if (p.lower()[i] < p.upper()[i]) x[i] += noise(rng);
  const Layout& L = p.layout();
  int checked = 0;
  for (const auto& piece : p.pieces()) {
    if (piece->kind != "shin_ik") continue;
    // Which foot and knot: the piece's variables are the foot's position at a knot (3; its
    // foothold in stance, its spline knot in swing), base position (3), euler (3).
    const int pv = piece->vars[0], bv = piece->vars[3];
    int foot = -1;
    for (std::size_t f = 0; f < L.foot_pos.size(); ++f)
      for (int k = 0; k <= L.num_segments; ++k)
        if (L.foot_pos[f][k] == pv && L.base[k] == bv) foot = static_cast<int>(f);
    ASSERT_GE(foot, 0);
    const Eigen::Vector3d pf(x[pv], x[pv + 1], x[pv + 2]), base(x[bv], x[bv + 1], x[bv + 2]);
    const Eigen::Vector3d e(x[bv + 6], x[bv + 7], x[bv + 8]);
    const Eigen::Matrix3d R = (Eigen::AngleAxisd(e[0], Eigen::Vector3d::UnitZ()) *
                               Eigen::AngleAxisd(e[1], Eigen::Vector3d::UnitY()) *
                               Eigen::AngleAxisd(e[2], Eigen::Vector3d::UnitX()))
                                  .toRotationMatrix();
    const auto ik = robot::inverse_kinematics(r.legs[foot], R.transpose() * (pf - base));
    if (ik.status == robot::IkStatus::unreachable) continue;
    const Eigen::Vector3d knee = base + R * robot::knee_position(r.legs[foot], ik.q);
    std::vector<double> xl(piece->vars.size()), g(piece->rows());
    for (std::size_t i = 0; i < xl.size(); ++i) xl[i] = x[piece->vars[i]];
    piece->eval(xl.data(), g.data());
    EXPECT_NEAR(g[(g.size() - 1) / 2], knee.z(), 1e-9);  // row nk-1: the knee; flat ground z = 0
    ++checked;
  }
  EXPECT_GT(checked, 10);
}

// Merged shin_ik (the default): each knot's row is the soft minimum of its 2 nk - 1 point rows.
TEST(FeasibilityValues, MergedShinKinematicRowIsTheSoftMinimum) {
  const auto r = hyq();
  MarginStep terrain(0.1, 0.5, 0.05, 0.01);
  PlannerOptions o;
  const PhaseTimeline tl = make_timeline(load_gait(resolve_gait_path("crawl")), feet_of(r), 1, 2.0);
  SrbdProblem points(r, terrain, tl, o), merged(r, terrain, tl, o);
  FeasibilityOptions fp, fm;
  fp.shin_softmin = 0.0;
  build_shin_ik_set(points, fp);
  build_shin_ik_set(merged, fm);
  ASSERT_GT(fm.shin_softmin, 0.0);
  std::vector<double> x = points.initial_guess();
  std::mt19937 rng(7);
  std::normal_distribution<double> noise(0.0, 0.01);
  for (std::size_t i = 0; i < x.size(); ++i)
    if (points.lower()[i] < points.upper()[i]) x[i] += noise(rng);
  std::vector<const Piece*> pp, mp;
  for (const auto& piece : points.pieces())
    if (piece->kind == "shin_ik") pp.push_back(piece.get());
  for (const auto& piece : merged.pieces())
    if (piece->kind == "shin_ik") mp.push_back(piece.get());
  ASSERT_EQ(pp.size(), mp.size());
  ASSERT_GT(pp.size(), 10u);
  for (std::size_t i = 0; i < pp.size(); ++i) {
    ASSERT_EQ(pp[i]->vars, mp[i]->vars);
    std::vector<double> xl(pp[i]->vars.size()), g(pp[i]->rows()), gm(1);
    for (std::size_t k = 0; k < xl.size(); ++k) xl[k] = x[pp[i]->vars[k]];
    pp[i]->eval(xl.data(), g.data());
    mp[i]->eval(xl.data(), gm.data());
    double mn = 1e300, sum = 0.0;
    for (double v : g) mn = std::min(mn, v);
    for (double v : g) sum += std::exp(-(v - mn) / fm.shin_softmin);
    EXPECT_NEAR(gm[0], mn - fm.shin_softmin * std::log(sum), 1e-12);
    EXPECT_LE(gm[0], mn);
  }
}

TEST(FeasibilityDerivatives, PiecesHaveNonzeroJacobians) {
  // A derivative test passes trivially for a piece whose value ignores its variables: make sure
  // each kind actually depends on its foothold (and the shin/polytope on the base too).
  const auto r = hyq();
  MarginStep terrain(0.1, 0.5, 0.05, 0.01);
  PlannerOptions o;
  o.has_goal = true;
  o.goal = Eigen::Vector3d(0.4, 0.0, 0.2);
  o.constraints = {"foot", "shin", "polytope"};
  const PhaseTimeline tl = make_timeline(load_gait(resolve_gait_path("crawl")), feet_of(r), 1, 2.0);
  SrbdProblem p(r, terrain, tl, o);
  const auto& x = p.initial_guess();
  std::map<std::string, double> largest;
  for (const auto& piece : p.pieces()) {
    const int n = static_cast<int>(piece->vars.size()), m = piece->rows();
    std::vector<double> xl(n), g(m), J(m * n);
    for (int i = 0; i < n; ++i) xl[i] = x[piece->vars[i]];
    piece->eval_jacobian(xl.data(), g.data(), J.data());
    for (double v : J) largest[piece->kind] = std::max(largest[piece->kind], std::abs(v));
  }
  EXPECT_GT(largest["foot"], 0.1);
  EXPECT_GT(largest["shin"], 0.1);
  EXPECT_GT(largest["polytope"], 1e-3);
}

TEST(FeasibilityDerivatives, MonopedPolytopePiecesMatchFiniteDifferences) {
  const auto r = robot::load_robot(robot::resolve_robot_path("monoped"));
  MarginStep terrain(0.0, 0.5, 0.05, 0.01);
  PlannerOptions o;
  o.gait = "hop";
  o.optimize_timing = true;
  o.constraints = {"all", "shin"};
  const PhaseTimeline tl = make_timeline(load_gait(resolve_gait_path("hop")), feet_of(r), 1, 0.0);
  SrbdProblem p(r, terrain, tl, o);
  EXPECT_GT(check_pieces(p, {"foot", "shin", "polytope"}, 5u, 0.01), 0);
  EXPECT_GT(count_kinds(p)["polytope"], 0);
}

// Values: each piece against the paper's formula evaluated here from the problem's own
// continuous-time solution (evaluate), at the initial guess perturbed. Points only at the knots
// (shin_yaw_points 1, no inner polytope points), so the extremes must agree exactly.
TEST(FeasibilityValues, PiecesEvaluateThePapersFormulas) {
  const auto r = hyq();
  MarginStep terrain(0.1, 0.5, 0.05, 0.01);
  PlannerOptions o;
  o.has_goal = true;
  o.goal = Eigen::Vector3d(0.4, 0.0, 0.3);
  const PhaseTimeline tl = make_timeline(load_gait(resolve_gait_path("crawl")), feet_of(r), 1, 2.0);
  SrbdProblem p(r, terrain, tl, o);
  FeasibilityOptions fo;
  fo.shin_yaw_points = 1;
  fo.shin_points = 3;
  fo.shin_exclusion = 0.1;  // k = 1/3, 2/3, 1 on the 0.3 m shin, as in the paper
  fo.polytope_inner_points = 0;
  fo.shin_softmin = 0.0;  // one row per point, so the extremes compare exactly
  fo.polytope_softmax = 0.0;
  build_foot_set(p, fo);
  build_shin_set(p, fo);
  build_polytope_set(p, fo);
  std::vector<double> x = p.initial_guess();
  std::mt19937 rng(11);
  std::normal_distribution<double> noise(0.0, 0.01);
  for (std::size_t i = 0; i < x.size(); ++i)
    if (p.lower()[i] < p.upper()[i]) x[i] += noise(rng);
  const Layout& L = p.layout();
  const auto polys = load_polytope_model(r);
  const double mg = r.mass * 9.81;

  // Minimum over each kind's rows, from the pieces, and from the formulas at the knots.
  std::map<std::string, double> piece_min, piece_max;
  for (const auto& piece : p.pieces()) {
    std::vector<double> xl(piece->vars.size()), g(piece->rows());
    for (std::size_t i = 0; i < xl.size(); ++i) xl[i] = x[piece->vars[i]];
    piece->eval(xl.data(), g.data());
    auto& mn = piece_min.emplace(piece->kind, 1e300).first->second;
    auto& mx = piece_max.emplace(piece->kind, -1e300).first->second;
    for (double v : g) {
      mn = std::min(mn, v);
      mx = std::max(mx, v);
    }
  }
  double foot_min = 1e300, shin_min = 1e300, poly_max = -1e300;
  double t = 0.0;
  std::vector<double> knot_t{0.0};
  for (int s = 0; s < L.num_segments; ++s)
    knot_t.push_back(knot_t.back() + x[L.interval_var[L.seg_interval[s]]] * L.seg_fraction[s]);
  for (const auto& st : L.stances) {
    const auto& leg = r.legs[st.foot];
    const Eigen::Vector3d pf(x[st.pos_var], x[st.pos_var + 1], x[st.pos_var + 2]);
    if (!st.fixed)
      foot_min = std::min(foot_min, terrain.safety_margin(pf.x(), pf.y(), r.foot_radius).margin);
    for (int k = st.first_seg; k <= st.last_seg + 1; ++k) {
      t = k == st.last_seg + 1 ? knot_t[k] - 1e-9 : knot_t[k];
      const auto state = p.evaluate(x, t);
      const double psi = state.euler[0];
      for (int j = 1; j <= 3; ++j) {
        const double a = j / 3.0 * leg.shin_length;
        const double qx = pf.x() + a * std::cos(leg.shin_angle) * std::cos(psi);
        const double qy = pf.y() + a * std::cos(leg.shin_angle) * std::sin(psi);
        shin_min = std::min(shin_min, pf.z() + a * std::sin(leg.shin_angle) - terrain.height(qx, qy));
      }
      const Eigen::Matrix3d R =
          (Eigen::AngleAxisd(state.euler[0], Eigen::Vector3d::UnitZ()) *
           Eigen::AngleAxisd(state.euler[1], Eigen::Vector3d::UnitY()) *
           Eigen::AngleAxisd(state.euler[2], Eigen::Vector3d::UnitX()))
              .toRotationMatrix();
      const Eigen::Vector3d pb = R.transpose() * (state.foot_pos[st.foot] - state.pos);
      const Eigen::Vector3d fb = R.transpose() * state.force[st.foot];
      poly_max = std::max(poly_max, polys.legs[st.foot].constraint(pb, fb).maxCoeff() / mg);
    }
  }
  EXPECT_NEAR(piece_min["foot"], foot_min, 1e-12);
  EXPECT_NEAR(piece_min["shin"], shin_min, 1e-7);
  EXPECT_NEAR(piece_max["polytope"], poly_max, 1e-7);
  EXPECT_LT(foot_min, 0.0);  // the test terrain has unsafe spots under the guess: not vacuous
}

// Both variants of the shin and polytope sets (per-point rows, and the default merged rows: one
// per stance segment): Jacobians against finite differences, optimised timing and a turn.
class FeasibilityVariants : public ::testing::TestWithParam<double> {};
INSTANTIATE_TEST_SUITE_P(SoftScale, FeasibilityVariants, ::testing::Values(0.0, 0.003));
TEST_P(FeasibilityVariants, PiecesMatchFiniteDifferences) {
  const double t_soft = GetParam();
  const auto r = hyq();
  MarginStep terrain(0.1, 0.5, 0.05, 0.01);
  PlannerOptions o;
  o.has_goal = true;
  o.goal = Eigen::Vector3d(0.4, 0.05, 0.3);
  o.optimize_timing = true;
  const PhaseTimeline tl = make_timeline(load_gait(resolve_gait_path("crawl")), feet_of(r), 1, 2.0);
  SrbdProblem p(r, terrain, tl, o);
  FeasibilityOptions fo;
  fo.shin_softmin = t_soft;
  fo.polytope_softmax = t_soft;
  build_shin_set(p, fo);
  build_shin_ik_set(p, fo);
  build_polytope_set(p, fo);
  for (const auto& piece : p.pieces()) {
    if (piece->kind == "shin") {
      EXPECT_EQ(piece->rows(), t_soft > 0 ? 1 : fo.shin_points);
    } else if (piece->kind == "shin_ik") {
      EXPECT_EQ(piece->rows(), t_soft > 0 ? 1 : 2 * fo.shin_points - 1);
    } else if (piece->kind == "polytope") {
      EXPECT_EQ(piece->rows(), t_soft > 0 ? 1 : 6);
    }
  }
  for (unsigned seed : {1u, 2u, 3u})
    EXPECT_GT(check_pieces(p, {"shin", "shin_ik", "polytope"}, seed, 0.02), 0);
}

TEST(FeasibilityValues, SoftMinIsAConservativeBound) {
  const double v[4] = {0.05, 0.02, 0.021, 0.3}, t = 0.004;
  const double sm = feasibility::soft_min(v, 4, t), sx = feasibility::soft_max(v, 4, t);
  EXPECT_LE(sm, 0.02);
  EXPECT_GE(sm, 0.02 - t * std::log(4.0));
  EXPECT_GE(sx, 0.3);
  EXPECT_LE(sx, 0.3 + t * std::log(4.0));
  // Exact formula, and far apart values: the soft minimum is the minimum to within t e^-(gap/t).
  EXPECT_NEAR(sm, -t * std::log(std::exp(-0.05 / t) + std::exp(-0.02 / t) + std::exp(-0.021 / t) +
                                std::exp(-0.3 / t)),
              1e-15);
  const double w[2] = {1.0, 1.5};
  EXPECT_NEAR(feasibility::soft_min(w, 2, 0.01), 1.0, 1e-15);
  // Large values do not overflow (the minimum is factored out).
  const double big[2] = {1e4, -1e4};
  EXPECT_DOUBLE_EQ(feasibility::soft_max(big, 2, 1e-3), 1e4);
}

// Each merged shin row is the soft minimum of the per-point rows it replaces (so it lies below
// every one of them), and each merged polytope row the soft maximum of the facet rows at the
// segment's force knots and midpoint, evaluated here from the continuous solution.
TEST(FeasibilityValues, MergedRowsBoundThePointRows) {
  const auto r = hyq();
  MarginStep terrain(0.1, 0.5, 0.05, 0.01);
  PlannerOptions o;
  o.has_goal = true;
  o.goal = Eigen::Vector3d(0.4, 0.0, 0.3);
  const PhaseTimeline tl = make_timeline(load_gait(resolve_gait_path("crawl")), feet_of(r), 1, 2.0);
  SrbdProblem points(r, terrain, tl, o), merged(r, terrain, tl, o);
  FeasibilityOptions fp, fm;
  fp.shin_softmin = 0.0;
  fm.shin_softmin = 0.004;
  fm.polytope_softmax = 0.004;
  build_shin_set(points, fp);
  build_shin_set(merged, fm);
  build_polytope_set(merged, fm);
  std::vector<double> x = points.initial_guess();
  std::mt19937 rng(5);
  std::normal_distribution<double> noise(0.0, 0.01);
  for (std::size_t i = 0; i < x.size(); ++i)
    if (points.lower()[i] < points.upper()[i]) x[i] += noise(rng);
  auto values = [&](const Piece& piece) {
    std::vector<double> xl(piece.vars.size()), g(piece.rows());
    for (std::size_t i = 0; i < xl.size(); ++i) xl[i] = x[piece.vars[i]];
    piece.eval(xl.data(), g.data());
    return g;
  };
  std::vector<const Piece*> pp, mp, poly;
  for (const auto& piece : points.pieces())
    if (piece->kind == "shin") pp.push_back(piece.get());
  for (const auto& piece : merged.pieces()) {
    if (piece->kind == "shin") mp.push_back(piece.get());
    if (piece->kind == "polytope") poly.push_back(piece.get());
  }
  // Per stance segment: shin_yaw_points pieces (one more in the stance's last segment).
  const Layout& L = points.layout();
  const int ny = fp.shin_yaw_points;
  std::size_t next = 0, m = 0;
  int checked = 0;
  for (const auto& st : L.stances) {
    if (!(r.legs[st.foot].shin_length > 0.0)) continue;
    for (int seg = st.first_seg; seg <= st.last_seg; ++seg, ++m) {
      const int group = ny + (seg == st.last_seg ? 1 : 0);
      std::vector<double> all;
      for (int k = 0; k < group; ++k) {
        ASSERT_LT(next, pp.size());
        const auto g = values(*pp[next++]);
        all.insert(all.end(), g.begin(), g.end());
      }
      ASSERT_LT(m, mp.size());
      const double merged_value = values(*mp[m])[0];
      double sum = 0.0, mn = 1e300;
      for (double v : all) mn = std::min(mn, v);
      for (double v : all) sum += std::exp(-(v - mn) / fm.shin_softmin);
      EXPECT_NEAR(merged_value, mn - fm.shin_softmin * std::log(sum), 1e-12);
      EXPECT_LE(merged_value, mn);
      ++checked;
    }
  }
  EXPECT_EQ(next, pp.size());
  EXPECT_EQ(m, mp.size());
  EXPECT_GT(checked, 10);

  // Polytope: pieces in order foot, stance segment.
  const auto polys = load_polytope_model(r);
  const double mg = r.mass * 9.81;
  std::vector<double> knot_t{0.0};
  for (int s = 0; s < L.num_segments; ++s)
    knot_t.push_back(knot_t.back() + x[L.interval_var[L.seg_interval[s]]] * L.seg_fraction[s]);
  std::size_t q = 0;
  for (int f = 0; f < static_cast<int>(r.legs.size()); ++f)
    for (int s = 0; s < L.num_segments; ++s) {
      if (!L.contact[f][s]) continue;
      ASSERT_LT(q, poly.size());
      std::vector<double> facets;
      for (double t : {knot_t[s] + 1e-12, 0.5 * (knot_t[s] + knot_t[s + 1]), knot_t[s + 1] - 1e-12}) {
        const auto state = merged.evaluate(x, t);
        const Eigen::Matrix3d R =
            (Eigen::AngleAxisd(state.euler[0], Eigen::Vector3d::UnitZ()) *
             Eigen::AngleAxisd(state.euler[1], Eigen::Vector3d::UnitY()) *
             Eigen::AngleAxisd(state.euler[2], Eigen::Vector3d::UnitX()))
                .toRotationMatrix();
        const Eigen::Vector3d pb = R.transpose() * (state.foot_pos[f] - state.pos);
        const Eigen::Vector3d fb = R.transpose() * state.force[f];
        const auto v = polys.legs[f].constraint(pb, fb);
        for (int j = 0; j < v.size(); ++j) facets.push_back(v[j] / mg);
      }
      double mx = -1e300, sum = 0.0;
      for (double v : facets) mx = std::max(mx, v);
      for (double v : facets) sum += std::exp((v - mx) / fm.polytope_softmax);
      const double merged_value = values(*poly[q++])[0];
      EXPECT_NEAR(merged_value, mx + fm.polytope_softmax * std::log(sum), 1e-7);
      EXPECT_GE(merged_value, mx - 1e-7);
    }
  EXPECT_EQ(q, poly.size());
  EXPECT_GT(q, 10u);
}

TEST(FeasibilityValues, DefaultsAddPointsInsideSegments) {
  const auto r = hyq();
  testing::FlatField flat;
  const PhaseTimeline tl = make_timeline(load_gait(resolve_gait_path("crawl")), feet_of(r), 1, 2.0);
  PlannerOptions o;
  SrbdProblem knots(r, flat, tl, o), dflt(r, flat, tl, o);
  FeasibilityOptions fo, fd;
  fo.shin_yaw_points = 1;
  fo.polytope_inner_points = 0;
  fo.shin_softmin = fd.shin_softmin = 0.0;  // piece counts of the per-point rows
  fo.polytope_softmax = fd.polytope_softmax = 0.0;
  build_shin_set(knots, fo);
  build_polytope_set(knots, fo);
  build_shin_set(dflt, fd);
  build_polytope_set(dflt, fd);
  // Every stance segment gains one shin point and one polytope point.
  int stance_segments = 0;
  for (const auto& st : knots.layout().stances) stance_segments += st.last_seg - st.first_seg + 1;
  auto kinds = count_kinds(knots), kinds2 = count_kinds(dflt);
  EXPECT_EQ(kinds2["shin"] - kinds["shin"], stance_segments);
  EXPECT_EQ(kinds2["polytope"] - kinds["polytope"], stance_segments);
}

TEST(FeasibilityRegistry, AllExpandsAndNamesAreListed) {
  const auto names = constraint_set_names();
  for (const std::string n : {"baseline", "foot", "shin", "shin_ik", "polytope", "swing", "joints", "all"})
    EXPECT_NE(std::find(names.begin(), names.end(), n), names.end()) << n;
  const auto r = hyq();
  testing::FlatField flat;
  const PhaseTimeline tl = make_timeline(load_gait(resolve_gait_path("crawl")), feet_of(r), 1, 2.0);
  PlannerOptions a, b;
  a.constraints = {"all"};
  b.constraints = {"baseline", "foot", "shin_ik", "polytope", "joints", "foot"};  // duplicates added once
  SrbdProblem pa(r, flat, tl, a), pb(r, flat, tl, b);
  EXPECT_EQ(count_kinds(pa), count_kinds(pb));
  EXPECT_EQ(pa.num_constraints(), pb.num_constraints());
  PlannerOptions c;
  c.constraints = {"all", "shinn"};
  try {
    SrbdProblem pc(r, flat, tl, c);
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("shinn"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace terrastride::planner
