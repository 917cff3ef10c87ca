// Where the leg clearance families (shin_ik, thigh) put constraint points inside segments: where
// the terrain near the leg is tall (leg_capsule_clearance.hpp). On flat ground a leg's links are
// far above the terrain and the knots suffice; beside a step they move past an edge within a
// segment (measured on eur_pallet --goal 1.5,0,0 with knots only: a swinging LH shin 33 mm into
// the pallet 0.04 s from a knot where its row held).
#include <algorithm>
#include <cmath>
#include <vector>

#include "leg_capsule_clearance.hpp"

namespace terrastride::planner::feasibility {

std::vector<std::vector<int>> leg_clearance_points(SrbdProblem& problem,
                                                   const FeasibilityOptions& options) {
  const Layout& L = problem.layout();
  const int S = L.num_segments;
  const int nf = static_cast<int>(L.foot_pos.size());
  const std::vector<double>& x0 = problem.initial_guess();
  const terrain::HeightField& field = problem.terrain();
  // The highest terrain within the reach of each foot's initial-guess position at each knot,
  // sampled on a grid finer than the narrowest feature the planner's smoothed terrain keeps.
  constexpr double kStep = 0.03;
  const int n = static_cast<int>(std::ceil(kTallTerrainReach / kStep));
  std::vector<std::vector<double>> top(nf, std::vector<double>(S + 1)),
      foot_z(nf, std::vector<double>(S + 1));
  for (int f = 0; f < nf; ++f)
    for (int k = 0; k <= S; ++k) {
      const int v = L.foot_pos[f][k];
      const double px = x0[v], py = x0[v + 1];
      foot_z[f][k] = x0[v + 2];
      // A foot in stance keeps its guess position from knot to knot (three quarters of a crawl's
      // knots): the disc around it is the previous knot's, so is its highest terrain.
      if (k > 0) {
        const int u = L.foot_pos[f][k - 1];
        if (x0[u] == px && x0[u + 1] == py) {
          top[f][k] = top[f][k - 1];
          continue;
        }
      }
      double m = -1e300;
      for (int i = -n; i <= n; ++i)
        for (int j = -n; j <= n; ++j) {
          if ((i * i + j * j) * kStep * kStep > kTallTerrainReach * kTallTerrainReach) continue;
          m = std::max(m, field.height(px + i * kStep, py + j * kStep));
        }
      top[f][k] = m;
    }
  std::vector<std::vector<int>> points(nf, std::vector<int>(S, 0));
  for (int f = 0; f < nf; ++f)
    for (int s = 0; s < S; ++s) {
      const double rise = std::max(top[f][s], top[f][s + 1]) -
                          std::min(foot_z[f][s], foot_z[f][s + 1]);
      if (rise > kTallTerrainRise) points[f][s] = std::max(1, options.leg_clearance_points);
    }
  return points;
}

}  // namespace terrastride::planner::feasibility
