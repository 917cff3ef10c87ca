// Leg capsules (shin: knee to near the foot; thigh: HFE to knee) against the terrain's OctoMap,
// with FCL's octree-shape distance and collision queries.
#include <fcl/geometry/shape/capsule.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <atomic>
#include <cmath>
#include <exception>
#include <limits>
#include <memory>
#include <mutex>
#include <thread>
#include <vector>

#include "terrastride/collision/checks.hpp"
#include "terrastride/collision/octree_terrain.hpp"
#include "fcl_distance.hpp"

namespace terrastride::collision {
namespace {

using fcl::Transform3d;
using detail::signed_distance;
using detail::SolidGeometry;

// Pose of an FCL capsule (axis along its local z, centred at the origin) spanning a -> b.
Transform3d capsule_pose(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  Transform3d tf = Transform3d::Identity();
  tf.translation() = 0.5 * (a + b);
  tf.linear() =
      Eigen::Quaterniond::FromTwoVectors(Eigen::Vector3d::UnitZ(), b - a).toRotationMatrix();
  return tf;
}

// One capsule's axis end points over the samples (valid = IK gave a configuration).
struct CapsuleTrack {
  std::vector<Eigen::Vector3d> a, b;
  std::vector<char> valid;
};

// Distances of a moving capsule to the terrain at every valid sample, using temporal coherence
// between samples. Every point of a segment is an affine combination of its end points, so moving
// the end points by at most delta moves every point of the capsule by at most delta, and its
// distance to the (fixed) terrain changes by at most delta: from an exact distance d at an earlier
// pose, d - delta and d + delta bound the distance now. Hence:
//  - the upper bound seeds FCL's search, which then skips every octree node farther away (exact
//    result, far fewer voxels visited);
//  - while delta stays within the allowance (bound_tolerance, or bound_relative of the margin
//    above exact_below when larger) and the lower bound stays above `exact_below`, the sample can
//    be neither in collision nor near it, and the lower bound (within 2 delta of the truth) is
//    reported instead of a query (`exact[k]` = 0). The minimum over the samples is then within the
//    allowance of the true one: every skipped value is >= d - delta for an exact d >= the minimum.
// Collisions (d <= 0 < exact_below) and every distance below `exact_below` are exact.
std::vector<double> capsule_distances(const fcl::OcTree<double>& tree,
                                      const fcl::Capsule<double>& capsule,
                                      const CapsuleTrack& track, const ClearanceOptions& options,
                                      std::vector<char>* exact, long* queries) {
  const size_t n = track.valid.size();
  std::vector<double> out(n, std::numeric_limits<double>::quiet_NaN());
  exact->assign(n, 0);
  bool have = false;
  size_t last = 0;  // last exactly evaluated sample
  double d_last = 0.0;
  for (size_t k = 0; k < n; ++k) {
    if (!track.valid[k]) {
      have = false;  // no pose to bound from across an IK failure
      continue;
    }
    double upper = std::numeric_limits<double>::infinity();
    if (have) {
      const double delta =
          std::max((track.a[k] - track.a[last]).norm(), (track.b[k] - track.b[last]).norm());
      const double allowed = std::max(options.bound_tolerance,
                                      options.bound_relative * (d_last - options.exact_below));
      if (delta <= allowed && d_last - delta > options.exact_below) {
        out[k] = d_last - delta;
        continue;
      }
      // The small slack keeps the nearest voxel strictly inside FCL's "closer than" test.
      if (d_last > 0) upper = d_last + delta + 1e-6;
    }
    d_last = signed_distance(tree, capsule, capsule_pose(track.a[k], track.b[k]),
                             options.distance_cutoff, upper);
    out[k] = d_last;
    (*exact)[k] = 1;
    ++*queries;
    last = k;
    have = true;
  }
  return out;
}

// A link's capsule as the union of `pieces` shorter capsules of the same radius along the same
// axis (their union is exactly the long capsule). FCL prunes octree nodes by the capsule's
// axis-aligned box; a long inclined capsule's box is mostly empty space and reaches down to its
// lowest point along its whole footprint, so FCL would test every voxel under it. Short pieces
// have tight boxes and only the lowest piece comes near the ground. Distance = minimum over
// pieces (a lower bound if that piece's value was a bound).
struct LinkResult {
  std::vector<double> distance, certain_distance;
  std::vector<char> exact;
};

// The pieces of a link of length `length`.
int piece_count(double length, const ClearanceOptions& options) {
  return std::max(1, static_cast<int>(std::ceil(length / options.piece_length - 1e-9)));
}

// One piece's distances: to the voxels (`distance`, `exact` as capsule_distances) and, where it
// comes within exact_below of the voxels, to the certain solid (`certain`; `solid` null: the voxel
// distance stands for it). Pieces are independent of each other (each has its own coherence
// track), so they are the leg check's tasks.
struct PieceResult {
  std::vector<double> distance, certain;
  std::vector<char> exact;
  long queries = 0, certain_queries = 0;
};

PieceResult piece_distances(const fcl::OcTree<double>& tree, SolidGeometry* solid, double radius,
                            const CapsuleTrack& track, double length, int piece,
                            const ClearanceOptions& options) {
  const size_t n = track.valid.size();
  const int pieces = piece_count(length, options);
  const auto capsule_ptr = std::make_shared<fcl::Capsule<double>>(radius, length / pieces);
  const double s0 = static_cast<double>(piece) / pieces,
               s1 = static_cast<double>(piece + 1) / pieces;
  CapsuleTrack part = track;
  for (size_t k = 0; k < n; ++k) {
    part.a[k] = track.a[k] + s0 * (track.b[k] - track.a[k]);
    part.b[k] = track.a[k] + s1 * (track.b[k] - track.a[k]);
  }
  PieceResult r;
  r.distance = capsule_distances(tree, *capsule_ptr, part, options, &r.exact, &r.queries);
  r.certain = r.distance;
  if (solid) {
    for (size_t k = 0; k < n; ++k) {
      if (std::isnan(r.distance[k]) || !(r.distance[k] < options.exact_below)) continue;
      r.certain[k] = solid->signed_distance(capsule_ptr, capsule_pose(part.a[k], part.b[k]),
                                            options.distance_cutoff);
      ++r.certain_queries;
    }
  }
  return r;
}

// A link's distances from its pieces' (in piece order): the voxel distance is the minimum over
// pieces (an exact piece wins a tie), the certain-solid distance the minimum of theirs.
LinkResult merge_pieces(const std::vector<PieceResult>& pieces, size_t n) {
  LinkResult r;
  r.distance.assign(n, std::numeric_limits<double>::quiet_NaN());
  r.certain_distance.assign(n, std::numeric_limits<double>::quiet_NaN());
  r.exact.assign(n, 0);
  for (const PieceResult& p : pieces) {
    for (size_t k = 0; k < n; ++k) {
      const double d = p.distance[k];
      if (std::isnan(d)) continue;
      if (std::isnan(r.distance[k]) || d < r.distance[k] ||
          (d == r.distance[k] && p.exact[k])) {
        r.distance[k] = d;
        r.exact[k] = p.exact[k];
      }
      const double c = p.certain[k];
      if (std::isnan(r.certain_distance[k]) || c < r.certain_distance[k]) r.certain_distance[k] = c;
    }
  }
  return r;
}

// Threads of the leg check: the machine's cores, at most 4 (a plan process runs alone on a
// 2-core robot computer; more threads than tasks would idle).
constexpr unsigned kClearanceThreads = 4;

// Runs task(0) ... task(n - 1) on up to kClearanceThreads threads (this one included), each task
// once, and rethrows the first exception a task threw.
template <class Task>
void run_in_parallel(size_t n, const Task& task) {
  const unsigned cores = std::max(1u, std::thread::hardware_concurrency());
  const size_t threads = std::min<size_t>({n, cores, kClearanceThreads});
  std::atomic<size_t> next{0};
  std::exception_ptr error;
  std::mutex error_mutex;
  auto worker = [&] {
    for (size_t t = next++; t < n; t = next++) {
      try {
        task(t);
      } catch (...) {
        std::lock_guard<std::mutex> lock(error_mutex);
        if (!error) error = std::current_exception();
      }
    }
  };
  std::vector<std::thread> pool;
  for (size_t k = 1; k < threads; ++k) pool.emplace_back(worker);
  worker();
  for (auto& th : pool) th.join();
  if (error) std::rethrow_exception(error);
}

// The shin and thigh capsule axes of every leg over the samples. The shin starts `exclusions[i]`
// above the foot (the part of the lower leg the foot's own contact may touch is left out).
struct LegTracks {
  std::vector<CapsuleTrack> shin, thigh;
};

LegTracks capsule_tracks(const robot::RobotModel& model, const planner::Trajectory& traj,
                         const TrajectoryKinematics& kin, const std::vector<double>& exclusions) {
  const size_t n = traj.samples.size(), n_legs = model.legs.size();
  LegTracks tracks{std::vector<CapsuleTrack>(n_legs), std::vector<CapsuleTrack>(n_legs)};
  for (size_t i = 0; i < n_legs; ++i) {
    const auto& leg = model.legs[i];
    const double exclusion = exclusions[i];
    if (!(exclusion < leg.l2))
      throw std::invalid_argument("shin exclusion " + std::to_string(exclusion) +
                                  " m leaves nothing of leg " + leg.name + "'s lower leg (" +
                                  std::to_string(leg.l2) + " m)");
    CapsuleTrack& shin_track = tracks.shin[i];
    CapsuleTrack& thigh_track = tracks.thigh[i];
    for (CapsuleTrack* t : {&shin_track, &thigh_track}) {
      t->a.assign(n, Eigen::Vector3d::Zero());
      t->b.assign(n, Eigen::Vector3d::Zero());
      t->valid.assign(n, 0);
    }
    for (size_t k = 0; k < n; ++k) {
      const LegSample& ls = kin.legs[i][k];
      if (!ls.has_q()) continue;
      const auto& base = traj.samples[k].base;
      const Eigen::Matrix3d rot = rotation_zyx(base.euler_zyx);
      const Eigen::Vector3d knee = base.position + rot * robot::knee_position(leg, ls.q);
      const Eigen::Vector3d foot = base.position + rot * robot::foot_position(leg, ls.q);
      shin_track.a[k] = foot + (knee - foot).normalized() * exclusion;
      shin_track.b[k] = knee;
      shin_track.valid[k] = 1;
      thigh_track.a[k] = base.position + rot * robot::hfe_position(leg, ls.q);
      thigh_track.b[k] = knee;
      thigh_track.valid[k] = 1;
    }
  }
  return tracks;
}

// One link's merged distances and the queries they took.
struct LinkTask {
  LinkResult result;
  long queries = 0, certain_queries = 0;
};
struct LinkDistances {
  std::vector<LinkTask> shin, thigh;  // per leg; thigh entries empty without check_thigh
};

// The FCL queries, nearly all of the check's time, as independent tasks (one per piece of each
// link, shins first: they come nearest the ground and cost most) on up to kClearanceThreads
// threads, so that the two cores of a robot computer share the work evenly: each task reads the
// shared trees and writes only its own result, so the figures are those of one thread, in the
// same order.
LinkDistances link_distances(const robot::RobotModel& model, const LegTracks& tracks,
                             const std::vector<double>& exclusions,
                             const fcl::OcTree<double>& tree, SolidGeometry* solid,
                             const ClearanceOptions& options, size_t n) {
  const size_t n_legs = model.legs.size();
  struct PieceTask {
    size_t leg;
    bool thigh;
    int piece;
  };
  std::vector<PieceTask> piece_tasks;
  std::vector<std::vector<PieceResult>> shin_pieces(n_legs), thigh_pieces(n_legs);
  for (const bool thigh : {false, true}) {
    if (thigh && !options.check_thigh) continue;
    for (size_t i = 0; i < n_legs; ++i) {
      const auto& leg = model.legs[i];
      const int pieces = piece_count(thigh ? leg.l1 : leg.l2 - exclusions[i], options);
      (thigh ? thigh_pieces : shin_pieces)[i].resize(static_cast<size_t>(pieces));
      for (int j = 0; j < pieces; ++j) piece_tasks.push_back({i, thigh, j});
    }
  }
  run_in_parallel(piece_tasks.size(), [&](size_t t) {
    const PieceTask& task = piece_tasks[t];
    const auto& leg = model.legs[task.leg];
    const size_t j = static_cast<size_t>(task.piece);
    if (task.thigh)
      thigh_pieces[task.leg][j] = piece_distances(tree, solid, leg.thigh_radius,
                                                  tracks.thigh[task.leg], leg.l1, task.piece,
                                                  options);
    else
      shin_pieces[task.leg][j] =
          piece_distances(tree, solid, leg.shin_radius, tracks.shin[task.leg],
                          leg.l2 - exclusions[task.leg], task.piece, options);
  });
  LinkDistances out{std::vector<LinkTask>(n_legs), std::vector<LinkTask>(n_legs)};
  for (size_t i = 0; i < n_legs; ++i) {
    for (auto [pieces, task] : {std::pair{&shin_pieces[i], &out.shin[i]},
                                std::pair{&thigh_pieces[i], &out.thigh[i]}}) {
      if (pieces->empty()) continue;
      task->result = merge_pieces(*pieces, n);
      for (const PieceResult& p : *pieces) {
        task->queries += p.queries;
        task->certain_queries += p.certain_queries;
      }
      pieces->clear();
    }
  }
  return out;
}

// Where one capsule's summary goes: its minima, voxel contacts, certain collisions and verdicts.
struct LinkSummary {
  double* min;
  int* min_sample;
  double* certain_min;
  int* collisions;
  int* certain_collisions;
  std::vector<ContactVerdict>* verdict;
};

// Summarises one link's distances into `out` and `series` (first collision times) and raises the
// per-sample worst verdict over the legs.
void summarise_link(const LinkResult& r, const LinkSummary& out, const std::vector<double>& time,
                    const ClearanceOptions& options, double deep_depth,
                    std::vector<ContactVerdict>* worst, LegClearanceSeries* series) {
  const size_t n = time.size();
  *out.min = options.distance_cutoff;
  *out.certain_min = options.distance_cutoff;
  out.verdict->assign(n, ContactVerdict::clear);
  for (size_t k = 0; k < n; ++k) {
    const double d = r.distance[k];
    if (std::isnan(d)) continue;
    if (d < *out.min) {
      *out.min = d;
      *out.min_sample = static_cast<int>(k);
    }
    *out.certain_min = std::min(*out.certain_min, r.certain_distance[k]);
    const ContactVerdict v = detail::contact_verdict(d, r.certain_distance[k], deep_depth);
    if (d <= 0 || v == ContactVerdict::certain) {
      ++*out.collisions;
      if (series->first_collision_t < 0 || time[k] < series->first_collision_t)
        series->first_collision_t = time[k];
    }
    if (v == ContactVerdict::certain) {
      ++*out.certain_collisions;
      if (series->first_certain_collision_t < 0 || time[k] < series->first_certain_collision_t)
        series->first_certain_collision_t = time[k];
    }
    (*out.verdict)[k] = v;
    (*worst)[k] = std::max((*worst)[k], v);
  }
}

// Leg i's series (shin, and thigh when checked) from its link distances, folded into the
// report's minima, first collision times and query counts.
void summarise_leg(size_t i, const robot::RobotModel& model, LinkDistances& links,
                   const std::vector<double>& time, const ClearanceOptions& options,
                   std::vector<ContactVerdict>* shin_worst,
                   std::vector<ContactVerdict>* thigh_worst, ClearanceReport& rep) {
  const double deep_depth = rep.deep_contact_depth;
  LegClearanceSeries& series = rep.legs[i];
  series.leg = model.legs[i].name;
  LinkResult& shin = links.shin[i].result;
  rep.fcl_queries += links.shin[i].queries;
  rep.certain_queries += links.shin[i].certain_queries;
  summarise_link(shin,
                 {&series.shin_min, &series.shin_min_sample, &series.shin_certain_min,
                  &series.shin_collision_samples, &series.shin_certain_samples,
                  &series.shin_verdict},
                 time, options, deep_depth, shin_worst, &series);
  series.shin_distance = std::move(shin.distance);
  series.shin_exact = std::move(shin.exact);
  series.shin_certain_distance = std::move(shin.certain_distance);
  series.thigh_min = options.distance_cutoff;
  series.thigh_certain_min = options.distance_cutoff;
  if (options.check_thigh) {
    LinkResult& thigh = links.thigh[i].result;
    rep.fcl_queries += links.thigh[i].queries;
    rep.certain_queries += links.thigh[i].certain_queries;
    summarise_link(thigh,
                   {&series.thigh_min, &series.thigh_min_sample, &series.thigh_certain_min,
                    &series.thigh_collision_samples, &series.thigh_certain_samples,
                    &series.thigh_verdict},
                   time, options, deep_depth, thigh_worst, &series);
    series.thigh_distance = std::move(thigh.distance);
    series.thigh_exact = std::move(thigh.exact);
    series.thigh_certain_distance = std::move(thigh.certain_distance);
  }
  rep.shin_min_distance = std::min(rep.shin_min_distance, series.shin_min);
  rep.thigh_min_distance = std::min(rep.thigh_min_distance, series.thigh_min);
  rep.shin_min_certain_distance = std::min(rep.shin_min_certain_distance, series.shin_certain_min);
  rep.thigh_min_certain_distance =
      std::min(rep.thigh_min_certain_distance, series.thigh_certain_min);
  if (series.first_collision_t >= 0 &&
      (rep.first_collision_t < 0 || series.first_collision_t < rep.first_collision_t))
    rep.first_collision_t = series.first_collision_t;
  if (series.first_certain_collision_t >= 0 &&
      (rep.first_certain_collision_t < 0 ||
       series.first_certain_collision_t < rep.first_certain_collision_t))
    rep.first_certain_collision_t = series.first_certain_collision_t;
}

void check_clearance_inputs(const robot::RobotModel& model, const planner::Trajectory& traj,
                            const TrajectoryKinematics& kin, const ClearanceOptions& options) {
  if (kin.time.size() != traj.samples.size() || kin.legs.size() != model.legs.size())
    throw TrajectoryError("kinematics do not belong to this trajectory (sample or leg count)");
  if (!(options.distance_cutoff > 0))
    throw std::invalid_argument("clearance distance cutoff must be > 0");
  if (!(options.exact_below >= 0) || !(options.bound_tolerance >= 0) || !(options.piece_length > 0))
    throw std::invalid_argument(
        "clearance options: exact_below and bound_tolerance must be >= 0, piece_length > 0");
}

}  // namespace

ClearanceReport check_leg_clearance(const robot::RobotModel& model, const planner::Trajectory& traj,
                                    const TrajectoryKinematics& kin, const octomap::OcTree& octree,
                                    const ClearanceOptions& options, const CertainSolid* certain) {
  check_clearance_inputs(model, traj, kin, options);
  const size_t n = traj.samples.size();
  const size_t n_legs = model.legs.size();
  ClearanceReport rep;
  rep.time = kin.time;
  rep.octree_resolution = octree.getResolution();
  rep.certain_resolved_below = options.exact_below;
  rep.deep_contact_depth = detail::deep_contact_depth(options, octree, certain);
  std::vector<double> exclusions(n_legs);
  for (size_t i = 0; i < n_legs; ++i) {
    exclusions[i] = options.shin_exclusion >= 0
                        ? options.shin_exclusion
                        : robot::shin_exclusion(model, model.legs[i],
                                                std::max(options.exclusion_margin,
                                                         octree.getResolution()));
    rep.shin_exclusion = std::max(rep.shin_exclusion, exclusions[i]);
  }
  rep.shin_min_distance = options.distance_cutoff;
  rep.thigh_min_distance = options.distance_cutoff;
  rep.shin_min_certain_distance = options.distance_cutoff;
  rep.thigh_min_certain_distance = options.distance_cutoff;
  rep.legs.resize(n_legs);

  // fcl::OcTree only reads the octomap tree; the aliasing constructor shares it without a copy or
  // ownership (the caller keeps `octree` alive for the duration of this call).
  const std::shared_ptr<const octomap::OcTree> view(std::shared_ptr<const octomap::OcTree>(),
                                                    &octree);
  const fcl::OcTree<double> tree(view);
  std::unique_ptr<SolidGeometry> solid;
  if (certain) {
    solid = std::make_unique<SolidGeometry>(*certain);
    rep.certain_source = certain->source;
  }

  // The capsule tracks of every leg first (cheap), then their distances, then the summaries.
  const LegTracks tracks = capsule_tracks(model, traj, kin, exclusions);
  LinkDistances links = link_distances(model, tracks, exclusions, tree, solid.get(), options, n);
  std::vector<ContactVerdict> shin_worst(n, ContactVerdict::clear),
      thigh_worst(n, ContactVerdict::clear);
  for (size_t i = 0; i < n_legs; ++i)
    summarise_leg(i, model, links, kin.time, options, &shin_worst, &thigh_worst, rep);
  for (size_t k = 0; k < n; ++k) {
    rep.shin_collisions += shin_worst[k] != ContactVerdict::clear;
    rep.thigh_collisions += thigh_worst[k] != ContactVerdict::clear;
    rep.shin_collisions_certain += shin_worst[k] == ContactVerdict::certain;
    rep.thigh_collisions_certain += thigh_worst[k] == ContactVerdict::certain;
    rep.shin_contacts_uncertain += shin_worst[k] == ContactVerdict::uncertain;
    rep.thigh_contacts_uncertain += thigh_worst[k] == ContactVerdict::uncertain;
  }
  return rep;
}

}  // namespace terrastride::collision
