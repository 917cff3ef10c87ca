// "joints" (constraints/joints.cpp; joint ranges): Jacobians against central differences (merged
// and separate rows), the separate rows against the robot's own inverse kinematics, and the merged
// rows against the soft maximum of those rows' distances past their bounds.
#include <algorithm>
#include <cmath>

#include "family_test.hpp"
#include "terrastride/robot/leg_kinematics.hpp"

namespace terrastride::planner {
namespace {

using namespace testing;

TEST(Joints, JacobianMatchesCentralDifferences) {
  const auto r = hyq();
  TanhStep terrain(0.1, 0.5, 0.05, 0.01);
  PlannerOptions o;
  o.has_goal = true;
  o.goal = Eigen::Vector3d(0.4, 0.05, 0.3);  // a turn: yaw enters the base-frame foot position
  o.constraints = {"joints"};
  o.feasibility_settings = {{"joints_softmax", 0.005}};  // merged rows (separate: below)
  SrbdProblem p(r, terrain, crawl_timeline(r), o);
  ASSERT_GT(count_kinds(p)["joints"], 0);
  for (unsigned seed : {1u, 2u, 3u})
    EXPECT_GT(check_piece_derivatives(p, seed, 0.02,
                                      [](const Piece& piece) { return piece.kind == "joints"; }),
              0);
}

// The separate rows (joints_softmax = 0, the default) too.
TEST(Joints, SeparateRowsJacobianMatchesCentralDifferences) {
  const auto r = hyq();
  TanhStep terrain(0.1, 0.5, 0.05, 0.01);
  PlannerOptions o;
  o.has_goal = true;
  o.goal = Eigen::Vector3d(0.4, 0.05, 0.3);
  SrbdProblem p(r, terrain, crawl_timeline(r), o);
  FeasibilityOptions fo;
  fo.joints_softmax = 0.0;
  const auto pieces = pieces_added_by(p, [&] { build_joints_set(p, fo); });
  ASSERT_FALSE(pieces.empty());
  for (const Piece* piece : pieces) EXPECT_EQ(piece->rows(), 3);
  for (unsigned seed : {1u, 2u})
    EXPECT_GT(check_piece_derivatives(p, seed, 0.02,
                                      [](const Piece& piece) { return piece.kind == "joints"; }),
              0);
}

// Merged (joints_softmax > 0): one piece and one row per foot and base knot, then one per swing segment
// (its three points); each row is the soft maximum of the separate rows' distances past their
// bounds, so >= the largest of them (the row implies every bound) and at most t log(n) above it.
TEST(Joints, MergedRowIsTheSoftMaximumOfTheSeparateRowsExcess) {
  const auto r = hyq();
  FlatField flat;
  PlannerOptions o;
  o.has_goal = true;
  o.goal = Eigen::Vector3d(0.4, 0.0, 0.2);
  SrbdProblem merged(r, flat, crawl_timeline(r), o), separate(r, flat, crawl_timeline(r), o);
  FeasibilityOptions fm, fs;
  fm.joints_softmax = 0.01;
  fs.joints_softmax = 0.0;
  const auto pm = pieces_added_by(merged, [&] { build_joints_set(merged, fm); });
  const auto ps = pieces_added_by(separate, [&] { build_joints_set(separate, fs); });
  const Layout& L = merged.layout();
  const int nf = static_cast<int>(r.legs.size());
  int swing_segments = 0;
  for (int f = 0; f < nf; ++f)
    for (int s = 0; s < L.num_segments; ++s) swing_segments += !L.contact[f][s];
  ASSERT_EQ(static_cast<int>(pm.size()), nf * (L.num_segments + 1) + swing_segments);
  ASSERT_EQ(ps.size(), pm.size() + 2 * swing_segments);
  std::vector<double> x = merged.initial_guess();
  for (std::size_t i = 0; i < x.size(); ++i)
    if (merged.lower()[i] < merged.upper()[i]) x[i] += 0.02 * std::sin(2.3 * static_cast<double>(i));
  // Each separate piece's largest distance past a bound (q - ub, lb - q).
  auto excess = [&](const Piece& piece) {
    std::vector<double> xl(piece.vars.size()), g(piece.rows());
    for (std::size_t i = 0; i < xl.size(); ++i) xl[i] = x[piece.vars[i]];
    piece.eval(xl.data(), g.data());
    double m = -1e300;
    for (int j = 0; j < piece.rows(); ++j) m = std::max({m, g[j] - piece.ub[j], piece.lb[j] - g[j]});
    return m;
  };
  std::size_t s_index = 0;
  int checked = 0;
  const std::size_t knot_pieces = nf * (L.num_segments + 1);
  for (std::size_t i = 0; i < pm.size(); ++i) {
    const Piece* piece = pm[i];
    ASSERT_EQ(piece->rows(), 1);
    EXPECT_EQ(piece->ub[0], 0.0);
    // A knot's piece stands for one separate piece, a swing segment's for three.
    const int n = i < knot_pieces ? 1 : 3;
    double largest = -1e300;
    for (int k = 0; k < n; ++k) largest = std::max(largest, excess(*ps[s_index++]));
    std::vector<double> xl(piece->vars.size());
    for (std::size_t i = 0; i < xl.size(); ++i) xl[i] = x[piece->vars[i]];
    double g = 0.0;
    piece->eval(xl.data(), &g);
    if (!std::isfinite(largest) || !std::isfinite(g)) continue;
    EXPECT_GE(g, largest - 1e-12);
    EXPECT_LE(g, largest + 0.01 * std::log(6.0 * n) + 1e-12);
    ++checked;
  }
  EXPECT_EQ(s_index, ps.size());
  EXPECT_GT(checked, static_cast<int>(pm.size()) * 3 / 4);
}

// Separate rows: one piece per foot and base knot, then three per swing segment (at 1/4, 1/2,
// 3/4); the rows are the IK joint angles, bounded by the joint range shrunk by the margin.
TEST(Joints, RowsAreTheIkAnglesWithinTheRangeLessTheMargin) {
  const auto r = hyq();
  FlatField flat;
  PlannerOptions o;
  o.has_goal = true;
  o.goal = Eigen::Vector3d(0.4, 0.0, 0.2);
  SrbdProblem p(r, flat, crawl_timeline(r), o);
  const std::size_t before = p.pieces().size();
  FeasibilityOptions fo;
  fo.joint_margin = 0.05;
  fo.joints_softmax = 0.0;
  build_joints_set(p, fo);
  const Layout& L = p.layout();
  const int nf = static_cast<int>(r.legs.size());
  int swing_segments = 0;
  for (int f = 0; f < nf; ++f)
    for (int s = 0; s < L.num_segments; ++s) swing_segments += !L.contact[f][s];
  ASSERT_EQ(static_cast<int>(p.pieces().size() - before),
            nf * (L.num_segments + 1) + 3 * swing_segments);
  std::vector<double> x = p.initial_guess();
  for (std::size_t i = 0; i < x.size(); ++i)
    if (p.lower()[i] < p.upper()[i]) x[i] += 0.02 * std::sin(2.3 * static_cast<double>(i));
  std::vector<double> g(p.num_constraints());
  p.eval_constraints(x.data(), g.data());
  int row = 0;
  for (std::size_t i = 0; i < before; ++i) row += p.pieces()[i]->rows();
  int knots_checked = 0;
  for (int f = 0; f < nf; ++f)
    for (int k = 0; k <= L.num_segments; ++k, row += 3) {
      const auto v = [&](int i) { return Eigen::Vector3d(x[i], x[i + 1], x[i + 2]); };
      const Eigen::Vector3d e = v(L.base[k] + 6);
      const Eigen::Matrix3d R = (Eigen::AngleAxisd(e[0], Eigen::Vector3d::UnitZ()) *
                                 Eigen::AngleAxisd(e[1], Eigen::Vector3d::UnitY()) *
                                 Eigen::AngleAxisd(e[2], Eigen::Vector3d::UnitX()))
                                    .toRotationMatrix();
      const auto ik = robot::inverse_kinematics(
          r.legs[f], R.transpose() * (v(L.foot_pos[f][k]) - v(L.base[k])));
      // The perturbed guess may put a foot out of reach (no IK angles to compare with).
      if (ik.status == robot::IkStatus::unreachable) continue;
      ++knots_checked;
      const Piece& piece = *p.pieces()[before + f * (L.num_segments + 1) + k];
      for (int j = 0; j < 3; ++j) {
        EXPECT_NEAR(g[row + j], ik.q[j], 1e-9) << "foot " << f << " knot " << k << " joint " << j;
        EXPECT_DOUBLE_EQ(piece.lb[j], r.legs[f].q_min[j] + 0.05);
        EXPECT_DOUBLE_EQ(piece.ub[j], r.legs[f].q_max[j] - 0.05);
      }
    }
  EXPECT_GT(knots_checked, 3 * nf * (L.num_segments + 1) / 4);
  // Then three pieces per swing segment of each foot, at 1/4, 1/2 and 3/4 of it: the IK angles of
  // the splines evaluated there.
  std::size_t piece_index = before + nf * (L.num_segments + 1);
  int swing_checked = 0;
  for (int f = 0; f < nf; ++f)
    for (int s = 0; s < L.num_segments; ++s) {
      if (L.contact[f][s]) continue;
      for (const double sigma : {0.25, 0.5, 0.75}) {
        const Piece& piece = *p.pieces()[piece_index++];
        ASSERT_EQ(piece.kind, "joints");
        const double t = L.nominal_knot_time[s] +
                         sigma * (L.nominal_knot_time[s + 1] - L.nominal_knot_time[s]);
        const auto st = p.evaluate(x, t);
        const Eigen::Vector3d e = st.euler;
        const Eigen::Matrix3d R = (Eigen::AngleAxisd(e[0], Eigen::Vector3d::UnitZ()) *
                                   Eigen::AngleAxisd(e[1], Eigen::Vector3d::UnitY()) *
                                   Eigen::AngleAxisd(e[2], Eigen::Vector3d::UnitX()))
                                      .toRotationMatrix();
        const auto ik =
            robot::inverse_kinematics(r.legs[f], R.transpose() * (st.foot_pos[f] - st.pos));
        row += 3;
        if (ik.status == robot::IkStatus::unreachable) continue;
        for (int j = 0; j < 3; ++j)
          EXPECT_NEAR(g[row - 3 + j], ik.q[j], 1e-9)
              << "foot " << f << " swing segment " << s << " at " << sigma;
        ++swing_checked;
      }
    }
  EXPECT_GT(swing_checked, 3 * 3 * swing_segments / 4);
  EXPECT_GT(swing_segments, 0);
  FeasibilityOptions bad;
  bad.joint_margin = 2.0;  // more than half of every range
  EXPECT_THROW(build_joints_set(p, bad), std::invalid_argument);
}

}  // namespace
}  // namespace terrastride::planner
