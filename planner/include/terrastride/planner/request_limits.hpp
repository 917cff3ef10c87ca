// The limits every plan request meets, whoever sends it: `terrastride plan`, the socket's `plan`
// and library callers. plan_motion enforces them before it builds anything, so no caller can ask
// for a problem whose size (and memory) is unbounded; the CLI and the service call
// check_plan_request early as well, to refuse before loading a terrain.
#pragma once

#include <stdexcept>
#include <string>

#include "terrastride/planner/nlp.hpp"

namespace terrastride::planner {

struct PlanLimits {
  // The horizon: the problem grows linearly with it (a 120 s crawl is ~48 k variables, 140 k
  // constraints, a few hundred MB in MUMPS); `--duration 1e9` reached the OOM killer at 24 GB.
  static constexpr double kMaxDuration = 120.0;
  // plan.json's sampling period: 2e-5 s made 6.6 GB of samples, 1e-9 overflowed to zero samples.
  // 1 ms is twice as fine as the dense checks (2 ms) and bounds a plan at 120,001 samples.
  static constexpr double kMinSampleDt = 1e-3;
  static constexpr double kMaxSampleDt = 1.0;
  static constexpr int kMinCycles = 1;
  static constexpr int kMaxCycles = 50;
  // A goal farther than this from the start is not a legged-robot plan on one map.
  static constexpr double kMaxGoalDistance = 1000.0;
};

// A request field out of its limits. what() is "FIELD: PROBLEM"; callers that name fields their
// own way (the CLI's --sample-dt, the socket's "sample_dt") compose field() and problem().
class RequestError : public std::invalid_argument {
 public:
  RequestError(std::string field, std::string problem)
      : std::invalid_argument(field + ": " + problem),
        field_(std::move(field)),
        problem_(std::move(problem)) {}
  const std::string& field() const { return field_; }
  const std::string& problem() const { return problem_; }

 private:
  std::string field_;
  std::string problem_;
};

// Checks what can be checked before the gait is read: duration (when given, > 0 and at most
// kMaxDuration), cycles, sample_dt, max_time, goal and start. Fields as in plan.json/the socket:
// "duration", "cycles", "sample_dt", "max_time", "goal", "start".
void check_plan_request(const PlannerOptions& options, double sample_dt);

// The horizon a request resolves to (a given duration, or the gait's period times its cycles, or
// an "init" plan's duration): at most kMaxDuration. `field` names where it came from.
void check_plan_horizon(double duration, const std::string& field);

}  // namespace terrastride::planner
