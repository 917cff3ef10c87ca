// Scalar-generic pieces of the interpolated force-polytope model (see polytope_model.hpp), shared
// by the double-precision evaluation and the Ceres fit (which instantiates them with Jets).
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <cmath>
#include <vector>

#include "terrastride/planner/polytope_model.hpp"

namespace terrastride::planner::polytope_core {

template <typename T>
using Vec3 = Eigen::Matrix<T, 3, 1>;

// Unit normal from spherical angles about the pole axis: phi = 0 lies in the plane normal to the
// pole, theta turns in that plane from axis (pole+1)%3 towards (pole+2)%3.
template <typename T>
Vec3<T> local_normal(int pole, const T& theta, const T& phi) {
  using std::cos;
  using std::sin;
  Vec3<T> n;
  n[(pole + 1) % 3] = cos(phi) * cos(theta);
  n[(pole + 2) % 3] = cos(phi) * sin(theta);
  n[pole] = sin(phi);
  return n;
}

// hip = (h_x, h_y, h_z, l0).
template <typename T>
void leg_coordinates(bool use_roll, const T* hip, const Eigen::Vector3d& p, T* gamma, T* l,
                     T* alpha) {
  using std::atan2;
  using std::sqrt;
  const T vx = T(p.x()) - hip[0];
  const T vy = T(p.y()) - hip[1];
  const T vz = T(p.z()) - hip[2];
  T b;
  if (use_roll) {
    *gamma = atan2(vy, -vz);
    b = sqrt(vy * vy + vz * vz) - hip[3];
  } else {
    *gamma = T(0.0);
    b = -vz - hip[3];
  }
  *l = sqrt(vx * vx + b * b);
  *alpha = atan2(vx, b);
}

// n = Rx(gamma) Ry(-alpha) v, from the cosines and sines of gamma and alpha.
template <typename T>
Vec3<T> rotate_cs(const T& cg, const T& sg, const T& ca, const T& sa, const Vec3<T>& v) {
  const Vec3<T> w(ca * v[0] - sa * v[2], v[1], sa * v[0] + ca * v[2]);
  return Vec3<T>(w[0], cg * w[1] - sg * w[2], sg * w[1] + cg * w[2]);
}

template <typename T>
Vec3<T> rotate(const T& gamma, const T& alpha, const Vec3<T>& v) {
  using std::cos;
  using std::sin;
  return rotate_cs(cos(gamma), sin(gamma), cos(alpha), sin(alpha), v);
}

// Segment of a knot vector holding x (end segments extended) and the fraction along it (< 0 or
// > 1 when extrapolating). One knot: segment 0 with fraction 0 (the value is constant).
inline int locate(const std::vector<double>& knots, double x) {
  const int k = static_cast<int>(knots.size());
  if (k < 2) return 0;
  int i = 0;
  // Paper (13): l_1 <= l <= l_2 uses the first segment; a knot belongs to the lower segment.
  while (i < k - 2 && x > knots[i + 1]) ++i;
  return i;
}

template <typename T>
T fraction(const std::vector<double>& knots, int i, const T& x) {
  if (knots.size() < 2) return T(0.0);
  return (x - T(knots[i])) / T(knots[i + 1] - knots[i]);
}

// Vertex where facets rows[0..2] meet: solves [n0 n1 n2]^T v = d by the adjugate (3x3).
template <typename T>
Vec3<T> meet(const Vec3<T>& n0, const Vec3<T>& n1, const Vec3<T>& n2, const T& d0, const T& d1,
             const T& d2) {
  const Vec3<T> c12 = n1.cross(n2), c20 = n2.cross(n0), c01 = n0.cross(n1);
  const T det = n0.dot(c12);
  return (d0 * c12 + d1 * c20 + d2 * c01) / det;
}

// Facet k of vertex v: joint i uses facet 2i when bit i of v is set, 2i+1 otherwise.
inline int vertex_facet(int vertex, int joint) {
  return 2 * joint + (((vertex >> joint) & 1) ? 0 : 1);
}

}  // namespace terrastride::planner::polytope_core
