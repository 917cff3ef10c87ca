// "shin_ik" (constraints/shin_ik.cpp; the shin inequality on the leg's IK shin): Jacobians against
// central differences (per-point and merged rows), and the rows against the robot's own inverse
// kinematics and knee position.
#include <cmath>
#include <optional>

#include "family_test.hpp"
#include "terrastride/robot/leg_kinematics.hpp"

namespace terrastride::planner {
namespace {

using namespace testing;

TEST(ShinIk, JacobianMatchesCentralDifferences) {
  const auto r = hyq();
  MarginStep terrain(0.1, 0.5, 0.05, 0.01);
  ProblemOptions o = turning_crawl_options(false);
  o.constraints = {"shin_ik"};
  const SrbdProblem p(r, terrain, crawl_timeline(r), o);
  ASSERT_GT(count_kinds(p)["shin_ik"], 0);
  for (unsigned seed : {1u, 2u})
    EXPECT_GT(check_piece_derivatives(p, seed, 0.02,
                                      [](const Piece& piece) { return piece.kind == "shin_ik"; }),
              0);
}

// Both variants: 4 nk - 1 rows per point (shin_softmin 0: under each point, under the next, two
// probes across), and one merged row per point.
class ShinIkVariants : public ::testing::TestWithParam<double> {};
INSTANTIATE_TEST_SUITE_P(SoftScale, ShinIkVariants, ::testing::Values(0.0, 0.003));
TEST_P(ShinIkVariants, JacobianMatchesCentralDifferences) {
  const double t_soft = GetParam();
  const auto r = hyq();
  MarginStep terrain(0.1, 0.5, 0.05, 0.01);
  SrbdProblem p(r, terrain, crawl_timeline(r), turning_crawl_options());
  FeasibilityOptions fo;
  fo.shin_softmin = t_soft;
  fo.shin_points = 10;  // 39 rows per piece unmerged (at most 64)
  const auto pieces = pieces_added_by(p, [&] { build_shin_ik_set(p, fo); });
  ASSERT_FALSE(pieces.empty());
  int inside = 0;  // pieces inside a segment (the step is tall): the Hermite and duration paths
  for (const Piece* piece : pieces) {
    EXPECT_EQ(piece->rows(), t_soft > 0 ? 1 : 4 * fo.shin_points - 1);
    inside += piece->vars.size() > 9;
  }
  EXPECT_GT(inside, 0);
  EXPECT_GT(check_kind_derivatives(p, "shin_ik"), 0);
}

// The knee is the robot's own IK knee: at every knot, the piece's row for point nk - 1 (the knee;
// rows 2 j - 1 are the points j >= 1 without probes) is the height of robot::knee_position at the
// IK solution above the flat ground. With the robot's foot radius, a stance foot rolls (see
// constraints/leg_capsule_clearance.hpp): the knee is then the IK knee of the foot moved along
// the heading by r_foot times the change of the shin's pitch since the stance's first knot,
// computed here with the robot's own IK; with a point foot (radius 0) nothing rolls.
void expect_rows_at_the_ik_knee(double foot_radius) {
  auto r = hyq();
  r.foot_radius = foot_radius;
  FlatField flat;
  SrbdProblem p(r, flat, crawl_timeline(r), ProblemOptions{});
  FeasibilityOptions fo;
  fo.shin_clearance = 0.0;  // rows are plain heights above the flat ground
  fo.shin_softmin = 0.0;    // one row per point
  fo.leg_probe_margin = -1.0;  // no probes: 2 nk - 1 rows
  const auto pieces = pieces_added_by(p, [&] { build_shin_ik_set(p, fo); });
  const std::vector<double> x = perturbed_guess(p, 3, 0.01);
  const Layout& L = p.layout();
  const auto knee_of = [&](int foot, const Eigen::Vector3d& pf, const Eigen::Vector3d& base,
                           const Eigen::Matrix3d& R) -> std::optional<Eigen::Vector3d> {
    const auto ik = robot::inverse_kinematics(r.legs[foot], R.transpose() * (pf - base));
    if (ik.status == robot::IkStatus::unreachable) return std::nullopt;
    return base + R * robot::knee_position(r.legs[foot], ik.q);
  };
  int checked = 0, rolled = 0;
  for (const Piece* piece : pieces) {
    // Which foot and knot: the piece's variables are the foot's position at a knot (3; its
    // foothold in stance, its spline knot in swing), base position (3), euler (3), and in stance
    // the base pose at the stance's first knot.
    const int pv = piece->vars[0], bv = piece->vars[3];
    int foot = -1, knot = -1;
    for (std::size_t f = 0; f < L.foot_pos.size(); ++f)
      for (int k = 0; k <= L.num_segments; ++k)
        if (L.foot_pos[f][k] == pv && L.base[k] == bv) foot = static_cast<int>(f), knot = k;
    ASSERT_GE(foot, 0);
    Eigen::Vector3d pf = vec3_at(x, pv);
    const Eigen::Vector3d base = vec3_at(x, bv), e = vec3_at(x, bv + 6);
    const Eigen::Matrix3d R = rotation_of(e);
    const int seg = std::min(knot, L.num_segments - 1);
    if (foot_radius > 0.0 && L.contact[foot][seg]) {
      const Layout::Stance* stance = nullptr;
      for (const auto& st : L.stances)
        if (st.foot == foot && st.first_seg <= seg && seg <= st.last_seg) stance = &st;
      ASSERT_NE(stance, nullptr);
      const Eigen::Vector3d b0 = vec3_at(x, L.base[stance->first_seg]);
      const Eigen::Matrix3d R0 = rotation_of(vec3_at(x, L.base[stance->first_seg] + 6));
      const auto k0 = knee_of(foot, pf, b0, R0), k1 = knee_of(foot, pf, base, R);
      if (!k0 || !k1) continue;
      const Eigen::Vector3d h(std::cos(e[0]), std::sin(e[0]), 0.0);
      const auto pitch = [&](const Eigen::Vector3d& u) { return std::atan2(u.dot(h), u.z()); };
      const double dphi = pitch(*k1 - pf) - pitch(*k0 - pf);
      pf += foot_radius * dphi * h;
      rolled += std::abs(dphi) > 1e-3;
    }
    const auto knee = knee_of(foot, pf, base, R);
    if (!knee) continue;
    const auto g = rows_at(*piece, x);
    ASSERT_EQ(g.size(), 2u * fo.shin_points - 1);
    EXPECT_NEAR(g[2 * fo.shin_points - 3], knee->z(), 1e-9);  // the knee; flat ground z = 0
    ++checked;
  }
  EXPECT_GT(checked, 10);
  if (foot_radius > 0.0) {
    EXPECT_GT(rolled, 5) << "stance knots where the shin has turned";
  }
}

TEST(ShinIk, KneeIsTheIkKnee) { expect_rows_at_the_ik_knee(0.0); }
TEST(ShinIk, StanceKneeIsTheIkKneeOfTheRolledFoot) { expect_rows_at_the_ik_knee(0.02); }

// Merged (the default): each piece's row is the soft minimum of its 4 nk - 1 point rows.
TEST(ShinIk, MergedRowIsTheSoftMinimumOfTheKnotsPointRows) {
  const auto r = hyq();
  MarginStep terrain(0.1, 0.5, 0.05, 0.01);
  SrbdProblem p(r, terrain, crawl_timeline(r), ProblemOptions{});
  FeasibilityOptions fp, fm;
  fp.shin_softmin = 0.0;
  fp.shin_points = fm.shin_points = 10;  // 39 rows unmerged
  const auto pp = pieces_added_by(p, [&] { build_shin_ik_set(p, fp); });
  const auto mp = pieces_added_by(p, [&] { build_shin_ik_set(p, fm); });
  ASSERT_GT(fm.shin_softmin, 0.0);
  const std::vector<double> x = perturbed_guess(p, 7, 0.01);
  ASSERT_EQ(pp.size(), mp.size());
  ASSERT_GT(pp.size(), 10u);
  for (std::size_t i = 0; i < pp.size(); ++i) {
    ASSERT_EQ(pp[i]->vars, mp[i]->vars);
    const auto g = rows_at(*pp[i], x);
    const double merged = rows_at(*mp[i], x)[0];
    double mn = 1e300, sum = 0.0;
    for (double v : g) mn = std::min(mn, v);
    for (double v : g) sum += std::exp(-(v - mn) / fm.shin_softmin);
    EXPECT_NEAR(merged, mn - fm.shin_softmin * std::log(sum), 1e-12);
    EXPECT_LE(merged, mn);
  }
}

// A ridge beside the shin, not under it: the probes across the base's heading see it. A ridge
// (0.3 m high, 4 cm wide) runs along x at y = foot's y + 4 cm, beside the LF shin of the nominal
// stance (the shin lies in the leg's x-z plane): the row without probes holds, the row with
// probes (shin radius + 2 cm = 4.5 cm across) does not.
class Ridge : public terrain::HeightField {
 public:
  explicit Ridge(double y0) : y0_(y0) {}
  terrain::HeightSample sample(double, double y) const override {
    terrain::HeightSample s;
    s.height = std::abs(y - y0_) < 0.02 ? 0.3 : 0.0;
    return s;
  }
  terrain::MarginSample safety_margin(double, double, double) const override {
    return {1e9, Eigen::Vector2d::Zero()};
  }
  Eigen::Vector2d min_corner() const override { return {-5, -5}; }
  Eigen::Vector2d max_corner() const override { return {5, 5}; }
  std::string describe() const override { return "ridge"; }

 private:
  double y0_;
};

TEST(ShinIk, ProbesSeeARidgeBesideTheShin) {
  const auto r = hyq();
  const double foot_y = r.legs[0].nominal_foot.y();
  Ridge ridge(foot_y + 0.04);
  ProblemOptions o;
  for (const double margin : {-1.0, 0.02}) {
    SrbdProblem p(r, ridge, crawl_timeline(r), o);
    FeasibilityOptions fo;
    fo.leg_probe_margin = margin;
    const auto pieces = pieces_added_by(p, [&] { build_shin_ik_set(p, fo); });
    const std::vector<double> x = p.initial_guess();
    // The first piece: LF at the first knot, the nominal stance.
    ASSERT_FALSE(pieces.empty());
    const double row = rows_at(*pieces[0], x)[0];
    if (margin < 0)
      EXPECT_GT(row, pieces[0]->lb[0]) << "without probes the terrain under the shin is flat";
    else
      EXPECT_LT(row, pieces[0]->lb[0]) << "the probes read the ridge 4 cm beside the shin";
  }
}

}  // namespace
}  // namespace terrastride::planner
