#include "terrastride/terrain/height_grid.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

#include "terrastride/terrain/scenes.hpp"

namespace terrastride::terrain {
namespace {

using perception::InputError;

constexpr uint32_t kOutside = std::numeric_limits<uint32_t>::max();

struct Entry {
  float z;
  float z_entry;  // height at which the ray entered the cell's column; +inf when unknown
};

std::string fmt(double v) {
  std::ostringstream os;
  os << v;
  return os.str();
}

void validate_resolution(double res) {
  if (!std::isfinite(res) || res < 0.002 || res > 1.0)
    throw InputError("resolution " + fmt(res) +
                     " m is outside the accepted range [0.002, 1] m for a height grid");
}

GridGeometry make_geometry(const Eigen::Vector2d& lo, const Eigen::Vector2d& hi, double res,
                           size_t max_cells) {
  GridGeometry g;
  g.resolution = res;
  g.origin = Eigen::Vector2d(std::floor(lo.x() / res) * res, std::floor(lo.y() / res) * res);
  const double nx = std::floor((hi.x() - g.origin.x()) / res) + 1;
  const double ny = std::floor((hi.y() - g.origin.y()) / res) + 1;
  if (!(nx * ny <= static_cast<double>(max_cells)) || nx > 1e7 || ny > 1e7)
    throw InputError("resolution " + fmt(res) + " m gives a " + fmt(nx) + " x " + fmt(ny) +
                     " cell grid for an extent of " + fmt(hi.x() - lo.x()) + " x " +
                     fmt(hi.y() - lo.y()) + " m (more than " + std::to_string(max_cells) +
                     " cells); use a coarser resolution");
  g.nx = static_cast<int>(nx);
  g.ny = static_cast<int>(ny);
  return g;
}

void allocate(HeightGrid& grid) {
  const size_t n = grid.geometry.size();
  grid.elevation.assign(n, 0.0f);
  grid.variance.assign(n, 0.0f);
  grid.min.assign(n, 0.0f);
  grid.max.assign(n, 0.0f);
  grid.count.assign(n, 0);
  grid.support.assign(n, 0);
  grid.observed.assign(n, 0);
}

struct Range {
  size_t b, e;
  size_t size() const { return e - b; }
};

// Splits one cell's sorted heights into clusters, bottom to top; returns how many.
size_t find_clusters(const Entry* e, size_t n, double gap, Range* clusters, size_t cap) {
  size_t nc = 0, begin = 0;
  for (size_t i = 1; i <= n; ++i) {
    if (i == n || e[i].z - e[i - 1].z > gap) {
      if (nc < cap) {
        clusters[nc++] = {begin, i};
      } else {
        clusters[cap - 1].e = i;  // pathological cell: merge the rest into the top cluster
      }
      begin = i;
    }
  }
  return nc;
}

// True when most rays that reached points below cluster `c` entered the cell's column beneath it:
// the sensor saw under that surface, so it is an overhang, not support.
bool seen_beneath(const Entry* e, const Range& c, double vote) {
  const float bottom = e[c.b].z;
  size_t beneath = 0, pierced = 0;
  for (size_t i = 0; i < c.b; ++i) {
    if (!std::isfinite(e[i].z_entry)) continue;
    if (e[i].z_entry < bottom) {
      ++beneath;
    } else {
      ++pierced;
    }
  }
  return beneath > 0 && beneath > vote * (beneath + pierced);
}

void write_stats(const Entry* e, const Range& r, HeightGrid& grid, size_t k) {
  const size_t m = r.size();
  double sum = 0, sum2 = 0;
  for (size_t i = r.b; i < r.e; ++i) sum += e[i].z;
  const double mean = sum / m;
  for (size_t i = r.b; i < r.e; ++i) sum2 += (e[i].z - mean) * (e[i].z - mean);
  const size_t mid = r.b + m / 2;
  grid.elevation[k] = m % 2 ? e[mid].z : 0.5f * (e[mid - 1].z + e[mid].z);
  grid.variance[k] = static_cast<float>(sum2 / m);
  grid.min[k] = e[r.b].z;
  grid.max[k] = e[r.e - 1].z;
  grid.support[k] = static_cast<uint32_t>(m);
  grid.observed[k] = 1;
}

constexpr size_t kMaxClusters = 64;

// Picks the support cluster of one cell (entries sorted by z) and writes its statistics. Returns
// whether a higher, sparse cluster was passed over (a candidate for promotion, see below).
bool process_cell(const Entry* e, size_t n, const HeightGridOptions& o, HeightGrid& grid,
                  size_t k) {
  Range clusters[kMaxClusters];
  const size_t nc = find_clusters(e, n, o.cluster_gap, clusters, kMaxClusters);
  const size_t need = std::max<size_t>(static_cast<size_t>(std::max(o.min_support_points, 1)),
                                       static_cast<size_t>(std::ceil(o.min_support_fraction * n)));
  auto substantial = [&](int c) { return clusters[c].size() >= need; };
  int s = -1;
  for (int c = static_cast<int>(nc) - 1; c >= 0; --c) {
    if (substantial(c)) {
      s = c;
      break;
    }
  }
  if (s < 0) {  // no surface stands out (sparse cell): take the largest cluster, highest on ties
    size_t best = 0;
    for (size_t c = 0; c < nc; ++c) {
      if (clusters[c].size() >= best) {
        best = clusters[c].size();
        s = static_cast<int>(c);
      }
    }
  }
  bool overhang = false;
  for (;;) {
    int lower = -1;
    for (int c = s - 1; c >= 0; --c) {
      if (substantial(c)) {
        lower = c;
        break;
      }
    }
    if (lower < 0 || !seen_beneath(e, clusters[s], o.overhang_vote)) break;
    s = lower;
    overhang = true;
  }
  write_stats(e, clusters[s], grid, k);
  // A lone return (a flying pixel in a shadow, a stray reflection) is not evidence of a surface:
  // keep its height but leave the cell unobserved.
  if (clusters[s].size() < static_cast<size_t>(std::max(o.min_cell_points, 1))) {
    grid.observed[k] = 0;
    return false;
  }
  if (overhang) {
    ++grid.overhang_cells;
  } else if (clusters[s].b > 0) {
    ++grid.see_through_cells;
  }
  return !overhang && s + 1 < static_cast<int>(nc);
}

// A sparse cluster above the support is promoted when a neighbouring cell's support lies at its
// height: the surface (a grating tread seen by few rays here) continues into this cell and the
// denser returns below are see-through. Overhangs (seen beneath) are never promoted.
void promote_sparse_surfaces(const std::vector<Entry>& entries, const std::vector<uint32_t>& start,
                             const std::vector<uint8_t>& candidate, const HeightGridOptions& o,
                             HeightGrid& grid) {
  const GridGeometry& g = grid.geometry;
  const std::vector<float> elevation = grid.elevation;  // decisions use first-pass values only
  const std::vector<uint8_t> observed = grid.observed;
  Range clusters[kMaxClusters];
  for (int i = 0; i < g.nx; ++i) {
    for (int j = 0; j < g.ny; ++j) {
      const size_t k = g.index(i, j);
      if (!candidate[k]) continue;
      const Entry* e = entries.data() + start[k];
      const size_t n = start[k + 1] - start[k];
      const size_t nc = find_clusters(e, n, o.cluster_gap, clusters, kMaxClusters);
      for (int c = static_cast<int>(nc) - 1; c >= 0; --c) {
        const Range& r = clusters[c];
        const float median = e[r.b + r.size() / 2].z;
        if (median <= elevation[k] + o.cluster_gap) break;  // reached the current support
        bool matched = false;
        for (int di = -1; di <= 1 && !matched; ++di)
          for (int dj = -1; dj <= 1 && !matched; ++dj) {
            const int a = i + di, b = j + dj;
            if ((!di && !dj) || a < 0 || b < 0 || a >= g.nx || b >= g.ny) continue;
            const size_t nb = g.index(a, b);
            matched = observed[nb] && std::abs(elevation[nb] - median) <= 0.5 * o.cluster_gap;
          }
        if (matched && !seen_beneath(e, r, o.overhang_vote)) {
          write_stats(e, r, grid, k);
          ++grid.see_through_cells;
          break;
        }
      }
    }
  }
}

// Narrow pits (at most 2 K cells wide) more than cluster_gap deep are openings of a surface seen
// through (grating holes, gaps between deck boards): a grey-level closing (max then min filter over
// a (2K+1)^2 window) bridges them. Those cells did not observe the surface, so they become
// unobserved (hence unsafe) and fill_holes gives them the bridged height. Steps and wide trenches
// are untouched: a closing only removes valleys narrower than its window.
void close_narrow_pits(HeightGrid& grid, int K, double depth) {
  if (K <= 0) return;
  const GridGeometry& g = grid.geometry;
  constexpr float inf = std::numeric_limits<float>::infinity();
  std::vector<float> a(g.size()), b(g.size());
  for (size_t k = 0; k < g.size(); ++k) a[k] = grid.observed[k] ? grid.elevation[k] : -inf;
  // Separable running max / min; cells outside the grid are ignored.
  auto filter = [&](std::vector<float>& src, std::vector<float>& dst, bool take_max) {
    for (int i = 0; i < g.nx; ++i)
      for (int j = 0; j < g.ny; ++j) {
        float v = take_max ? -inf : inf;
        for (int d = std::max(0, j - K); d <= std::min(g.ny - 1, j + K); ++d)
          v = take_max ? std::max(v, src[g.index(i, d)]) : std::min(v, src[g.index(i, d)]);
        dst[g.index(i, j)] = v;
      }
    for (int i = 0; i < g.nx; ++i)
      for (int j = 0; j < g.ny; ++j) {
        float v = take_max ? -inf : inf;
        for (int d = std::max(0, i - K); d <= std::min(g.nx - 1, i + K); ++d)
          v = take_max ? std::max(v, dst[g.index(d, j)]) : std::min(v, dst[g.index(d, j)]);
        src[g.index(i, j)] = v;
      }
  };
  filter(a, b, true);
  filter(a, b, false);  // a = closing
  for (size_t k = 0; k < g.size(); ++k) {
    if (grid.observed[k] && std::isfinite(a[k]) && a[k] - grid.elevation[k] > depth) {
      grid.observed[k] = 0;
      --grid.observed_cells;
      ++grid.bridged_cells;
    }
  }
}

}  // namespace

HeightGrid build_height_grid(const std::vector<PointBatch>& batches, const HeightGridOptions& o) {
  validate_resolution(o.resolution);
  if (!(o.cluster_gap > 0) || !(o.min_support_fraction >= 0 && o.min_support_fraction <= 1))
    throw InputError("height grid: cluster_gap must be > 0 and min_support_fraction in [0, 1]");
  HeightGrid grid;
  size_t total = 0;
  for (const auto& b : batches) total += b.size;
  grid.points_in = total;

  Eigen::Vector2d lo, hi;
  if (o.lo && o.hi) {
    lo = *o.lo;
    hi = *o.hi;
    if (!(hi.x() > lo.x() && hi.y() > lo.y()) || !lo.allFinite() || !hi.allFinite())
      throw InputError("height grid: the extent's max corner must exceed its min corner");
  } else {
    float mnx = std::numeric_limits<float>::infinity(), mny = mnx, mxx = -mnx, mxy = -mnx;
    size_t finite = 0;
    for (const auto& b : batches) {
      for (size_t i = 0; i < b.size; ++i) {
        const Eigen::Vector3f& p = b.points[i];
        if (!std::isfinite(p.x()) || !std::isfinite(p.y()) || !std::isfinite(p.z())) continue;
        ++finite;
        mnx = std::min(mnx, p.x());
        mxx = std::max(mxx, p.x());
        mny = std::min(mny, p.y());
        mxy = std::max(mxy, p.y());
      }
    }
    if (finite == 0) throw InputError("no finite points to build a height grid from");
    lo = Eigen::Vector2d(mnx, mny);
    hi = Eigen::Vector2d(mxx, mxy);
  }
  grid.geometry = make_geometry(lo, hi, o.resolution, o.max_cells);
  allocate(grid);
  const GridGeometry& g = grid.geometry;
  const size_t ncell = g.size();

  // Pass 1: cell of every point (counting sort keeps this cache friendly and allocation free).
  std::vector<uint32_t> cell(total);
  std::vector<uint32_t> start(ncell + 1, 0);
  const float inv = static_cast<float>(1.0 / g.resolution);
  const float ox = static_cast<float>(g.origin.x()), oy = static_cast<float>(g.origin.y());
  size_t t = 0;
  for (const auto& b : batches) {
    for (size_t i = 0; i < b.size; ++i, ++t) {
      const Eigen::Vector3f& p = b.points[i];
      const float fx = (p.x() - ox) * inv, fy = (p.y() - oy) * inv;
      // The comparisons are false for NaN, so non-finite points land outside too.
      if (!(fx >= 0.0f && fy >= 0.0f && fx < g.nx && fy < g.ny && std::isfinite(p.z()))) {
        cell[t] = kOutside;
        continue;
      }
      const uint32_t k = static_cast<uint32_t>(static_cast<int>(fx) * g.ny + static_cast<int>(fy));
      cell[t] = k;
      ++start[k + 1];
    }
  }
  for (size_t k = 0; k < ncell; ++k) start[k + 1] += start[k];
  grid.points_in_grid = start[ncell];
  if (grid.points_in_grid == 0) throw InputError("no finite points inside the height grid extent");

  // Pass 2: scatter heights (and ray entry heights when the origin is known) into cell order.
  std::vector<Entry> entries(grid.points_in_grid);
  std::vector<uint32_t> fill(start.begin(), start.end() - 1);
  t = 0;
  const float res = static_cast<float>(g.resolution);
  for (const auto& b : batches) {
    const bool has_origin = b.origin.has_value();
    const Eigen::Vector3f o3 =
        has_origin ? Eigen::Vector3f(b.origin->cast<float>()) : Eigen::Vector3f::Zero();
    for (size_t i = 0; i < b.size; ++i, ++t) {
      const uint32_t k = cell[t];
      if (k == kOutside) continue;
      const Eigen::Vector3f& p = b.points[i];
      float ze = std::numeric_limits<float>::infinity();
      if (has_origin) {
        // Where the segment origin -> p enters the column of its cell (slab test in x and y).
        const int ci = static_cast<int>(k / g.ny), cj = static_cast<int>(k % g.ny);
        const float x0 = ox + ci * res, y0 = oy + cj * res;
        const Eigen::Vector3f d = p - o3;
        float tin = 0.0f;
        if (std::abs(d.x()) > 1e-9f) {
          const float ta = (x0 - o3.x()) / d.x(), tb = (x0 + res - o3.x()) / d.x();
          tin = std::max(tin, std::min(ta, tb));
        }
        if (std::abs(d.y()) > 1e-9f) {
          const float ta = (y0 - o3.y()) / d.y(), tb = (y0 + res - o3.y()) / d.y();
          tin = std::max(tin, std::min(ta, tb));
        }
        ze = o3.z() + std::min(tin, 1.0f) * d.z();
      }
      entries[fill[k]++] = Entry{p.z(), ze};
    }
  }
  cell.clear();
  cell.shrink_to_fit();

  // Pass 3: sort every cell and estimate the sensor noise: the median over cells of the
  // within-cell MAD, scaled to a standard deviation. Most cells hold one surface, so this is the
  // noise of a single surface; the cluster gap grows to 4 sigma so noise never splits a surface.
  std::vector<float> mads;
  for (size_t k = 0; k < ncell; ++k) {
    const size_t n = start[k + 1] - start[k];
    grid.count[k] = static_cast<uint32_t>(n);
    if (n == 0) continue;
    Entry* e = entries.data() + start[k];
    if (n < 24) {  // insertion sort: most cells hold a handful of points
      for (size_t i = 1; i < n; ++i) {
        const Entry v = e[i];
        size_t j = i;
        for (; j > 0 && e[j - 1].z > v.z; --j) e[j] = e[j - 1];
        e[j] = v;
      }
    } else {
      std::sort(e, e + n, [](const Entry& a, const Entry& b) { return a.z < b.z; });
    }
    if (n >= 5) {
      const float med = e[n / 2].z;
      float dev[16];
      const size_t m = std::min<size_t>(n, 16);  // a sample is enough for the median deviation
      for (size_t i = 0; i < m; ++i) dev[i] = std::abs(e[i * n / m].z - med);
      std::nth_element(dev, dev + m / 2, dev + m);
      mads.push_back(dev[m / 2]);
    }
  }
  if (!mads.empty()) {
    std::nth_element(mads.begin(), mads.begin() + mads.size() / 2, mads.end());
    grid.noise_sigma = 1.4826 * mads[mads.size() / 2];
  }
  HeightGridOptions eff = o;
  eff.cluster_gap = std::max(o.cluster_gap, 4.0 * grid.noise_sigma);
  grid.cluster_gap = eff.cluster_gap;
  // Pass 4: per-cell support surface.
  std::vector<uint8_t> candidate(ncell, 0);
  for (size_t k = 0; k < ncell; ++k) {
    const size_t n = start[k + 1] - start[k];
    if (n == 0) continue;
    candidate[k] = process_cell(entries.data() + start[k], n, eff, grid, k) ? 1 : 0;
    grid.observed_cells += grid.observed[k];
  }
  promote_sparse_surfaces(entries, start, candidate, eff, grid);
  close_narrow_pits(grid, o.bridge_cells, eff.cluster_gap);
  fill_holes(grid, o.min_cell_points);
  return grid;
}

HeightGrid build_height_grid(const std::vector<perception::PointCloud>& clouds,
                             const HeightGridOptions& options) {
  std::vector<PointBatch> batches;
  for (const auto& c : clouds)
    batches.push_back({c.points.data(), c.points.size(), c.sensor_origin});
  return build_height_grid(batches, options);
}

void fill_holes(HeightGrid& grid, int min_points) {
  const GridGeometry& g = grid.geometry;
  // Sampling gaps: a cell without any point whose eight neighbours all measured one surface
  // (spread within the cluster gap) lies on that surface; interpolate it and count it observed
  // (value 2). Bridged see-through cells had points and stay unobserved.
  const double gap = grid.cluster_gap > 0 ? grid.cluster_gap : 0.05;
  std::vector<size_t> gaps;
  for (int i = 1; i + 1 < g.nx; ++i)
    for (int j = 1; j + 1 < g.ny; ++j) {
      const size_t k = g.index(i, j);
      if (grid.observed[k] || grid.count[k] >= static_cast<uint32_t>(min_points)) continue;
      float lo = std::numeric_limits<float>::infinity(), hi = -lo;
      bool all = true;
      for (int di = -1; di <= 1 && all; ++di)
        for (int dj = -1; dj <= 1; ++dj) {
          if (!di && !dj) continue;
          const size_t n = g.index(i + di, j + dj);
          if (grid.observed[n] != 1) {
            all = false;
            break;
          }
          lo = std::min(lo, grid.elevation[n]);
          hi = std::max(hi, grid.elevation[n]);
        }
      if (all && hi - lo <= gap) gaps.push_back(k);
    }
  for (size_t k : gaps) {
    const int i = static_cast<int>(k / g.ny), j = static_cast<int>(k % g.ny);
    double sum = 0, var = 0;
    for (int di = -1; di <= 1; ++di)
      for (int dj = -1; dj <= 1; ++dj) {
        if (!di && !dj) continue;
        sum += grid.elevation[g.index(i + di, j + dj)];
        var += grid.variance[g.index(i + di, j + dj)];
      }
    grid.elevation[k] = grid.min[k] = grid.max[k] = static_cast<float>(sum / 8);
    grid.variance[k] = static_cast<float>(var / 8);
    grid.observed[k] = 2;
    ++grid.interpolated_cells;
  }
  std::vector<uint8_t> known(grid.observed);
  std::vector<size_t> frontier, next;
  auto has_known_neighbour = [&](int i, int j) {
    for (int di = -1; di <= 1; ++di)
      for (int dj = -1; dj <= 1; ++dj) {
        const int a = i + di, b = j + dj;
        if ((di || dj) && a >= 0 && b >= 0 && a < g.nx && b < g.ny && known[g.index(a, b)])
          return true;
      }
    return false;
  };
  for (int i = 0; i < g.nx; ++i)
    for (int j = 0; j < g.ny; ++j)
      if (!known[g.index(i, j)] && has_known_neighbour(i, j)) frontier.push_back(g.index(i, j));
  std::vector<uint8_t> queued(g.size(), 0);
  while (!frontier.empty()) {
    // Values of one ring come from the previous rings only, so the fill does not depend on order.
    std::vector<std::pair<size_t, float>> values;
    for (size_t k : frontier) {
      const int i = static_cast<int>(k / g.ny), j = static_cast<int>(k % g.ny);
      float best = -std::numeric_limits<float>::infinity();
      for (int di = -1; di <= 1; ++di)
        for (int dj = -1; dj <= 1; ++dj) {
          const int a = i + di, b = j + dj;
          if (a < 0 || b < 0 || a >= g.nx || b >= g.ny) continue;
          const size_t n = g.index(a, b);
          if (known[n]) best = std::max(best, grid.elevation[n]);
        }
      values.emplace_back(k, best);
    }
    next.clear();
    for (const auto& [k, v] : values) {
      grid.elevation[k] = grid.min[k] = grid.max[k] = v;
      grid.variance[k] = 0.0f;
      known[k] = 1;
      ++grid.filled_cells;
    }
    for (const auto& [k, v] : values) {
      const int i = static_cast<int>(k / g.ny), j = static_cast<int>(k % g.ny);
      for (int di = -1; di <= 1; ++di)
        for (int dj = -1; dj <= 1; ++dj) {
          const int a = i + di, b = j + dj;
          if (a < 0 || b < 0 || a >= g.nx || b >= g.ny) continue;
          const size_t n = g.index(a, b);
          if (!known[n] && !queued[n]) {
            queued[n] = 1;
            next.push_back(n);
          }
        }
    }
    frontier.swap(next);
  }
}

HeightGrid rasterize_scene(const Scene& scene, double resolution, std::optional<Eigen::Vector2d> lo,
                           std::optional<Eigen::Vector2d> hi) {
  validate_resolution(resolution);
  const Eigen::Vector2d a = lo.value_or(scene.min_corner());
  const Eigen::Vector2d b = hi.value_or(scene.max_corner());
  HeightGrid grid;
  // The scene's extent is exact, so the last partial cell is not needed.
  grid.geometry = make_geometry(a, b - Eigen::Vector2d::Constant(1e-9), resolution, 25'000'000);
  allocate(grid);
  const GridGeometry& g = grid.geometry;
  constexpr int kSub = 8;  // sub-samples per cell side: finds any step further than res/16 inside
  for (int i = 0; i < g.nx; ++i) {
    for (int j = 0; j < g.ny; ++j) {
      const size_t k = g.index(i, j);
      const Eigen::Vector2d c = g.center(i, j);
      float mn = std::numeric_limits<float>::infinity(), mx = -mn;
      for (int u = 0; u < kSub; ++u)
        for (int v = 0; v < kSub; ++v) {
          const double x = g.origin.x() + (i + (u + 0.5) / kSub) * resolution;
          const double y = g.origin.y() + (j + (v + 0.5) / kSub) * resolution;
          const float h = static_cast<float>(scene.height(x, y));
          mn = std::min(mn, h);
          mx = std::max(mx, h);
        }
      grid.elevation[k] = static_cast<float>(scene.height(c.x(), c.y()));
      grid.min[k] = mn;
      grid.max[k] = mx;
      grid.count[k] = grid.support[k] = 1;
      grid.observed[k] = 1;
    }
  }
  grid.observed_cells = g.size();
  return grid;
}

}  // namespace terrastride::terrain
