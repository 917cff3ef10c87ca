// The feasibility sets' shared helpers (constraints/feasibility_common.hpp).
#include <cmath>

#include "../../../planner/src/constraints/feasibility_common.hpp"
#include "family_test.hpp"

namespace terrastride::planner {
namespace {

using namespace testing;

TEST(FeasibilityCommon, SoftMinAndMaxAreConservativeBounds) {
  const double v[4] = {0.05, 0.02, 0.021, 0.3}, t = 0.004;
  const double sm = feasibility::soft_min(v, 4, t), sx = feasibility::soft_max(v, 4, t);
  EXPECT_LE(sm, 0.02);
  EXPECT_GE(sm, 0.02 - t * std::log(4.0));
  EXPECT_GE(sx, 0.3);
  EXPECT_LE(sx, 0.3 + t * std::log(4.0));
  // Exact formula, and far apart values: the soft minimum is the minimum to within t e^-(gap/t).
  EXPECT_NEAR(sm,
              -t * std::log(std::exp(-0.05 / t) + std::exp(-0.02 / t) + std::exp(-0.021 / t) +
                            std::exp(-0.3 / t)),
              1e-15);
  const double w[2] = {1.0, 1.5};
  EXPECT_NEAR(feasibility::soft_min(w, 2, 0.01), 1.0, 1e-15);
  // Large values do not overflow (the minimum is factored out).
  const double big[2] = {1e4, -1e4};
  EXPECT_DOUBLE_EQ(feasibility::soft_max(big, 2, 1e-3), 1e4);
}

}  // namespace
}  // namespace terrastride::planner
