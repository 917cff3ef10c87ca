// The SRBD trajectory optimisation problem as a set of variables and small constraint pieces.
//
// Parameterisation (see docs/design.md §6.1). The contact schedule's switch times split the plan
// into intervals; each interval is cut into equal segments of at most `segment_dt` (default
// 0.1 s). EVERY polynomial piece has its knots on these segment boundaries:
//  - base position and ZYX Euler angles: cubic Hermite splines (value and derivative per knot);
//  - each foot: cubic Hermite spline whose knots in a stance phase all share one position variable
//    with zero velocity (so the foot cannot slip), and have their own position/velocity in swing;
//  - contact forces: continuous piecewise LINEAR in time within a stance, zero in swing.
// Because base acceleration is linear inside a segment and so is the sum of forces, imposing
// m r'' = sum f - m g at both ends of each segment makes it hold at every instant; the friction
// pyramid is linear in f for the (constant) stance foothold, so imposing it at the force knots
// makes it hold along the whole stance. The remaining nonlinear constraints (angular dynamics,
// range of motion, swing clearance) are imposed at several points per segment (angular dynamics
// within a small band between the segment ends, see angular_band), and swing clearance
// conservatively (terrain probed around the foot, see constraints/swing_clearance.cpp).
// With optimised timing the interval durations become variables, every segment scaling with its
// interval, so the alignment above is kept.
#pragma once

#include <Eigen/Core>
#include <array>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "terrastride/planner/constraints.hpp"
#include "terrastride/planner/gait.hpp"
#include "terrastride/planner/layout.hpp"
#include "terrastride/planner/options.hpp"
#include "terrastride/robot/robot_model.hpp"
#include "terrastride/terrain/height_field.hpp"

namespace terrastride::planner {

// Largest number of variables one piece may depend on (fixed-size forward-mode AD).
constexpr int kMaxPieceVars = 72;

// One block of constraint rows depending on a few variables. Derivatives are exact: each piece is
// written once as a function template and differentiated by forward-mode automatic
// differentiation (Eigen AutoDiffScalar) over its local variables only.
class Piece {
 public:
  virtual ~Piece() = default;
  std::string kind;         // e.g. "dynamics_linear"; used in tests and reports
  std::vector<int> vars;    // global indices of the local variables (distinct)
  std::vector<double> lb, ub;  // per row
  int rows() const { return static_cast<int>(lb.size()); }
  // g: rows values; J: rows x vars.size(), row-major.
  virtual void eval(const double* x_local, double* g) const = 0;
  virtual void eval_jacobian(const double* x_local, double* g, double* jac) const = 0;
};

class SrbdProblem {
 public:
  // Builds variables, bounds, initial guess and pieces. `timeline` is the contact schedule;
  // start state: base pose/velocity and feet from `start_state` when given, else nominal stance
  // at options.start on `terrain`. `end_state` (a receding-horizon step, planning_session.hpp):
  // the base at the last knot is held at its pose, velocity and Euler rates instead of resting at
  // the goal (degrees of freedom the robot cannot move keep their start value), and the feet there
  // at its foot positions and their forces when it has them (a stance the start fixes keeps the
  // start's); the end then gets no rest rows. It is fixed before the constraint sets are built, so their rows see the pinned
  // end as fixed (a row on fixed variables only is left out, not left as a constant).
  struct StartState {
    Eigen::Vector3d position, euler_zyx, linear_velocity, euler_rates;
    std::vector<Eigen::Vector3d> foot_position, foot_velocity;
    // An end state's contact forces (world, N), when it has them: held at the last knot.
    std::vector<Eigen::Vector3d> foot_force;
  };
  SrbdProblem(const robot::RobotModel& robot, const terrain::HeightField& terrain,
              const PhaseTimeline& timeline, const ProblemOptions& options,
              const StartState* start_state = nullptr, const StartState* end_state = nullptr);
  ~SrbdProblem();

  int num_variables() const { return variables_.size(); }
  int num_free_variables() const;
  int num_constraints() const { return num_rows_; }
  const std::vector<std::unique_ptr<Piece>>& pieces() const { return pieces_; }
  const std::vector<double>& lower() const { return variables_.lower; }
  const std::vector<double>& upper() const { return variables_.upper; }
  std::vector<double>& initial_guess() { return variables_.initial; }
  const robot::RobotModel& robot() const { return robot_; }
  const terrain::HeightField& terrain() const { return terrain_; }
  const PhaseTimeline& timeline() const { return timeline_; }
  const ProblemOptions& options() const { return options_; }
  const Layout& layout() const { return layout_; }

  // Adds the piece's rows. A re-plan from a measured state (a start state given) pins knot 0 to
  // the measurement, so a piece on fixed variables only is a constant there: one the measurement
  // already violates (e.g. a joint past its range after a push) no solve can repair, and imposed it
  // made the step infeasible by construction. Such a piece is not added: its excess is
  // recorded in start_excess() instead (in end_excess() when only a pinned horizon end makes it
  // constant). Cold plans, and constant pieces within their bounds, are added as before.
  void add_piece(std::unique_ptr<Piece> piece);
  // The measured start's own violations, largest per piece kind (rows' units), of the pieces
  // add_piece left out; empty for a start within every bound. Excesses of at most
  // kConstantExcessReportMin (round-off) are left out without being reported.
  const std::map<std::string, double>& start_excess() const { return start_excess_; }
  // Likewise for the pieces that are constant only because a session step pins its horizon end.
  const std::map<std::string, double>& end_excess() const { return end_excess_; }
  static constexpr double kConstantExcessReportMin = 1e-6;

  // The objective (planner/src/costs/): a sum of squares of the rows of its cost pieces,
  // f(x) = sum over pieces and rows of g_r(x)^2 (a cost piece's bounds are unused). Empty when
  // every weight is zero: then the problem is the feasibility problem of the original design.
  void add_cost(std::unique_ptr<Piece> piece);
  const std::vector<std::unique_ptr<Piece>>& cost_pieces() const { return cost_pieces_; }
  bool has_objective() const { return !cost_pieces_.empty(); }
  double eval_objective(const double* x) const;
  // grad (num_variables() entries) = df/dx.
  void eval_objective_gradient(const double* x, double* grad) const;
  // Whether the plan starts from rest (no start state was given) and so gets the rest rows there.
  bool starts_at_rest() const { return starts_at_rest_; }
  // Whether the plan ends at rest at its goal (no end state was given) and so gets the rest rows
  // there.
  bool ends_at_rest() const { return ends_at_rest_; }

  // Full constraint vector and the Jacobian as triplets (row, col, value) in piece order.
  void eval_constraints(const double* x, double* g) const;
  void jacobian_structure(int* rows, int* cols) const;
  void eval_jacobian(const double* x, double* values) const;
  int jacobian_nonzeros() const { return nnz_; }
  std::vector<double> row_lower() const;
  std::vector<double> row_upper() const;
  // Largest bound violation of x (rows and variable bounds), in the constraint's own units.
  double max_violation(const std::vector<double>& x) const;
  // The same from the constraint values g = eval_constraints(x) already at hand.
  double max_violation(const std::vector<double>& x, const std::vector<double>& g) const;
  // The same, per piece kind (for diagnostics: which constraint family is violated).
  std::map<std::string, double> violation_by_kind(const std::vector<double>& x) const;

  // Continuous-time evaluation of a solution x (world frame), t in [0, duration(x)].
  struct State {
    Eigen::Vector3d pos, vel, acc, euler, euler_rate, euler_acc;
    std::vector<Eigen::Vector3d> foot_pos, foot_vel, force;
    std::vector<bool> contact;
  };
  State evaluate(const std::vector<double>& x, double t) const;
  double duration(const std::vector<double>& x) const;
  // Event times of the solution (optimised timing moves them).
  std::vector<double> event_times(const std::vector<double>& x) const;

  // Initial guess from a previous plan (time `shift` of that plan becomes t = 0 here). With
  // bridge_span > 0 and a measured start, the guess's first bridge_span seconds go from the
  // measured state to the previous plan instead (bridge_guess_from_start, for a start far from it).
  void warm_start_from(const struct Trajectory& previous, double shift, double bridge_span = 0.0);

 private:

  const robot::RobotModel& robot_;
  const terrain::HeightField& terrain_;
  PhaseTimeline timeline_;
  ProblemOptions options_;
  Layout layout_;
  Variables variables_;
  std::vector<std::unique_ptr<Piece>> pieces_;
  std::vector<std::unique_ptr<Piece>> cost_pieces_;
  bool starts_at_rest_ = true;
  bool ends_at_rest_ = true;
  std::map<std::string, double> start_excess_, end_excess_;
  std::vector<char> fixed_by_start_;  // per variable: fixed by the start state (re-plans only)
  void pin_end_state(const StartState& end);
  void bridge_guess_from_start(const struct TrajectorySample& guess_start, double span);
  std::vector<int> row_offset_, nz_offset_;
  int num_rows_ = 0, nnz_ = 0;
};

}  // namespace terrastride::planner
