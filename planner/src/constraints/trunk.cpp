// "trunk" (beyond the paper; in "all"): the trunk box of the robot file kept above the terrain
// where the terrain near it is tall. The box's bottom face is sampled on a grid (the four corners
// and points at most kTrunkSpacing apart along each edge and across the face), each point moved
// with the base pose (robot::trunk_corner_world's frame) and held above the terrain under it by
// trunk_margin:
//   p_z - h(p_x, p_y) >= trunk_margin   for every grid point p of the bottom face.
// With shin_softmin > 0 the values of one knot are folded into one row, their soft minimum (as
// for the shin rows). Imposed at every knot of the base spline where tall terrain is near: the
// base moves a few centimetres per 0.1 s segment, which trunk_margin covers.
// "Tall": within the trunk's footprint grown by kTrunkReach around the initial-guess base pose at
// the knot, the terrain rises within kTrunkTallBelow of the box's bottom (on the flat scenes and
// the pallets the bottom is 0.5 m up and no row is added; on the stairs' top treads and beside a
// maze's walls they are). A wall thinner than the grid spacing (minus the smoothing's spread)
// could pass between two points; the post-hoc trunk check judges the box itself.
#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <utility>
#include <vector>

#include "feasibility_common.hpp"
#include "terrastride/planner/feasibility.hpp"
#include "terrastride/planner/nlp.hpp"
#include "terrastride/robot/geometry.hpp"

namespace terrastride::planner {

namespace {
constexpr double kTrunkSpacing = 0.1;     // m, at most between grid points of the bottom face
constexpr double kTrunkReach = 0.2;       // m, around the footprint where terrain counts as near
constexpr double kTrunkTallBelow = 0.25;  // m below the bottom face
}  // namespace

void build_trunk_set(SrbdProblem& problem, const FeasibilityOptions& options) {
  const robot::RobotModel& robot = problem.robot();
  if (!robot.has_trunk()) return;
  const robot::TrunkBox box = *robot.trunk;
  const Layout& L = problem.layout();
  const terrain::HeightField* field = &problem.terrain();
  // The bottom face's grid in the base frame.
  const Eigen::Vector3d h = box.half_size();
  const int nx = 1 + static_cast<int>(std::ceil(box.size.x() / kTrunkSpacing - 1e-9));
  const int ny = 1 + static_cast<int>(std::ceil(box.size.y() / kTrunkSpacing - 1e-9));
  std::vector<Eigen::Vector3d> grid;
  for (int i = 0; i < nx; ++i)
    for (int j = 0; j < ny; ++j)
      grid.push_back(box.center + Eigen::Vector3d(-h.x() + box.size.x() * i / (nx - 1),
                                                  -h.y() + box.size.y() * j / (ny - 1), -h.z()));
  const int n = static_cast<int>(grid.size());
  const double t_soft = options.shin_softmin;
  if (n > feasibility::kMaxShinValues)
    throw std::invalid_argument("trunk: the trunk box needs " + std::to_string(n) +
                                " points on its bottom face, more than one piece holds");
  // Unmerged rows (shin_softmin 0): the points in pieces of at most 64 rows (a piece's limit).
  std::vector<std::pair<int, int>> chunks;  // [first, last) points of each piece at a knot
  if (t_soft > 0.0)
    chunks.push_back({0, n});
  else
    for (int a = 0; a < n; a += 64) chunks.push_back({a, std::min(n, a + 64)});
  const std::vector<double>& x0 = problem.initial_guess();
  for (int k = 0; k <= L.num_segments; ++k) {
    // Tall terrain near the trunk at the initial guess's base pose?
    const int b = L.base[k];
    const Eigen::Vector3d r0(x0[b], x0[b + 1], x0[b + 2]), e0(x0[b + 6], x0[b + 7], x0[b + 8]);
    const Eigen::Matrix3d R0 = rotation_zyx<double>(e0);
    const double bottom = (r0 + R0 * (box.center - Eigen::Vector3d(0, 0, h.z()))).z();
    double top = -1e300;
    const double gx = h.x() + kTrunkReach, gy = h.y() + kTrunkReach;
    for (double u = -gx; u <= gx + 1e-9; u += 0.5 * kTrunkSpacing)
      for (double v = -gy; v <= gy + 1e-9; v += 0.5 * kTrunkSpacing) {
        const Eigen::Vector3d p = r0 + R0 * (box.center + Eigen::Vector3d(u, v, 0.0));
        top = std::max(top, field->height(p.x(), p.y()));
      }
    if (!(top > bottom - kTrunkTallBelow)) continue;
    for (const auto& [first, last] : chunks) {
      LocalVars lv;
      const auto r = lv.add3(b);
      const auto e = lv.add3(b + 6);
      const int rows = t_soft > 0.0 ? 1 : last - first;
      const std::vector<double> lo(rows, options.trunk_margin), hi(rows, kInf);
      const std::vector<Eigen::Vector3d> points(grid.begin() + first, grid.begin() + last);
      problem.add_piece(make_piece("trunk", lv, lo, hi, [=](const auto* x, auto* g) {
        using T = std::decay_t<decltype(*g)>;
        const Vec3<T> base = gather3(x, r);
        const Eigen::Matrix<T, 3, 3> R = rotation_zyx<T>(gather3(x, e));
        const int m = static_cast<int>(points.size());
        T values[feasibility::kMaxShinValues] = {};
        T* out = t_soft > 0.0 ? values : g;
        for (int i = 0; i < m; ++i) {
          const Vec3<T> p = base + R * points[i].cast<T>();
          out[i] = p[2] - terrain_height(*field, p[0], p[1]);
        }
        if (t_soft > 0.0) g[0] = feasibility::soft_min(values, m, t_soft);
      }));
    }
  }
}

}  // namespace terrastride::planner
