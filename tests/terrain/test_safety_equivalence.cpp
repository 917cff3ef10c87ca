// The optimised foothold-safety computation (compute_safety) gives bit-identical masks and margins
// to the straightforward one it replaced, kept here verbatim as the reference: per-cell disk sums
// from row prefix sums with an early exit, and two full Felzenszwalb-Huttenlocher distance
// transforms (both passes) per radius. Scanned grids (with a smoothed surface) take their slope
// tests from the surface; the reference does that per cell too.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <random>

#include "terrastride/perception/filters.hpp"
#include "terrastride/terrain/scan_sim.hpp"
#include "terrastride/terrain/scenes.hpp"
#include "terrastride/terrain/terrain_map.hpp"

using namespace terrastride::terrain;

namespace reference {

namespace {
// 1-D squared Euclidean distance transform of f (0 at sites, +inf elsewhere), Felzenszwalb &
// Huttenlocher 2012, in place with scratch buffers.
void edt_1d(double* f, int n, std::vector<double>& d, std::vector<int>& v, std::vector<double>& z) {
  constexpr double inf = std::numeric_limits<double>::infinity();
  d.resize(n);
  v.resize(n);
  z.resize(n + 1);
  int k = -1;
  for (int q = 0; q < n; ++q) {
    if (f[q] == inf) continue;
    if (k < 0) {
      k = 0;
      v[0] = q;
      z[0] = -inf;
      z[1] = inf;
      continue;
    }
    double s;
    for (;;) {
      const int p = v[k];
      s = ((f[q] + double(q) * q) - (f[p] + double(p) * p)) / (2.0 * (q - p));
      if (s <= z[k] && k > 0) {
        --k;
      } else {
        break;
      }
    }
    if (s <= z[k]) {  // k == 0 and the new parabola dominates everywhere
      v[0] = q;
      z[0] = -inf;
      z[1] = inf;
      continue;
    }
    ++k;
    v[k] = q;
    z[k] = s;
    z[k + 1] = inf;
  }
  if (k < 0) return;  // no site on this line: leave +inf
  int j = 0;
  for (int q = 0; q < n; ++q) {
    while (z[j + 1] < q) ++j;
    const double dq = q - v[j];
    d[q] = dq * dq + f[v[j]];
  }
  std::copy(d.begin(), d.end(), f);
}

// Squared distance (in cells) from every cell to the nearest cell where `site` is true.
std::vector<double> squared_distance(const GridGeometry& g, const std::vector<uint8_t>& mask,
                                     uint8_t site) {
  constexpr double inf = std::numeric_limits<double>::infinity();
  std::vector<double> f(g.size());
  for (size_t k = 0; k < f.size(); ++k) f[k] = mask[k] == site ? 0.0 : inf;
  std::vector<double> d, z, line(g.nx);
  std::vector<int> v;
  for (int i = 0; i < g.nx; ++i) edt_1d(&f[g.index(i, 0)], g.ny, d, v, z);  // along y
  for (int j = 0; j < g.ny; ++j) {                                          // along x
    for (int i = 0; i < g.nx; ++i) line[i] = f[g.index(i, j)];
    edt_1d(line.data(), g.nx, d, v, z);
    for (int i = 0; i < g.nx; ++i) f[g.index(i, j)] = line[i];
  }
  return f;
}

// The radius-independent part of the safety computation, shared by all radii: row prefix sums
// along y (z, z^2, j z, unobserved cells; one extra slot per row) and the sliding min of cell min /
// max of cell max along y for every half-width 0..W.
struct SafetyPrecompute {
  size_t ps = 0;
  std::vector<double> pz, pz2, pjz;
  std::vector<int> pun;
  std::vector<std::vector<float>> rmin, rmax;
  double mean_support = 1.0;
};

// The disk's reach in cells: r + res/2, and at least the 8 neighbours for a foot of any size.
double disk_reach(double radius, double res) {
  const double reach = radius / res + 0.5;
  return (radius > 0 ? std::max(reach, std::sqrt(2.0)) : reach) + 1e-9;
}

int disk_half_width(double radius, double res) {
  return static_cast<int>(std::floor(disk_reach(radius, res)));
}

SafetyPrecompute precompute_safety(const HeightGrid& grid, int W) {
  const GridGeometry& g = grid.geometry;
  const int nx = g.nx, ny = g.ny;
  SafetyPrecompute p;
  p.ps = ny + 1;
  const size_t ps = p.ps;
  p.pz.resize(nx * ps);
  p.pz2.resize(nx * ps);
  p.pjz.resize(nx * ps);
  p.pun.resize(nx * ps);
  for (int i = 0; i < nx; ++i) {
    double a = 0, b = 0, c = 0;
    int u = 0;
    p.pz[i * ps] = p.pz2[i * ps] = p.pjz[i * ps] = 0;
    p.pun[i * ps] = 0;
    for (int j = 0; j < ny; ++j) {
      const size_t k = g.index(i, j);
      const double z = grid.elevation[k];
      a += z;
      b += z * z;
      c += j * z;
      u += grid.observed[k] ? 0 : 1;
      p.pz[i * ps + j + 1] = a;
      p.pz2[i * ps + j + 1] = b;
      p.pjz[i * ps + j + 1] = c;
      p.pun[i * ps + j + 1] = u;
    }
  }
  p.rmin.resize(W + 1);
  p.rmax.resize(W + 1);
  p.rmin[0] = grid.min;
  p.rmax[0] = grid.max;
  for (int k = 1; k <= W; ++k) {
    p.rmin[k] = p.rmin[k - 1];
    p.rmax[k] = p.rmax[k - 1];
    float* mn = p.rmin[k].data();
    float* mx = p.rmax[k].data();
    for (int i = 0; i < nx; ++i) {
      const size_t row = g.index(i, 0);
      for (int j = k; j < ny; ++j) {
        mn[row + j] = std::min(mn[row + j], grid.min[row + j - k]);
        mx[row + j] = std::max(mx[row + j], grid.max[row + j - k]);
      }
      for (int j = 0; j + k < ny; ++j) {
        mn[row + j] = std::min(mn[row + j], grid.min[row + j + k]);
        mx[row + j] = std::max(mx[row + j], grid.max[row + j + k]);
      }
    }
  }
  double support_sum = 0;
  size_t support_cells = 0;
  for (size_t k = 0; k < g.size(); ++k)
    if (grid.observed[k]) {
      support_sum += grid.support[k];
      ++support_cells;
    }
  p.mean_support = support_cells ? std::max(1.0, support_sum / support_cells) : 1.0;
  return p;
}

SafetyLayer safety_for_radius(const HeightGrid& grid, const SafetyPrecompute& pre, double radius,
                              const SafetyOptions& o) {
  const GridGeometry& g = grid.geometry;
  const int nx = g.nx, ny = g.ny;
  const double res = g.resolution;
  // Disk rows: for a row offset di, the cells j - w[di] .. j + w[di].
  const double reach = disk_reach(radius, res);
  const int R = static_cast<int>(std::floor(reach));
  std::vector<int> w(2 * R + 1);
  double sxx = 0, syy = 0;
  int ncells = 0;
  for (int di = -R; di <= R; ++di) {
    const int wi = static_cast<int>(std::floor(std::sqrt(std::max(0.0, reach * reach - di * di))));
    w[di + R] = wi;
    sxx += double(di) * di * (2 * wi + 1);
    syy += wi * (wi + 1.0) * (2 * wi + 1) / 3.0;
    ncells += 2 * wi + 1;
  }
  const int W = *std::max_element(w.begin(), w.end());
  const size_t ps = pre.ps;
  const std::vector<double>&pz = pre.pz, &pz2 = pre.pz2, &pjz = pre.pjz;
  const std::vector<int>& pun = pre.pun;
  const std::vector<std::vector<float>>&rmin = pre.rmin, &rmax = pre.rmax;
  SafetyLayer layer;
  layer.radius = radius;
  layer.safe.assign(g.size(), 0);
  const double max_slope_cells = o.max_slope * res;  // slope per cell
  // Sensor noise widens the raw step (a disk's extreme points lie a few sigma either side of the
  // surface) and the fit residual; allow for it so a noisy plane is not called rough.
  const double sigma = std::max(0.0, grid.noise_sigma);
  const double max_step = o.max_step + o.step_noise_factor * sigma;
  const double max_rms = o.max_rms + o.rms_noise_factor * sigma;
  const double max_rss_n = max_rms * max_rms;
  // The fitted slope of a small disk is noisy: each elevation is a median of `support` points with
  // standard error about 1.25 sigma / sqrt(support), so the slope's standard error per axis is that
  // over sqrt(sum of squared offsets). Allow slope_noise_factor of those.
  const double sigma_median = 1.2533 * sigma / std::sqrt(pre.mean_support);
  const double slope_noise = sxx > 0 ? sigma_median / std::sqrt(sxx) : 0.0;  // per cell
  double max_slope_eff = max_slope_cells + o.slope_noise_factor * slope_noise;
  // Scanned grids (a smoothed surface): the slope tests are on the surface instead, its plane fit
  // over the disk and the B-spline approximant's gradient at the cell centre, both <= max_slope.
  const bool scanned = grid.surface.size() == g.size();
  std::vector<double> psz, pjsz;
  std::vector<float> centre;
  if (scanned) {
    max_slope_eff = std::numeric_limits<double>::infinity();
    psz.resize(nx * ps);
    pjsz.resize(nx * ps);
    for (int i = 0; i < nx; ++i) {
      double a = 0, c = 0;
      psz[i * ps] = pjsz[i * ps] = 0;
      for (int j = 0; j < ny; ++j) {
        const double z = grid.surface[g.index(i, j)];
        a += z;
        c += j * z;
        psz[i * ps + j + 1] = a;
        pjsz[i * ps + j + 1] = c;
      }
    }
    centre.resize(g.size());
    const auto at = [&](int i, int j) {
      return double(grid.surface[g.index(std::clamp(i, 0, nx - 1), std::clamp(j, 0, ny - 1))]);
    };
    const double inv = 1.0 / (12.0 * res);
    for (int i = 0; i < nx; ++i)
      for (int j = 0; j < ny; ++j) {
        double gx = 0, gy = 0;
        for (int b = -1; b <= 1; ++b) {
          const double wb = b == 0 ? 4.0 : 1.0;
          gx += wb * (at(i + 1, j + b) - at(i - 1, j + b));
          gy += wb * (at(i + b, j + 1) - at(i + b, j - 1));
        }
        centre[g.index(i, j)] = static_cast<float>(std::hypot(gx * inv, gy * inv));
      }
  }
  for (int i = 0; i < nx; ++i) {
    if (i - R < 0 || i + R >= nx) continue;  // disk leaves the grid: not fully observed
    for (int j = 0; j < ny; ++j) {
      if (j - W < 0 || j + W >= ny) continue;
      double sz = 0, sz2 = 0, sdiz = 0, sdjz = 0;
      float lo = std::numeric_limits<float>::infinity(), hi = -lo;
      bool ok = true;
      for (int di = -R; di <= R && ok; ++di) {
        const int wi = w[di + R];
        const size_t row = static_cast<size_t>(i + di) * ps;
        const int a = j - wi, b = j + wi + 1;  // [a, b)
        if (pun[row + b] - pun[row + a] != 0) {
          ok = false;
          break;
        }
        const double z = pz[row + b] - pz[row + a];
        sz += z;
        sz2 += pz2[row + b] - pz2[row + a];
        sdiz += di * z;
        sdjz += (pjz[row + b] - pjz[row + a]) - j * z;
        const size_t c = g.index(i + di, j);
        lo = std::min(lo, rmin[wi][c]);
        hi = std::max(hi, rmax[wi][c]);
      }
      if (!ok || !(hi - lo <= max_step)) continue;
      const double a = sxx > 0 ? sdiz / sxx : 0.0;
      const double b = syy > 0 ? sdjz / syy : 0.0;
      const double mean = sz / ncells;
      const double rss = sz2 - ncells * mean * mean - a * sdiz - b * sdjz;
      if (!(rss <= max_rss_n * ncells)) continue;
      if (!(a * a + b * b <= max_slope_eff * max_slope_eff)) continue;
      if (scanned) {
        double ssdiz = 0, ssdjz = 0;
        for (int di = -R; di <= R; ++di) {
          const int wi = w[di + R];
          const size_t row = static_cast<size_t>(i + di) * ps;
          const int lo_j = j - wi, hi_j = j + wi + 1;
          const double z = psz[row + hi_j] - psz[row + lo_j];
          ssdiz += di * z;
          ssdjz += (pjsz[row + hi_j] - pjsz[row + lo_j]) - j * z;
        }
        const double sa = sxx > 0 ? ssdiz / sxx : 0.0, sb = syy > 0 ? ssdjz / syy : 0.0;
        const double max_plane = o.max_slope * res;
        if (!(sa * sa + sb * sb <= max_plane * max_plane)) continue;
        if (!(centre[g.index(i, j)] <= o.max_slope)) continue;
      }
      layer.safe[g.index(i, j)] = 1;
      ++layer.safe_cells;
    }
  }

  // Signed margin from two distance transforms.
  layer.margin.assign(g.size(), 0.0f);
  const std::vector<double> to_unsafe = squared_distance(g, layer.safe, 0);
  const std::vector<double> to_safe = squared_distance(g, layer.safe, 1);
  // With no unsafe (or no safe) cell at all, distances are infinite: cap at the grid diagonal.
  const double cap = std::hypot(nx, ny) * res;
  for (size_t k = 0; k < g.size(); ++k) {
    if (layer.safe[k]) {
      const double d = std::isfinite(to_unsafe[k]) ? std::sqrt(to_unsafe[k]) * res : cap;
      layer.margin[k] = static_cast<float>(d - 0.5 * res);
    } else {
      const double d = std::isfinite(to_safe[k]) ? std::sqrt(to_safe[k]) * res : cap;
      layer.margin[k] = static_cast<float>(-(d - 0.5 * res));
    }
  }
  return layer;
}

}  // namespace

std::vector<SafetyLayer> reference_safety(const HeightGrid& grid, const std::vector<double>& radii,
                                          const SafetyOptions& o) {
  int W = 0;
  for (double r : radii) {
    if (!std::isfinite(r) || r < 0 || r > 1.0)
      throw terrastride::perception::InputError("foot radius " + std::to_string(r) +
                                                " m is outside [0, 1] m");
    W = std::max(W, disk_half_width(r, grid.geometry.resolution));
  }
  const SafetyPrecompute pre = precompute_safety(grid, W);
  std::vector<SafetyLayer> layers;
  for (double r : radii) layers.push_back(safety_for_radius(grid, pre, r, o));
  return layers;
}

}  // namespace reference

namespace {

void expect_identical(const HeightGrid& grid, const std::vector<double>& radii,
                      const SafetyOptions& o = {}) {
  const auto want = reference::reference_safety(grid, radii, o);
  const auto got = compute_safety(grid, radii, o);
  ASSERT_EQ(want.size(), got.size());
  size_t safe = 0, unsafe = 0;
  for (size_t l = 0; l < want.size(); ++l) {
    SCOPED_TRACE("radius " + std::to_string(radii[l]));
    EXPECT_EQ(got[l].radius, want[l].radius);
    EXPECT_EQ(got[l].safe_cells, want[l].safe_cells);
    ASSERT_EQ(got[l].safe, want[l].safe);
    ASSERT_EQ(got[l].margin.size(), want[l].margin.size());
    // Bitwise, not approximately.
    EXPECT_EQ(0, std::memcmp(got[l].margin.data(), want[l].margin.data(),
                             want[l].margin.size() * sizeof(float)));
    safe += want[l].safe_cells;
    unsafe += want[l].safe.size() - want[l].safe_cells;
  }
  // The cases must exercise both kinds of cell.
  EXPECT_GT(safe, 0u);
  EXPECT_GT(unsafe, 0u);
}

const std::vector<double> kRadii{0.0, 0.02, 0.05, 0.10, 0.13};

TEST(SafetyEquivalence, RasterisedScenes) {
  for (const std::string name : {"eur_pallet", "stairs", "gap", "pallet_10", "flat"}) {
    SCOPED_TRACE(name);
    auto scene = make_scene(name);
    expect_identical(rasterize_scene(*scene, 0.02), kRadii);
    expect_identical(rasterize_scene(*scene, 0.035), {0.02, 0.05, 0.11});
  }
}

TEST(SafetyEquivalence, SimulatedScansWithHolesAndNoise) {
  for (const std::string name : {"pallet_15", "stairs"}) {
    SCOPED_TRACE(name);
    auto scene = make_scene(name);
    std::vector<terrastride::perception::PointCloud> clouds;
    for (auto& s : simulate_scans(*scene, DepthSensorOptions{})) clouds.push_back(s.cloud);
    const HeightGrid grid = build_height_grid(clouds);
    expect_identical(grid, kRadii);
    SafetyOptions tight;
    tight.max_rms = 0.002;
    tight.max_slope = 0.1;
    tight.slope_noise_factor = 0.0;
    expect_identical(grid, {0.02, 0.05}, tight);
  }
}

TEST(SafetyEquivalence, RandomGridsAllSizes) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  const int sizes[][2] = {{1, 1}, {3, 50}, {50, 3}, {17, 23}, {64, 64}, {120, 37}};
  for (const auto& s : sizes) {
    SCOPED_TRACE(std::to_string(s[0]) + " x " + std::to_string(s[1]));
    HeightGrid grid;
    grid.geometry.resolution = 0.02;
    grid.geometry.nx = s[0];
    grid.geometry.ny = s[1];
    const size_t n = grid.geometry.size();
    grid.elevation.resize(n);
    grid.min.resize(n);
    grid.max.resize(n);
    grid.observed.resize(n);
    grid.support.assign(n, 3);
    grid.noise_sigma = 0.002;
    for (int i = 0; i < s[0]; ++i)
      for (int j = 0; j < s[1]; ++j) {
        const size_t k = grid.geometry.index(i, j);
        // Smooth terrain with a few steps, rough patches and holes.
        float z = 0.01f * std::sin(0.2f * i) + (i > s[0] / 2 ? 0.08f : 0.0f);
        if (u(rng) < 0.05f) z += 0.03f * u(rng);
        grid.elevation[k] = z;
        grid.min[k] = z - 0.004f * u(rng);
        grid.max[k] = z + 0.004f * u(rng);
        grid.observed[k] = u(rng) < 0.01f ? 0 : (u(rng) < 0.1f ? 2 : 1);
      }
    // As a rasterised grid (no surface), then as a scanned one (a smoothed surface beside the
    // raw elevation, with slopes around the 0.6 limit).
    for (bool scanned : {false, true}) {
      SCOPED_TRACE(scanned ? "with a surface" : "elevation only");
      if (scanned) {
        grid.surface.resize(n);
        for (int i = 0; i < s[0]; ++i)
          for (int j = 0; j < s[1]; ++j)
            grid.surface[grid.geometry.index(i, j)] =
                0.012f * (i % 7) + 0.003f * u(rng) + (i > s[0] / 2 ? 0.08f : 0.0f);
      }
      const auto want = reference::reference_safety(grid, kRadii, SafetyOptions{});
      const auto got = compute_safety(grid, kRadii);
      for (size_t l = 0; l < want.size(); ++l) {
        EXPECT_EQ(got[l].safe, want[l].safe);
        EXPECT_EQ(0, std::memcmp(got[l].margin.data(), want[l].margin.data(),
                                 want[l].margin.size() * sizeof(float)));
      }
    }
  }
}

TEST(SafetyEquivalence, AllSafeAndAllUnsafe) {
  auto scene = make_scene("flat");
  HeightGrid grid = rasterize_scene(*scene, 0.02);
  const auto want = reference::reference_safety(grid, {0.0}, SafetyOptions{});
  const auto got = compute_safety(grid, std::vector<double>{0.0});
  EXPECT_EQ(got[0].safe_cells, grid.geometry.size());  // r = 0: every cell, border included
  EXPECT_EQ(got[0].safe, want[0].safe);
  EXPECT_EQ(got[0].margin, want[0].margin);
  std::fill(grid.observed.begin(), grid.observed.end(), 0);
  const auto want0 = reference::reference_safety(grid, {0.05}, SafetyOptions{});
  const auto got0 = compute_safety(grid, std::vector<double>{0.05});
  EXPECT_EQ(got0[0].safe_cells, 0u);
  EXPECT_EQ(got0[0].safe, want0[0].safe);
  EXPECT_EQ(got0[0].margin, want0[0].margin);
}

}  // namespace
