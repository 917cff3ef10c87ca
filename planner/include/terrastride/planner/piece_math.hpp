// Building blocks for constraint pieces: forward-mode AD over a piece's local variables, cubic
// Hermite segments, ZYX Euler kinematics and terrain height with derivatives, all written for a
// generic scalar so one definition gives both values and exact Jacobians.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <cmath>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>
#include <type_traits>
#include <unsupported/Eigen/AutoDiff>
#include <utility>

#include "terrastride/planner/nlp.hpp"
#include "terrastride/robot/geometry.hpp"
#include "terrastride/terrain/height_field.hpp"

namespace terrastride::planner {

using AdVector = Eigen::Matrix<double, Eigen::Dynamic, 1, 0, kMaxPieceVars, 1>;
using Ad = Eigen::AutoDiffScalar<AdVector>;

constexpr double kGravity = 9.81;
constexpr double kInf = 2e19;  // an unbounded row or variable (Ipopt's nlp_upper_bound_inf is 1e19)

// d = a * da + b * db for AD derivative vectors that may be empty (constants).
inline AdVector chain2(double a, const AdVector& da, double b, const AdVector& db) {
  if (da.size() && db.size()) return a * da + b * db;
  if (da.size()) return a * da;
  if (db.size()) return b * db;
  return AdVector();
}

inline double value_of(double v) { return v; }
inline double value_of(const Ad& v) { return v.value(); }

// A piece from a generic callable f(const T* x_local, T* g) (T = double or Ad).
template <class F>
class FunctionPiece : public Piece {
 public:
  explicit FunctionPiece(F f) : f_(std::move(f)) {}
  void eval(const double* x, double* g) const override { f_(x, g); }
  void eval_jacobian(const double* x, double* g, double* jac) const override {
    const int n = static_cast<int>(vars.size()), m = rows();
    Ad xa[kMaxPieceVars];
    for (int i = 0; i < n; ++i) xa[i] = Ad(x[i], n, i);
    Ad ga[64];
    f_(static_cast<const Ad*>(xa), static_cast<Ad*>(ga));
    for (int r = 0; r < m; ++r) {
      g[r] = ga[r].value();
      const auto& d = ga[r].derivatives();
      for (int i = 0; i < n; ++i) jac[r * n + i] = d.size() ? d[i] : 0.0;
    }
  }

 private:
  F f_;
};

// Collects distinct global variables for a piece and gives their local positions.
class LocalVars {
 public:
  int add(int global) {
    for (std::size_t i = 0; i < vars.size(); ++i)
      if (vars[i] == global) return static_cast<int>(i);
    vars.push_back(global);
    return static_cast<int>(vars.size()) - 1;
  }
  // Three consecutive globals; returns local indices (they may not be consecutive locally).
  std::array<int, 3> add3(int global) {
    if (global < 0) return {-1, -1, -1};
    return {add(global), add(global + 1), add(global + 2)};
  }
  std::vector<int> vars;
};

// A piece of kind `kind` over the variables in `lv`, rows bounded by [lb, ub], from a generic
// callable f(const T* x_local, T* g). Every constraint family (constraints/) builds its pieces with it.
template <class F>
std::unique_ptr<Piece> make_piece(std::string kind, const LocalVars& lv, std::vector<double> lb,
                                  std::vector<double> ub, F f) {
  if (static_cast<int>(lv.vars.size()) > kMaxPieceVars || lb.size() > 64 || lb.size() != ub.size())
    throw std::logic_error("piece " + kind + ": too many variables or rows, or bounds mismatch");
  auto p = std::make_unique<FunctionPiece<F>>(std::move(f));
  p->kind = std::move(kind);
  p->vars = lv.vars;
  p->lb = std::move(lb);
  p->ub = std::move(ub);
  return p;
}

template <class T>
using Vec3 = Eigen::Matrix<T, 3, 1>;

template <class T>
Vec3<T> gather3(const T* x, const std::array<int, 3>& idx) {
  if (idx[0] < 0) return Vec3<T>(T(0.0), T(0.0), T(0.0));
  return Vec3<T>(x[idx[0]], x[idx[1]], x[idx[2]]);
}

// The variables of one cubic Hermite segment that a piece needs: at sigma = 0 or 1 the value
// depends on one knot value only, so the other columns are left out of the Jacobian altogether
// (fewer nonzeros, a cheaper KKT factorisation). Missing entries read as zero.
struct HermiteLocal {
  std::array<int, 3> p0{{-1, -1, -1}}, v0{{-1, -1, -1}}, p1{{-1, -1, -1}}, v1{{-1, -1, -1}};
  bool needs_duration = true;
};
inline HermiteLocal add_hermite(LocalVars& lv, int gp0, int gv0, int gp1, int gv1, double sigma,
                                bool value_only) {
  HermiteLocal h;
  if (value_only && sigma == 0.0) {
    h.p0 = lv.add3(gp0);
    h.needs_duration = false;
  } else if (value_only && sigma == 1.0) {
    h.p1 = lv.add3(gp1);
    h.needs_duration = false;
  } else {
    h.p0 = lv.add3(gp0);
    h.v0 = lv.add3(gv0);
    h.p1 = lv.add3(gp1);
    h.v1 = lv.add3(gv1);
  }
  return h;
}

// Cubic Hermite segment of duration h at fraction s in [0, 1]: value, first and second derivative.
template <class T>
void hermite(double s, const T& h, const Vec3<T>& p0, const Vec3<T>& v0, const Vec3<T>& p1,
             const Vec3<T>& v1, Vec3<T>* p, Vec3<T>* v, Vec3<T>* a) {
  const double s2 = s * s, s3 = s2 * s;
  if (p) *p = (2 * s3 - 3 * s2 + 1) * p0 + (s3 - 2 * s2 + s) * h * v0 + (-2 * s3 + 3 * s2) * p1 +
              (s3 - s2) * h * v1;
  if (v)
    *v = ((6 * s2 - 6 * s) * p0 + (-6 * s2 + 6 * s) * p1) / h + (3 * s2 - 4 * s + 1) * v0 +
         (3 * s2 - 2 * s) * v1;
  if (a)
    *a = ((12 * s - 6) * p0 + (-12 * s + 6) * p1) / (h * h) +
         ((6 * s - 4) * v0 + (6 * s - 2) * v1) / h;
}

// The value alone of one scalar Hermite segment (e.g. the yaw, without pitch and roll).
template <class T>
T hermite_value(double s, const T& h, const T& p0, const T& v0, const T& p1, const T& v1) {
  const double s2 = s * s, s3 = s2 * s;
  return (2 * s3 - 3 * s2 + 1) * p0 + (s3 - 2 * s2 + s) * h * v0 + (-2 * s3 + 3 * s2) * p1 +
         (s3 - s2) * h * v1;
}

template <class T>
void hermite(double s, const T& h, const T* x, const HermiteLocal& l, Vec3<T>* p, Vec3<T>* v,
             Vec3<T>* a) {
  // The value alone at a segment end that reads one knot (add_hermite's value_only): the knot
  // plus the formula's other terms, exact zeros (+ 0.0 keeps the formula's +0 for a -0 knot), so
  // the same value and derivatives bit for bit, without the AD arithmetic on the missing knots'
  // zeros (measured: range_of_motion's Jacobian 2.3 -> 2.15 ms on pallet_15 all; the other
  // kinds within noise).
  if (!v && !a && l.v0[0] < 0 && l.v1[0] < 0) {
    const std::array<int, 3>* knot = s == 0.0 && l.p1[0] < 0   ? &l.p0
                                     : s == 1.0 && l.p0[0] < 0 ? &l.p1
                                                               : nullptr;
    if (knot && (*knot)[0] >= 0) {
      for (int i = 0; i < 3; ++i) (*p)[i] = x[(*knot)[i]] + 0.0;
      return;
    }
  }
  hermite<T>(s, h, gather3(x, l.p0), gather3(x, l.v0), gather3(x, l.p1), gather3(x, l.v1), p, v, a);
}

// R = Rz(yaw) Ry(pitch) Rx(roll), euler = (yaw, pitch, roll): the robot's (robot/geometry.hpp).
using robot::rotation_zyx;

// The Euler-rate matrix E(e) of ZYX Euler angles e = (yaw, pitch, roll): the world angular
// velocity is w = E(e) e'. Singular at pitch +-pi/2 (gimbal lock).
template <class T>
Eigen::Matrix<T, 3, 3> euler_rate_matrix(const Vec3<T>& e) {
  using std::cos;
  using std::sin;
  const T cy = cos(e[0]), sy = sin(e[0]), cp = cos(e[1]), sp = sin(e[1]);
  Eigen::Matrix<T, 3, 3> E;
  E << T(0.0), -sy, cy * cp, T(0.0), cy, sy * cp, T(1.0), T(0.0), -sp;
  return E;
}

// World angular velocity and acceleration from ZYX Euler angles and their derivatives:
// w = E(e) e', w' = E e'' + E' e'.
template <class T>
void euler_to_angular(const Vec3<T>& e, const Vec3<T>& ed, const Vec3<T>& edd, Vec3<T>* w,
                      Vec3<T>* wd) {
  using std::cos;
  using std::sin;
  const T cy = cos(e[0]), sy = sin(e[0]), cp = cos(e[1]), sp = sin(e[1]);
  const Eigen::Matrix<T, 3, 3> E = euler_rate_matrix<T>(e);
  Eigen::Matrix<T, 3, 3> Ed;
  const T yd = ed[0], pd = ed[1];
  Ed << T(0.0), -cy * yd, -sy * cp * yd - cy * sp * pd, T(0.0), -sy * yd,
      cy * cp * yd - sy * sp * pd, T(0.0), T(0.0), -cp * pd;
  if (w) *w = E * ed;
  if (wd) *wd = E * edd + Ed * ed;
}

// Terrain height with its derivative chained through the foot coordinates.
inline double terrain_height(const terrain::HeightField& f, double x, double y) {
  return f.height(x, y);
}
inline Ad terrain_height(const terrain::HeightField& f, const Ad& x, const Ad& y) {
  Eigen::Vector2d g;
  const double h = f.height_and_gradient(x.value(), y.value(), &g);
  return Ad(h, chain2(g.x(), x.derivatives(), g.y(), y.derivatives()));
}
// Terrain gradient (hx, hy) with its derivative chained through the foot coordinates (Hessian).
inline void terrain_gradient(const terrain::HeightField& f, double x, double y, double* hx,
                             double* hy) {
  Eigen::Vector2d g;
  f.height_and_gradient(x, y, &g);
  *hx = g.x();
  *hy = g.y();
}
inline void terrain_gradient(const terrain::HeightField& f, const Ad& x, const Ad& y, Ad* hx,
                             Ad* hy) {
  const auto s = f.sample(x.value(), y.value());
  const auto& dx = x.derivatives();
  const auto& dy = y.derivatives();
  *hx = Ad(s.gradient.x(), AdVector(s.hessian(0, 0) * dx + s.hessian(0, 1) * dy));
  *hy = Ad(s.gradient.y(), AdVector(s.hessian(1, 0) * dx + s.hessian(1, 1) * dy));
}

// Unit normal and tangents of the terrain at (x, y): n ~ (-hx, -hy, 1), t1 ~ (1, 0, hx),
// t2 = n x t1 (orthonormal).
inline void terrain_frame(const terrain::HeightField& f, double x, double y, Vec3<double>* n,
                          Vec3<double>* t1, Vec3<double>* t2) {
  Eigen::Vector2d g;
  f.height_and_gradient(x, y, &g);
  *n = Vec3<double>(-g.x(), -g.y(), 1.0).normalized();
  *t1 = Vec3<double>(1.0, 0.0, g.x()).normalized();
  *t2 = n->cross(*t1);
}
inline void terrain_frame(const terrain::HeightField& f, const Ad& x, const Ad& y, Vec3<Ad>* n,
                          Vec3<Ad>* t1, Vec3<Ad>* t2) {
  const auto s = f.sample(x.value(), y.value());
  // hx, hy as AD scalars carrying the Hessian chain.
  const auto& dx = x.derivatives();
  const auto& dy = y.derivatives();
  AdVector dhx = s.hessian(0, 0) * dx + s.hessian(0, 1) * dy;
  AdVector dhy = s.hessian(1, 0) * dx + s.hessian(1, 1) * dy;
  const Ad hx(s.gradient.x(), dhx), hy(s.gradient.y(), dhy);
  Vec3<Ad> nn(-hx, -hy, Ad(1.0));
  *n = nn / sqrt(nn.squaredNorm());
  Vec3<Ad> tt(Ad(1.0), Ad(0.0), hx);
  *t1 = tt / sqrt(tt.squaredNorm());
  *t2 = n->cross(*t1);
}

}  // namespace terrastride::planner
