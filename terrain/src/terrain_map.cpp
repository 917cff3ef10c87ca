#include "terrastride/terrain/terrain_map.hpp"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <cstdint>
#include <limits>
#include <optional>
#include <sstream>
#include <type_traits>

#include <Eigen/SparseCholesky>

#include "terrastride/perception/json_input.hpp"
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

// Exact squared Euclidean distance transform of a binary mask (Felzenszwalb & Huttenlocher 2012),
// separable: pass 1 along x gives, per cell, the distance to the nearest site in its column; pass
// 2 runs the lower envelope of parabolas along each (contiguous) row. Everything is integer: the
// envelope's breakpoints are kept as fractions and compared by cross-multiplication, so there is no
// division and no rounding, and the result is the exact squared distance in cells (an integer,
// hence exact as a double too). kNoSite marks "no site on this line".
constexpr int64_t kNoSite = std::numeric_limits<int64_t>::max();
// Breakpoint comparisons multiply a numerator (up to nx^2 + ny^2) by a denominator (up to 2 ny):
// beyond 64 bits for the longest grids the height grid accepts (1e7 cells a side).
__extension__ typedef __int128 Wide;

struct EdtScratch {
  std::vector<int32_t> col0, col1;  // pass 1: column distance to the nearest 0 / non-0 cell
  std::vector<int32_t> last0, last1;
  std::vector<int64_t> f, d, h, zn, zd;
  std::vector<int> v;
};

// 1-D transform of f (squared distances, kNoSite where there is none) into d; returns false when
// the line holds no site at all (d is left untouched then). Product is the type of the
// cross-multiplied breakpoint comparison: int64_t when it cannot overflow, Wide otherwise.
template <class Product>
bool edt_1d_exact(const int64_t* f, int n, EdtScratch& s, int64_t* d) {
  int* v = s.v.data();
  int64_t* h = s.h.data();    // f[v[k]] + v[k]^2 of the parabolas on the envelope
  int64_t* zn = s.zn.data();  // breakpoint k between parabola k-1 and k is zn[k] / zd[k], zd > 0
  int64_t* zd = s.zd.data();
  int k = -1;
  for (int q = 0; q < n; ++q) {
    if (f[q] == kNoSite) continue;
    const int64_t fq = f[q] + int64_t(q) * q;
    if (k < 0) {
      k = 0;
      v[0] = q;
      h[0] = fq;
      continue;
    }
    int64_t sn, sd;
    for (;;) {
      sn = fq - h[k];
      sd = 2 * int64_t(q - v[k]);
      // Pop parabola k while the new one overtakes it no later than it took over (s <= z[k]).
      if (k > 0 && Product(sn) * zd[k] <= Product(zn[k]) * sd) {
        --k;
      } else {
        break;
      }
    }
    ++k;
    v[k] = q;
    h[k] = fq;
    zn[k] = sn;
    zd[k] = sd;
  }
  if (k < 0) return false;
  int j = 0;
  for (int q = 0; q < n; ++q) {
    while (j < k && zn[j + 1] < int64_t(q) * zd[j + 1]) ++j;  // z[j + 1] < q
    const int64_t dq = q - v[j];
    d[q] = dq * dq + f[v[j]];
  }
  return true;
}

// Squared distance (in cells, exact) from every cell to the nearest cell of the other kind: for a
// cell with mask != 0 the nearest cell with mask == 0, and the other way round; +inf when there is
// none.
void binary_distances(const GridGeometry& g, const uint8_t* mask, EdtScratch& s, double* out) {
  constexpr double inf = std::numeric_limits<double>::infinity();
  const int nx = g.nx, ny = g.ny;
  s.col0.resize(g.size());
  s.col1.resize(g.size());
  s.last0.resize(ny);
  s.last1.resize(ny);
  // Pass 1 along x, a whole row of columns at a time (contiguous, vectorises). Distances beyond
  // nx mean "no site in this column"; the sentinels keep them there.
  const int32_t far = 2 * nx + 2;
  int32_t* __restrict l0 = s.last0.data();
  int32_t* __restrict l1 = s.last1.data();
  std::fill(l0, l0 + ny, -far);
  std::fill(l1, l1 + ny, -far);
  for (int i = 0; i < nx; ++i) {  // forward: nearest site at or before row i
    const uint8_t* __restrict m = mask + g.index(i, 0);
    int32_t* __restrict c0 = s.col0.data() + g.index(i, 0);
    int32_t* __restrict c1 = s.col1.data() + g.index(i, 0);
    for (int j = 0; j < ny; ++j) {
      l0[j] = m[j] ? l0[j] : i;
      l1[j] = m[j] ? i : l1[j];
      c0[j] = i - l0[j];
      c1[j] = i - l1[j];
    }
  }
  std::fill(l0, l0 + ny, nx + far);
  std::fill(l1, l1 + ny, nx + far);
  for (int i = nx - 1; i >= 0; --i) {  // backward: nearest site at or after row i
    const uint8_t* __restrict m = mask + g.index(i, 0);
    int32_t* __restrict c0 = s.col0.data() + g.index(i, 0);
    int32_t* __restrict c1 = s.col1.data() + g.index(i, 0);
    for (int j = 0; j < ny; ++j) {
      l0[j] = m[j] ? l0[j] : i;
      l1[j] = m[j] ? i : l1[j];
      c0[j] = std::min(c0[j], l0[j] - i);
      c1[j] = std::min(c1[j], l1[j] - i);
    }
  }
  // Pass 2 along y, row by row.
  s.f.resize(ny);
  s.d.resize(ny);
  s.v.resize(ny);
  s.zn.resize(ny + 1);
  s.h.resize(ny + 1);
  // Breakpoint numerators stay below nx^2 + ny^2 (plus q^2 terms), denominators below 2 ny.
  const double worst = (4.0 * nx * nx + 4.0 * ny * ny) * (2.0 * ny + 2.0);
  const bool narrow = worst < 4e18;
  s.zd.resize(ny + 1);
  for (int pass = 0; pass < 2; ++pass) {
    // Pass 0: distances to mask == 0 cells, kept for mask != 0 cells; pass 1 the other way round.
    const int32_t* col = pass == 0 ? s.col0.data() : s.col1.data();
    const uint8_t keep = pass == 0 ? 1 : 0;
    for (int i = 0; i < nx; ++i) {
      const int32_t* c = col + g.index(i, 0);
      const uint8_t* m = mask + g.index(i, 0);
      double* o = out + g.index(i, 0);
      int64_t* f = s.f.data();
      bool any = false;  // a cell of the kind that keeps this pass's distances
      for (int j = 0; j < ny; ++j) {
        f[j] = c[j] > nx ? kNoSite : int64_t(c[j]) * c[j];
        any |= (m[j] != 0) == (keep != 0);
      }
      if (!any) continue;
      const bool found = narrow ? edt_1d_exact<int64_t>(f, ny, s, s.d.data())
                                : edt_1d_exact<Wide>(f, ny, s, s.d.data());
      for (int j = 0; j < ny; ++j)
        if ((m[j] != 0) == (keep != 0)) o[j] = found ? static_cast<double>(s.d[j]) : inf;
    }
  }
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

// A square (2 r + 1)-cell window's minimum (erode) or "any finite" flag (near) per cell, done as
// two separable passes.
std::vector<float> window_min(const GridGeometry& g, const std::vector<float>& v, int r) {
  std::vector<float> rows(v.size()), out(v.size());
  for (int i = 0; i < g.nx; ++i)
    for (int j = 0; j < g.ny; ++j) {
      float m = std::numeric_limits<float>::infinity();
      for (int a = std::max(0, i - r); a <= std::min(g.nx - 1, i + r); ++a)
        m = std::min(m, v[g.index(a, j)]);
      rows[g.index(i, j)] = m;
    }
  for (int i = 0; i < g.nx; ++i)
    for (int j = 0; j < g.ny; ++j) {
      float m = std::numeric_limits<float>::infinity();
      for (int b = std::max(0, j - r); b <= std::min(g.ny - 1, j + r); ++b)
        m = std::min(m, rows[g.index(i, b)]);
      out[g.index(i, j)] = m;
    }
  return out;
}

}  // namespace

// ---------------------------------------------------------------------------------------------
BSplineField::BSplineField(const GridGeometry& g, const std::vector<float>& values,
                           bool interpolate)
    : geometry_(g),
      inv_resolution_(1.0 / g.resolution),
      gradient_scale_(inv_resolution_ / 12.0),
      stride_(g.ny + kPadLo + kPadHi) {
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

inline const double* BSplineField::locate(double x, double y, double* tx, double* ty) const {
  // Control point i sits at the centre of cell i: u = i there. Clamping u to [-1, n] keeps the
  // field C2 (the padded control points are equal, so all derivatives vanish at the clamp).
  double u = (x - geometry_.origin.x()) * inv_resolution_ - 0.5;
  double v = (y - geometry_.origin.y()) * inv_resolution_ - 0.5;
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
  // The planner's hot path: the basis is taken times 6 and its derivative times 2, and the
  // constant factors are applied once at the end, which saves the dozen divisions by 6 of basis()
  // (the result differs from sample()'s in the last bits only).
  double tx, ty;
  const double* c = locate(x, y, &tx, &ty);
  const double sx = 1.0 - tx, tx2 = tx * tx, tx3 = tx2 * tx;
  const double sy = 1.0 - ty, ty2 = ty * ty, ty3 = ty2 * ty;
  const double bx[4] = {sx * sx * sx, 3.0 * tx3 - 6.0 * tx2 + 4.0,
                        -3.0 * tx3 + 3.0 * tx2 + 3.0 * tx + 1.0, tx3};
  const double by[4] = {sy * sy * sy, 3.0 * ty3 - 6.0 * ty2 + 4.0,
                        -3.0 * ty3 + 3.0 * ty2 + 3.0 * ty + 1.0, ty3};
  const double dx[4] = {-sx * sx, 3.0 * tx2 - 4.0 * tx, -3.0 * tx2 + 2.0 * tx + 1.0, tx2};
  const double dy[4] = {-sy * sy, 3.0 * ty2 - 4.0 * ty, -3.0 * ty2 + 2.0 * ty + 1.0, ty2};
  double h = 0, gx = 0, gy = 0;
  for (int a = 0; a < 4; ++a, c += stride_) {
    const double rb = by[0] * c[0] + by[1] * c[1] + by[2] * c[2] + by[3] * c[3];
    const double rd = dy[0] * c[0] + dy[1] * c[1] + dy[2] * c[2] + dy[3] * c[3];
    h += bx[a] * rb;
    gx += dx[a] * rb;
    gy += bx[a] * rd;
  }
  *gradient = Eigen::Vector2d(gx * gradient_scale_, gy * gradient_scale_);
  return h * (1.0 / 36.0);
}

// sample()'s arithmetic in sample()'s order, less the second derivatives: the same bits.
double BSplineField::sample_value_gradient(double x, double y, Eigen::Vector2d* gradient) const {
  double tx, ty, bx[4], by[4], dx[4], dy[4];
  const double* c = locate(x, y, &tx, &ty);
  basis(tx, bx);
  basis(ty, by);
  basis_d1(tx, dx);
  basis_d1(ty, dy);
  double h = 0, gx = 0, gy = 0;
  for (int a = 0; a < 4; ++a, c += stride_) {
    double r0 = 0, r1 = 0;
    for (int b = 0; b < 4; ++b) {
      r0 += by[b] * c[b];
      r1 += dy[b] * c[b];
    }
    h += bx[a] * r0;
    gx += dx[a] * r0;
    gy += bx[a] * r1;
  }
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

// One disk row's contribution to a row of cells (a separate function so the compiler sees
// distinct, non-aliasing arrays and vectorises it).
void accumulate_disk_row(const double* __restrict za, const double* __restrict zb,
                         const double* __restrict jza, const double* __restrict jzb,
                         const double* __restrict jd, double ddi, int n, double* __restrict sz,
                         double* __restrict sdiz, double* __restrict sdjz) {
  for (int t = 0; t < n; ++t) {
    const double z = zb[t] - za[t];
    sz[t] += z;
    sdiz[t] += ddi * z;
    sdjz[t] += (jzb[t] - jza[t]) - jd[t] * z;
  }
}

// Observed disk and raw step: 1 where the disk holds no unobserved cell and hi - lo <= max_step.
void test_step(const int* __restrict un, const float* __restrict lo, const float* __restrict hi,
               double max_step, int n, int32_t* __restrict ok) {
  for (int t = 0; t < n; ++t) {
    const float step = hi[t] - lo[t];
    ok[t] = (un[t] == 0) & (step <= max_step);
  }
}

// Plane fit of a disk: the least-squares plane z = mean + a di + b dj (the offsets are symmetric,
// so the three fits decouple), its residual sum of squares and its slope.
struct FitLimits {
  double sxx, syy;
  int ncells;
  double max_rss_n, max_slope_eff;
};

void test_fit(const double* __restrict sz, const double* __restrict sz2,
              const double* __restrict sdiz, const double* __restrict sdjz, const FitLimits& l,
              int n, double* __restrict rss, double* __restrict slope2, double* __restrict ok) {
  const double sxx = l.sxx, syy = l.syy;
  const int ncells = l.ncells;
  if (sxx > 0 && syy > 0) {  // every disk wider than one cell: no branch in the loop
    for (int t = 0; t < n; ++t) {
      const double a = sdiz[t] / sxx;
      const double b = sdjz[t] / syy;
      const double mean = sz[t] / ncells;
      rss[t] = sz2[t] - ncells * mean * mean - a * sdiz[t] - b * sdjz[t];
      slope2[t] = a * a + b * b;
    }
  } else {
    for (int t = 0; t < n; ++t) {
      const double a = sxx > 0 ? sdiz[t] / sxx : 0.0;
      const double b = syy > 0 ? sdjz[t] / syy : 0.0;
      const double mean = sz[t] / ncells;
      rss[t] = sz2[t] - ncells * mean * mean - a * sdiz[t] - b * sdjz[t];
      slope2[t] = a * a + b * b;
    }
  }
  const double max_rss = l.max_rss_n * ncells, max_slope2 = l.max_slope_eff * l.max_slope_eff;
  for (int t = 0; t < n; ++t) ok[t] = rss[t] <= max_rss ? 1.0 : 0.0;
  for (int t = 0; t < n; ++t) ok[t] = slope2[t] <= max_slope2 ? ok[t] : 0.0;
}

// One grid row's radius-independent data, shared by every radius and every cell row whose disks
// reach it: prefix sums along y (z, z^2, j z, unobserved cells; one extra leading slot) and the
// sliding min of cell min / max of cell max along y for every half-width 0..W.
struct RowData {
  std::vector<double> pz, pz2, pjz;
  std::vector<int> pun;
  std::vector<float> rmin, rmax;  // (W + 1) x ny, half-width major
  std::vector<double> psz, pjsz;  // prefix sums of the smoothed surface and j times it (scanned)
};

void fill_row(const HeightGrid& grid, int i, int W, RowData& r) {
  const GridGeometry& g = grid.geometry;
  const int ny = g.ny;
  r.pz.resize(ny + 1);
  r.pz2.resize(ny + 1);
  r.pjz.resize(ny + 1);
  r.pun.resize(ny + 1);
  double a = 0, b = 0, c = 0;
  int u = 0;
  r.pz[0] = r.pz2[0] = r.pjz[0] = 0;
  r.pun[0] = 0;
  const size_t row = g.index(i, 0);
  for (int j = 0; j < ny; ++j) {
    const double z = grid.elevation[row + j];
    a += z;
    b += z * z;
    c += j * z;
    u += grid.observed[row + j] ? 0 : 1;
    r.pz[j + 1] = a;
    r.pz2[j + 1] = b;
    r.pjz[j + 1] = c;
    r.pun[j + 1] = u;
  }
  r.rmin.resize(static_cast<size_t>(W + 1) * ny);
  r.rmax.resize(static_cast<size_t>(W + 1) * ny);
  const float* cmin = grid.min.data() + row;
  const float* cmax = grid.max.data() + row;
  std::copy(cmin, cmin + ny, r.rmin.begin());
  std::copy(cmax, cmax + ny, r.rmax.begin());
  for (int k = 1; k <= W; ++k) {
    const float* pmn = r.rmin.data() + static_cast<size_t>(k - 1) * ny;
    const float* pmx = r.rmax.data() + static_cast<size_t>(k - 1) * ny;
    float* mn = r.rmin.data() + static_cast<size_t>(k) * ny;
    float* mx = r.rmax.data() + static_cast<size_t>(k) * ny;
    const auto edge = [&](int j) {
      float lo = pmn[j], hi = pmx[j];
      if (j >= k) {
        lo = std::min(lo, cmin[j - k]);
        hi = std::max(hi, cmax[j - k]);
      }
      if (j + k < ny) {
        lo = std::min(lo, cmin[j + k]);
        hi = std::max(hi, cmax[j + k]);
      }
      mn[j] = lo;
      mx[j] = hi;
    };
    // Cells [k, ny - k) have both neighbours: the same min/max in the same order, without the
    // branches, so the loop vectorises.
    const int a = std::min(k, ny), b = std::max(a, ny - k);
    for (int j = 0; j < a; ++j) edge(j);
    for (int j = a; j < b; ++j) {
      mn[j] = std::min(std::min(pmn[j], cmin[j - k]), cmin[j + k]);
      mx[j] = std::max(std::max(pmx[j], cmax[j - k]), cmax[j + k]);
    }
    for (int j = b; j < ny; ++j) edge(j);
  }
  if (grid.surface.size() == g.size()) {
    r.psz.resize(ny + 1);
    r.pjsz.resize(ny + 1);
    double s = 0, js = 0;
    r.psz[0] = r.pjsz[0] = 0;
    for (int j = 0; j < ny; ++j) {
      const double z = grid.surface[row + j];
      s += z;
      js += j * z;
      r.psz[j + 1] = s;
      r.pjsz[j + 1] = js;
    }
  }
}

// One radius: the disk's rows and the thresholds.
struct DiskSpec {
  int R = 0, W = 0;
  std::vector<int> w;  // half-width of disk row di = -R..R (index di + R)
  FitLimits fit{};
  double max_step = 0;
  bool field_slope = false;    // slope tests on the smoothed field (scanned grids)
  double max_field_slope = 0;  // tan
};

// The slope of the planner's field (the B-spline approximant of grid.surface, borders clamped as
// BSplineField pads them) at every cell centre: there the basis is (1, 4, 1) / 6 and its
// derivative (-1, 0, 1) / 2 along each axis. (Equal to BSplineField's up to rounding.)
std::vector<float> centre_slopes(const HeightGrid& grid) {
  const GridGeometry& g = grid.geometry;
  const std::vector<float>& c = grid.surface;
  std::vector<float> slope(g.size());
  const auto at = [&](int i, int j) {
    return double(c[g.index(std::clamp(i, 0, g.nx - 1), std::clamp(j, 0, g.ny - 1))]);
  };
  const double inv = 1.0 / (12.0 * g.resolution);  // (1, 4, 1) / 6 times 1 / (2 res)
  for (int i = 0; i < g.nx; ++i)
    for (int j = 0; j < g.ny; ++j) {
      double gx = 0, gy = 0;
      for (int b = -1; b <= 1; ++b) {
        const double w = b == 0 ? 4.0 : 1.0;
        gx += w * (at(i + 1, j + b) - at(i - 1, j + b));
        gy += w * (at(i + b, j + 1) - at(i + b, j - 1));
      }
      slope[g.index(i, j)] = static_cast<float>(std::hypot(gx * inv, gy * inv));
    }
  return slope;
}

DiskSpec disk_spec(const HeightGrid& grid, double radius, double mean_support,
                   const SafetyOptions& o) {
  const double res = grid.geometry.resolution;
  DiskSpec d;
  // Disk rows: for a row offset di, the cells j - w[di] .. j + w[di]. A foot of any size reaches
  // at least the 8 neighbours: on cells wider than the foot (a 2 cm foot on an 8 cm OctoMap) the
  // disk would otherwise be the cell alone, and a step, a partition's one-cell crest or a wall top
  // would pass as flat. (Where r + res/2 already spans the neighbours, 2 cm cells from a 2 cm foot
  // up, the disk is unchanged.)
  double reach = radius / res + 0.5;
  if (radius > 0) reach = std::max(reach, std::sqrt(2.0));
  reach += 1e-9;
  const int R = static_cast<int>(std::floor(reach));
  d.R = R;
  d.w.resize(2 * R + 1);
  double sxx = 0, syy = 0;
  int ncells = 0;
  for (int di = -R; di <= R; ++di) {
    const int wi = static_cast<int>(std::floor(std::sqrt(std::max(0.0, reach * reach - di * di))));
    d.w[di + R] = wi;
    sxx += double(di) * di * (2 * wi + 1);
    syy += wi * (wi + 1.0) * (2 * wi + 1) / 3.0;
    ncells += 2 * wi + 1;
  }
  d.W = *std::max_element(d.w.begin(), d.w.end());
  const double max_slope_cells = o.max_slope * res;  // slope per cell
  // Sensor noise widens the raw step (a disk's extreme points lie a few sigma either side of the
  // surface) and the fit residual; allow for it so a noisy plane is not called rough.
  const double sigma = std::max(0.0, grid.noise_sigma);
  d.max_step = o.max_step + o.step_noise_factor * sigma;
  const double max_rms = o.max_rms + o.rms_noise_factor * sigma;
  const double max_rss_n = max_rms * max_rms;
  // The fitted slope of a small disk is noisy: each elevation is a median of `support` points with
  // standard error about 1.25 sigma / sqrt(support), so the slope's standard error per axis is that
  // over sqrt(sum of squared offsets). Allow slope_noise_factor of those.
  const double sigma_median = 1.2533 * sigma / std::sqrt(mean_support);
  const double slope_noise = sxx > 0 ? sigma_median / std::sqrt(sxx) : 0.0;  // per cell
  double max_slope_eff = max_slope_cells + o.slope_noise_factor * slope_noise;
  if (grid.surface.size() == grid.geometry.size()) {
    // Scanned grids: the slope that counts is the one the planner sees, that of the smoothed
    // field: the plane fitted to it over the foot disk (the foot's contact plane) and its gradient
    // at the cell centre, both without a noise allowance (the smoothing took the noise out, and
    // what is left the planner sees too). The raw elevations' plane fit still judges roughness.
    max_slope_eff = std::numeric_limits<double>::infinity();
    d.field_slope = true;
    d.max_field_slope = o.max_slope;
  }
  d.fit = FitLimits{sxx, syy, ncells, max_rss_n, max_slope_eff};
  return d;
}

// Per-row accumulators and distance-transform buffers, reused across radii.
struct SafetyScratch {
  std::vector<double> sz, sz2, sdiz, sdjz;
  std::vector<int> un;
  std::vector<float> lo, hi;
  std::vector<double> jd;
  std::vector<int32_t> ok_a;
  std::vector<double> ok_b, rss, slope2;
  std::vector<double> ssz, ssdiz, ssdjz;  // disk sums of the smoothed surface
  const float* centre_slope = nullptr;    // the field's slope at every cell centre
  std::vector<double> dist2;              // squared distance to the nearest cell of the other kind
  EdtScratch edt;
};

// The mask of cell row i for one radius. rows(r) gives the data of grid row r.
template <class Rows>
void mask_row(const HeightGrid& grid, int i, const DiskSpec& d, const Rows& rows, SafetyScratch& sc,
              SafetyLayer& layer) {
  const GridGeometry& g = grid.geometry;
  const int ny = g.ny, R = d.R, W = d.W;
  // Disk sums for the row's cells: they accumulate the disk rows di = -R..R in that order, exactly
  // the additions a per-cell loop over the disk makes (so the sums are bit for bit those), but with
  // the cells innermost the loops run over contiguous arrays and vectorise.
  const int j0 = W, j1 = ny - W;  // cells [j0, j1) keep the disk inside the grid along y
  if (j0 >= j1) return;
  const int n = j1 - j0;
  double* __restrict SZ = sc.sz.data() + j0;
  double* __restrict SZ2 = sc.sz2.data() + j0;
  double* __restrict SDIZ = sc.sdiz.data() + j0;
  double* __restrict SDJZ = sc.sdjz.data() + j0;
  int* __restrict UN = sc.un.data() + j0;
  float* __restrict LO = sc.lo.data() + j0;
  float* __restrict HI = sc.hi.data() + j0;
  std::fill(SZ, SZ + n, 0.0);
  std::fill(SZ2, SZ2 + n, 0.0);
  std::fill(SDIZ, SDIZ + n, 0.0);
  std::fill(SDJZ, SDJZ + n, 0.0);
  std::fill(UN, UN + n, 0);
  std::fill(LO, LO + n, std::numeric_limits<float>::infinity());
  std::fill(HI, HI + n, -std::numeric_limits<float>::infinity());
  for (int di = -R; di <= R; ++di) {
    const int wi = d.w[di + R];
    const RowData& r = rows(i + di);
    // Cell j uses the prefix-sum slots [j - wi, j + wi + 1) of its row.
    const int a = j0 - wi, b = j0 + wi + 1;
    accumulate_disk_row(r.pz.data() + a, r.pz.data() + b, r.pjz.data() + a, r.pjz.data() + b,
                        sc.jd.data() + j0, di, n, SZ, SDIZ, SDJZ);
    const double* __restrict z2a = r.pz2.data() + a;
    const double* __restrict z2b = r.pz2.data() + b;
    for (int t = 0; t < n; ++t) SZ2[t] += z2b[t] - z2a[t];
    const int* __restrict ua = r.pun.data() + a;
    const int* __restrict ub = r.pun.data() + b;
    for (int t = 0; t < n; ++t) UN[t] += ub[t] - ua[t];
    const float* __restrict mn = r.rmin.data() + static_cast<size_t>(wi) * ny + j0;
    const float* __restrict mx = r.rmax.data() + static_cast<size_t>(wi) * ny + j0;
    for (int t = 0; t < n; ++t) {
      LO[t] = std::min(LO[t], mn[t]);
      HI[t] = std::max(HI[t], mx[t]);
    }
  }
  // The tests, branch free over the row (so they vectorise): the same expressions as a per-cell
  // early-exit chain, evaluated for every cell.
  test_step(UN, LO, HI, d.max_step, n, sc.ok_a.data());
  test_fit(SZ, SZ2, SDIZ, SDJZ, d.fit, n, sc.rss.data(), sc.slope2.data(), sc.ok_b.data());
  if (d.field_slope) {
    double* __restrict S = sc.ssz.data() + j0;
    double* __restrict SDI = sc.ssdiz.data() + j0;
    double* __restrict SDJ = sc.ssdjz.data() + j0;
    std::fill(S, S + n, 0.0);
    std::fill(SDI, SDI + n, 0.0);
    std::fill(SDJ, SDJ + n, 0.0);
    for (int di = -R; di <= R; ++di) {
      const int wi = d.w[di + R];
      const RowData& r = rows(i + di);
      const int a = j0 - wi, b = j0 + wi + 1;
      accumulate_disk_row(r.psz.data() + a, r.psz.data() + b, r.pjsz.data() + a, r.pjsz.data() + b,
                          sc.jd.data() + j0, di, n, S, SDI, SDJ);
    }
    const double sxx = d.fit.sxx, syy = d.fit.syy;
    const double max_plane2 =
        (d.max_field_slope * g.resolution) * (d.max_field_slope * g.resolution);
    const float* centre = sc.centre_slope + g.index(i, j0);
    for (int t = 0; t < n; ++t) {
      const double a = sxx > 0 ? SDI[t] / sxx : 0.0;  // per cell
      const double b = syy > 0 ? SDJ[t] / syy : 0.0;
      if (!(a * a + b * b <= max_plane2) || !(centre[t] <= d.max_field_slope)) sc.ok_a[t] = 0;
    }
  }
  uint8_t* out = layer.safe.data() + g.index(i, j0);
  size_t count = 0;
  for (int t = 0; t < n; ++t) {
    const uint8_t ok = sc.ok_a[t] != 0 && sc.ok_b[t] != 0.0;
    out[t] = ok;
    count += ok;
  }
  layer.safe_cells += count;
}

// The signed margin of a finished mask: distance transforms from the unsafe cells (for safe
// cells) and from the safe cells (for unsafe ones), minus half a cell.
void fill_margin(const GridGeometry& g, SafetyScratch& sc, SafetyLayer& layer) {
  const double res = g.resolution;
  layer.margin.resize(g.size());
  sc.dist2.resize(g.size());
  binary_distances(g, layer.safe.data(), sc.edt, sc.dist2.data());
  const double* dist2 = sc.dist2.data();
  // With no unsafe (or no safe) cell at all, distances are infinite: cap at the grid diagonal.
  const double cap = std::hypot(g.nx, g.ny) * res;
  for (size_t k = 0; k < g.size(); ++k) {
    const double d = std::isfinite(dist2[k]) ? std::sqrt(dist2[k]) * res : cap;
    layer.margin[k] = static_cast<float>(layer.safe[k] ? d - 0.5 * res : -(d - 0.5 * res));
  }
}

// The masks and margins for validated radii.
inline std::vector<SafetyLayer> safety_layers(const HeightGrid& grid,
                                              const std::vector<double>& radii,
                                              const SafetyOptions& o, const GroundLevels& levels) {
  const GridGeometry& g = grid.geometry;
  const int nx = g.nx, ny = g.ny;
  double support_sum = 0;
  size_t support_cells = 0;
  for (size_t k = 0; k < g.size(); ++k)
    if (grid.observed[k]) {
      support_sum += grid.support[k];
      ++support_cells;
    }
  const double mean_support = support_cells ? std::max(1.0, support_sum / support_cells) : 1.0;
  std::vector<DiskSpec> disks;
  int W = 0;
  for (double r : radii) {
    disks.push_back(disk_spec(grid, r, mean_support, o));
    W = std::max(W, disks.back().R);
  }
  std::vector<SafetyLayer> layers(radii.size());
  for (size_t l = 0; l < radii.size(); ++l) {
    layers[l].radius = radii[l];
    layers[l].safe.assign(g.size(), 0);
  }
  // Cell rows in order; the grid rows their disks reach (i - W .. i + W) live in a ring, each
  // computed once and used by every radius while it is in cache.
  const int ring = 2 * W + 1;
  std::vector<RowData> rows(static_cast<size_t>(std::min(ring, nx)));
  const auto row_at = [&](int r) -> const RowData& { return rows[r % rows.size()]; };
  SafetyScratch sc;
  for (auto* v : {&sc.sz, &sc.sz2, &sc.sdiz, &sc.sdjz, &sc.ok_b, &sc.rss, &sc.slope2, &sc.jd})
    v->resize(ny);
  sc.un.resize(ny);
  sc.lo.resize(ny);
  sc.hi.resize(ny);
  sc.ok_a.resize(ny);
  for (int j = 0; j < ny; ++j) sc.jd[j] = j;  // j as a double (exact), loaded, not converted
  std::vector<float> slope;
  if (grid.surface.size() == g.size()) {
    slope = centre_slopes(grid);
    sc.centre_slope = slope.data();
    for (auto* v : {&sc.ssz, &sc.ssdiz, &sc.ssdjz}) v->resize(ny);
  }
  int filled = 0;  // rows [0, filled) have been computed
  for (int i = 0; i < nx; ++i) {
    for (; filled < nx && filled <= i + W; ++filled)
      fill_row(grid, filled, W, rows[filled % rows.size()]);
    for (size_t l = 0; l < disks.size(); ++l) {
      const int R = disks[l].R;
      if (i - R < 0 || i + R >= nx) continue;  // disk leaves the grid: not fully observed
      mask_row(grid, i, disks[l], row_at, sc, layers[l]);
    }
  }
  // Unreachable levels are no ground to walk on: never safe, out of the safe fraction.
  size_t observed = 0;
  for (size_t k = 0; k < g.size(); ++k) observed += grid.observed[k] != 0;
  for (auto& l : layers) {
    if (levels.unreachable_cells > 0)
      for (size_t k = 0; k < g.size(); ++k)
        if (levels.unreachable[k] && l.safe[k]) {
          l.safe[k] = 0;
          --l.safe_cells;
        }
    fill_margin(g, sc, l);
    l.observed_cells = observed - levels.unreachable_cells;
    l.unreachable_cells = levels.unreachable_cells;
  }
  return layers;
}

// The row loops are element-wise over cells, so on CPUs with AVX2 a copy of safety_layers compiled
// for it (everything inlined: flatten) runs them twice as wide, with the same operations per
// element in the same order: bit-identical results (no FMA, which would round differently).
// Dispatched by hand: GCC 12's target_clones lets exceptions thrown below it terminate.
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__)
#define TERRASTRIDE_SAFETY_AVX2 1
__attribute__((target("avx2"), flatten)) std::vector<SafetyLayer> safety_layers_avx2(
    const HeightGrid& grid, const std::vector<double>& radii, const SafetyOptions& o,
    const GroundLevels& levels) {
  return safety_layers(grid, radii, o, levels);
}
#endif
__attribute__((flatten)) std::vector<SafetyLayer> safety_layers_portable(
    const HeightGrid& grid, const std::vector<double>& radii, const SafetyOptions& o,
    const GroundLevels& levels) {
  return safety_layers(grid, radii, o, levels);
}

}  // namespace

std::vector<SafetyLayer> compute_safety(const HeightGrid& grid, const std::vector<double>& radii,
                                        const SafetyOptions& o) {
  if (!(o.max_climb > 0))
    throw InputError("safety options: max_climb must be positive (infinity: every level reachable)");
  return compute_safety(grid, radii, o,
                        std::isfinite(o.max_climb) ? ground_levels(grid, o.max_climb)
                                                   : GroundLevels{});
}

std::vector<SafetyLayer> compute_safety(const HeightGrid& grid, const std::vector<double>& radii,
                                        const SafetyOptions& o, const GroundLevels& levels) {
  for (double r : radii) {
    if (!std::isfinite(r) || r < 0 || r > 1.0)
      throw InputError("foot radius " + std::to_string(r) + " m is outside [0, 1] m");
  }
#ifdef TERRASTRIDE_SAFETY_AVX2
  static const bool avx2 = [] {
    __builtin_cpu_init();  // a no-op after start-up; needed if this runs from a static initialiser
    return __builtin_cpu_supports("avx2") != 0;
  }();
  if (avx2) return safety_layers_avx2(grid, radii, o, levels);
#endif
  return safety_layers_portable(grid, radii, o, levels);
}

SafetyLayer compute_safety(const HeightGrid& grid, double radius, const SafetyOptions& o) {
  return std::move(compute_safety(grid, std::vector<double>{radius}, o).front());
}

// ---------------------------------------------------------------------------------------------
TerrainMap::TerrainMap(HeightGrid grid, const std::vector<double>& radii, SafetyOptions options)
    : grid_(std::move(grid)),
      options_(options),
      height_(grid_.geometry,
              grid_.surface.size() == grid_.geometry.size() ? grid_.surface : grid_.elevation) {
  if (!(options_.max_step > 0) || !(options_.max_rms > 0) || !(options_.max_slope > 0))
    throw InputError("safety options: max_step, max_rms and max_slope must be positive");
  if (!(options_.max_climb > 0))
    throw InputError("safety options: max_climb must be positive (infinity: every level reachable)");
  if (std::isfinite(options_.max_climb)) levels_ = ground_levels(grid_, options_.max_climb);
  std::vector<double> todo;
  for (double r : radii)
    if (std::none_of(todo.begin(), todo.end(), [r](double t) { return std::abs(t - r) < 1e-9; }))
      todo.push_back(r);
  for (auto& l : compute_safety(grid_, todo, options_, levels_)) {
    l.margin_field = BSplineField(grid_.geometry, l.margin, /*interpolate=*/true);
    layers_.push_back(std::move(l));
  }
  build_overhead_field();
}

void TerrainMap::build_overhead_field() {
  const GridGeometry& g = grid_.geometry;
  if (grid_.overhead.empty()) return;
  if (grid_.overhead.size() != g.size())
    throw InputError("terrain: the overhead layer has " + std::to_string(grid_.overhead.size()) +
                     " cells, the grid " + std::to_string(g.size()));
  std::vector<float> capped(g.size());
  bool any = false;
  for (size_t k = 0; k < g.size(); ++k) {
    const float o = grid_.overhead[k];
    if (std::isnan(o)) throw InputError("terrain: the overhead layer holds NaN");
    any = any || std::isfinite(o);
    capped[k] = std::min(o, grid_.elevation[k] + static_cast<float>(kOverheadCap));
  }
  if (!any) return;
  overhead_field_ = BSplineField(g, window_min(g, capped, 2));
  std::vector<float> finite(g.size());
  for (size_t k = 0; k < g.size(); ++k)
    finite[k] = std::isfinite(grid_.overhead[k]) ? 0.0f : 1.0f;
  const std::vector<float> nearest = window_min(g, finite, 4);
  near_overhead_.resize(g.size());
  for (size_t k = 0; k < g.size(); ++k) near_overhead_[k] = nearest[k] == 0.0f;
}

double TerrainMap::overhead_and_gradient(double x, double y, Eigen::Vector2d* gradient) const {
  if (near_overhead_.empty()) return HeightField::overhead_and_gradient(x, y, gradient);
  // Outside the grid the field continues its border cells, as the height field does.
  const GridGeometry& g = grid_.geometry;
  const int i = std::clamp(static_cast<int>(std::floor((x - g.origin.x()) / g.resolution)), 0,
                           g.nx - 1);
  const int j = std::clamp(static_cast<int>(std::floor((y - g.origin.y()) / g.resolution)), 0,
                           g.ny - 1);
  if (!near_overhead_[g.index(i, j)]) return HeightField::overhead_and_gradient(x, y, gradient);
  return overhead_field_.value_gradient(x, y, gradient);
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
  SafetyLayer l = std::move(compute_safety(grid_, {r}, options_, levels_).front());
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

PointAnswer TerrainMap::answer(double x, double y, double foot_radius) const {
  PointAnswer a;
  a.ground = sample(x, y);
  a.field_margin = safety_margin(x, y, foot_radius).margin;
  const int k = cell_index(x, y);
  if (k < 0) {
    a.margin = -std::numeric_limits<double>::infinity();
    a.unsafe_because = "outside the map";
    return a;
  }
  const SafetyLayer& l = layer(foot_radius);
  a.observed = grid_.observed[k] != 0;
  a.safe = l.safe[k] != 0;
  a.margin = l.margin[k];
  if (grid_.overhead.size() == grid_.geometry.size()) a.overhead = grid_.overhead[k];
  a.overhang_only = !a.observed && grid_.support[k] == 0 && std::isfinite(a.overhead);
  a.unreachable = !levels_.unreachable.empty() && levels_.unreachable[k];
  if (a.observed && std::isfinite(a.overhead)) a.free_height = a.overhead - grid_.elevation[k];
  std::ostringstream why;
  if (a.overhang_only) {
    why << "no walkable ground: only an overhang was seen here (a ceiling, a table top seen from "
           "beneath; its underside at z "
        << a.overhead << " m), not the ground beneath it";
  } else if (!a.observed) {
    why << "not observed: the map holds no measured ground here";
  } else if (a.unreachable) {
    why << "an unreachable level: no step of at most " << options_.max_climb
        << " m joins this surface (z " << grid_.elevation[k]
        << " m) to the floor's level (a cupboard top, a wall's crest?)";
  } else if (!a.safe) {
    why << "not a safe foothold for the " << foot_radius
        << " m foot: an edge, a step, a slope or roughness within reach (margin " << a.margin
        << " m)";
  }
  a.unsafe_because = why.str();
  return a;
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
  const bool scanned = g.surface.size() == geo.size();
  if (scanned) put_f("surface", g.surface);
  if (g.overhead.size() == geo.size()) put_f("overhead", g.overhead);
  nlohmann::json safety = nlohmann::json::array();
  for (double r : map.radii()) {
    const SafetyLayer& l = map.layer(r);
    put_u8("safe_" + radius_tag(r), l.safe);
    put_f("margin_" + radius_tag(r), l.margin);
    safety.push_back({{"radius", r},
                      {"safe_cells", l.safe_cells},
                      {"observed_cells", l.observed_cells},
                      {"safe_fraction", l.safe_fraction()},
                      {"safe", "layers/safe_" + radius_tag(r) + ".npy"},
                      {"margin", "layers/margin_" + radius_tag(r) + ".npy"}});
  }
  const SafetyOptions& o = map.safety_options();
  nlohmann::json grid = {{"origin", {geo.origin.x(), geo.origin.y()}},
                         {"resolution", geo.resolution},
                         {"nx", geo.nx},
                         {"ny", geo.ny},
                         {"noise_sigma", g.noise_sigma},
                         {"cluster_gap", g.cluster_gap},
                         {"layout",
                          "layers are nx x ny arrays; element [i][j] is the cell whose min corner "
                          "is origin + resolution * (i, j)"}};
  if (scanned) {
    grid["noise"] = {{"estimated", g.noise.estimated}, {"sigma", g.noise.sigma},
                     {"bins", g.noise.bins},           {"rejected_bins", g.noise.rejected_bins},
                     {"bin_size", g.noise.bin_size},   {"point_spacing", g.noise.point_spacing}};
    if (!g.noise.note.empty()) grid["noise"]["note"] = g.noise.note;
    grid["smoothing_length"] = g.smoothing_length;
    grid["gap_radius"] = g.gap_radius;
    grid["field"] =
        "the planner's height field is the C2 B-spline approximant of layers/surface (the support "
        "elevation smoothed over smoothing_length, steps kept)";
  }
  nlohmann::json meta = {
      {"format", "terrastride-terrain"},
      {"version", 1},
      {"grid", grid},
      {"layers", files},
      {"safety",
       {{"max_step", o.max_step},
        {"step_noise_factor", o.step_noise_factor},
        {"rms_noise_factor", o.rms_noise_factor},
        {"slope_noise_factor", o.slope_noise_factor},
        {"max_climb", o.max_climb},
        {"max_rms", o.max_rms},
        {"max_slope", o.max_slope},
        {"safe_fraction_definition",
         "safe cells / walkable observed cells (measured or interpolated, on the floor's level): "
         "hole-filled, bridged and uncertain cells, and cells whose only surface is an overhang, "
         "are not observed; observed cells on levels no step of at most max_climb joins to the "
         "floor's are unreachable (statistics.unreachable_cells)"},
        {"radii", safety}}},
      {"statistics",
       {{"points_in_grid", g.points_in_grid},
        {"cells", geo.size()},
        {"observed_cells", g.observed_cells},
        {"filled_cells", g.filled_cells},
        {"bridged_cells", g.bridged_cells},
        {"interpolated_cells", g.interpolated_cells},
        {"see_through_cells", g.see_through_cells},
        {"uncertain_cells", g.uncertain_cells},
        {"overhang_cells", g.overhang_cells},
        {"overhang_cells_over_unobserved_ground", g.overhang_unobserved_cells},
        {"unreachable_cells", map.levels().unreachable_cells},
        {"unreachable_levels", map.levels().unreachable_levels}}}};
  if (!g.notes.empty()) meta["notes"] = g.notes;
  return meta;
}

namespace {

// A count in terrain.json: a whole number in [0, max]. get<int>() or get<size_t>() of a number
// written as 1e300 or -1.5 would be an undefined conversion; `fallback` when the key is absent.
size_t count_field(const nlohmann::json& parent, const char* key, size_t max,
                   const std::string& where, std::optional<size_t> fallback = std::nullopt) {
  if (fallback && !parent.contains(key)) return *fallback;
  const nlohmann::json& v = parent.at(key);
  const bool whole = v.is_number_unsigned() ||
                     (v.is_number_integer() && v.get<std::int64_t>() >= 0);
  if (!whole || v.get<std::uint64_t>() > max) {
    const std::string shown = v.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
    throw InputError(where + ": " + key + " is " + shown + ", not a whole number in [0, " +
                     std::to_string(max) + "]");
  }
  return static_cast<size_t>(v.get<std::uint64_t>());
}

// A layer's value as the grid's element type T, or why it cannot be one: floats hold finite
// values within float's range (the overhead layer also +infinity: no overhang), counts whole
// numbers within T's range (a cast of anything else is undefined).
template <class T>
const char* layer_value_problem(double v, bool allow_infinity) {
  if (std::is_floating_point_v<T>) {
    if (allow_infinity && v == std::numeric_limits<double>::infinity()) return nullptr;
    if (!std::isfinite(v)) return "non-finite value in a layer";
    return std::abs(v) <= std::numeric_limits<T>::max() ? nullptr
                                                        : "value beyond a 32-bit float in a layer";
  }
  return v >= 0 && v <= static_cast<double>(std::numeric_limits<T>::max()) && v == std::floor(v)
             ? nullptr
             : "a count layer holds a value that is not a whole number in its range";
}

}  // namespace

std::unique_ptr<TerrainMap> load_terrain_dir(const std::string& dir) {
  namespace fs = std::filesystem;
  const fs::path meta_path = fs::path(dir) / "terrain.json";
  if (!fs::is_directory(dir)) throw InputError(dir + ": not a directory (expected a terrain map)");
  std::ifstream in(meta_path);
  if (!in) throw InputError(meta_path.string() + ": missing or unreadable");
  nlohmann::json meta;
  try {
    meta = perception::parse_json_input(in);
  } catch (const std::exception& e) {
    throw InputError(meta_path.string() + ": not valid JSON (" + e.what() + ")");
  }
  HeightGrid grid;
  std::vector<double> radii;
  SafetyOptions opts;
  bool has_surface = false;  // maps of earlier versions have none: the field is the elevation
  bool has_overhead = false;  // maps without an overhang have none
  try {
    if (meta.at("format").get<std::string>() != "terrastride-terrain")
      throw InputError(meta_path.string() + ": not a terrastride terrain (format field)");
    const auto& gj = meta.at("grid");
    GridGeometry& geo = grid.geometry;
    geo.origin =
        Eigen::Vector2d(gj.at("origin").at(0).get<double>(), gj.at("origin").at(1).get<double>());
    geo.resolution = gj.at("resolution").get<double>();
    // make_geometry's bound on either side; the layers' shapes must match, so the file sizes
    // bound the product.
    geo.nx = static_cast<int>(count_field(gj, "nx", 10'000'000, meta_path.string() + ": grid"));
    geo.ny = static_cast<int>(count_field(gj, "ny", 10'000'000, meta_path.string() + ": grid"));
    grid.noise_sigma = gj.value("noise_sigma", 0.0);
    grid.cluster_gap = gj.value("cluster_gap", 0.0);
    grid.smoothing_length = gj.value("smoothing_length", 0.0);
    grid.gap_radius = gj.value("gap_radius", 0.0);
    if (gj.contains("noise")) {
      const auto& nj = gj.at("noise");
      grid.noise.estimated = nj.value("estimated", false);
      grid.noise.sigma = nj.value("sigma", 0.0);
      const std::string where = meta_path.string() + ": grid.noise";
      const size_t any = std::numeric_limits<uint32_t>::max();
      grid.noise.bins = count_field(nj, "bins", any, where, 0);
      grid.noise.rejected_bins = count_field(nj, "rejected_bins", any, where, 0);
      grid.noise.bin_size = nj.value("bin_size", 0.0);
      grid.noise.point_spacing = nj.value("point_spacing", 0.0);
      grid.noise.note = nj.value("note", std::string());
    }
    if (meta.contains("notes")) grid.notes = meta.at("notes").get<std::vector<std::string>>();
    has_surface = meta.contains("layers") && meta.at("layers").contains("surface");
    has_overhead = meta.contains("layers") && meta.at("layers").contains("overhead");
    if (geo.nx <= 0 || geo.ny <= 0 || !geo.origin.allFinite())
      throw InputError(meta_path.string() + ": invalid grid metadata");
    try {
      validate_resolution(geo.resolution);
    } catch (const InputError& e) {
      throw InputError(meta_path.string() + ": grid: " + e.what());
    }
    const auto& sj = meta.at("safety");
    opts.max_step = sj.at("max_step").get<double>();
    opts.max_rms = sj.at("max_rms").get<double>();
    opts.max_slope = sj.at("max_slope").get<double>();
    opts.step_noise_factor = sj.value("step_noise_factor", opts.step_noise_factor);
    opts.rms_noise_factor = sj.value("rms_noise_factor", opts.rms_noise_factor);
    opts.slope_noise_factor = sj.value("slope_noise_factor", opts.slope_noise_factor);
    // JSON has no infinity: a map written without the level rule holds null.
    if (sj.contains("max_climb"))
      opts.max_climb = sj.at("max_climb").is_null() ? std::numeric_limits<double>::infinity()
                                                     : sj.at("max_climb").get<double>();
    for (const auto& r : sj.at("radii")) radii.push_back(r.at("radius").get<double>());
  } catch (const nlohmann::json::exception& e) {
    throw InputError(meta_path.string() + ": missing or malformed field (" + e.what() + ")");
  }
  const GridGeometry& geo = grid.geometry;
  auto load = [&](const std::string& name, auto& out, bool allow_infinity = false) {
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
        if (const char* problem = layer_value_problem<T>(v, allow_infinity))
          throw InputError(path + ": " + problem + " (cell " + std::to_string(i) + ", " +
                           std::to_string(j) + ": " + std::to_string(v) + ")");
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
  if (has_surface) load("surface", grid.surface);
  if (has_overhead) load("overhead", grid.overhead, /*allow_infinity=*/true);
  for (size_t k = 0; k < geo.size(); ++k) {
    if (grid.observed[k] > 2)
      throw InputError(dir + "/layers/observed.npy: values must be 0, 1 or 2");
    grid.observed_cells += grid.observed[k] == 1;
    grid.interpolated_cells += grid.observed[k] == 2;
  }
  grid.filled_cells = geo.size() - grid.observed_cells - grid.interpolated_cells;
  count_overhangs(grid);
  return std::make_unique<TerrainMap>(std::move(grid), radii, opts);
}

}  // namespace terrastride::terrain
