// Stance footholds against the foothold-safety margin (paper section III-B, "terrain constant
// within r").
#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "terrastride/collision/checks.hpp"

namespace terrastride::collision {

FootholdReport check_footholds(const planner::Trajectory& traj, const terrain::HeightField& field,
                               double foot_radius) {
  if (!std::isfinite(foot_radius) || foot_radius < 0)
    throw std::invalid_argument("foot radius must be finite and >= 0");
  FootholdReport rep;
  rep.foot_radius = foot_radius;
  rep.worst_margin = 1e9;  // the scenes' "nothing unsafe anywhere" value
  const size_t n = traj.samples.size();
  const size_t n_feet = traj.feet.size();
  for (size_t i = 0; i < n_feet; ++i) {
    for (size_t k = 0; k < n;) {
      if (i >= traj.samples[k].feet.size())
        throw TrajectoryError("samples[" + std::to_string(k) + "].feet: no entry for foot " +
                              std::to_string(i));
      if (!traj.samples[k].feet[i].contact) {
        ++k;
        continue;
      }
      Foothold fh;
      fh.leg = static_cast<int>(i);
      fh.first_sample = static_cast<int>(k);
      fh.t_start = traj.samples[k].t;
      fh.margin = 1e9;
      for (; k < n && i < traj.samples[k].feet.size() && traj.samples[k].feet[i].contact; ++k) {
        const Eigen::Vector3d& p = traj.samples[k].feet[i].position;
        const double m = field.safety_margin(p.x(), p.y(), foot_radius).margin;
        if (!std::isfinite(m))
          throw std::runtime_error("safety margin at (" + std::to_string(p.x()) + ", " +
                                   std::to_string(p.y()) + ") is not finite (" + field.describe() +
                                   ")");
        if (m < fh.margin || fh.last_sample < 0) {
          fh.margin = m;
          fh.position = p;
        }
        fh.last_sample = static_cast<int>(k);
        fh.t_end = traj.samples[k].t;
      }
      rep.footholds.push_back(fh);
    }
  }
  std::sort(rep.footholds.begin(), rep.footholds.end(), [](const Foothold& a, const Foothold& b) {
    return a.t_start != b.t_start ? a.t_start < b.t_start : a.leg < b.leg;
  });
  for (size_t f = 0; f < rep.footholds.size(); ++f) {
    const Foothold& fh = rep.footholds[f];
    if (!fh.safe()) ++rep.unsafe;
    if (rep.worst < 0 || fh.margin < rep.worst_margin) {
      rep.worst_margin = fh.margin;
      rep.worst = static_cast<int>(f);
    }
  }
  return rep;
}

}  // namespace terrastride::collision
