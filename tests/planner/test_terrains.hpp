// Small analytic terrains for the planner tests: flat ground, a C2 (tanh) step, and the step with a
// safety margin that varies smoothly.
#pragma once

#include <cmath>
#include <string>

#include "terrastride/terrain/height_field.hpp"

namespace terrastride::planner::testing {

class FlatField : public terrain::HeightField {
 public:
  explicit FlatField(double z = 0.0) : z_(z) {}
  terrain::HeightSample sample(double, double) const override {
    terrain::HeightSample s;
    s.height = z_;
    return s;
  }
  terrain::MarginSample safety_margin(double, double, double) const override {
    return {1e9, Eigen::Vector2d::Zero()};
  }
  Eigen::Vector2d min_corner() const override { return {-5, -5}; }
  Eigen::Vector2d max_corner() const override { return {5, 5}; }
  std::string describe() const override { return "flat"; }

 private:
  double z_;
};

// h = H/2 (1 + tanh((x - x0)/w)) + a small y ripple so every derivative path is exercised.
class TanhStep : public terrain::HeightField {
 public:
  TanhStep(double height, double x0, double width, double ripple = 0.0)
      : H_(height), x0_(x0), w_(width), r_(ripple) {}
  terrain::HeightSample sample(double x, double y) const override {
    const double th = std::tanh((x - x0_) / w_);
    const double sech2 = 1.0 - th * th;
    terrain::HeightSample s;
    s.height = 0.5 * H_ * (1.0 + th) + r_ * std::sin(3.0 * y) * std::cos(2.0 * x);
    s.gradient.x() = 0.5 * H_ * sech2 / w_ - 2.0 * r_ * std::sin(3.0 * y) * std::sin(2.0 * x);
    s.gradient.y() = 3.0 * r_ * std::cos(3.0 * y) * std::cos(2.0 * x);
    s.hessian(0, 0) = -H_ * th * sech2 / (w_ * w_) - 4.0 * r_ * std::sin(3.0 * y) * std::cos(2.0 * x);
    s.hessian(0, 1) = s.hessian(1, 0) = -6.0 * r_ * std::cos(3.0 * y) * std::sin(2.0 * x);
    s.hessian(1, 1) = -9.0 * r_ * std::sin(3.0 * y) * std::cos(2.0 * x);
    return s;
  }
  terrain::MarginSample safety_margin(double, double, double) const override {
    return {1e9, Eigen::Vector2d::Zero()};
  }
  Eigen::Vector2d min_corner() const override { return {-5, -5}; }
  Eigen::Vector2d max_corner() const override { return {5, 5}; }
  std::string describe() const override { return "tanh step"; }

 private:
  double H_, x0_, w_, r_;
};

// The tanh step with a safety margin that varies smoothly in x and y (so the foot set's gradient
// chain is exercised): m = 0.03 + 0.05 sin(4x) cos(3y) - r.
class MarginStep : public TanhStep {
 public:
  using TanhStep::TanhStep;
  terrain::MarginSample safety_margin(double x, double y, double r) const override {
    terrain::MarginSample m;
    m.margin = 0.03 + 0.05 * std::sin(4 * x) * std::cos(3 * y) - r;
    m.gradient = Eigen::Vector2d(0.2 * std::cos(4 * x) * std::cos(3 * y),
                                 -0.15 * std::sin(4 * x) * std::sin(3 * y));
    return m;
  }
};

}  // namespace terrastride::planner::testing
