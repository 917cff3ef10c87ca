#include "terrastride/terrain/height_grid.hpp"

#include <Eigen/Cholesky>
#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

#include "terrastride/terrain/scenes.hpp"

namespace terrastride::terrain {
namespace {

using perception::InputError;

constexpr uint32_t kOutside = std::numeric_limits<uint32_t>::max();

// A cell with an overhang and no support surface beneath it (a ceiling over a floor never
// scanned): not ground, and no sampling gap of the ground around it either.
bool no_ground(const HeightGrid& grid, size_t k) {
  return !grid.overhead.empty() && grid.support[k] == 0 && std::isfinite(grid.overhead[k]);
}

struct Entry {
  float z;
  float z_entry;   // height at which the ray entered the cell's column; +inf when unknown
  float z_origin;  // height of the ray's origin (the sensor); +inf when unknown
};

std::string fmt(double v) {
  std::ostringstream os;
  os << v;
  return os.str();
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

// True when the cluster was seen only from beneath: most of its points were hit by rays rising
// into them from a sensor at least the overhang free height below the cluster, and the cluster is
// thin (a wall seen from a sensor below its top is hit by rising rays too, but spans its height).
bool hit_from_beneath(const Entry* e, const Range& c, const HeightGridOptions& o) {
  const float bottom = e[c.b].z;
  if (e[c.e - 1].z - bottom > 2.0 * o.cluster_gap) return false;
  size_t rising = 0, known = 0;
  for (size_t i = c.b; i < c.e; ++i) {
    if (!std::isfinite(e[i].z_origin)) continue;
    ++known;
    rising += e[i].z_entry < e[i].z && e[i].z_origin <= bottom - o.overhang_free_height;
  }
  return rising > 0 && rising > o.overhang_vote * known;
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
  // Step down past overhangs: surfaces the sensor saw beneath with the overhang free height or more
  // between them and the next lower surface. One seen only from beneath with no surface below is a
  // ceiling over ground the sensor did not see.
  bool overhang = false;
  for (;;) {
    const bool under_it = seen_beneath(e, clusters[s], o.overhang_vote);
    const bool from_beneath = !under_it && hit_from_beneath(e, clusters[s], o);
    if (!under_it && !from_beneath) break;
    int lower = -1;
    for (int c = s - 1; c >= 0; --c) {
      if (substantial(c)) {
        lower = c;
        break;
      }
    }
    if (lower < 0) {
      if (!from_beneath) break;
      grid.overhead[k] = e[clusters[s].b].z;  // no ground: the cell stays unobserved
      return false;
    }
    if (e[clusters[s].b].z - e[clusters[lower].e - 1].z < o.overhang_free_height) break;
    grid.overhead[k] = e[clusters[s].b].z;
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
  if (!overhang && clusters[s].b > 0) {
    ++grid.see_through_cells;
  }
  return !overhang && s + 1 < static_cast<int>(nc);
}

// A sparse cluster above the support is promoted when the surface it belongs to continues into a
// neighbouring cell: that cell's support lies at its height, or two neighbours hold a cluster of at
// least min_support_points points at its height too (a grating tread seen by few rays in every
// cell, the floor beneath it by many). Overhangs (seen beneath) are never promoted. A cell whose
// upper cluster of min_support_points or more is not promoted is uncertain: something was seen
// above the support and nothing says it is an overhang, so the lower surface is not ground a foot
// can reach (it would step onto or through the upper one). It becomes unobserved; a lone return
// above the support (a flying pixel) does not count.
void promote_sparse_surfaces(const std::vector<Entry>& entries, const std::vector<uint32_t>& start,
                             const std::vector<uint8_t>& candidate, const HeightGridOptions& o,
                             HeightGrid& grid, std::vector<uint8_t>& sample) {
  const GridGeometry& g = grid.geometry;
  const std::vector<float> elevation = grid.elevation;  // decisions use first-pass values only
  const std::vector<uint8_t> observed = grid.observed;
  const size_t min_upper = static_cast<size_t>(std::max(o.min_support_points, 2));
  Range clusters[kMaxClusters];
  // First pass: the medians of every candidate's upper clusters that are substantial enough to be
  // a surface (min_upper points) and not an overhang, as compressed rows per cell.
  std::vector<uint32_t> upper_start(g.size() + 1, 0);
  std::vector<float> upper;
  for (size_t k = 0; k < g.size(); ++k) {
    upper_start[k] = static_cast<uint32_t>(upper.size());
    if (!candidate[k]) continue;
    const Entry* e = entries.data() + start[k];
    const size_t n = start[k + 1] - start[k];
    const size_t nc = find_clusters(e, n, o.cluster_gap, clusters, kMaxClusters);
    for (size_t c = 0; c < nc; ++c) {
      const Range& r = clusters[c];
      const float median = e[r.b + r.size() / 2].z;
      if (median <= elevation[k] + o.cluster_gap || r.size() < min_upper) continue;
      if (seen_beneath(e, r, o.overhang_vote)) continue;
      upper.push_back(median);
    }
  }
  upper_start[g.size()] = static_cast<uint32_t>(upper.size());
  const float half_gap = static_cast<float>(0.5 * o.cluster_gap);
  for (int i = 0; i < g.nx; ++i) {
    for (int j = 0; j < g.ny; ++j) {
      const size_t k = g.index(i, j);
      if (!candidate[k]) continue;
      const Entry* e = entries.data() + start[k];
      const size_t n = start[k + 1] - start[k];
      const size_t nc = find_clusters(e, n, o.cluster_gap, clusters, kMaxClusters);
      bool promoted = false;
      for (int c = static_cast<int>(nc) - 1; c >= 0 && !promoted; --c) {
        const Range& r = clusters[c];
        const float median = e[r.b + r.size() / 2].z;
        if (median <= elevation[k] + o.cluster_gap) break;  // reached the current support
        bool matched = false;
        int upper_matches = 0;
        for (int di = -1; di <= 1 && !matched; ++di)
          for (int dj = -1; dj <= 1 && !matched; ++dj) {
            const int a = i + di, b = j + dj;
            if ((!di && !dj) || a < 0 || b < 0 || a >= g.nx || b >= g.ny) continue;
            const size_t nb = g.index(a, b);
            matched = observed[nb] && std::abs(elevation[nb] - median) <= half_gap;
            for (uint32_t u = upper_start[nb]; u < upper_start[nb + 1]; ++u)
              if (std::abs(upper[u] - median) <= half_gap) {
                ++upper_matches;
                break;
              }
          }
        matched |= upper_matches >= 2 && r.size() >= min_upper;
        if (matched && !seen_beneath(e, r, o.overhang_vote)) {
          write_stats(e, r, grid, k);
          sample[k] = 1;
          ++grid.see_through_cells;
          promoted = true;
        }
      }
      if (!promoted && upper_start[k + 1] > upper_start[k]) {
        grid.observed[k] = 0;
        sample[k] = 0;
        ++grid.uncertain_cells;
      }
    }
  }
}

// Narrow pits (at most 2 K cells wide) more than cluster_gap deep are openings of a surface seen
// through (grating holes, gaps between deck boards): a grey-level closing (max then min filter over
// a (2K+1)^2 window) bridges them. Those cells did not observe the surface, so they become
// unobserved (hence unsafe) and take the bridged height, which the hole filling keeps and grows
// from (the returned flags). Steps and wide trenches
// are untouched: a closing only removes valleys narrower than its window. Two closings: one
// ignoring unobserved cells (a pit with the surface seen around it), then one taking unobserved
// cells and cells beyond the grid as high, since what was not seen may be the surface continuing
// (a grating's opening between a tread and the edge of the data).
std::vector<uint8_t> close_narrow_pits(HeightGrid& grid, int K, double depth) {
  std::vector<uint8_t> bridged(grid.geometry.size(), 0);
  if (K <= 0) return bridged;
  const GridGeometry& g = grid.geometry;
  constexpr float inf = std::numeric_limits<float>::infinity();
  std::vector<float> tmp(g.size());
  // Separable running max / min; `outside` is the value of cells beyond the grid in the max.
  auto filter = [&](std::vector<float>& src, bool take_max, float outside) {
    for (int i = 0; i < g.nx; ++i)
      for (int j = 0; j < g.ny; ++j) {
        float v = take_max ? (j - K < 0 || j + K >= g.ny ? outside : -inf) : inf;
        for (int d = std::max(0, j - K); d <= std::min(g.ny - 1, j + K); ++d)
          v = take_max ? std::max(v, src[g.index(i, d)]) : std::min(v, src[g.index(i, d)]);
        tmp[g.index(i, j)] = v;
      }
    for (int i = 0; i < g.nx; ++i)
      for (int j = 0; j < g.ny; ++j) {
        float v = take_max ? (i - K < 0 || i + K >= g.nx ? outside : -inf) : inf;
        for (int d = std::max(0, i - K); d <= std::min(g.nx - 1, i + K); ++d)
          v = take_max ? std::max(v, tmp[g.index(d, j)]) : std::min(v, tmp[g.index(d, j)]);
        src[g.index(i, j)] = v;
      }
  };
  auto closing = [&](float unobserved) {
    std::vector<float> a(g.size());
    for (size_t k = 0; k < g.size(); ++k) a[k] = grid.observed[k] ? grid.elevation[k] : unobserved;
    filter(a, true, unobserved);
    filter(a, false, unobserved);
    return a;
  };
  // A bridged cell takes the height of the lowest surface seen (or bridged) above it within 2 K
  // cells (the tread around the opening, not a bracket sticking up from it), at most the
  // closing's.
  const auto lowest_above = [&](const std::vector<float>& height, const std::vector<uint8_t>& seen,
                                int i, int j) {
    const float z = height[g.index(i, j)];
    float lowest = inf;
    for (int u = std::max(0, i - 2 * K); u <= std::min(g.nx - 1, i + 2 * K); ++u)
      for (int v = std::max(0, j - 2 * K); v <= std::min(g.ny - 1, j + 2 * K); ++v) {
        const size_t n = g.index(u, v);
        if ((seen[n] || bridged[n]) && height[n] - z > depth) lowest = std::min(lowest, height[n]);
      }
    return lowest;
  };
  // Decisions and heights of each pass come from the heights and observations before it.
  auto bridge_pass = [&](const std::vector<float>& closed, const std::vector<float>* above,
                         double min_depth) {
    const std::vector<float> height = grid.elevation;
    const std::vector<uint8_t> seen = grid.observed;
    for (int i = 0; i < g.nx; ++i)
      for (int j = 0; j < g.ny; ++j) {
        const size_t k = g.index(i, j);
        const float z = height[k];
        if (!seen[k] || !(closed[k] - z > min_depth)) continue;
        if (above && !((*above)[k] - z > min_depth)) continue;
        if (seen[k] == 2) {
          --grid.interpolated_cells;
        } else {
          --grid.observed_cells;
        }
        grid.observed[k] = 0;
        grid.elevation[k] = grid.min[k] = grid.max[k] =
            std::min(closed[k], lowest_above(height, seen, i, j));
        grid.variance[k] = 0.0f;
        bridged[k] = 1;
        ++grid.bridged_cells;
      }
  };
  std::vector<float> seen_closing = closing(-inf);
  for (auto& c : seen_closing)
    if (!std::isfinite(c)) c = -inf;  // no surface seen around: not a pit
  bridge_pass(seen_closing, nullptr, depth);
  // The second closing runs after the first has bridged its pits, which then count as unseen (a
  // grating's open riser bridged first leaves the patch of floor beside it enclosed). A pit there
  // also needs a surface seen above it within 2 K cells (a max filter applied twice), so a patch
  // among unseen cells alone, as a sparse cloud leaves them, is not one.
  const std::vector<float> unseen_high = closing(inf);
  std::vector<float> above(g.size());
  for (size_t k = 0; k < g.size(); ++k) above[k] = grid.observed[k] ? grid.elevation[k] : -inf;
  filter(above, true, -inf);
  filter(above, true, -inf);
  // Guessing that unseen space holds the surface is only safe for clearly deeper pits: three
  // cluster gaps (15 cm by default; the floor under the grated stairs lies 45 cm below the treads,
  // while a bracket standing 9 cm on a tread must not make the tread beside it a pit).
  bridge_pass(unseen_high, &above, 3.0 * depth);
  return bridged;
}

// ---- Sensor noise and point spacing ----------------------------------------------------------
// Bins of a few cells: enough points for a plane fit (the median occupied bin holds at least
// kBinPoints), no larger than kMaxBinSize (or two cells). The per-bin sample is capped at
// kBinSample points (every m-th of each cell's sorted heights): the MAD of 48 points is within
// about 15 % of sigma, and the median over hundreds of bins removes most of that.
constexpr size_t kBinPoints = 12;
constexpr double kMaxBinSize = 0.32;
constexpr size_t kBinSample = 48;
constexpr size_t kMaxNoiseBins = 3000;   // bins visited at most (evenly spread over the grid)
constexpr size_t kMinClusterPoints = 6;  // a bin's surface needs this many points for a figure
constexpr size_t kMinNoiseBins = 10;     // and the grid this many such bins
constexpr double kMaxGroundSlope = 1.0;  // steeper bin surfaces (walls) are not read as noise
// Nor are bins whose surface spreads more than this about its plane: no range sensor a legged robot
// steps by is that noisy, but a wall seen within one column of cells is (a 1 m wall spreads by
// about 0.3 m), and its plane fit cannot tell, having no horizontal extent across the wall.
constexpr double kMaxNoise = 0.1;
constexpr double kMaxGapRadius = 0.1;  // sampling gaps are never bridged beyond 10 cm

struct BinPoint {
  float z, u, v;
};

size_t median_of(std::vector<size_t> v) {
  if (v.empty()) return 0;
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

double median_of(std::vector<double> v) {
  if (v.empty()) return 0.0;
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

std::string metres(double v, int precision) {
  std::ostringstream os;
  os.setf(std::ios::fixed);
  os.precision(precision);
  os << v;
  return os.str();
}

// One pass over the bins with a given cluster gap: per bin, the largest cluster of the sampled
// heights, a least-squares plane z = a + b u + c v over it (u, v: cell centres in the bin, m) and
// the MAD of the residuals, scaled to a standard deviation (and for the three fitted parameters).
struct BinFigures {
  std::vector<double> sigma;    // accepted bins
  std::vector<double> spacing;  // accepted bins: bin side / sqrt(points of the surface)
  size_t rejected = 0;
};

BinFigures bin_noise(const std::vector<Entry>& entries, const std::vector<uint32_t>& start,
                     const GridGeometry& g, int k, double gap) {
  BinFigures f;
  std::vector<BinPoint> pts;
  std::vector<double> res;
  const double bin = k * g.resolution;
  const int bx = (g.nx + k - 1) / k, by = (g.ny + k - 1) / k;
  // A median over a few thousand bins is as good as over all: large grids use every m-th bin
  // (the 1 M-point benchmark's 7500 bins took 29 ms, a third of the grid's time).
  const size_t every = std::max<size_t>(1, static_cast<size_t>(bx) * by / kMaxNoiseBins);
  size_t visited = 0;
  for (int a = 0; a < bx; ++a)
    for (int b = 0; b < by; ++b) {
      if (visited++ % every) continue;
      const int i0 = a * k, j0 = b * k, i1 = std::min(g.nx, i0 + k), j1 = std::min(g.ny, j0 + k);
      size_t total = 0;
      for (int i = i0; i < i1; ++i)
        for (int j = j0; j < j1; ++j) {
          const size_t c = g.index(i, j);
          total += start[c + 1] - start[c];
        }
      if (total < kMinClusterPoints) continue;
      const size_t stride = (total + kBinSample - 1) / kBinSample;
      pts.clear();
      for (int i = i0; i < i1; ++i)
        for (int j = j0; j < j1; ++j) {
          const size_t c = g.index(i, j);
          const float u = static_cast<float>((i - i0 - 0.5 * (k - 1)) * g.resolution);
          const float v = static_cast<float>((j - j0 - 0.5 * (k - 1)) * g.resolution);
          for (uint32_t p = start[c] + static_cast<uint32_t>(stride / 2); p < start[c + 1];
               p += static_cast<uint32_t>(stride))
            pts.push_back({entries[p].z, u, v});
        }
      std::sort(pts.begin(), pts.end(),
                [](const BinPoint& x, const BinPoint& y) { return x.z < y.z; });
      // Largest cluster (the higher one on ties).
      size_t best_b = 0, best_e = 0, begin = 0;
      for (size_t p = 1; p <= pts.size(); ++p)
        if (p == pts.size() || pts[p].z - pts[p - 1].z > gap) {
          if (p - begin >= best_e - best_b) {
            best_b = begin;
            best_e = p;
          }
          begin = p;
        }
      const size_t n = best_e - best_b;
      if (n < kMinClusterPoints) continue;
      // Normal equations; a tiny ridge keeps a direction without spread (all points in one cell
      // row) solvable, with zero slope along it.
      Eigen::Matrix3d A = Eigen::Matrix3d::Zero();
      Eigen::Vector3d rhs = Eigen::Vector3d::Zero();
      for (size_t p = best_b; p < best_e; ++p) {
        const Eigen::Vector3d x(1.0, pts[p].u, pts[p].v);
        A += x * x.transpose();
        rhs += x * double(pts[p].z);
      }
      A(1, 1) += 1e-9 * n * bin * bin;
      A(2, 2) += 1e-9 * n * bin * bin;
      const Eigen::LDLT<Eigen::Matrix3d> ldlt(A);
      const Eigen::Vector3d coef = ldlt.solve(rhs);
      if (!coef.allFinite()) continue;
      res.clear();
      for (size_t p = best_b; p < best_e; ++p)
        res.push_back(pts[p].z - (coef(0) + coef(1) * pts[p].u + coef(2) * pts[p].v));
      const double med = median_of(res);
      for (auto& r : res) r = std::abs(r - med);
      const double sigma = 1.4826 * median_of(res) * std::sqrt(double(n) / (n - 3.0));
      // Steep beyond what the noise explains (three standard errors of the fitted slope, from the
      // inverse normal matrix): a wall or another vertical surface, not ground with noise. On a
      // 4 cm bin of the real noisy floor (sigma 2.6 cm) the slope's standard error is about 0.5.
      const double slope = std::hypot(coef(1), coef(2));
      bool steep = false;
      if (slope > kMaxGroundSlope) {
        const Eigen::Matrix3d cov = ldlt.solve(Eigen::Matrix3d::Identity());
        steep =
            slope - 3.0 * sigma * std::sqrt(std::max(0.0, cov(1, 1) + cov(2, 2))) > kMaxGroundSlope;
      }
      if (steep || sigma > kMaxNoise) {
        ++f.rejected;
        continue;
      }
      f.sigma.push_back(sigma);
      f.spacing.push_back(bin / std::sqrt(double(n) * stride));
    }
  return f;
}

NoiseEstimate estimate_noise(const std::vector<Entry>& entries, const std::vector<uint32_t>& start,
                             const GridGeometry& g, double base_gap) {
  NoiseEstimate est;
  // Bin size: the median occupied bin must hold kBinPoints (a 2 cm cell of a 4 cm spaced cloud
  // holds one point or none).
  const double max_bin = std::max(2.0 * g.resolution, kMaxBinSize);
  int k = 2;
  size_t median_count = 0;
  for (;;) {
    std::vector<size_t> counts;
    const int bx = (g.nx + k - 1) / k, by = (g.ny + k - 1) / k;
    std::vector<size_t> per_bin(static_cast<size_t>(bx) * by, 0);
    for (int i = 0; i < g.nx; ++i)
      for (int j = 0; j < g.ny; ++j) {
        const size_t c = g.index(i, j);
        per_bin[static_cast<size_t>(i / k) * by + j / k] += start[c + 1] - start[c];
      }
    for (size_t n : per_bin)
      if (n) counts.push_back(n);
    median_count = median_of(counts);
    if (median_count >= kBinPoints || 2 * k * g.resolution > max_bin + 1e-9) break;
    k *= 2;
  }
  est.bin_size = k * g.resolution;
  // The largest cluster must not split a noisy surface: the gap starts at the option and grows to
  // 4 sigma of the figure it gives (the same rule as the grid's cluster gap), at most 3 rounds.
  double gap = base_gap;
  BinFigures f;
  for (int round = 0; round < 3; ++round) {
    f = bin_noise(entries, start, g, k, gap);
    const double sigma = f.sigma.size() >= kMinNoiseBins ? median_of(f.sigma) : 0.0;
    if (!(4.0 * sigma > 1.05 * gap)) break;
    gap = 4.0 * sigma;
  }
  est.bins = f.sigma.size();
  est.rejected_bins = f.rejected;
  if (!f.spacing.empty()) {
    est.point_spacing = median_of(f.spacing);
  } else if (median_count > 0) {
    est.point_spacing = est.bin_size / std::sqrt(double(median_count));
  }
  if (f.sigma.size() >= kMinNoiseBins) {
    est.estimated = true;
    est.sigma = median_of(f.sigma);
    return est;
  }
  std::ostringstream note;
  note << "sensor noise not estimated: " << f.sigma.size() << " bins of " << metres(est.bin_size, 2)
       << " m hold " << kMinClusterPoints << " or more points of one ground-like surface ("
       << kMinNoiseBins << " needed)";
  if (f.rejected > 0)
    note << "; " << f.rejected
         << " more hold steep or vertical surfaces (walls), not read as noise";
  if (median_count < kBinPoints)
    note << "; the cloud is sparse (a median of " << median_count
         << (median_count == 1 ? " point" : " points") << " per occupied "
         << metres(est.bin_size, 2) << " m bin)";
  note << ". The safety tests get no noise allowance and the surface is smoothed at the foot scale "
          "only.";
  est.note = note.str();
  return est;
}

// The Gaussian length of the smoothed surface (HeightGridOptions). For a Gaussian-weighted mean of
// points of density rho = 1 / spacing^2 with noise s_p each, each slope component has standard
// deviation s_p / (L^2 sqrt(8 pi rho)) (the gradient of the weights, summed in quadrature); cell
// medians of n points average like n points of sigma sqrt(pi / 2). |grad| of a flat noisy surface
// then has a Rayleigh distribution whose 95th percentile is 2.448 times that deviation.
double smoothing_length(const NoiseEstimate& noise, const HeightGridOptions& o) {
  double length = 0.5 * std::max(0.0, o.foot_radius);
  if (noise.estimated && noise.sigma > 0 && noise.point_spacing > 0 && o.noise_slope_p95 > 0) {
    const double per_component = o.noise_slope_p95 / 2.448;
    const double point_sigma = 1.2533 * noise.sigma;
    const double l2 =
        point_sigma * noise.point_spacing / (per_component * std::sqrt(8.0 * 3.14159265358979));
    length = std::max(length, std::sqrt(l2));
  }
  return std::min(length, std::max(0.0, o.max_smoothing_length));
}

// The input's own overhangs (an OctoMap's runs with free space beneath): per cell, the lowest
// underside above the support's top, or over a cell without support, is its overhead.
void add_input_overhangs(const std::vector<PointBatch>& batches, HeightGrid& grid) {
  const GridGeometry& g = grid.geometry;
  const double inv = 1.0 / g.resolution;
  for (const auto& b : batches)
    for (size_t i = 0; i < b.overhang_count; ++i) {
      const Eigen::Vector3f& p = b.overhangs[i];
      const double fx = (p.x() - g.origin.x()) * inv, fy = (p.y() - g.origin.y()) * inv;
      if (!(fx >= 0 && fy >= 0 && fx < g.nx && fy < g.ny && std::isfinite(p.z()))) continue;
      const size_t k = g.index(static_cast<int>(fx), static_cast<int>(fy));
      if (grid.support[k] > 0 && !(p.z() > grid.max[k])) continue;  // below the surface
      grid.overhead[k] = std::min(grid.overhead[k], p.z());
    }
}

// An overhang is an underside with room beneath it: at least `free_height` above the ground under
// it. Where its own cell has no ground (an OctoMap column whose lowest run had free voxels beneath
// it, a thin cluster seen from beneath), that ground is the lowest observed ground within
// kOverheadRoomCells: the planner's overhead field takes the lowest underside within that many
// cells (TerrainMap's overhead field), so each underside is judged against every ground it reaches.
// An underside lower than that is the foot of a wall whose free voxels lie under the floor (rays
// through a glass or unscanned floor; geb079's corridor walls reach 0.12 m below it): no robot
// passes under it, so it is no overhead; its cell stays what it was (unobserved without ground).
constexpr int kOverheadRoomCells = 2;
void drop_overhangs_without_room(HeightGrid& grid, double free_height) {
  const GridGeometry& g = grid.geometry;
  std::vector<uint32_t> dropped;
  for (int i = 0; i < g.nx; ++i)
    for (int j = 0; j < g.ny; ++j) {
      const size_t k = g.index(i, j);
      if (!std::isfinite(grid.overhead[k])) continue;
      float ground = std::numeric_limits<float>::infinity();
      for (int a = std::max(0, i - kOverheadRoomCells);
           a <= std::min(g.nx - 1, i + kOverheadRoomCells); ++a)
        for (int b = std::max(0, j - kOverheadRoomCells);
             b <= std::min(g.ny - 1, j + kOverheadRoomCells); ++b) {
          const size_t n = g.index(a, b);
          if (grid.observed[n] == 1) ground = std::min(ground, grid.elevation[n]);
        }
      if (std::isfinite(ground) && grid.overhead[k] < ground + free_height)
        dropped.push_back(static_cast<uint32_t>(k));
    }
  // Judged against the ground as observed, before any underside is dropped.
  for (const uint32_t k : dropped) grid.overhead[k] = std::numeric_limits<float>::infinity();
}

void add_notes(HeightGrid& grid, double input_voxel) {
  const double res = grid.geometry.resolution;
  if (!grid.noise.estimated) grid.notes.push_back(grid.noise.note);
  if (input_voxel > 0) {
    // An OctoMap's points are its voxels' tops, one per voxel column: a grid at the voxel size or
    // coarser measures every cell the map saw, and only a finer one interpolates.
    if (res < 0.75 * input_voxel) {
      std::ostringstream n;
      n << "grid finer than its OctoMap: one point per " << input_voxel << " m voxel, "
        << metres(res * res / (input_voxel * input_voxel), 2) << " per " << res
        << " m cell; cells without a voxel of their own are interpolated between voxels up to "
        << metres(100 * grid.gap_radius, 1) << " cm away (observed = 2); --resolution "
        << input_voxel << " (the OctoMap's) or coarser measures every cell";
      grid.notes.push_back(n.str());
    }
    return;
  }
  const double spacing = grid.noise.point_spacing;
  if (spacing > 0.75 * res) {
    std::ostringstream n;
    n << "sparse cloud: its points are about " << metres(100 * spacing, 1) << " cm apart, "
      << metres(res * res / (spacing * spacing), 2) << " per " << res
      << " m cell; cells without points of their own are interpolated between points up to "
      << metres(100 * grid.gap_radius, 1) << " cm away (observed = 2); --resolution "
      << metres(std::ceil(2.0 * spacing * 100) / 100, 2) << " or coarser measures every cell";
    grid.notes.push_back(n.str());
  }
}

// The xy bounding box of the finite points and of the overhangs; throws when no point is finite.
void points_extent(const std::vector<PointBatch>& batches, Eigen::Vector2d* lo_out,
                   Eigen::Vector2d* hi_out) {
  Eigen::Vector2d& lo = *lo_out;
  Eigen::Vector2d& hi = *hi_out;
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
    // Overhangs widen the extent: a ceiling over a floor never scanned still has cells, which
    // say that no walkable ground is known there.
    for (size_t i = 0; i < b.overhang_count; ++i) {
      const Eigen::Vector3f& p = b.overhangs[i];
      if (!p.allFinite()) continue;
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

void validate_grid_options(const HeightGridOptions& o) {
  validate_resolution(o.resolution);
  if (!(o.cluster_gap > 0) || !(o.min_support_fraction >= 0 && o.min_support_fraction <= 1))
    throw InputError("height grid: cluster_gap must be > 0 and min_support_fraction in [0, 1]");
  if (!(o.overhang_free_height > 0) || !std::isfinite(o.overhang_free_height))
    throw InputError("height grid: the overhang free height must be a positive number of metres");
}

// The grid's xy extent: the options' corners when given, else the points'.
void grid_extent(const std::vector<PointBatch>& batches, const HeightGridOptions& o,
                 Eigen::Vector2d* lo, Eigen::Vector2d* hi) {
  if (o.lo && o.hi) {
    *lo = *o.lo;
    *hi = *o.hi;
    if (!(hi->x() > lo->x() && hi->y() > lo->y()) || !lo->allFinite() || !hi->allFinite())
      throw InputError("height grid: the extent's max corner must exceed its min corner");
  } else {
    points_extent(batches, lo, hi);
  }
}

// Pass 1: cell of every point (counting sort keeps this cache friendly and allocation free). The
// points' cells (kOutside for those outside the grid) in batch order; `start` gets each cell's
// first entry (its last element: the points in the grid).
std::vector<uint32_t> bin_points(const std::vector<PointBatch>& batches, const GridGeometry& g,
                                 size_t total, std::vector<uint32_t>* start_out) {
  const size_t ncell = g.size();
  std::vector<uint32_t> cell(total);
  std::vector<uint32_t>& start = *start_out;
  start.assign(ncell + 1, 0);
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
  return cell;
}

// Pass 2: scatter heights (and ray entry heights when the origin is known) into cell order.
std::vector<Entry> scatter_entries(const std::vector<PointBatch>& batches, const GridGeometry& g,
                                   const std::vector<uint32_t>& cell,
                                   const std::vector<uint32_t>& start) {
  std::vector<Entry> entries(start.back());
  std::vector<uint32_t> fill(start.begin(), start.end() - 1);
  size_t t = 0;
  const float ox = static_cast<float>(g.origin.x()), oy = static_cast<float>(g.origin.y());
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
      entries[fill[k]++] = Entry{p.z(), ze, has_origin ? o3.z() : ze};
    }
  }
  return entries;
}

// Pass 3: sort every cell's entries by height; each cell's point count into the grid.
void sort_cells(std::vector<Entry>& entries, const std::vector<uint32_t>& start,
                HeightGrid& grid) {
  const size_t ncell = start.size() - 1;
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
  }
}

// Pass 4: per-cell support surface, then the surface made whole: sparse surfaces, the input's
// overhangs, sampling gaps, narrow pits, holes, smoothing; `eff` is the options with the
// noise-widened cluster gap.
void build_surface(const std::vector<PointBatch>& batches, const std::vector<Entry>& entries,
                   const std::vector<uint32_t>& start, const HeightGridOptions& o,
                   const HeightGridOptions& eff, HeightGrid& grid) {
  const GridGeometry& g = grid.geometry;
  const size_t ncell = g.size();
  std::vector<uint8_t> candidate(ncell, 0);
  for (size_t k = 0; k < ncell; ++k) {
    const size_t n = start[k + 1] - start[k];
    if (n == 0) continue;
    candidate[k] = process_cell(entries.data() + start[k], n, eff, grid, k) ? 1 : 0;
  }
  // Surface samples: every cell with a support cluster, unless it turns out to be uncertain (a
  // lower surface under an upper one) or a bridged pit.
  std::vector<uint8_t> sample(ncell, 0);
  for (size_t k = 0; k < ncell; ++k) sample[k] = grid.support[k] > 0;
  promote_sparse_surfaces(entries, start, candidate, eff, grid, sample);
  add_input_overhangs(batches, grid);
  drop_overhangs_without_room(grid, o.overhang_free_height);
  for (size_t k = 0; k < ncell; ++k) grid.observed_cells += grid.observed[k] == 1;
  // Sampling gaps at the scale of the point spacing (1.5 cells for dense clouds, as before), then
  // the see-through openings: in that order, a sparse cloud's surface is whole before the pits
  // are looked for (the other way round, the maze's floor within 8 cm of its walls, islands of
  // single points among unseen cells, read as pits of the wall tops: 470 cells).
  const double spacing = grid.noise.point_spacing;
  grid.gap_radius = std::max(1.5 * g.resolution, std::min(2.5 * spacing, kMaxGapRadius));
  fill_sampling_gaps(grid, sample, grid.gap_radius);
  const std::vector<uint8_t> bridged = close_narrow_pits(grid, o.bridge_cells, eff.cluster_gap);
  fill_holes_around(grid, o.min_cell_points, bridged);
  grid.smoothing_length = smoothing_length(grid.noise, o);
  smooth_surface(grid, grid.smoothing_length);
}

}  // namespace

HeightGrid build_height_grid(const std::vector<PointBatch>& batches, const HeightGridOptions& o) {
  validate_grid_options(o);
  HeightGrid grid;
  size_t total = 0;
  for (const auto& b : batches) total += b.size;
  grid.points_in = total;

  Eigen::Vector2d lo, hi;
  grid_extent(batches, o, &lo, &hi);
  grid.geometry = make_geometry(lo, hi, o.resolution, o.max_cells);
  allocate(grid);
  grid.overhead.assign(grid.geometry.size(), std::numeric_limits<float>::infinity());
  const GridGeometry& g = grid.geometry;

  std::vector<uint32_t> start;
  std::vector<uint32_t> cell = bin_points(batches, g, total, &start);
  grid.points_in_grid = start.back();
  if (grid.points_in_grid == 0) throw InputError("no finite points inside the height grid extent");
  std::vector<Entry> entries = scatter_entries(batches, g, cell, start);
  cell.clear();
  cell.shrink_to_fit();

  sort_cells(entries, start, grid);
  // The sensor noise (and the point spacing) from the sorted cells.
  grid.noise = estimate_noise(entries, start, g, o.cluster_gap);
  grid.noise_sigma = grid.noise.sigma;
  HeightGridOptions eff = o;
  // The gap grows to 4 sigma so noise never splits a surface.
  eff.cluster_gap = std::max(o.cluster_gap, 4.0 * grid.noise_sigma);
  grid.cluster_gap = eff.cluster_gap;
  build_surface(batches, entries, start, o, eff, grid);
  count_overhangs(grid);
  if (grid.overhang_cells == 0) grid.overhead.clear();
  add_notes(grid, o.input_voxel);
  return grid;
}

HeightGrid build_height_grid(const std::vector<perception::PointCloud>& clouds,
                             const HeightGridOptions& options) {
  std::vector<PointBatch> batches;
  for (const auto& c : clouds)
    batches.push_back({c.points.data(), c.points.size(), c.sensor_origin, c.overhangs.data(),
                       c.overhangs.size()});
  return build_height_grid(batches, options);
}

void validate_resolution(double res) {
  if (!std::isfinite(res) || res < 0.002 || res > 1.0)
    throw InputError("resolution " + fmt(res) +
                     " m is outside the accepted range [0.002, 1] m for a height grid");
}

void count_overhangs(HeightGrid& grid) {
  grid.overhang_cells = grid.overhang_unobserved_cells = 0;
  if (grid.overhead.size() != grid.geometry.size()) return;
  for (size_t k = 0; k < grid.overhead.size(); ++k) {
    if (!std::isfinite(grid.overhead[k])) continue;
    ++grid.overhang_cells;
    grid.overhang_unobserved_cells += grid.observed[k] == 0;
  }
}

void fill_sampling_gaps(HeightGrid& grid, const std::vector<uint8_t>& sample, double radius) {
  const GridGeometry& g = grid.geometry;
  const double gap = grid.cluster_gap > 0 ? grid.cluster_gap : 0.05;
  const double reach = radius / g.resolution;
  const int R = static_cast<int>(std::floor(reach + 1e-9));
  if (R < 1 || sample.size() != g.size()) return;
  struct Tap {
    int di, dj;
    uint8_t sector_bit;
  };
  std::vector<Tap> taps;
  for (int di = -R; di <= R; ++di)
    for (int dj = -R; dj <= R; ++dj) {
      if ((!di && !dj) || di * di + dj * dj > reach * reach + 1e-9) continue;
      // One cell: eight sectors centred on the neighbour directions, so all eight neighbours are
      // needed (the rule fill_holes applies). Wider disks: four quadrants, as a sparse cloud's
      // points are scattered (in a disk of 2.5 spacings a quadrant holds 4.9 points on average,
      // and is empty in under 1 % of cases).
      const double angle = std::atan2(double(dj), double(di));
      const int sector = R == 1 ? (static_cast<int>(std::lround(angle / (M_PI / 4))) + 8) % 8
                                : (static_cast<int>(std::floor(angle / (M_PI / 2))) + 4) % 4;
      taps.push_back({di, dj, static_cast<uint8_t>(1u << sector)});
    }
  const auto is_source = [&](size_t k) { return sample[k] != 0; };
  struct Fill {
    size_t k;
    float z, var;
  };
  std::vector<Fill> fills;
  for (int i = 0; i < g.nx; ++i)
    for (int j = 0; j < g.ny; ++j) {
      const size_t k = g.index(i, j);
      // Candidates: no points, or no cluster of min_cell_points (lone returns, kept as its sample);
      // cells whose points were judged not to be ground (uncertain, bridged) stay holes.
      if (grid.observed[k] || (grid.count[k] > 0 && !sample[k]) || no_ground(grid, k)) continue;
      float lo = std::numeric_limits<float>::infinity(), hi = -lo;
      if (sample[k]) lo = hi = grid.elevation[k];
      unsigned sectors = 0;
      double sum = 0, weight = 0, var = 0;
      for (const Tap& t : taps) {
        const int a = i + t.di, b = j + t.dj;
        if (a < 0 || b < 0 || a >= g.nx || b >= g.ny) continue;
        const size_t n = g.index(a, b);
        if (!is_source(n)) continue;
        sectors |= t.sector_bit;
        lo = std::min(lo, grid.elevation[n]);
        hi = std::max(hi, grid.elevation[n]);
        const double w = std::max<uint32_t>(grid.support[n], 1);
        sum += w * grid.elevation[n];
        var += w * grid.variance[n];
        weight += w;
      }
      if (sectors == (R == 1 ? 0xffu : 0x0fu) && hi - lo <= gap)
        fills.push_back({k, static_cast<float>(sum / weight), static_cast<float>(var / weight)});
    }
  for (const Fill& f : fills) {
    grid.elevation[f.k] = grid.min[f.k] = grid.max[f.k] = f.z;
    grid.variance[f.k] = f.var;
    grid.observed[f.k] = 2;
    ++grid.interpolated_cells;
  }
}

void smooth_surface(HeightGrid& grid, double length) {
  const GridGeometry& g = grid.geometry;
  grid.surface = grid.elevation;
  const double reach = 2.5 * length / g.resolution;  // the Gaussian is cut at 2.5 sigma
  const int R = static_cast<int>(std::floor(reach + 1e-9));
  if (!(length > 0) || R < 1) return;
  // Long kernels on fine grids are sampled (every step-th cell, each standing for step^2 cells),
  // so the cost stays within 17 x 17 taps a cell.
  const int step = (R + 7) / 8;
  struct Tap {
    int di, dj;
    double w;
  };
  std::vector<Tap> taps;
  const double inv2l2 = g.resolution * g.resolution / (2.0 * length * length);
  for (int di = -R / step * step; di <= R; di += step)
    for (int dj = -R / step * step; dj <= R; dj += step) {
      const double d2 = double(di) * di + double(dj) * dj;
      if (d2 > reach * reach + 1e-9) continue;
      taps.push_back({di, dj, std::exp(-d2 * inv2l2) * step * step});
    }
  // Per cell: its weight as a source (measured: its support; interpolated: one point's worth) and
  // the variance of its height, (pi / 2) sigma^2 / weight for a median.
  const double point_var = 1.5708 * grid.noise_sigma * grid.noise_sigma;
  constexpr double kFloor2 = 1e-6;  // (1 mm)^2: heights closer than this are always one surface
  std::vector<float> weight(g.size(), 0.0f), var(g.size());
  for (size_t k = 0; k < g.size(); ++k) {
    if (grid.observed[k] == 1)
      weight[k] = static_cast<float>(std::max<uint32_t>(grid.support[k], 1));
    if (grid.observed[k] == 2) weight[k] = 1.0f;
    var[k] = static_cast<float>(point_var / std::max(1.0f, weight[k]));
  }
  // The support-weighted median of the observed cells in each cell's 3 x 3 neighbourhood: a second
  // reference, robust to the cell's own noise. A noisy cell beside a step (a 2 cm cell of the real
  // floor holds 6 points, its median is off by 1.2 cm typically and 3 cm at times) would otherwise
  // take in the other side of a 10 cm step; a box corner, where the neighbourhood's median lies on
  // the other side, keeps its own height.
  struct Near {
    float z, w;
  };
  std::vector<float> median(g.size()), median_var(g.size());
  std::vector<uint8_t> has_median(g.size(), 0);
  for (int i = 0; i < g.nx; ++i)
    for (int j = 0; j < g.ny; ++j) {
      Near near[9];
      int n = 0;
      float total = 0;
      for (int a = std::max(0, i - 1); a <= std::min(g.nx - 1, i + 1); ++a)
        for (int b = std::max(0, j - 1); b <= std::min(g.ny - 1, j + 1); ++b) {
          const size_t c = g.index(a, b);
          if (weight[c] == 0.0f) continue;
          near[n++] = {grid.elevation[c], weight[c]};
          total += weight[c];
        }
      if (n == 0) continue;
      std::sort(near, near + n, [](const Near& x, const Near& y) { return x.z < y.z; });
      float below = 0;
      int m = 0;
      while (m + 1 < n && below + near[m].w < 0.5f * total) below += near[m++].w;
      const size_t k = g.index(i, j);
      median[k] = near[m].z;
      median_var[k] = static_cast<float>(point_var / total);
      has_median[k] = 1;
    }
  for (int i = 0; i < g.nx; ++i)
    for (int j = 0; j < g.ny; ++j) {
      const size_t k = g.index(i, j);
      const double z = grid.elevation[k];
      const double vk = var[k];
      const double zm = median[k], vm = median_var[k];
      const bool use_median = has_median[k];
      double sw = 0, swz = 0;
      for (const Tap& t : taps) {
        const int a = i + t.di, b = j + t.dj;
        if (a < 0 || b < 0 || a >= g.nx || b >= g.ny) continue;
        const size_t n = g.index(a, b);
        if (weight[n] == 0.0f) continue;
        const double dz = grid.elevation[n] - z;
        // Three standard errors of the difference, from the cell and from its neighbourhood's
        // median: beyond that the two lie on different surfaces (a step), which must stay sharp.
        if (dz * dz > 9.0 * (vk + var[n]) + kFloor2) continue;
        if (use_median) {
          const double dm = grid.elevation[n] - zm;
          if (dm * dm > 9.0 * (vm + var[n]) + kFloor2) continue;
        }
        const double w = t.w * weight[n];
        sw += w;
        swz += w * dz;
      }
      if (sw > 0) grid.surface[k] = static_cast<float>(z + swz / sw);
    }
}

void fill_holes(HeightGrid& grid, int min_points) {
  fill_holes_around(grid, min_points, std::vector<uint8_t>(grid.geometry.size(), 0));
}

void fill_holes_around(HeightGrid& grid, int min_points, const std::vector<uint8_t>& keep) {
  const GridGeometry& g = grid.geometry;
  // Sampling gaps: a cell without any point whose eight neighbours all measured one surface
  // (spread within the cluster gap) lies on that surface; interpolate it and count it observed
  // (value 2). Bridged see-through cells had points and stay unobserved.
  const double gap = grid.cluster_gap > 0 ? grid.cluster_gap : 0.05;
  std::vector<size_t> gaps;
  for (int i = 1; i + 1 < g.nx; ++i)
    for (int j = 1; j + 1 < g.ny; ++j) {
      const size_t k = g.index(i, j);
      if (grid.observed[k] || grid.count[k] >= static_cast<uint32_t>(min_points) ||
          no_ground(grid, k))
        continue;
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
  for (size_t k = 0; k < g.size(); ++k) known[k] |= keep[k];
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
  // Overhangs: a cell's overhead is the lowest underside over any part of it (conservative at the
  // overhang's border). Scenes without one leave the layer empty, as before.
  if (scene.has_overhangs()) {
    grid.overhead.resize(g.size());
    for (int i = 0; i < g.nx; ++i)
      for (int j = 0; j < g.ny; ++j) {
        const Eigen::Vector2d c0 = g.origin + resolution * Eigen::Vector2d(i, j);
        grid.overhead[g.index(i, j)] = static_cast<float>(
            scene.lowest_overhead(c0, c0 + Eigen::Vector2d::Constant(resolution)));
      }
  }
  return grid;
}

}  // namespace terrastride::terrain
