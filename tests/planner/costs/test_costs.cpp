// The objective's terms (planner/src/costs/): each term's Jacobian against central
// differences, its value against an independent evaluation (the integral by fine quadrature of
// the problem's own solution evaluation, or the deviation it measures), and the objective's
// gradient against central differences of its value.
#include <cmath>

#include "../constraints/family_test.hpp"

namespace terrastride::planner {
namespace {

using namespace testing;

ObjectiveWeights only(const std::string& term, double w = 1.0) {
  ObjectiveWeights o = ObjectiveWeights::none();
  if (term == "base_acceleration") o.base_acceleration = w;
  if (term == "base_angular_acceleration") o.base_angular_acceleration = w;
  if (term == "force_rate") o.force_rate = w;
  if (term == "swing_acceleration") o.swing_acceleration = w;
  if (term == "body_height") o.body_height = w;
  if (term == "heading") o.heading = w;
  if (term == "lateral") o.lateral = w;
  if (term == "progress") o.progress = w;
  if (term == "base_jerk") o.base_jerk = w;
  return o;
}

int check_cost_derivatives(const SrbdProblem& p, const std::string& kind) {
  int checked = 0;
  for (unsigned seed : {1u, 2u, 3u})
    checked += check_piece_derivatives(p, p.cost_pieces(), seed, 0.02,
                                       [&](const Piece& piece) { return piece.kind == kind; });
  return checked;
}

TEST(Costs, JacobiansMatchCentralDifferences) {
  const auto r = hyq();
  TanhStep terrain(0.1, 0.5, 0.05, 0.01);
  for (bool timing : {false, true}) {
    ProblemOptions o = turning_crawl_options(timing);
    o.constraints = {"force_ramp"};
    o.objective = ObjectiveWeights{};  // the tuned weights: every term
    const SrbdProblem p(r, terrain, crawl_timeline(r), o);
    for (const char* kind : {"cost_base_acceleration", "cost_force_rate",
                             "cost_swing_acceleration", "cost_nominal_pose", "cost_base_jerk"})
      EXPECT_GT(check_cost_derivatives(p, kind), 3) << kind << " timing " << timing;
  }
}

// The objective's value by term: default weights give every kind; zero weights none.
TEST(Costs, WeightsSelectTheTerms) {
  const auto r = hyq();
  FlatField flat;
  ProblemOptions o = paper_test_options();
  EXPECT_FALSE(o.objective.any());  // off by default
  o.objective = ObjectiveWeights{};
  const SrbdProblem p(r, flat, crawl_timeline(r), o);
  std::map<std::string, int> kinds;
  for (const auto& c : p.cost_pieces()) ++kinds[c->kind];
  EXPECT_EQ(kinds.size(), 5u);
  EXPECT_EQ(kinds["cost_base_jerk"], 2 * p.layout().num_segments - 1);
  EXPECT_EQ(kinds["cost_base_acceleration"], p.layout().num_segments);
  EXPECT_EQ(kinds["cost_nominal_pose"], p.layout().num_segments + 1);
  o.objective = ObjectiveWeights::none();
  const SrbdProblem none(r, flat, crawl_timeline(r), o);
  EXPECT_FALSE(none.has_objective());
  const std::vector<double> x = const_cast<SrbdProblem&>(none).initial_guess();
  EXPECT_EQ(none.eval_objective(x.data()), 0.0);
}

// Midpoint quadrature of f(t) over [0, T] in n steps.
template <class F>
double integral(double T, int n, F f) {
  double sum = 0.0;
  for (int i = 0; i < n; ++i) sum += f((i + 0.5) * T / n);
  return sum * T / n;
}

TEST(Costs, BaseAccelerationIsTheIntegralOfTheSquaredAccelerations) {
  const auto r = hyq();
  FlatField flat;
  ProblemOptions o = turning_crawl_options(true);
  o.objective = only("base_acceleration", 2.0);
  o.objective.base_angular_acceleration = 0.3;
  SrbdProblem p(r, flat, crawl_timeline(r), o);
  const auto x = perturbed_guess(p, 4, 0.02);
  // Segment by segment (the accelerations jump at knots), midpoint rule in 2000 steps each.
  const Layout& L = p.layout();
  double expected = 0.0;
  for (int s = 0; s < L.num_segments; ++s) {
    const double t0 = segment_start(L, x, s), h = segment_length(L, x, s);
    expected += integral(h, 2000, [&](double t) {
      const auto st = p.evaluate(x, t0 + t);
      return 2.0 * (st.acc / 9.81).squaredNorm() + 0.3 * st.euler_acc.squaredNorm();
    });
  }
  EXPECT_GT(expected, 1e-3);
  EXPECT_NEAR(p.eval_objective(x.data()), expected, 1e-6 * expected);
}

TEST(Costs, ForceRateIsTheIntegralOfTheSquaredForceRate) {
  const auto r = hyq();
  FlatField flat;
  for (const char* sets : {"baseline", "force_ramp"}) {
    ProblemOptions o = turning_crawl_options(true);
    o.constraints = {sets};
    o.objective = only("force_rate", 0.5);
    SrbdProblem p(r, flat, crawl_timeline(r), o);
    const auto x = perturbed_guess(p, 6, 0.02);
    const Layout& L = p.layout();
    const double mg = r.mass * 9.81;
    // Per segment the force is linear: its rate is the change between just after the segment's
    // start and just before its end, over the time between.
    double expected = 0.0;
    for (int s = 0; s < L.num_segments; ++s) {
      const double t0 = segment_start(L, x, s), h = segment_length(L, x, s), e = 1e-7 * h;
      const auto a = p.evaluate(x, t0 + e), b = p.evaluate(x, t0 + h - e);
      for (int f = 0; f < 4; ++f)
        if (L.contact[f][s]) {
          const Eigen::Vector3d rate = (b.force[f] - a.force[f]) / (h - 2 * e) / mg;
          expected += 0.5 * rate.squaredNorm() * h;
        }
    }
    EXPECT_GT(expected, 1e-4) << sets;
    EXPECT_NEAR(p.eval_objective(x.data()), expected, 1e-5 * expected) << sets;
  }
}

TEST(Costs, SwingAccelerationIsTheIntegralOverSwings) {
  const auto r = hyq();
  FlatField flat;
  ProblemOptions o = turning_crawl_options(false);
  o.objective = only("swing_acceleration", 3.0);
  SrbdProblem p(r, flat, crawl_timeline(r), o);
  const auto x = perturbed_guess(p, 7, 0.02);
  const double T = p.duration(x), dt = 1e-6;
  const double expected = integral(T, 40000, [&](double t) {
    const auto a = p.evaluate(x, t - dt), b = p.evaluate(x, t + dt), c = p.evaluate(x, t);
    double sum = 0.0;
    for (int f = 0; f < 4; ++f)
      if (!c.contact[f] && a.contact[f] == c.contact[f] && b.contact[f] == c.contact[f])
        sum += ((b.foot_vel[f] - a.foot_vel[f]) / (2 * dt) / 9.81).squaredNorm();
    return 3.0 * sum;
  });
  EXPECT_GT(expected, 1e-3);
  EXPECT_NEAR(p.eval_objective(x.data()), expected, 2e-3 * expected);
}

// Zero on the nominal path (the cold guess); a uniform offset d of every free knot gives
// weight * (d / scale)^2 times the free knots' share of the plan's time.
TEST(Costs, NominalPoseMeasuresTheOffsetFromTheGuess) {
  const auto r = hyq();
  FlatField flat;
  ProblemOptions o = paper_test_options();
  o.goal = Eigen::Vector3d(0.4, 0.0, 0.0);
  for (const char* term : {"body_height", "heading", "lateral", "progress"}) {
    o.objective = only(term, 2.0);
    SrbdProblem p(r, flat, crawl_timeline(r), o);
    const Layout& L = p.layout();
    std::vector<double> x = p.initial_guess();
    EXPECT_NEAR(p.eval_objective(x.data()), 0.0, 1e-20) << term;
    const std::string t = term;
    const int offset = t == "body_height" ? 2 : t == "heading" ? 6 : t == "lateral" ? 1 : 0;
    const double d = 0.01, scale = std::string(term) == "heading" ? 0.1 : 0.05;
    const int S = L.num_segments;
    const double T = L.nominal_knot_time[S];
    double share = 0.0;
    for (int k = 0; k <= S; ++k) {
      const int i = L.base[k] + offset;
      if (!(p.lower()[i] < p.upper()[i])) continue;  // fixed (start, goal): stays
      x[i] += d;
      const double tp = L.nominal_knot_time[std::max(0, k - 1)];
      const double tn = L.nominal_knot_time[std::min(S, k + 1)];
      share += 0.5 * (tn - tp) / T;
    }
    EXPECT_GT(share, 0.8) << term;
    EXPECT_NEAR(p.eval_objective(x.data()), 2.0 * share * std::pow(d / scale, 2), 1e-12) << term;
  }
}

TEST(Costs, GradientMatchesCentralDifferencesOfTheObjective) {
  const auto r = hyq();
  TanhStep terrain(0.1, 0.5, 0.05, 0.01);
  ProblemOptions o = turning_crawl_options(true);
  o.constraints = {"force_ramp"};
  o.objective = ObjectiveWeights{};
  SrbdProblem p(r, terrain, crawl_timeline(r), o);
  auto x = perturbed_guess(p, 9, 0.02);
  std::vector<double> grad(p.num_variables());
  p.eval_objective_gradient(x.data(), grad.data());
  int nonzero = 0;
  for (int i = 0; i < p.num_variables(); i += 7) {
    const double h = 1e-6 * std::max(1.0, std::abs(x[i]));
    auto xp = x, xm = x;
    xp[i] += h;
    xm[i] -= h;
    const double fd = (p.eval_objective(xp.data()) - p.eval_objective(xm.data())) / (2 * h);
    EXPECT_NEAR(grad[i], fd, 1e-5 * std::max(1.0, std::abs(fd))) << "variable " << i;
    nonzero += grad[i] != 0.0;
  }
  EXPECT_GT(nonzero, 20);
}

// Within segments the jerk is constant, (a1 - a0) / h; at interior knots the jump of the
// acceleration counts over the mean of the two segments' durations.
TEST(Costs, BaseJerkIsTheJerkIntegralPlusTheKnotJumps) {
  const auto r = hyq();
  FlatField flat;
  ProblemOptions o = turning_crawl_options(true);
  o.objective = only("base_jerk", 0.7);
  SrbdProblem p(r, flat, crawl_timeline(r), o);
  const auto x = perturbed_guess(p, 8, 0.02);
  const Layout& L = p.layout();
  const int S = L.num_segments;
  double expected = 0.0;
  std::vector<Eigen::Vector3d> start_acc(S), end_acc(S);
  for (int s = 0; s < S; ++s) {
    const double t0 = segment_start(L, x, s), h = segment_length(L, x, s), e = 1e-9;
    start_acc[s] = p.evaluate(x, t0 + e * h).acc;
    end_acc[s] = p.evaluate(x, t0 + h * (1 - e)).acc;
    expected += 0.7 * ((end_acc[s] - start_acc[s]) / 9.81).squaredNorm() / h;
  }
  for (int s = 1; s < S; ++s) {
    const double hm = 0.5 * (segment_length(L, x, s - 1) + segment_length(L, x, s));
    expected += 0.7 * ((start_acc[s] - end_acc[s - 1]) / 9.81).squaredNorm() / hm;
  }
  EXPECT_GT(expected, 1.0);
  EXPECT_NEAR(p.eval_objective(x.data()), expected, 1e-6 * expected);
}

}  // namespace
}  // namespace terrastride::planner
