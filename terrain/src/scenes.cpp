#include "terrastride/terrain/scenes.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <cstdio>
#include <sstream>

#include "terrastride/perception/point_cloud.hpp"

namespace terrastride::terrain {
namespace {

constexpr double kNoEdge = 1e9;

Box box(double x0, double x1, double y0, double y1, double z0, double z1) {
  return Box{Eigen::Vector3d(x0, y0, z0), Eigen::Vector3d(x1, y1, z1)};
}

// Distance from p to segment ab and the closest point on it.
double segment_distance(const Eigen::Vector2d& p, const Eigen::Vector2d& a,
                        const Eigen::Vector2d& b, Eigen::Vector2d* closest) {
  const Eigen::Vector2d ab = b - a;
  const double len2 = ab.squaredNorm();
  double t = len2 > 0 ? (p - a).dot(ab) / len2 : 0.0;
  t = std::clamp(t, 0.0, 1.0);
  *closest = a + t * ab;
  return (p - *closest).norm();
}

}  // namespace

Scene::Scene(std::string name, std::string description, double ground_z, std::vector<Box> boxes,
             Eigen::Vector2d lo, Eigen::Vector2d hi)
    : name_(std::move(name)),
      description_(std::move(description)),
      ground_z_(ground_z),
      boxes_(std::move(boxes)),
      lo_(lo),
      hi_(hi) {
  for (const Box& b : boxes_) overhang_.push_back(b.lo.z() - ground_z_ > kOverhangGap ? 1 : 0);
  compute_edges();
}

bool Scene::has_overhangs() const {
  return std::any_of(overhang_.begin(), overhang_.end(), [](char o) { return o != 0; });
}

HeightSample Scene::sample(double x, double y) const {
  HeightSample s;
  double h = ground_z_;
  // Closed footprints: on an edge the higher side wins (the foot would rest on the corner).
  for (size_t i = 0; i < boxes_.size(); ++i) {
    const Box& b = boxes_[i];
    if (overhang_[i]) continue;  // the robot walks beneath it
    if (x >= b.lo.x() && x <= b.hi.x() && y >= b.lo.y() && y <= b.hi.y()) h = std::max(h, b.hi.z());
  }
  s.height = h;
  return s;
}

void Scene::compute_edges() {
  // Candidate lines are the box footprint borders. Each is split at every other box border that
  // crosses it; a piece is an edge when the height differs on its two sides. Pieces hidden under
  // a taller box or shared by boxes of equal height drop out this way.
  // Overhangs are no part of the walkable surface: their borders are no candidates.
  std::vector<Box> ground;
  for (size_t i = 0; i < boxes_.size(); ++i)
    if (!overhang_[i]) ground.push_back(boxes_[i]);
  std::vector<double> xs, ys;
  for (const Box& b : ground) {
    xs.push_back(b.lo.x());
    xs.push_back(b.hi.x());
    ys.push_back(b.lo.y());
    ys.push_back(b.hi.y());
  }
  std::sort(xs.begin(), xs.end());
  xs.erase(std::unique(xs.begin(), xs.end()), xs.end());
  std::sort(ys.begin(), ys.end());
  ys.erase(std::unique(ys.begin(), ys.end()), ys.end());
  constexpr double eps = 1e-7;
  auto try_piece = [&](const Eigen::Vector2d& a, const Eigen::Vector2d& b,
                       const Eigen::Vector2d& normal) {
    const Eigen::Vector2d m = 0.5 * (a + b);
    const double h1 = height(m.x() + eps * normal.x(), m.y() + eps * normal.y());
    const double h2 = height(m.x() - eps * normal.x(), m.y() - eps * normal.y());
    if (std::abs(h1 - h2) < 1e-9) return;
    // Lines shared by several boxes produce the same piece more than once; keep one.
    for (const EdgeSegment& e : edges_) {
      if ((e.a - a).norm() < 1e-12 && (e.b - b).norm() < 1e-12) return;
    }
    edges_.push_back(EdgeSegment{a, b, std::abs(h1 - h2)});
  };
  for (const Box& b : ground) {
    for (double y : {b.lo.y(), b.hi.y()}) {  // lines along x
      std::vector<double> cuts{b.lo.x()};
      for (double x : xs)
        if (x > b.lo.x() && x < b.hi.x()) cuts.push_back(x);
      cuts.push_back(b.hi.x());
      for (size_t i = 0; i + 1 < cuts.size(); ++i)
        try_piece({cuts[i], y}, {cuts[i + 1], y}, {0.0, 1.0});
    }
    for (double x : {b.lo.x(), b.hi.x()}) {  // lines along y
      std::vector<double> cuts{b.lo.y()};
      for (double y : ys)
        if (y > b.lo.y() && y < b.hi.y()) cuts.push_back(y);
      cuts.push_back(b.hi.y());
      for (size_t i = 0; i + 1 < cuts.size(); ++i)
        try_piece({x, cuts[i]}, {x, cuts[i + 1]}, {1.0, 0.0});
    }
  }
}

double Scene::edge_distance(double x, double y, Eigen::Vector2d* away) const {
  const Eigen::Vector2d p(x, y);
  double best = kNoEdge;
  Eigen::Vector2d best_closest = p;
  for (const EdgeSegment& e : edges_) {
    Eigen::Vector2d c;
    const double d = segment_distance(p, e.a, e.b, &c);
    if (d < best) {
      best = d;
      best_closest = c;
    }
  }
  if (away) {
    const Eigen::Vector2d v = p - best_closest;
    *away = v.norm() > 0 ? Eigen::Vector2d(v / v.norm()) : Eigen::Vector2d::Zero();
  }
  return best;
}

MarginSample Scene::safety_margin(double x, double y, double foot_radius) const {
  MarginSample m;
  Eigen::Vector2d away;
  const double d = edge_distance(x, y, &away);
  if (d >= kNoEdge) {
    m.margin = kNoEdge;
    return m;
  }
  m.margin = d - foot_radius;
  m.gradient = away;
  return m;
}

double Scene::overhead_and_gradient(double x, double y, Eigen::Vector2d* gradient) const {
  gradient->setZero();
  return lowest_overhead(Eigen::Vector2d(x, y), Eigen::Vector2d(x, y));
}

double Scene::lowest_overhead(const Eigen::Vector2d& lo, const Eigen::Vector2d& hi) const {
  double z = std::numeric_limits<double>::infinity();
  for (size_t i = 0; i < boxes_.size(); ++i) {
    const Box& b = boxes_[i];
    if (overhang_[i] && hi.x() >= b.lo.x() && lo.x() <= b.hi.x() && hi.y() >= b.lo.y() &&
        lo.y() <= b.hi.y())
      z = std::min(z, b.lo.z());
  }
  return z;
}

// Ray casts meet every box, overhangs included: a depth sensor sees a shelf.
std::optional<RayHit> Scene::ray_cast(const Eigen::Vector3d& origin, const Eigen::Vector3d& dir,
                                      double max_range) const {
  const double len = dir.norm();
  if (!(len > 0) || !std::isfinite(len)) return std::nullopt;
  const Eigen::Vector3d d = dir / len;
  double best_t = max_range;
  std::optional<RayHit> hit;
  if (d.z() < 0) {
    const double t = (ground_z_ - origin.z()) / d.z();
    if (t > 0 && t <= best_t) {
      best_t = t;
      hit = RayHit{t, origin + t * d, Eigen::Vector3d::UnitZ()};
    }
  }
  for (const Box& b : boxes_) {
    // Slab test; remember which slab the ray entered last: that face is the one hit.
    double t_enter = -std::numeric_limits<double>::infinity();
    double t_exit = std::numeric_limits<double>::infinity();
    int axis = -1;
    double sign = 0;
    bool miss = false;
    for (int k = 0; k < 3 && !miss; ++k) {
      if (std::abs(d[k]) < 1e-15) {
        if (origin[k] < b.lo[k] || origin[k] > b.hi[k]) miss = true;
        continue;
      }
      double t0 = (b.lo[k] - origin[k]) / d[k];
      double t1 = (b.hi[k] - origin[k]) / d[k];
      double s = -1.0;  // entering through the low face: outward normal -e_k
      if (t0 > t1) {
        std::swap(t0, t1);
        s = 1.0;
      }
      if (t0 > t_enter) {
        t_enter = t0;
        axis = k;
        sign = s;
      }
      t_exit = std::min(t_exit, t1);
      if (t_enter > t_exit) miss = true;
    }
    if (miss || axis < 0 || t_enter <= 0 || t_enter > best_t) continue;
    best_t = t_enter;
    Eigen::Vector3d n = Eigen::Vector3d::Zero();
    n[axis] = sign;
    hit = RayHit{t_enter, origin + t_enter * d, n};
  }
  return hit;
}

std::string Scene::describe() const {
  std::ostringstream os;
  os << "scene " << name_ << ": " << description_ << " (" << boxes_.size() << " boxes, ";
  if (const auto n = std::count(overhang_.begin(), overhang_.end(), 1); n > 0)
    os << n << " of them overhead, ";
  os << edges_.size() << " edge segments)";
  return os.str();
}

int pallet_height_cm(const std::string& name) {
  if (name.size() < 8 || name.size() > 9 || name.compare(0, 7, "pallet_") != 0) return 0;
  int cm = 0;
  for (size_t i = 7; i < name.size(); ++i) {
    if (name[i] < '0' || name[i] > '9') return 0;
    cm = 10 * cm + (name[i] - '0');
  }
  if (name[7] == '0') return 0;  // one spelling per height
  return cm >= 1 && cm <= 60 ? cm : 0;
}

namespace {

// NN of PREFIX + "NN" for NN in [lo, hi] spelt without a leading zero, else 0.
int height_suffix_cm(const std::string& name, const std::string& prefix, int lo, int hi) {
  if (name.size() <= prefix.size() || name.size() > prefix.size() + 3 ||
      name.compare(0, prefix.size(), prefix) != 0 || name[prefix.size()] == '0')
    return 0;
  int cm = 0;
  for (size_t i = prefix.size(); i < name.size(); ++i) {
    if (name[i] < '0' || name[i] > '9') return 0;
    cm = 10 * cm + (name[i] - '0');
  }
  return cm >= lo && cm <= hi ? cm : 0;
}

constexpr int kOverheadMinCm = 25, kOverheadMaxCm = 150;
constexpr double kSlab = 0.04;  // m, the overhang's board thickness

}  // namespace

int overhang_height_cm(const std::string& name) {
  for (const char* prefix : {"shelf_", "half_shelf_", "tread_"})
    if (const int cm = height_suffix_cm(name, prefix, kOverheadMinCm, kOverheadMaxCm)) return cm;
  return 0;
}

bool is_scene_name(const std::string& name) {
  const auto names = scene_names();
  return std::find(names.begin(), names.end(), name) != names.end() || pallet_height_cm(name) > 0 ||
         overhang_height_cm(name) > 0;
}

std::vector<std::string> scene_names() {
  return {"flat", "pallet_10", "pallet_15", "eur_pallet", "stairs", "gap"};
}

std::string scene_names_text() {
  std::string text;
  for (const auto& n : scene_names()) text += (text.empty() ? "" : ", ") + n;
  return text +
         ", pallet_NN (a box NN cm high, 1 to 60), shelf_NN, half_shelf_NN, tread_NN (an overhang "
         "whose underside is NN cm up, 25 to 150)";
}

namespace {

// The overhang scenes: a 4 cm slab whose underside is `u` m up, on supports that stand outside
// every robot's corridor (|y| >= 0.72: HyQ's feet reach 0.49). The shelves begin at x = 0.4,
// ahead of Go2's trunk at the start (its front at 0.34 m), so Go2 walks in under them; HyQ's
// 1 m trunk reaches 0.5 m ahead of its base and is under one from the start.
std::unique_ptr<Scene> overhang_scene(const std::string& name, double u, const Eigen::Vector2d& lo,
                                      const Eigen::Vector2d& hi) {
  char height[16];
  std::snprintf(height, sizeof height, "%.2f", u);
  const std::string under = "underside " + std::string(height) + " m up";
  std::vector<Box> b;
  std::string what;
  if (name.rfind("shelf_", 0) == 0) {
    // Four legs at the slab's corners.
    b.push_back(box(0.4, 0.9, -0.8, 0.8, u, u + kSlab));
    for (const double x : {0.4, 0.82})
      for (const double y : {-0.8, 0.72}) b.push_back(box(x, x + 0.08, y, y + 0.08, 0.0, u));
    what = "shelf across the path, x in [0.40, 0.90], y in [-0.80, 0.80], " + under +
           ", on four legs at |y| >= 0.72";
  } else if (name.rfind("half_shelf_", 0) == 0) {
    // Cantilevered from a wall on the left: it covers the path's left half only.
    b.push_back(box(0.4, 0.9, 0.0, 0.8, u, u + kSlab));
    b.push_back(box(0.4, 0.9, 0.72, 0.8, 0.0, u));
    what = "shelf over the path's left half, x in [0.40, 0.90], y in [0, 0.80], " + under +
           ", cantilevered from a wall at y in [0.72, 0.80]";
  } else {
    // A flight's tread overhead: the robot starts beneath it and walks out.
    b.push_back(box(-0.7, 0.25, -0.8, 0.8, u, u + kSlab));
    for (const double y : {-0.8, 0.72}) b.push_back(box(-0.7, -0.62, y, y + 0.08, 0.0, u));
    what = "stair tread overhead above the start, x in [-0.70, 0.25], y in [-0.80, 0.80], " +
           under + ", on two legs at x = -0.70, |y| >= 0.72";
  }
  return std::make_unique<Scene>(name, what, 0.0, std::move(b), lo, hi);
}

}  // namespace

std::unique_ptr<Scene> make_scene(const std::string& name) {
  // The region of interest: the robot (hind feet near x = -0.31) to beyond its goal (front feet
  // near x = 1.31), wide enough for the sensor footprint.
  const Eigen::Vector2d lo(-1.0, -1.0), hi(2.5, 1.0);
  if (name == "flat")
    return std::make_unique<Scene>(name, "flat ground", 0.0, std::vector<Box>{}, lo, hi);
  // pallet_NN: the solid box NN cm high (pallet_10 and pallet_15 are HyQ's; other heights scale
  // the step to another robot's legs, e.g. a third of Go2's 0.426 m of thigh and shank).
  if (const int cm = pallet_height_cm(name); cm > 0) {
    const double h = cm / 100.0;
    char height[16];
    std::snprintf(height, sizeof height, "%.2f", h);
    return std::make_unique<Scene>(
        name, "solid box " + std::string(height) + " m high, x in [0.55, 1.75], y in [-0.6, 0.6]",
        0.0, std::vector<Box>{box(0.55, 1.75, -0.6, 0.6, 0.0, h)}, lo, hi);
  }
  if (const int cm = overhang_height_cm(name); cm > 0)
    return overhang_scene(name, cm / 100.0, lo, hi);
  if (name == "eur_pallet") {
    // EUR pallet (EN 13698-1), 1.2 m along x, 0.8 m across: three bottom boards, nine blocks,
    // three stringer boards across and five top deck boards along x with 41 mm gaps between them.
    const double x0 = 0.55, x1 = 1.75;
    const double board = 0.022;
    std::vector<Box> b;
    const double bottom_y[3][2] = {{-0.4, -0.3}, {-0.0725, 0.0725}, {0.3, 0.4}};
    const double block_x[3][2] = {{x0, x0 + 0.145}, {1.075, 1.225}, {x1 - 0.145, x1}};
    for (const auto& y : bottom_y) b.push_back(box(x0, x1, y[0], y[1], 0.0, board));
    for (const auto& x : block_x)
      for (const auto& y : bottom_y) b.push_back(box(x[0], x[1], y[0], y[1], board, 0.100));
    for (const auto& x : block_x) b.push_back(box(x[0], x[1], -0.4, 0.4, 0.100, 0.122));
    const double top_y[5][2] = {
        {-0.4, -0.255}, {-0.21375, -0.11375}, {-0.0725, 0.0725}, {0.11375, 0.21375}, {0.255, 0.4}};
    for (const auto& y : top_y) b.push_back(box(x0, x1, y[0], y[1], 0.122, 0.144));
    return std::make_unique<Scene>(
        name, "EUR pallet 1.2 x 0.8 x 0.144 m, x in [0.55, 1.75], y in [-0.4, 0.4]", 0.0,
        std::move(b), lo, hi);
  }
  if (name == "stairs") {
    std::vector<Box> b;
    for (int k = 0; k < 3; ++k)
      b.push_back(box(0.55 + 0.30 * k, 1.75, -0.6, 0.6, 0.0, 0.12 * (k + 1)));
    return std::make_unique<Scene>(
        name, "three 0.12 m risers at x = 0.55, 0.85, 1.15 (0.30 m treads), y in [-0.6, 0.6]", 0.0,
        std::move(b), lo, hi);
  }
  if (name == "gap") {
    // Ground at z = 0 is two large slabs; the trench floor is the plane 0.30 m below.
    const double depth = 0.30;
    std::vector<Box> b{box(-10.0, 0.50, -10.0, 10.0, -depth, 0.0),
                       box(0.70, 10.0, -10.0, 10.0, -depth, 0.0)};
    return std::make_unique<Scene>(name, "0.20 m wide, 0.30 m deep trench at x in [0.50, 0.70]",
                                   -depth, std::move(b), lo, hi);
  }
  throw perception::InputError("unknown scene '" + name + "' (valid scenes: " +
                               scene_names_text() + ")");
}

}  // namespace terrastride::terrain
