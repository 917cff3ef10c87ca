// The trunk box (robot file `trunk`, fixed to the base) against the terrain's OctoMap and the
// certain solid, with FCL, sample by sample along the plan.
#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <limits>
#include <memory>
#include <stdexcept>
#include <string>

#include "fcl_distance.hpp"
#include "terrastride/collision/checks.hpp"
#include "terrastride/collision/octree_terrain.hpp"
#include "terrastride/robot/geometry.hpp"

namespace terrastride::collision {

TrunkClearanceReport check_trunk_clearance(const robot::RobotModel& model,
                                           const planner::Trajectory& traj,
                                           const octomap::OcTree& octree,
                                           const ClearanceOptions& options,
                                           const CertainSolid* certain) {
  if (!model.trunk)
    throw std::invalid_argument("robot " + model.name + " has no trunk box (robot file " +
                                model.source_file + " says trunk: none)");
  if (!(options.distance_cutoff > 0))
    throw std::invalid_argument("clearance distance cutoff must be > 0");
  const robot::TrunkBox& box = *model.trunk;
  const size_t n = traj.samples.size();

  TrunkClearanceReport rep;
  rep.deep_contact_depth = detail::deep_contact_depth(options, octree, certain);
  rep.certain_resolved_below = options.exact_below;
  rep.time.resize(n);
  rep.distance.assign(n, std::numeric_limits<double>::quiet_NaN());
  rep.certain_distance.assign(n, std::numeric_limits<double>::quiet_NaN());
  rep.exact.assign(n, 0);
  rep.verdict.assign(n, ContactVerdict::clear);
  rep.min_distance = options.distance_cutoff;
  rep.min_certain_distance = options.distance_cutoff;

  const std::shared_ptr<const octomap::OcTree> view(std::shared_ptr<const octomap::OcTree>(),
                                                    &octree);
  const fcl::OcTree<double> tree(view);
  std::unique_ptr<detail::SolidGeometry> solid;
  if (certain) {
    solid = std::make_unique<detail::SolidGeometry>(*certain);
    rep.certain_source = certain->source;
  }
  const auto shape = std::make_shared<fcl::Box<double>>(box.size);

  // Temporal coherence as for the leg capsules (leg_clearance.cpp): a rigid box's points move by
  // an affine function of their box coordinates, so no point moves farther than the farthest
  // corner; from an exact distance d, d +- that motion bounds the distance now.
  bool have = false;
  double d_last = 0.0;
  std::array<Eigen::Vector3d, 8> corners_last;
  corners_last.fill(Eigen::Vector3d::Zero());  // read only once `have` is set
  for (size_t k = 0; k < n; ++k) {
    const auto& base = traj.samples[k].base;
    rep.time[k] = traj.samples[k].t;
    const Eigen::Vector3d euler = base.euler_zyx;
    detail::Transform3d pose = detail::Transform3d::Identity();
    pose.linear() = robot::rotation_zyx<double>(euler);
    pose.translation() = robot::trunk_center_world<double>(box, base.position, euler);
    std::array<Eigen::Vector3d, 8> corners;
    for (int c = 0; c < 8; ++c)
      corners[c] = robot::trunk_corner_world<double>(box, c, base.position, euler);
    double upper = std::numeric_limits<double>::infinity();
    double d = 0.0;
    bool bounded = false;
    if (have) {
      double delta = 0.0;
      for (int c = 0; c < 8; ++c) delta = std::max(delta, (corners[c] - corners_last[c]).norm());
      const double allowed = std::max(options.bound_tolerance,
                                      options.bound_relative * (d_last - options.exact_below));
      if (delta <= allowed && d_last - delta > options.exact_below) {
        d = d_last - delta;
        bounded = true;
      } else if (d_last > 0) {
        upper = d_last + delta + 1e-6;
      }
    }
    if (!bounded) {
      d = detail::signed_distance(tree, *shape, pose, options.distance_cutoff, upper);
      ++rep.fcl_queries;
      rep.exact[k] = 1;
      d_last = d;
      corners_last = corners;
      have = true;
    }
    double c = d;
    if (solid && d < options.exact_below) {
      c = solid->signed_distance(shape, pose, options.distance_cutoff);
      ++rep.certain_queries;
    }
    rep.distance[k] = d;
    rep.certain_distance[k] = c;
    const ContactVerdict v = detail::contact_verdict(d, c, rep.deep_contact_depth);
    rep.verdict[k] = v;
    if (d < rep.min_distance) {
      rep.min_distance = d;
      rep.min_sample = static_cast<int>(k);
      rep.min_base = base.position;
    }
    rep.min_certain_distance = std::min(rep.min_certain_distance, c);
    if (v != ContactVerdict::clear) {
      ++rep.collisions;
      if (rep.first_collision_t < 0) rep.first_collision_t = rep.time[k];
    }
    if (v == ContactVerdict::certain) {
      ++rep.collisions_certain;
      if (rep.first_certain_collision_t < 0) rep.first_certain_collision_t = rep.time[k];
    } else if (v == ContactVerdict::uncertain) {
      ++rep.contacts_uncertain;
    }
  }
  return rep;
}

void name_trunk_overhang(const robot::RobotModel& model, const planner::Trajectory& traj,
                         const terrain::HeightField& field, TrunkClearanceReport* report) {
  constexpr double kNear = 0.02;  // m, two voxels of the default check
  if (!model.trunk || report->min_sample < 0) return;
  const robot::TrunkBox& box = *model.trunk;
  const auto& base = traj.samples[report->min_sample].base;
  const Eigen::Matrix3d R = robot::rotation_zyx<double>(base.euler_zyx);
  const Eigen::Vector3d h = box.half_size();
  // The top face on a 5 cm grid: the overhang's clearance at each point.
  const int nx = 1 + static_cast<int>(std::ceil(box.size.x() / 0.05)),
            ny = 1 + static_cast<int>(std::ceil(box.size.y() / 0.05));
  double least = std::numeric_limits<double>::infinity();
  Eigen::Vector3d at = Eigen::Vector3d::Zero();
  double under = 0.0;
  for (int i = 0; i < nx; ++i)
    for (int j = 0; j < ny; ++j) {
      const Eigen::Vector3d q =
          box.center + Eigen::Vector3d(-h.x() + box.size.x() * i / (nx - 1),
                                       -h.y() + box.size.y() * j / (ny - 1), h.z());
      const Eigen::Vector3d p = base.position + R * q;
      const double o = field.overhead(p.x(), p.y());
      if (std::isfinite(o) && o - p.z() < least) {
        least = o - p.z();
        at = p;
        under = o;
      }
    }
  if (!(least < kNear)) return;
  char text[256];
  std::snprintf(text, sizeof text,
                "the box's top reaches z = %.3f m under the overhang at (%.2f, %.2f) whose "
                "underside is at z = %.3f m, %.3f m above the walkable surface (t = %.2f s)",
                at.z(), at.x(), at.y(), under, under - field.height(at.x(), at.y()),
                report->time[report->min_sample]);
  report->overhang = text;
}

}  // namespace terrastride::collision
