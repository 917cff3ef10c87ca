#include "terrastride/planner/layout.hpp"

#include <algorithm>
#include <cmath>

#include "terrastride/planner/constraints.hpp"
#include "terrastride/planner/piece_math.hpp"

namespace terrastride::planner {

std::vector<double> Layout::segment_points(int s, int n, bool with_end) const {
  std::vector<double> sigmas;
  const double c = s == 0 ? first_segment_cropped : 0.0;
  for (int q = 0; q <= n; ++q) {
    if (q == n && !with_end) break;
    const double old_sigma = static_cast<double>(q) / n;
    if (c == 0.0) {
      sigmas.push_back(old_sigma);
    } else if (q == 0) {
      sigmas.push_back(0.0);  // the new start
    } else if (old_sigma > c + 1e-9) {
      sigmas.push_back(q == n ? 1.0 : (old_sigma - c) / (1.0 - c));
    }
  }
  return sigmas;
}

namespace {

// n variables within [lo, hi]; the index of the first.
int add_variables(Variables* variables, int n, double lo, double hi) {
  const int first = variables->size();
  for (int i = 0; i < n; ++i) {
    variables->lower.push_back(lo);
    variables->upper.push_back(hi);
  }
  return first;
}

// Intervals (a duration variable each) and their segments, and the segments' nominal knot times.
void add_intervals_and_segments(const PhaseTimeline& timeline, const ProblemOptions& options,
                                Variables* variables, Layout* layout) {
  Layout& L = *layout;
  auto add = [&](int n, double lo, double hi) { return add_variables(variables, n, lo, hi); };
  const int ni = timeline.num_intervals();
  for (int j = 0; j < ni; ++j) {
    const double d = timeline.events[j + 1] - timeline.events[j];
    const int n = std::max(1, static_cast<int>(std::ceil(d / options.segment_dt - 1e-6)));
    L.interval_nominal.push_back(d);
    double lo = d, hi = d;
    if (options.optimize_timing) {
      lo = std::min(d, std::max(options.min_interval, options.interval_min_scale * d));
      hi = options.interval_max_scale * d;
    }
    L.interval_var.push_back(add(1, lo, hi));
    const double elapsed = j == 0 ? timeline.first_interval_elapsed : 0.0;
    if (elapsed > 0.0) {
      // The tail of a longer interval (a cropped timeline): knots where that interval had them,
      // a first segment up to the next one (merged into the following segment when shorter than
      // a tenth of a segment, which would only make the problem stiff).
      const double full = d + elapsed;
      const int n_full = std::max(1, static_cast<int>(std::ceil(full / options.segment_dt - 1e-6)));
      const double len = full / n_full;
      std::vector<double> bounds{0.0};
      for (int k = 1; k <= n_full; ++k) {
        const double b = k * len - elapsed;
        if (b <= 0.1 * len || b >= d - 1e-9) continue;
        bounds.push_back(b);
      }
      bounds.push_back(d);
      // The previous segment the start falls in: [k0 len, (k0 + 1) len] of the full interval.
      const int k0 = static_cast<int>(std::floor(elapsed / len + 1e-9));
      const double first_end = (k0 + 1) * len - elapsed;
      if (bounds.size() > 1 && std::abs(bounds[1] - first_end) < 1e-9)
        L.first_segment_cropped = elapsed / len - k0;
      for (std::size_t k = 0; k + 1 < bounds.size(); ++k) {
        L.seg_interval.push_back(j);
        L.seg_fraction.push_back((bounds[k + 1] - bounds[k]) / d);
      }
      continue;
    }
    for (int k = 0; k < n; ++k) {
      L.seg_interval.push_back(j);
      L.seg_fraction.push_back(1.0 / n);
    }
  }
  const int S = L.num_segments = static_cast<int>(L.seg_interval.size());
  L.nominal_knot_time.assign(S + 1, 0.0);
  for (int s = 0; s < S; ++s)
    L.nominal_knot_time[s + 1] =
        L.nominal_knot_time[s] + L.interval_nominal[L.seg_interval[s]] * L.seg_fraction[s];
}

// Each foot's position, velocity and force variables per knot, its stances and its swings.
void add_feet(int nf, const std::vector<bool>& ramp_knot, Variables* variables, Layout* layout) {
  Layout& L = *layout;
  const int S = L.num_segments;
  auto add = [&](int n, double lo, double hi) { return add_variables(variables, n, lo, hi); };
  L.foot_pos.assign(nf, std::vector<int>(S + 1, -1));
  L.foot_vel.assign(nf, std::vector<int>(S + 1, -1));
  L.force.assign(nf, std::vector<std::array<int, 2>>(S, {-1, -1}));
  for (int f = 0; f < nf; ++f) {
    for (int k = 0; k <= S; ++k) {
      const int left = k > 0 ? L.contact[f][k - 1] : -1;  // -1 none, 0 swing, 1 stance
      const int right = k < S ? L.contact[f][k] : -1;
      if (right == 1) {
        if (left == 1) {
          L.foot_pos[f][k] = L.foot_pos[f][k - 1];
        } else {
          L.foot_pos[f][k] = add(3, -kInf, kInf);
          L.stances.push_back({f, k, k, L.foot_pos[f][k], k == 0});
        }
      } else if (left == 1) {
        L.foot_pos[f][k] = L.foot_pos[f][k - 1];
      } else {
        L.foot_pos[f][k] = add(3, -kInf, kInf);
        L.foot_vel[f][k] = add(3, -kInf, kInf);
      }
      // Forces: one value per knot, shared by the stance segments on both sides of it. With
      // force ramps, none at a touch-down or lift-off that another foot's stance carries through
      // (ramp_knot): the force is zero there, so it rises from and falls to zero continuously
      // (constraints/force_ramp.cpp).
      const bool switch_knot = (left == 0 && right == 1) || (left == 1 && right == 0);
      if ((left == 1 || right == 1) && !(ramp_knot[k] && switch_knot)) {
        const int fv = add(3, -kInf, kInf);
        if (left == 1) L.force[f][k - 1][1] = fv;
        if (right == 1) L.force[f][k][0] = fv;
      }
      if (right == 1 && left == 1)
        for (auto& st : L.stances)
          if (st.foot == f && st.pos_var == L.foot_pos[f][k]) st.last_seg = k;
    }
    // Swings.
    for (int s = 0; s < S; ++s)
      if (!L.contact[f][s]) {
        if (s > 0 && !L.contact[f][s - 1])
          L.swings.back().last_seg = s;
        else
          L.swings.push_back({f, s, s});
      }
  }
}

}  // namespace

Layout make_layout(int num_feet, const PhaseTimeline& timeline, const ProblemOptions& options,
                   Variables* variables) {
  Layout L;
  const int nf = num_feet;
  const bool force_ramps = requests_constraint_set(options.constraints, "force_ramp");
  add_intervals_and_segments(timeline, options, variables, &L);
  const int S = L.num_segments;
  // Base knots.
  for (int k = 0; k <= S; ++k) L.base.push_back(add_variables(variables, 12, -kInf, kInf));
  // Contact per segment.
  L.contact.assign(nf, std::vector<bool>(S));
  for (int f = 0; f < nf; ++f)
    for (int s = 0; s < S; ++s) L.contact[f][s] = timeline.contact[f][L.seg_interval[s]];
  // Knots where force ramps apply: those that some foot's stance passes through. A gait without
  // such a foot at a contact switch (a trot whose diagonal pairs swap at one instant) would have
  // no force at all there, a free fall the dynamics cannot follow (every trot with 'all' stalled):
  // its switch knots keep their force variables, as without ramps.
  std::vector<bool> ramp_knot(S + 1, false);
  if (force_ramps)
    for (int k = 1; k < S; ++k)
      for (int f = 0; f < nf; ++f)
        if (L.contact[f][k - 1] && L.contact[f][k]) ramp_knot[k] = true;

  // Feet.
  add_feet(nf, ramp_knot, variables, &L);
  return L;
}

}  // namespace terrastride::planner
