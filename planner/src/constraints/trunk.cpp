// "trunk" (beyond the paper; in "all"): the trunk box of the robot file kept between the terrain
// and any overhang above it.
// Below: where the terrain near the trunk is tall, the box's bottom face is sampled on a grid (the
// four corners and points at most kTrunkSpacing apart along each edge and across the face), each
// point moved with the base pose (robot::trunk_corner_world's frame) and held above the terrain
// under it by trunk_margin:
//   p_z - h(p_x, p_y) >= trunk_margin   for every grid point p of the bottom face.
// Above: where an overhang (HeightField::overhead: a shelf, a table, a tread overhead) is near,
// the top face's grid likewise stays under it:
//   min(o(p_x, p_y) - p_z, kOverheadFar) >= trunk_margin   for every grid point p of the top face,
// the clearance capped at kOverheadFar (and that constant where nothing is overhead, o = +inf):
// a finite row, flat far from any overhang, whose cap lies far from its bound.
// With shin_softmin > 0 the values of one knot and face are folded into one row, their soft
// minimum (as for the shin rows). Imposed at every knot of the base spline where tall terrain
// (overhang) is near: the base moves a few centimetres per 0.1 s segment, which trunk_margin
// covers.
// "Tall": within the trunk's footprint grown by kTrunkReach around the initial-guess base pose at
// the knot, the terrain rises within kTrunkTallBelow of the box's bottom (on the flat scenes and
// the pallets the bottom is 0.5 m up and no row is added; on the stairs' top treads and beside a
// maze's walls they are). "Near overhang": over that area an overhang comes down within
// kTrunkTallBelow of the box's top; where nothing is overhead no top row exists, so plans on
// terrain without overhangs are what they were. A wall (or board) thinner than the grid spacing
// (minus the smoothing's spread) could pass between two points; the post-hoc trunk check judges
// the box itself.
// Before any row, a robot that cannot fit under an overhang on its path, or whose fixed start
// pose already stands in one, is refused (UnreachableRequest, naming the trunk and the overhang):
// see require_start_clear and require_trunk_fits below.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "base_line.hpp"
#include "feasibility_common.hpp"
#include "terrastride/planner/feasibility.hpp"
#include "terrastride/planner/nlp.hpp"
#include "terrastride/planner/reachability.hpp"
#include "terrastride/robot/geometry.hpp"

namespace terrastride::planner {

namespace {
constexpr double kTrunkSpacing = 0.1;     // m, at most between grid points of a face
constexpr double kTrunkReach = 0.2;       // m, around the footprint where terrain counts as near
constexpr double kTrunkTallBelow = 0.25;  // m below the bottom face (above the top face)
constexpr double kOverheadFar = 1.0;      // m, the top rows' clearance cap

// The grid of the bottom (side -1) or top (side +1) face in the base frame.
std::vector<Eigen::Vector3d> face_grid(const robot::TrunkBox& box, double side) {
  const Eigen::Vector3d h = box.half_size();
  const int nx = 1 + static_cast<int>(std::ceil(box.size.x() / kTrunkSpacing - 1e-9));
  const int ny = 1 + static_cast<int>(std::ceil(box.size.y() / kTrunkSpacing - 1e-9));
  std::vector<Eigen::Vector3d> grid;
  for (int i = 0; i < nx; ++i)
    for (int j = 0; j < ny; ++j)
      grid.push_back(box.center + Eigen::Vector3d(-h.x() + box.size.x() * i / (nx - 1),
                                                  -h.y() + box.size.y() * j / (ny - 1),
                                                  side * h.z()));
  return grid;
}

// The overhang's clearance above the point (x, y, z), capped at kOverheadFar (see the top).
inline double overhead_clearance(const terrain::HeightField& f, double x, double y, double z) {
  const double o = f.overhead(x, y);
  return o - z < kOverheadFar ? o - z : kOverheadFar;
}
inline Ad overhead_clearance(const terrain::HeightField& f, const Ad& x, const Ad& y, const Ad& z) {
  Eigen::Vector2d g;
  const double o = f.overhead_and_gradient(x.value(), y.value(), &g);
  if (!(o - z.value() < kOverheadFar))
    return Ad(kOverheadFar, AdVector::Zero(z.derivatives().size()));
  return Ad(o, chain2(g.x(), x.derivatives(), g.y(), y.derivatives())) - z;
}

std::string fmt2(double v) {
  char b[32];
  std::snprintf(b, sizeof b, "%.2f", v);
  return b;
}

// The lowest base height above the walkable surface the robot holds with a foot in the air at
// the swing's knot: the range-of-motion box's top (-(nominal_z + b_z) below the base) under that
// foot, plus the height the swing clearance rows demand of it there, less the violation an
// "acceptable" solve may keep on each of the two. A level trunk (the guess's pose): pitching could
// lower one end, which the rows and the post-hoc check judge.
struct SwingKnot {
  int knot = 0, foot = 0;
  double lift = 0.0;  // m, the clearance demanded of the swing foot at the knot
};
std::vector<SwingKnot> swing_knots(const SrbdProblem& problem) {
  const Layout& L = problem.layout();
  const ProblemOptions& o = problem.options();
  std::vector<SwingKnot> out;
  for (const auto& sw : L.swings) {
    const double t0 = L.nominal_knot_time[sw.first_seg];
    const double T = L.nominal_knot_time[sw.last_seg + 1] - t0;
    const double tau = std::min(o.clearance_ramp, 0.5 * T);
    // A swing under way at a re-plan's start lifted off before it: its profile is unknown here.
    if (sw.first_seg == 0) continue;
    for (int k = sw.first_seg + 1; k <= sw.last_seg; ++k) {
      const double edge = std::min(L.nominal_knot_time[k] - t0, T - (L.nominal_knot_time[k] - t0));
      // clearance_profile of swing_clearance.cpp: sin^2 ramp over tau, 1 between.
      const double s = tau > 0 ? std::sin(0.5 * M_PI * std::clamp(edge / tau, 0.0, 1.0)) : 1.0;
      out.push_back({k, sw.foot, o.swing_clearance * s * s});
    }
  }
  return out;
}

// Refuses (UnreachableRequest) a request whose trunk cannot pass under an overhang on its path:
// at a swing's knot, with the base as low as the robot holds it then (above) and anywhere across
// the lateral corridor (its width plus the solver's slack), some point of the trunk's top face at
// the guess's pose comes closer to the underside of an overhang than these rows allow
// (trunk_margin less the slack). Every bound involved (range of motion, swing clearance, these
// rows) is relaxed by the slack an "acceptable" solve may keep, so only requests no solve could
// satisfy at the knots are refused. The base keeps to that corridor in a plan from rest
// (lateral_corridor, in "all"); elsewhere nothing is refused here.
void require_trunk_fits(SrbdProblem& problem, const FeasibilityOptions& options,
                        const std::vector<Eigen::Vector3d>& top) {
  if (!path_shape_applies(problem, options) || !(options.lateral_corridor > 0.0)) return;
  const robot::RobotModel& robot = problem.robot();
  const Layout& L = problem.layout();
  const terrain::HeightField& field = problem.terrain();
  const std::vector<double>& x0 = problem.initial_guess();
  const BaseLine line = base_line_of(problem);
  const double reach = options.lateral_corridor + kAcceptableViolation;
  for (const SwingKnot& sk : swing_knots(problem)) {
    const auto& leg = robot.legs[sk.foot];
    const int b = L.base[sk.knot], fp = L.foot_pos[sk.foot][sk.knot];
    const double ground = field.height(x0[fp], x0[fp + 1]);
    const double stand = -(leg.nominal_foot.z() + leg.range_of_motion.z());
    const double base_z = ground + stand + sk.lift - 2.0 * kAcceptableViolation;
    const double need = options.trunk_margin - kAcceptableViolation;
    const Eigen::Vector3d r0(x0[b], x0[b + 1], base_z), e0(x0[b + 6], x0[b + 7], x0[b + 8]);
    const Eigen::Matrix3d R0 = rotation_zyx<double>(e0);
    // The most favourable lateral place: the one whose worst top point is clearest.
    double best = -std::numeric_limits<double>::infinity();
    Eigen::Vector3d worst_p = Eigen::Vector3d::Zero();
    double worst_o = 0.0;
    for (const double shift : {-reach, 0.0, reach}) {
      const Eigen::Vector2d d =
          line.defined ? Eigen::Vector2d(shift * line.across) : Eigen::Vector2d::Zero();
      double least = std::numeric_limits<double>::infinity();
      Eigen::Vector3d at = Eigen::Vector3d::Zero();
      double at_o = 0.0;
      for (const Eigen::Vector3d& q : top) {
        Eigen::Vector3d p = r0 + R0 * q;
        p.head<2>() += d;
        const double o = field.overhead(p.x(), p.y());
        if (o - p.z() < least) {
          least = o - p.z();
          at = p;
          at_o = o;
        }
      }
      if (least > best) {
        best = least;
        worst_p = at;
        worst_o = at_o;
      }
    }
    if (best >= need) continue;
    const double top_above = worst_p.z() - base_z;
    const double surface = field.height(worst_p.x(), worst_p.y());
    throw UnreachableRequest(
        "trunk: " + robot.name + "'s trunk box cannot pass under the overhang at (" +
        fmt2(worst_p.x()) + ", " + fmt2(worst_p.y()) +
        "): its underside is at z = " + fmt2(worst_o) + " m, " + fmt2(worst_o - surface) +
        " m above the walkable surface, and the box's top stands at least " +
        fmt2(worst_p.z() - surface) + " m up there while the " + leg.name +
        " foot swings (t = " + fmt2(L.nominal_knot_time[sk.knot]) + " s): the lowest base height " +
        fmt2(base_z - ground) + " m (the range-of-motion box's top " + fmt2(stand) +
        " m above the foot, plus its " + fmt2(sk.lift) + " m swing clearance, less " +
        fmt2(2.0 * kAcceptableViolation) + " m solver slack), plus the box's top " +
        fmt2(top_above) + " m above the base; the trunk rows keep it " + fmt2(need) +
        " m below the underside (trunk_margin less the slack)");
  }
}

// Refuses a start whose trunk already stands in or too close under an overhang: a fixed start
// pose (a plan from rest, a measured state) is no variable, so no solve could move it out.
void require_start_clear(SrbdProblem& problem, const FeasibilityOptions& options,
                         const std::vector<Eigen::Vector3d>& top) {
  const int b = problem.layout().base[0];
  if (!all_fixed({b, b + 1, b + 2, b + 6, b + 7, b + 8}, problem.lower(), problem.upper())) return;
  const std::vector<double>& x0 = problem.initial_guess();
  const terrain::HeightField& field = problem.terrain();
  const Eigen::Vector3d r0(x0[b], x0[b + 1], x0[b + 2]), e0(x0[b + 6], x0[b + 7], x0[b + 8]);
  const Eigen::Matrix3d R0 = rotation_zyx<double>(e0);
  const double need = options.trunk_margin - kAcceptableViolation;
  for (const Eigen::Vector3d& q : top) {
    const Eigen::Vector3d p = r0 + R0 * q;
    const double o = field.overhead(p.x(), p.y());
    if (o - p.z() >= need) continue;
    throw UnreachableRequest(
        "trunk: at the start " + problem.robot().name +
        "'s trunk box's top stands at z = " + fmt2(p.z()) + " m at (" + fmt2(p.x()) + ", " +
        fmt2(p.y()) + "), under the overhang there whose underside is at z = " + fmt2(o) + " m, " +
        fmt2(o - field.height(p.x(), p.y())) +
        " m above the walkable surface: the trunk rows need it " + fmt2(need) +
        " m below (trunk_margin less the solver slack), and the start is fixed");
  }
}

// Whether, around the guess's trunk at the knot, the terrain rises within kTrunkTallBelow of the
// bottom face (below) or an overhang comes down within it of the top face (above).
void near_knot(const terrain::HeightField& field, const robot::TrunkBox& box,
               const Eigen::Vector3d& r0, const Eigen::Matrix3d& R0, bool* below, bool* above) {
  const Eigen::Vector3d h = box.half_size();
  const double bottom = (r0 + R0 * (box.center - Eigen::Vector3d(0, 0, h.z()))).z();
  const double top_face = (r0 + R0 * (box.center + Eigen::Vector3d(0, 0, h.z()))).z();
  double top = -1e300, low = 1e300;
  const double gx = h.x() + kTrunkReach, gy = h.y() + kTrunkReach;
  for (double u = -gx; u <= gx + 1e-9; u += 0.5 * kTrunkSpacing)
    for (double v = -gy; v <= gy + 1e-9; v += 0.5 * kTrunkSpacing) {
      const Eigen::Vector3d p = r0 + R0 * (box.center + Eigen::Vector3d(u, v, 0.0));
      top = std::max(top, field.height(p.x(), p.y()));
      low = std::min(low, field.overhead(p.x(), p.y()));
    }
  *below = top > bottom - kTrunkTallBelow;
  *above = low < top_face + kTrunkTallBelow;
}

// One face's rows at knot b's base variables: `side` -1 the bottom above the terrain, +1 the top
// under the overhang.
void add_face_rows(SrbdProblem& problem, const FeasibilityOptions& options, int b,
                   const std::vector<Eigen::Vector3d>& grid, double side) {
  const terrain::HeightField* field = &problem.terrain();
  const int n = static_cast<int>(grid.size());
  const double t_soft = options.shin_softmin;
  // Unmerged rows (shin_softmin 0): the points in pieces of at most 64 rows (a piece's limit).
  std::vector<std::pair<int, int>> chunks;  // [first, last) points of each piece at a knot
  if (t_soft > 0.0)
    chunks.push_back({0, n});
  else
    for (int a = 0; a < n; a += 64) chunks.push_back({a, std::min(n, a + 64)});
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
        out[i] = side < 0 ? T(p[2] - terrain_height(*field, p[0], p[1]))
                          : overhead_clearance(*field, p[0], p[1], p[2]);
      }
      if (t_soft > 0.0) g[0] = feasibility::soft_min(values, m, t_soft);
    }));
  }
}

}  // namespace

void build_trunk_set(SrbdProblem& problem, const FeasibilityOptions& options) {
  const robot::RobotModel& robot = problem.robot();
  if (!robot.has_trunk()) return;
  const robot::TrunkBox box = *robot.trunk;
  const Layout& L = problem.layout();
  const std::vector<Eigen::Vector3d> bottom = face_grid(box, -1.0), top = face_grid(box, 1.0);
  if (static_cast<int>(bottom.size()) > feasibility::kMaxShinValues)
    throw std::invalid_argument("trunk: the trunk box needs " + std::to_string(bottom.size()) +
                                " points on its bottom face, more than one piece holds");
  const std::vector<double>& x0 = problem.initial_guess();
  std::vector<char> below(L.num_segments + 1), above(L.num_segments + 1);
  bool any_above = false;
  for (int k = 0; k <= L.num_segments; ++k) {
    const int b = L.base[k];
    const Eigen::Vector3d r0(x0[b], x0[b + 1], x0[b + 2]), e0(x0[b + 6], x0[b + 7], x0[b + 8]);
    bool lo = false, hi = false;
    near_knot(problem.terrain(), box, r0, rotation_zyx<double>(e0), &lo, &hi);
    below[k] = lo;
    above[k] = hi;
    any_above = any_above || hi;
  }
  if (any_above) {
    // The robot's own limit first: it says why no start height would do.
    require_trunk_fits(problem, options, top);
    require_start_clear(problem, options, top);
  }
  for (int k = 0; k <= L.num_segments; ++k) {
    if (below[k]) add_face_rows(problem, options, L.base[k], bottom, -1.0);
    // A fixed knot's top rows would be constants (require_start_clear has judged the start).
    const int b = L.base[k];
    if (above[k] &&
        !all_fixed({b, b + 1, b + 2, b + 6, b + 7, b + 8}, problem.lower(), problem.upper()))
      add_face_rows(problem, options, b, top, 1.0);
  }
}

}  // namespace terrastride::planner
