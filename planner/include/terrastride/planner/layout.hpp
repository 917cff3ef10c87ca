// The variables of the SRBD problem (parameterisation in nlp.hpp): which segments the contact
// schedule's intervals are cut into, and where each quantity lives in the variable vector (base
// knots, one position per stance, position and velocity per swing knot, force knots).
#pragma once

#include <array>
#include <vector>

#include "terrastride/planner/gait.hpp"
#include "terrastride/planner/options.hpp"

namespace terrastride::planner {

// Where each quantity lives in the variable vector (indices; -1 = identically zero).
struct Layout {
  int num_segments = 0;
  std::vector<int> seg_interval;         // interval of each segment
  std::vector<double> seg_fraction;      // 1 / (segments in its interval)
  std::vector<int> interval_var;         // duration variable of each interval
  std::vector<double> interval_nominal;  // s
  std::vector<int> base;  // per knot: first of 12 = position(3) velocity(3) euler(3) euler rate(3)
  std::vector<std::vector<int>> foot_pos, foot_vel;    // [foot][knot]; foot_vel -1 = zero
  std::vector<std::vector<std::array<int, 2>>> force;  // [foot][segment][start/end]; -1 = zero
  std::vector<std::vector<bool>> contact;              // [foot][segment]
  struct Stance {
    int foot, first_seg, last_seg;  // segments [first_seg, last_seg]
    int pos_var;
    bool fixed;  // initial stance: position given
  };
  std::vector<Stance> stances;
  struct Swing {
    int foot, first_seg, last_seg;
  };
  std::vector<Swing> swings;
  std::vector<double> nominal_knot_time;
  // A re-plan's timeline starts inside an interval of the previous plan (first_interval_elapsed);
  // its first segment is then the tail of one of the previous plan's segments, of which this
  // fraction had elapsed (0 when it is not: a plan from rest, or a tail merged with the next).
  double first_segment_cropped = 0.0;
  // The constraint points of segment s for n points per segment: fractions q / n, q = 0 .. n - 1
  // (and n when with_end). In a cropped first segment the points stay where the previous plan had
  // them (the previous solution, exact there, then needs no iteration to re-verify), plus the
  // segment's new start.
  std::vector<double> segment_points(int s, int n, bool with_end) const;
};

// The variables' bounds and initial values, by index.
struct Variables {
  std::vector<double> lower, upper, initial;
  int size() const { return static_cast<int>(lower.size()); }
  // Holds variable i at v: both bounds and the initial value.
  void fix(int i, double v) { lower[i] = upper[i] = initial[i] = v; }
};

// The layout of `timeline`'s variables for a robot with `num_feet` feet. Appends the variables'
// bounds to `variables`: interval durations fixed at their nominal value (within
// [interval_min_scale, interval_max_scale] times it when the timing is optimised), everything
// else unbounded (the initial guess fixes what the start and goal determine).
Layout make_layout(int num_feet, const PhaseTimeline& timeline, const ProblemOptions& options,
                   Variables* variables);

}  // namespace terrastride::planner
