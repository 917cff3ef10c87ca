// The only view of terrain the planner has: a height field z = h(x, y) with analytic derivatives
// and a foothold-safety margin. Analytic test terrains and scanned terrains both implement it.
#pragma once

#include <Eigen/Core>
#include <limits>
#include <string>

namespace terrastride::terrain {

struct HeightSample {
  double height = 0.0;
  Eigen::Vector2d gradient = Eigen::Vector2d::Zero();  // (dh/dx, dh/dy)
  Eigen::Matrix2d hessian = Eigen::Matrix2d::Zero();
};

struct MarginSample {
  double margin = 0.0;  // metres to the nearest unsafe cell; negative inside unsafe area
  Eigen::Vector2d gradient = Eigen::Vector2d::Zero();
};

class HeightField {
 public:
  virtual ~HeightField() = default;
  // Height and its first and second derivatives at (x, y). Must be C2 for smooth fields; exact
  // analytic scenes (sharp edges) report one-sided derivatives at discontinuities.
  virtual HeightSample sample(double x, double y) const = 0;
  // Height and gradient alone, the same values as sample()'s to the bit: most of the planner's
  // terrain rows need no Hessian, and on a bicubic B-spline field it is a third of sample()'s work.
  virtual double height_and_gradient(double x, double y, Eigen::Vector2d* gradient) const {
    const HeightSample s = sample(x, y);
    *gradient = s.gradient;
    return s.height;
  }
  double height(double x, double y) const {
    Eigen::Vector2d gradient;
    return height_and_gradient(x, y, &gradient);
  }
  // Signed foothold-safety margin for a foot of radius `foot_radius` (see docs/design.md §5.4).
  virtual MarginSample safety_margin(double x, double y, double foot_radius) const = 0;
  // The underside of the lowest overhang above the walkable surface at (x, y) (world z, m): a
  // shelf, a table top or a ceiling that a robot standing on h(x, y) may pass under, with its
  // gradient. +infinity (zero gradient) where nothing is overhead. The overhead clearance (free
  // height above the walkable surface) is overhead(x, y) - h(x, y).
  virtual double overhead_and_gradient(double x, double y, Eigen::Vector2d* gradient) const {
    (void)x;
    (void)y;
    gradient->setZero();
    return std::numeric_limits<double>::infinity();
  }
  double overhead(double x, double y) const {
    Eigen::Vector2d gradient;
    return overhead_and_gradient(x, y, &gradient);
  }
  // Whether (x, y) was observed (always true for analytic terrains).
  virtual bool observed(double x, double y) const { return true; }
  // Axis-aligned extent where the field is defined: min and max corners.
  virtual Eigen::Vector2d min_corner() const = 0;
  virtual Eigen::Vector2d max_corner() const = 0;
  virtual std::string describe() const = 0;
};

}  // namespace terrastride::terrain
