#include "terrastride/terrain/terrain_map.hpp"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>

#include <Eigen/SparseCholesky>

#include "terrastride/perception/npy.hpp"
#include "terrastride/perception/point_cloud.hpp"
#include "terrastride/terrain/scenes.hpp"

namespace terrastride::terrain {
namespace {

using perception::InputError;
constexpr int kPadLo = 2;
constexpr int kPadHi = 3;

// Uniform cubic B-spline basis on [0, 1) and its first two derivatives.
inline void basis(double t, double b[4]) {
  const double s = 1.0 - t, t2 = t * t, t3 = t2 * t;
  b[0] = s * s * s / 6.0;
  b[1] = (3.0 * t3 - 6.0 * t2 + 4.0) / 6.0;
  b[2] = (-3.0 * t3 + 3.0 * t2 + 3.0 * t + 1.0) / 6.0;
  b[3] = t3 / 6.0;
}
inline void basis_d1(double t, double b[4]) {
  const double s = 1.0 - t, t2 = t * t;
  b[0] = -0.5 * s * s;
  b[1] = 1.5 * t2 - 2.0 * t;
  b[2] = -1.5 * t2 + t + 0.5;
  b[3] = 0.5 * t2;
}
inline void basis_d2(double t, double b[4]) {
  b[0] = 1.0 - t;
  b[1] = 3.0 * t - 2.0;
  b[2] = 1.0 - 3.0 * t;
  b[3] = t;
}

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

std::string radius_tag(double r) {
  std::ostringstream os;
  os << "r" << static_cast<long>(std::lround(r * 1000.0));
  return os.str();
}

// The B-spline interpolation matrix along one axis: (c[i-1] + 4 c[i] + c[i+1]) / 6 = v[i], with
// the replicated border control points (c[-1] = c[0], c[n] = c[n-1]) the padding uses.
Eigen::SparseMatrix<double> interpolation_matrix(int n) {
  std::vector<Eigen::Triplet<double>> t;
  for (int i = 0; i < n; ++i) {
    double diag = 4.0 / 6.0;
    if (i > 0)
      t.emplace_back(i, i - 1, 1.0 / 6.0);
    else
      diag += 1.0 / 6.0;
    if (i + 1 < n)
      t.emplace_back(i, i + 1, 1.0 / 6.0);
    else
      diag += 1.0 / 6.0;
    t.emplace_back(i, i, diag);
  }
  Eigen::SparseMatrix<double> a(n, n);
  a.setFromTriplets(t.begin(), t.end());
  return a;
}

}  // namespace

// ---------------------------------------------------------------------------------------------
BSplineField::BSplineField(const GridGeometry& g, const std::vector<float>& values,
                           bool interpolate)
    : geometry_(g), stride_(g.ny + kPadLo + kPadHi) {
  // Control points (nx x ny): the values themselves, or solved so the spline passes through them.
  Eigen::MatrixXd c(g.nx, g.ny);
  for (int i = 0; i < g.nx; ++i)
    for (int j = 0; j < g.ny; ++j) c(i, j) = values[g.index(i, j)];
  if (interpolate) {
    // Symmetric positive definite and tridiagonal: one sparse Cholesky per axis, all lines at once.
    Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> ax(interpolation_matrix(g.nx));
    c = ax.solve(c);
    Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> ay(interpolation_matrix(g.ny));
    c = ay.solve(Eigen::MatrixXd(c.transpose())).transpose();
  }
  const int px = g.nx + kPadLo + kPadHi;
  coeffs_.resize(static_cast<size_t>(px) * stride_);
  for (int a = 0; a < px; ++a) {
    const int i = std::clamp(a - kPadLo, 0, g.nx - 1);
    for (int b = 0; b < stride_; ++b) {
      const int j = std::clamp(b - kPadLo, 0, g.ny - 1);
      coeffs_[static_cast<size_t>(a) * stride_ + b] = c(i, j);
    }
  }
}

const double* BSplineField::locate(double x, double y, double* tx, double* ty) const {
  // Control point i sits at the centre of cell i: u = i there. Clamping u to [-1, n] keeps the
  // field C2 (the padded control points are equal, so all derivatives vanish at the clamp).
  double u = (x - geometry_.origin.x()) / geometry_.resolution - 0.5;
  double v = (y - geometry_.origin.y()) / geometry_.resolution - 0.5;
  u = std::clamp(u, -1.0, static_cast<double>(geometry_.nx));
  v = std::clamp(v, -1.0, static_cast<double>(geometry_.ny));
  if (!std::isfinite(u)) u = -1.0;  // NaN input: a defined (if meaningless) answer, never UB
  if (!std::isfinite(v)) v = -1.0;
  const double fu = std::floor(u), fv = std::floor(v);
  *tx = u - fu;
  *ty = v - fv;
  const int i = static_cast<int>(fu), j = static_cast<int>(fv);
  // Basis index a = 0..3 uses control point i - 1 + a, stored at i - 1 + a + kPadLo.
  return coeffs_.data() + static_cast<size_t>(i - 1 + kPadLo) * stride_ + (j - 1 + kPadLo);
}

double BSplineField::value(double x, double y) const {
  double tx, ty, bx[4], by[4];
  const double* c = locate(x, y, &tx, &ty);
  basis(tx, bx);
  basis(ty, by);
  double h = 0;
  for (int a = 0; a < 4; ++a, c += stride_) {
    h += bx[a] * (by[0] * c[0] + by[1] * c[1] + by[2] * c[2] + by[3] * c[3]);
  }
  return h;
}

double BSplineField::value_gradient(double x, double y, Eigen::Vector2d* gradient) const {
  double tx, ty, bx[4], by[4], dx[4], dy[4];
  const double* c = locate(x, y, &tx, &ty);
  basis(tx, bx);
  basis(ty, by);
  basis_d1(tx, dx);
  basis_d1(ty, dy);
  double h = 0, gx = 0, gy = 0;
  for (int a = 0; a < 4; ++a, c += stride_) {
    const double rb = by[0] * c[0] + by[1] * c[1] + by[2] * c[2] + by[3] * c[3];
    const double rd = dy[0] * c[0] + dy[1] * c[1] + dy[2] * c[2] + dy[3] * c[3];
    h += bx[a] * rb;
    gx += dx[a] * rb;
    gy += bx[a] * rd;
  }
  // Outside [-1, n] in cell units the field is constant: the clamped u hides that, so zero the
  // derivative explicitly there (it is zero at the clamp anyway, this only removes round-off).
  const double inv = 1.0 / geometry_.resolution;
  *gradient = Eigen::Vector2d(gx * inv, gy * inv);
  return h;
}

HeightSample BSplineField::sample(double x, double y) const {
  double tx, ty, bx[4], by[4], dx[4], dy[4], ddx[4], ddy[4];
  const double* c = locate(x, y, &tx, &ty);
  basis(tx, bx);
  basis(ty, by);
  basis_d1(tx, dx);
  basis_d1(ty, dy);
  basis_d2(tx, ddx);
  basis_d2(ty, ddy);
  double h = 0, gx = 0, gy = 0, hxx = 0, hxy = 0, hyy = 0;
  for (int a = 0; a < 4; ++a, c += stride_) {
    double r0 = 0, r1 = 0, r2 = 0;
    for (int b = 0; b < 4; ++b) {
      r0 += by[b] * c[b];
      r1 += dy[b] * c[b];
      r2 += ddy[b] * c[b];
    }
    h += bx[a] * r0;
    gx += dx[a] * r0;
    gy += bx[a] * r1;
    hxx += ddx[a] * r0;
    hxy += dx[a] * r1;
    hyy += bx[a] * r2;
  }
  const double inv = 1.0 / geometry_.resolution;
  HeightSample s;
  s.height = h;
  s.gradient = Eigen::Vector2d(gx * inv, gy * inv);
  s.hessian << hxx * inv * inv, hxy * inv * inv, hxy * inv * inv, hyy * inv * inv;
  return s;
}

// ---------------------------------------------------------------------------------------------
namespace {

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

int disk_half_width(double radius, double res) {
  return static_cast<int>(std::floor(radius / res + 0.5 + 1e-9));
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
  const double reach = radius / res + 0.5 + 1e-9;
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
  const double max_slope_eff = max_slope_cells + o.slope_noise_factor * slope_noise;
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

std::vector<SafetyLayer> compute_safety(const HeightGrid& grid, const std::vector<double>& radii,
                                        const SafetyOptions& o) {
  int W = 0;
  for (double r : radii) {
    if (!std::isfinite(r) || r < 0 || r > 1.0)
      throw InputError("foot radius " + std::to_string(r) + " m is outside [0, 1] m");
    W = std::max(W, disk_half_width(r, grid.geometry.resolution));
  }
  const SafetyPrecompute pre = precompute_safety(grid, W);
  std::vector<SafetyLayer> layers;
  for (double r : radii) layers.push_back(safety_for_radius(grid, pre, r, o));
  return layers;
}

SafetyLayer compute_safety(const HeightGrid& grid, double radius, const SafetyOptions& o) {
  return std::move(compute_safety(grid, std::vector<double>{radius}, o).front());
}

// ---------------------------------------------------------------------------------------------
TerrainMap::TerrainMap(HeightGrid grid, const std::vector<double>& radii, SafetyOptions options)
    : grid_(std::move(grid)), options_(options), height_(grid_.geometry, grid_.elevation) {
  if (!(options_.max_step > 0) || !(options_.max_rms > 0) || !(options_.max_slope > 0))
    throw InputError("safety options: max_step, max_rms and max_slope must be positive");
  std::vector<double> todo;
  for (double r : radii)
    if (std::none_of(todo.begin(), todo.end(), [r](double t) { return std::abs(t - r) < 1e-9; }))
      todo.push_back(r);
  for (auto& l : compute_safety(grid_, todo, options_)) {
    l.margin_field = BSplineField(grid_.geometry, l.margin, /*interpolate=*/true);
    layers_.push_back(std::move(l));
  }
}

std::unique_ptr<TerrainMap> TerrainMap::from_scene(const Scene& scene, double resolution,
                                                   const std::vector<double>& radii,
                                                   SafetyOptions options) {
  return std::make_unique<TerrainMap>(rasterize_scene(scene, resolution), radii, options);
}

const SafetyLayer& TerrainMap::layer(double r) const {
  std::lock_guard<std::mutex> lock(mutex_);
  for (const auto& l : layers_)
    if (std::abs(l.radius - r) < 1e-9) return l;
  SafetyLayer l = compute_safety(grid_, r, options_);
  l.margin_field = BSplineField(grid_.geometry, l.margin, /*interpolate=*/true);
  layers_.push_back(std::move(l));
  return layers_.back();
}

std::vector<double> TerrainMap::radii() const {
  std::lock_guard<std::mutex> lock(mutex_);
  std::vector<double> r;
  for (const auto& l : layers_) r.push_back(l.radius);
  return r;
}

int TerrainMap::cell_index(double x, double y) const {
  const GridGeometry& g = grid_.geometry;
  const double u = (x - g.origin.x()) / g.resolution, v = (y - g.origin.y()) / g.resolution;
  if (!(u >= 0 && v >= 0 && u <= g.nx && v <= g.ny)) return -1;
  const int i = std::min(static_cast<int>(u), g.nx - 1),
            j = std::min(static_cast<int>(v), g.ny - 1);
  return static_cast<int>(g.index(i, j));
}

MarginSample TerrainMap::safety_margin(double x, double y, double foot_radius) const {
  const SafetyLayer& l = layer(foot_radius);
  MarginSample m;
  m.margin = l.margin_field.value_gradient(x, y, &m.gradient);
  return m;
}

bool TerrainMap::observed(double x, double y) const {
  const int k = cell_index(x, y);
  return k >= 0 && grid_.observed[k];
}

bool TerrainMap::safe(double x, double y, double foot_radius) const {
  const int k = cell_index(x, y);
  return k >= 0 && layer(foot_radius).safe[k];
}

std::string TerrainMap::describe() const {
  const GridGeometry& g = grid_.geometry;
  std::ostringstream os;
  os << "terrain map " << g.nx << " x " << g.ny << " cells of " << g.resolution << " m from ("
     << g.origin.x() << ", " << g.origin.y() << ")";
  return os.str();
}

Clearance TerrainMap::clearance(const Eigen::Vector3d& a, const Eigen::Vector3d& b) const {
  const double len = (b - a).head<2>().norm();
  const int n = std::max(1, static_cast<int>(std::ceil(len / (0.25 * grid_.geometry.resolution))));
  Clearance c;
  c.min = std::numeric_limits<double>::infinity();
  for (int k = 0; k <= n; ++k) {
    const Eigen::Vector3d p = a + (b - a) * (double(k) / n);
    const double d = p.z() - height_.value(p.x(), p.y());
    if (d < c.min) {
      c.min = d;
      c.at = p;
    }
  }
  return c;
}

// ---------------------------------------------------------------------------------------------
nlohmann::json write_terrain_layers(const TerrainMap& map, const std::string& dir) {
  namespace fs = std::filesystem;
  const HeightGrid& g = map.grid();
  const GridGeometry& geo = g.geometry;
  const fs::path layers = fs::path(dir) / "layers";
  std::error_code ec;
  fs::create_directories(layers, ec);
  if (ec) throw InputError("cannot create " + layers.string() + ": " + ec.message());
  const size_t nx = geo.nx, ny = geo.ny;
  nlohmann::json files = nlohmann::json::object();
  auto put_f = [&](const std::string& name, const std::vector<float>& v) {
    perception::write_npy((layers / (name + ".npy")).string(), v.data(), nx, ny);
    files[name] = "layers/" + name + ".npy";
  };
  auto put_u8 = [&](const std::string& name, const std::vector<uint8_t>& v) {
    perception::write_npy((layers / (name + ".npy")).string(), v.data(), nx, ny);
    files[name] = "layers/" + name + ".npy";
  };
  put_f("elevation", g.elevation);
  put_f("variance", g.variance);
  put_f("min", g.min);
  put_f("max", g.max);
  put_f("count", std::vector<float>(g.count.begin(), g.count.end()));
  put_f("support", std::vector<float>(g.support.begin(), g.support.end()));
  put_u8("observed", g.observed);
  nlohmann::json safety = nlohmann::json::array();
  for (double r : map.radii()) {
    const SafetyLayer& l = map.layer(r);
    put_u8("safe_" + radius_tag(r), l.safe);
    put_f("margin_" + radius_tag(r), l.margin);
    safety.push_back({{"radius", r},
                      {"safe_cells", l.safe_cells},
                      {"safe_fraction", double(l.safe_cells) / geo.size()},
                      {"safe", "layers/safe_" + radius_tag(r) + ".npy"},
                      {"margin", "layers/margin_" + radius_tag(r) + ".npy"}});
  }
  const SafetyOptions& o = map.safety_options();
  return {{"format", "terrastride-terrain"},
          {"version", 1},
          {"grid",
           {{"origin", {geo.origin.x(), geo.origin.y()}},
            {"resolution", geo.resolution},
            {"nx", geo.nx},
            {"ny", geo.ny},
            {"noise_sigma", g.noise_sigma},
            {"cluster_gap", g.cluster_gap},
            {"layout",
             "layers are nx x ny arrays; element [i][j] is the cell whose min corner is "
             "origin + resolution * (i, j)"}}},
          {"layers", files},
          {"safety",
           {{"max_step", o.max_step},
            {"step_noise_factor", o.step_noise_factor},
            {"rms_noise_factor", o.rms_noise_factor},
            {"slope_noise_factor", o.slope_noise_factor},
            {"max_rms", o.max_rms},
            {"max_slope", o.max_slope},
            {"radii", safety}}},
          {"statistics",
           {{"points_in_grid", g.points_in_grid},
            {"cells", geo.size()},
            {"observed_cells", g.observed_cells},
            {"filled_cells", g.filled_cells},
            {"bridged_cells", g.bridged_cells},
            {"interpolated_cells", g.interpolated_cells},
            {"see_through_cells", g.see_through_cells},
            {"overhang_cells", g.overhang_cells}}}};
}

std::unique_ptr<TerrainMap> load_terrain_dir(const std::string& dir) {
  namespace fs = std::filesystem;
  const fs::path meta_path = fs::path(dir) / "terrain.json";
  if (!fs::is_directory(dir)) throw InputError(dir + ": not a directory (expected a terrain map)");
  std::ifstream in(meta_path);
  if (!in) throw InputError(meta_path.string() + ": missing or unreadable");
  nlohmann::json meta;
  try {
    meta = nlohmann::json::parse(in);
  } catch (const std::exception& e) {
    throw InputError(meta_path.string() + ": not valid JSON (" + e.what() + ")");
  }
  HeightGrid grid;
  std::vector<double> radii;
  SafetyOptions opts;
  try {
    if (meta.at("format").get<std::string>() != "terrastride-terrain")
      throw InputError(meta_path.string() + ": not a terrastride terrain (format field)");
    const auto& gj = meta.at("grid");
    GridGeometry& geo = grid.geometry;
    geo.origin =
        Eigen::Vector2d(gj.at("origin").at(0).get<double>(), gj.at("origin").at(1).get<double>());
    geo.resolution = gj.at("resolution").get<double>();
    geo.nx = gj.at("nx").get<int>();
    geo.ny = gj.at("ny").get<int>();
    grid.noise_sigma = gj.value("noise_sigma", 0.0);
    grid.cluster_gap = gj.value("cluster_gap", 0.0);
    if (!(geo.resolution > 0) || geo.nx <= 0 || geo.ny <= 0 || !geo.origin.allFinite())
      throw InputError(meta_path.string() + ": invalid grid metadata");
    const auto& sj = meta.at("safety");
    opts.max_step = sj.at("max_step").get<double>();
    opts.max_rms = sj.at("max_rms").get<double>();
    opts.max_slope = sj.at("max_slope").get<double>();
    opts.step_noise_factor = sj.value("step_noise_factor", opts.step_noise_factor);
    opts.rms_noise_factor = sj.value("rms_noise_factor", opts.rms_noise_factor);
    opts.slope_noise_factor = sj.value("slope_noise_factor", opts.slope_noise_factor);
    for (const auto& r : sj.at("radii")) radii.push_back(r.at("radius").get<double>());
  } catch (const nlohmann::json::exception& e) {
    throw InputError(meta_path.string() + ": missing or malformed field (" + e.what() + ")");
  }
  const GridGeometry& geo = grid.geometry;
  auto load = [&](const std::string& name, auto& out) {
    const std::string path = (fs::path(dir) / "layers" / (name + ".npy")).string();
    const perception::NpyArray a = perception::read_npy(path);
    if (a.shape.size() != 2 || a.rows() != static_cast<size_t>(geo.nx) ||
        a.cols() != static_cast<size_t>(geo.ny))
      throw InputError(path + ": layer shape does not match the grid (" + std::to_string(geo.nx) +
                       " x " + std::to_string(geo.ny) + ")");
    using T = typename std::decay_t<decltype(out)>::value_type;
    out.resize(geo.size());
    for (int i = 0; i < geo.nx; ++i)
      for (int j = 0; j < geo.ny; ++j) {
        const double v = a.at(i, j);
        if (!std::isfinite(v)) throw InputError(path + ": non-finite value in a layer");
        out[geo.index(i, j)] = static_cast<T>(v);
      }
  };
  load("elevation", grid.elevation);
  load("variance", grid.variance);
  load("min", grid.min);
  load("max", grid.max);
  load("count", grid.count);
  load("support", grid.support);
  load("observed", grid.observed);
  for (size_t k = 0; k < geo.size(); ++k) {
    if (grid.observed[k] > 2)
      throw InputError(dir + "/layers/observed.npy: values must be 0, 1 or 2");
    grid.observed_cells += grid.observed[k] == 1;
    grid.interpolated_cells += grid.observed[k] == 2;
  }
  grid.filled_cells = geo.size() - grid.observed_cells - grid.interpolated_cells;
  return std::make_unique<TerrainMap>(std::move(grid), radii, opts);
}

}  // namespace terrastride::terrain
