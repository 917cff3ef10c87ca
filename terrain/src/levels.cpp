#include "terrastride/terrain/levels.hpp"

#include <algorithm>
#include <cmath>
#include <deque>
#include <numeric>

namespace terrastride::terrain {
namespace {

// How many cells a step may reach along an axis and along a diagonal: the first always, farther
// ones while they lie within `reach`.
struct StepLimits {
  int axis = 1, diagonal = 1;
};

StepLimits step_limits(const GridGeometry& g, double reach) {
  // No step leaves the grid: the cap keeps a huge reach (a map's max_climb of 1e300) from an
  // undefined conversion to int.
  const double cells = std::min(std::floor(reach / g.resolution), double(g.nx) + g.ny);
  const int far = std::max(1, static_cast<int>(cells));
  const auto limit = [&](double length) {
    int d = 1;
    while (d < far + 1 && (d + 1) * length * g.resolution <= reach) ++d;
    return d;
  };
  return {limit(1.0), limit(std::sqrt(2.0))};
}

// Calls step(n) for every cell one step from cell k reaches (header's rule).
template <class Step>
void for_each_step(const LevelInput& in, int k, double reach, const StepLimits& limits,
                   Step&& step) {
  const GridGeometry& g = in.geometry;
  const int i = k / g.ny, j = k % g.ny;
  const double h = in.height[k];
  for (int di = -1; di <= 1; ++di)
    for (int dj = -1; dj <= 1; ++dj) {
      if (!di && !dj) continue;
      const int last = di && dj ? limits.diagonal : limits.axis;
      for (int d = 1; d <= last; ++d) {
        const int a = i + d * di, b = j + d * dj;
        if (a < 0 || b < 0 || a >= g.nx || b >= g.ny) break;
        const int n = static_cast<int>(g.index(a, b));
        if (in.ground[n] && std::abs(in.height[n] - h) <= reach) {
          step(n);
          break;
        }
        // Not a step: swung over only when it is a hole or no higher than a leg length above.
        if (in.ground[n] && in.height[n] > h + reach) break;
      }
    }
}

int find(std::vector<int32_t>& parent, int a) {
  while (parent[a] != a) a = parent[a] = parent[parent[a]];
  return a;
}

}  // namespace

LevelInput level_input(const HeightGrid& grid) {
  LevelInput in;
  const size_t n = grid.geometry.size();
  in.geometry = grid.geometry;
  in.height = grid.elevation;
  in.ground.assign(n, 1);
  if (grid.overhead.size() == n)
    for (size_t k = 0; k < n; ++k)
      if (grid.observed[k] == 0 && grid.support[k] == 0 && std::isfinite(grid.overhead[k]))
        in.ground[k] = 0;
  return in;
}

std::vector<uint8_t> reachable_cells(const LevelInput& in, int from, double reach) {
  const StepLimits limits = step_limits(in.geometry, reach);
  std::vector<uint8_t> seen(in.geometry.size(), 0);
  std::deque<int> queue{from};
  seen[from] = 1;
  while (!queue.empty()) {
    const int k = queue.front();
    queue.pop_front();
    for_each_step(in, k, reach, limits, [&](int n) {
      if (!seen[n]) {
        seen[n] = 1;
        queue.push_back(n);
      }
    });
  }
  return seen;
}

GroundLevels ground_levels(const HeightGrid& grid, double reach) {
  GroundLevels out;
  const size_t n = grid.geometry.size();
  out.level.assign(n, -1);
  out.unreachable.assign(n, 0);
  if (n == 0) return out;
  const LevelInput in = level_input(grid);
  // Union-find over every step, so a step taken in either direction joins (the levels do not
  // depend on the order cells are visited in).
  const StepLimits limits = step_limits(in.geometry, reach);
  std::vector<int32_t> parent(n);
  std::iota(parent.begin(), parent.end(), 0);
  for (size_t k = 0; k < n; ++k) {
    if (!in.ground[k]) continue;
    for_each_step(in, static_cast<int>(k), reach, limits, [&](int m) {
      const int a = find(parent, static_cast<int>(k)), b = find(parent, m);
      if (a != b) parent[std::max(a, b)] = std::min(a, b);
    });
  }
  std::vector<size_t> observed(n, 0);
  for (size_t k = 0; k < n; ++k) {
    if (!in.ground[k]) continue;
    out.level[k] = find(parent, static_cast<int>(k));
    observed[out.level[k]] += grid.observed[k] != 0;
  }
  size_t best = 0;
  for (size_t k = 0; k < n; ++k)
    if (observed[k] > best) {
      best = observed[k];
      out.floor = static_cast<int32_t>(k);
    }
  if (out.floor < 0) return out;
  for (size_t k = 0; k < n; ++k) {
    if (observed[k] > 0 && static_cast<int32_t>(k) != out.floor) ++out.unreachable_levels;
    if (grid.observed[k] && out.level[k] != out.floor) {
      out.unreachable[k] = 1;
      ++out.unreachable_cells;
    }
  }
  return out;
}

}  // namespace terrastride::terrain
