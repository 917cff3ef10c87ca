#include "terrastride/planner/solver.hpp"
#include "terrastride/planner/solver_fork.hpp"
#include "terrastride/planner/piece_math.hpp"  // kGravity
#include "step_blockers.hpp"

#include <IpIpoptApplication.hpp>
#include <IpIpoptCalculatedQuantities.hpp>
#include <IpTNLP.hpp>
#include <pthread.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <functional>
#include <limits>
#include <memory>
#include <mutex>
#include <new>
#include <sstream>
#include <thread>

namespace terrastride::planner {

namespace {

using Ipopt::Index;
using Ipopt::Number;

// The Gauss-Newton Hessian of the objective sum_r g_r^2: 2 J^T J, lower triangle, one block
// per cost piece (Ipopt adds entries given twice).
int objective_hessian_nonzeros(const SrbdProblem& p) {
  int n = 0;
  for (const auto& c : p.cost_pieces()) {
    const int k = static_cast<int>(c->vars.size());
    n += k * (k + 1) / 2;
  }
  return n;
}
void objective_hessian_structure(const SrbdProblem& p, Index* rows, Index* cols) {
  int z = 0;
  for (const auto& c : p.cost_pieces()) {
    const int k = static_cast<int>(c->vars.size());
    for (int i = 0; i < k; ++i)
      for (int j = 0; j <= i; ++j) {
        rows[z] = std::max(c->vars[i], c->vars[j]);
        cols[z] = std::min(c->vars[i], c->vars[j]);
        ++z;
      }
  }
}
void objective_hessian(const SrbdProblem& p, const double* x, double factor, double* values) {
  int z = 0;
  double xl[kMaxPieceVars], g[64];
  std::vector<double> jac(64 * kMaxPieceVars);
  for (const auto& c : p.cost_pieces()) {
    const int k = static_cast<int>(c->vars.size()), m = c->rows();
    for (int i = 0; i < k; ++i) xl[i] = x[c->vars[i]];
    c->eval_jacobian(xl, g, jac.data());
    for (int i = 0; i < k; ++i)
      for (int j = 0; j <= i; ++j) {
        double h = 0.0;
        for (int r = 0; r < m; ++r) h += jac[r * k + i] * jac[r * k + j];
        values[z++] = 2.0 * factor * h;
      }
  }
}

class SrbdTnlp : public Ipopt::TNLP {
 public:
  SrbdTnlp(const SrbdProblem& p, const SolverOptions& options)
      : p_(p),
        max_wall_(options.max_time),
        should_stop_(options.should_stop),
        feasibility_tol_(options.feasibility_stop_tolerance),
        objective_tol_(options.objective_stop_tolerance),
        stall_iterations_(options.stall_iterations) {
    start_ = std::chrono::steady_clock::now();
    if (std::getenv("TERRASTRIDE_DEBUG_STEPS")) step_blockers_ = std::make_unique<StepBlockers>(p);
  }
  bool get_nlp_info(Index& n, Index& m, Index& nnz_jac, Index& nnz_h,
                    IndexStyleEnum& style) override {
    n = p_.num_variables();
    m = p_.num_constraints();
    nnz_jac = p_.jacobian_nonzeros();
    nnz_h = improving_ ? objective_hessian_nonzeros(p_) : 0;
    style = C_STYLE;
    return true;
  }
  bool get_bounds_info(Index n, Number* xl, Number* xu, Index m, Number* gl, Number* gu) override {
    std::copy(p_.lower().begin(), p_.lower().end(), xl);
    std::copy(p_.upper().begin(), p_.upper().end(), xu);
    const auto lo = p_.row_lower(), hi = p_.row_upper();
    std::copy(lo.begin(), lo.end(), gl);
    std::copy(hi.begin(), hi.end(), gu);
    return true;
  }
  bool get_starting_point(Index n, bool init_x, Number* x, bool init_z, Number*, Number*, Index,
                          bool init_lambda, Number*) override {
    if (init_z || init_lambda) return false;
    const auto& x0 = start_x_ ? *start_x_ : const_cast<SrbdProblem&>(p_).initial_guess();
    std::copy(x0.begin(), x0.end(), x);
    return true;
  }
  // Forces are variables in newtons, hundreds of them, beside positions and angles of order one:
  // unscaled, the L-BFGS model and the fraction-to-the-boundary rule treat a newton like a metre,
  // and the first iterations crawl (steps of 1-10 % for some ten iterations). Forces are
  // therefore scaled to units of the robot's weight; the rows are already scaled by construction
  // (dynamics / m g, lengths in m), so Ipopt's own row scaling is not used. Measured over ten
  // scenarios (flat, pallets, EUR pallet, trot, monoped hop; baseline and all): 191 iterations
  // in all before, 90 after.
  bool get_scaling_parameters(Number& obj_scaling, bool& use_x_scaling, Index n, Number* x_scaling,
                              bool& use_g_scaling, Index, Number*) override {
    obj_scaling = 1.0;
    use_x_scaling = true;
    std::fill(x_scaling, x_scaling + n, 1.0);
    const double weight = p_.robot().mass * kGravity;
    for (const auto& foot : p_.layout().force)
      for (const auto& knot : foot)
        for (int v : knot)
          if (v >= 0)
            for (int d = 0; d < 3; ++d) x_scaling[v + d] = 1.0 / weight;
    use_g_scaling = false;
    return true;
  }
  // The objective (planner/src/costs/): zero when the problem has no cost pieces, the
  // feasibility problem of the original design.
  // In the feasibility phase the objective is zero whatever the problem's (see solve()).
  bool eval_f(Index, const Number* x, bool, Number& f) override {
    f = improving_ ? p_.eval_objective(x) : 0.0;
    return true;
  }
  bool eval_grad_f(Index n, const Number* x, bool, Number* g) override {
    if (improving_)
      p_.eval_objective_gradient(x, g);
    else
      std::fill(g, g + n, 0.0);
    return true;
  }
  // The improvement phase's Hessian: the objective's Gauss-Newton Hessian 2 J^T J (exact for
  // its linear residuals, all but the Hermite durations' terms), times obj_factor, and no
  // constraint curvature. Limited-memory BFGS could not model the objective's curvature beside
  // the constraints' (flat 2.4 s crawl: 40 iterations of objective and violation oscillating,
  // never a feasible iterate better than the start); see improve().
  bool eval_h(Index n, const Number* x, bool, Number obj_factor, Index, const Number*, bool,
              Index nele, Index* irow, Index* jcol, Number* values) override {
    if (values == nullptr) {
      objective_hessian_structure(p_, irow, jcol);
      return true;
    }
    objective_hessian(p_, x, obj_factor, values);
    return true;
  }
  bool eval_g(Index n, const Number* x, bool, Index m, Number* g) override {
    p_.eval_constraints(x, g);
    last_x_.assign(x, x + n);
    last_g_.assign(g, g + m);
    return true;
  }
  bool eval_jac_g(Index n, const Number* x, bool, Index, Index nele, Index* irow, Index* jcol,
                  Number* values) override {
    if (values == nullptr) {
      p_.jacobian_structure(irow, jcol);
      return true;
    }
    if (stops_at_verified_point(n, x)) return false;
    p_.eval_jacobian(x, values);
    return true;
  }
  // Ipopt asks for the Jacobian at an accepted iterate before it calls intermediate_callback there
  // (the callback's dual infeasibility needs it), so a solve that stops at a verified feasible point
  // used to evaluate one Jacobian it never used: a fifth of a session step's Jacobians (3.9
  // iterations, 4.9 Jacobians per step on pallet_15 `all`). The feasibility phase therefore checks
  // the point here first, from the values eval_g computed at it (the Jacobian at an iterate is
  // always asked for right after its constraints), and stops by declining the Jacobian: Ipopt
  // abandons the solve with an evaluation error, and solve() takes the verified point.
  bool stops_at_verified_point(Index n, const Number* x) {
    if (!stop_before_jacobian_ || improving_ || !(feasibility_tol_ > 0.0) ||
        static_cast<Index>(last_x_.size()) != n || !std::equal(last_x_.begin(), last_x_.end(), x))
      return false;
    const double violation = p_.max_violation(last_x_, last_g_);
    if (violation > feasibility_tol_) return false;
    feasible_x_ = last_x_;
    feasible_violation_ = violation;
    stopped_feasible_ = true;
    // The iterate after the last one intermediate_callback saw (or the starting point).
    if (callback_seen_) ++iterations_;
    declined_jacobian_ = true;
    return true;
  }
  // The objective is identically zero, so every feasible point is an optimum: once the primal
  // infeasibility is small, the last evaluated point is checked with our own violation measure
  // (every row and variable bound, in the constraints' own units) and the solve stops there
  // instead of iterating on for the multipliers (which the plan does not use). Ipopt's inf_pr only
  // triggers the check; the point returned is verified. The trigger is the unscaled max-norm
  // violation (the "inf_pr" column of Ipopt's output), not the callback's inf_pr argument, which
  // in Ipopt 3.11 is measured on the scaled problem: measured on a warm start, the argument stayed
  // near 1e-2 for seven iterations in which the unscaled violation was below 1e-10.
  bool intermediate_callback(Ipopt::AlgorithmMode mode, Index iter, Number, Number inf_pr, Number,
                             Number, Number, Number, Number, Number alpha_pr, Index,
                             const Ipopt::IpoptData* ip_data,
                             Ipopt::IpoptCalculatedQuantities* cq) override {
    iterations_ = iter;
    callback_seen_ = true;
    if (step_blockers_ && mode == Ipopt::RegularMode)
      step_blockers_->observe(iter, alpha_pr, ip_data, cq);
    if (max_wall_ > 0.0 && elapsed() > max_wall_) {
      timed_out_ = true;
      return false;
    }
    if (should_stop_ && should_stop_()) return false;
    if (cq != nullptr) inf_pr = cq->unscaled_curr_nlp_constraint_violation(Ipopt::NORM_MAX);
    // Progress is judged on regular iterations only: in the restoration phase the calculated
    // quantities are those of the restoration problem. Its iterations still count as time spent.
    if (mode == Ipopt::RegularMode && inf_pr < 0.99 * best_violation_) {
      best_violation_ = inf_pr;
      best_iteration_ = iter;
    }
    if (stall_iterations_ > 0 && iter - best_iteration_ > stall_iterations_) {
      stalled_ = true;
      return false;
    }
    // Improving, an iterate counts when it is nearly feasible (near_feasible_tol): the polish
    // (see improve()) makes it feasible.
    const double tol = improving_ ? near_feasible_tol_ : feasibility_tol_;
    if (tol > 0.0 && mode == Ipopt::RegularMode && inf_pr < 1e3 * tol &&
        static_cast<int>(last_x_.size()) == p_.num_variables()) {
      // From the values eval_g computed there: a second evaluation cost 30 ms of a 150 ms warm
      // re-plan on pallet_15.
      const double violation = p_.max_violation(last_x_, last_g_);
      if (violation <= tol) {
        if (!improving_) {
          feasible_x_ = last_x_;
          feasible_violation_ = violation;
          stopped_feasible_ = true;
          return false;
        }
        // Improving: keep the best verified feasible iterate; stop once the objective fell by
        // at most objective_tol (relative) since the previous iterate, which was feasible too.
        const double f = p_.eval_objective(last_x_.data());
        if (f < feasible_objective_) {
          feasible_x_ = last_x_;
          feasible_violation_ = violation;
          feasible_objective_ = f;
        }
        const bool settled = last_feasible_objective_ - f <= objective_tol_ * std::max(f, 1e-12);
        last_feasible_objective_ = f;
        if (settled) {
          stopped_feasible_ = true;
          return false;
        }
        return true;
      }
    }
    if (improving_) last_feasible_objective_ = std::numeric_limits<double>::infinity();
    return true;
  }
  void finalize_solution(Ipopt::SolverReturn status, Index n, const Number* x, const Number*,
                         const Number*, Index, const Number*, const Number*, Number,
                         const Ipopt::IpoptData*, Ipopt::IpoptCalculatedQuantities*) override {
    x_.assign(x, x + n);
    status_ = status;
  }
  double elapsed() const {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
  }

  std::vector<double> x_;
  std::vector<double> last_x_;       // the last point whose constraints Ipopt evaluated
  std::vector<double> last_g_;       // and its constraint values
  std::vector<double> feasible_x_;   // set when the solve stopped at a verified feasible point
  double feasible_violation_ = 0.0;  // its largest violation
  double feasible_objective_ = std::numeric_limits<double>::infinity();  // its objective
  bool stopped_feasible_ = false;  // the solve ended there (feasible_x_ is the solution)
  // false: the feasibility phase (zero objective); true: the improvement phase, from start_x_.
  bool improving_ = false;
  double near_feasible_tol_ = 1e-3;
  const std::vector<double>* start_x_ = nullptr;
  Ipopt::SolverReturn status_ = Ipopt::INTERNAL_ERROR;
  int iterations_ = 0;
  bool callback_seen_ = false;  // intermediate_callback has run (iterations_ is an iterate's)
  bool declined_jacobian_ = false;  // stopped by stops_at_verified_point
  // Off for Ipopt's derivative checker, which asks for the Jacobian at the starting point.
  bool stop_before_jacobian_ = true;
  bool timed_out_ = false;
  bool stalled_ = false;
  double best_violation_ = std::numeric_limits<double>::infinity();  // see stall_iterations
  int best_iteration_ = 0;

 private:
  const SrbdProblem& p_;
  double max_wall_;
  std::function<bool()> should_stop_;
  double feasibility_tol_;
  double objective_tol_;
  double last_feasible_objective_ = std::numeric_limits<double>::infinity();
  int stall_iterations_;
  std::chrono::steady_clock::time_point start_;
  std::unique_ptr<StepBlockers> step_blockers_;  // TERRASTRIDE_DEBUG_STEPS
};

// Debian's sequential MUMPS (libdmumps_seq, Ipopt's only linear solver there) is not re-entrant:
// two solves at once in one process crash inside it (the service's two workers: SIGSEGV in 11 of
// 11 tries). So one solve runs at a time per process, from building the IpoptApplication to
// destroying it (MUMPS's instance is terminated in its destructor). Concurrency comes from
// processes: the service runs each plan in a child process (service/src/server/child_process.cpp),
// forked under a SolverForkGuard so that no solve is half-way through when the child is made.
std::timed_mutex& solver_mutex() {
  static std::timed_mutex m;
  return m;
}

// Fork guards waiting for the solver: solves about to start give way to them, so a stream of
// planning-session steps cannot keep a plan process from being forked.
std::atomic<int>& forks_waiting() {
  static std::atomic<int> n{0};
  return n;
}

// The child of a fork made while some thread held the lock (the guard's own thread, or, without a
// guard, a solve) inherits it locked with no thread to release it: it starts with a fresh one.
void reset_solver_mutex_in_child() {
  new (&solver_mutex()) std::timed_mutex;
  forks_waiting().store(0);
}

void register_solver_atfork() {
  static std::once_flag once;
  std::call_once(once, [] { pthread_atfork(nullptr, nullptr, &reset_solver_mutex_in_child); });
}

// Takes the solver lock, polling `should_stop` while another solve (or a fork guard) holds it so
// that a cancelled or expired request does not wait for someone else's solve. Returns an unlocked
// lock if stopped.
std::unique_lock<std::timed_mutex> acquire_solver(const SolverOptions& options) {
  register_solver_atfork();
  std::unique_lock<std::timed_mutex> lock(solver_mutex(), std::defer_lock);
  for (;;) {
    if (forks_waiting().load() == 0 && lock.try_lock_for(std::chrono::milliseconds(5))) {
      if (forks_waiting().load() == 0) break;
      lock.unlock();  // a fork guard arrived while this solve took the lock: it goes first
    }
    if (options.should_stop && options.should_stop()) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
  return lock;
}

}  // namespace

SolverForkGuard::SolverForkGuard(const std::function<bool()>& should_stop)
    : lock_(solver_mutex(), std::defer_lock) {
  register_solver_atfork();
  forks_waiting()++;
  waiting_ = true;
  while (!lock_.try_lock_for(std::chrono::milliseconds(5)))
    if (should_stop && should_stop()) break;
}

SolverForkGuard::~SolverForkGuard() { release(); }

void SolverForkGuard::release() {
  if (lock_.owns_lock()) lock_.unlock();
  if (waiting_) forks_waiting()--;
  waiting_ = false;
}

void SolverForkGuard::release_in_child() {
  // The atfork handler made the mutex and the count fresh; the lock object must not unlock it.
  lock_.release();
  waiting_ = false;
}

namespace {

// The improvement phase (see SolverOptions::objective_max_iterations): from the feasible point
// of the feasibility phase, Ipopt minimises the objective with the barrier of a warm start
// (mu_init 1e-4, bound_push and bound_frac 1e-5: the point is feasible and most inequalities are
// active, and Ipopt's defaults would push it 1 % off its bounds and start at mu = 0.1), and stops
// at the first verified feasible iterate whose objective fell by at most objective_stop_tolerance
// since the previous (feasible) iterate. The best verified feasible iterate is kept; when none beats
// the feasibility phase's point, that point stays the solution (the objective never costs
// feasibility).
void improve(const SrbdProblem& problem, const SolverOptions& options,
             Ipopt::IpoptApplication& app, double spent_s, SolveResult* r) {
  const auto t0 = std::chrono::steady_clock::now();
  auto budget = [&](SolverOptions* o) {
    if (options.max_time <= 0.0) return true;
    o->max_time = options.max_time - spent_s -
                  std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    return o->max_time > 0.0;
  };
  SolverOptions left = options;
  if (!budget(&left)) return;
  const std::vector<double> start = r->x;
  const double f0 = problem.eval_objective(start.data());
  r->objective_start = f0;
  auto opts = app.Options();
  // Both phases below start from a point that is feasible or nearly so, with most inequalities
  // active: Ipopt's defaults would push it 1 % off its bounds and start the barrier at 0.1.
  opts->SetNumericValue("mu_init", 1e-4);
  opts->SetNumericValue("bound_push", 1e-5);
  opts->SetNumericValue("bound_frac", 1e-5);
  // Improve: the objective with its Gauss-Newton Hessian (SrbdTnlp::eval_h), up to a nearly
  // feasible iterate where it has settled.
  Ipopt::SmartPtr<SrbdTnlp> nlp = new SrbdTnlp(problem, left);
  nlp->improving_ = true;
  nlp->near_feasible_tol_ = options.objective_near_feasible_tolerance;
  nlp->start_x_ = &start;
  opts->SetIntegerValue("max_iter", options.objective_max_iterations);
  opts->SetStringValue("hessian_approximation", "exact");
  if (left.max_time > 0.0) opts->SetNumericValue("max_cpu_time", left.max_time);
  app.OptimizeTNLP(nlp);
  r->objective_iterations = nlp->iterations_;
  r->iterations += nlp->iterations_;
  if (nlp->feasible_x_.empty() || !(nlp->feasible_objective_ < f0)) return;
  // Polish: the feasibility phase again (zero objective, limited-memory Hessian) from the best
  // nearly feasible iterate, to a point verified feasible to feasibility_stop_tolerance.
  SolverOptions polish_options = options;
  if (!budget(&polish_options)) return;
  const std::vector<double> candidate = nlp->feasible_x_;
  Ipopt::SmartPtr<SrbdTnlp> polish = new SrbdTnlp(problem, polish_options);
  polish->start_x_ = &candidate;
  opts->SetStringValue("hessian_approximation", "limited-memory");
  opts->SetIntegerValue("max_iter", options.objective_max_iterations);
  if (polish_options.max_time > 0.0) opts->SetNumericValue("max_cpu_time", polish_options.max_time);
  app.OptimizeTNLP(polish);
  r->polish_iterations = polish->iterations_;
  r->objective_iterations += polish->iterations_;
  r->iterations += polish->iterations_;
  if (!polish->stopped_feasible_) return;
  if (!(problem.eval_objective(polish->feasible_x_.data()) < f0)) return;
  r->x = polish->feasible_x_;
  r->max_violation = polish->feasible_violation_;
}

}  // namespace

std::vector<std::pair<std::string, std::string>> ipopt_options_from_env(const char* variable) {
  std::vector<std::pair<std::string, std::string>> options;
  const char* env = std::getenv(variable);
  if (env == nullptr) return options;
  std::istringstream in(env);
  std::string item;
  while (in >> item)
    if (const auto eq = item.find('='); eq != std::string::npos)
      options.emplace_back(item.substr(0, eq), item.substr(eq + 1));
  return options;
}

namespace {

// The solver's fixed Ipopt settings for these problems (each one's reason beside it).
void set_ipopt_options(Ipopt::OptionsList& opts, const SolverOptions& options) {
  opts.SetIntegerValue("print_level", options.verbose ? 5 : 0);
  opts.SetStringValue("sb", "yes");  // no banner
  opts.SetStringValue("hessian_approximation", "limited-memory");
  opts.SetStringValue("linear_solver", "mumps");
  // Approximate minimum degree: on these banded-in-time KKT systems it needs 1.4-2.4x fewer
  // factorisation flops and 15-33 % fewer factor entries than MUMPS's automatic choice (AMF),
  // with the same iteration counts (pallet_15 baseline: 3.8e7 against 9.0e7 flops per factorisation).
  opts.SetIntegerValue("mumps_pivot_order", 0);
  // No maximum-transversal permutation/scaling in MUMPS's analysis: on pallet_15 it made the
  // analysis 0.14 s instead of 0.02 s, half of a warm-started re-plan, and the iteration counts
  // over the ten-scenario set are unchanged without it (factorisation flops 5 % lower).
  opts.SetIntegerValue("mumps_permuting_scaling", 0);
  // The L-BFGS update as extra rows of the factorised system instead of Sherman-Morrison: the
  // default spends 2 x history extra back-solves per iteration (pallet_15: 117 solves against 48),
  // and MUMPS's back-solves cost a fifth of a factorisation each on these small fronts.
  opts.SetStringValue("limited_memory_aug_solver", "extended");
  // Iterative refinement only when a solve's residual ratio exceeds 1e-8 (default: always one
  // step, and more above 1e-10). MUMPS back-solves cost about 4 ms each on the flat crawl's
  // system, whatever their size; this drops 24 of them to 17 there (pallet_15: 27 to 20) with the
  // same iteration counts over the ten-scenario set.
  opts.SetIntegerValue("min_refinement_steps", 0);
  opts.SetNumericValue("residual_ratio_max", 1e-8);
  opts.SetStringValue("fixed_variable_treatment", "make_parameter");
  opts.SetStringValue("nlp_scaling_method", "user-scaling");  // see get_scaling_parameters
  // Start the constraint multipliers at zero instead of a least-squares estimate: the estimate
  // costs a factorisation of the KKT system, and over the ten-scenario set the iteration counts
  // were the same or lower without it (flat "all": 15 -> 7).
  opts.SetNumericValue("constr_mult_init_max", 0.0);
  // The adaptive barrier falls back to a monotone mode when it stops making progress, and on the
  // demo's scanned pallet that fallback held mu near 6 for some 40 iterations (48 in all). Without
  // the fallback: 25 iterations, plan 4.3-4.7 s instead of 7.4-8.6 s. Flat, pallet_10 and pallet_15,
  // baseline and all, never fall back: the same iteration counts either way.
  opts.SetStringValue("adaptive_mu_globalization", "never-monotone-mode");
  opts.SetNumericValue("tol", options.tolerance);
  opts.SetNumericValue("constr_viol_tol", options.tolerance);
  opts.SetNumericValue("acceptable_tol", 10 * options.tolerance);
  opts.SetIntegerValue("max_iter", options.max_iterations);
  if (options.max_time > 0.0) opts.SetNumericValue("max_cpu_time", options.max_time);
}

// Ipopt options given by the caller, then those of TERRASTRIDE_IPOPT_OPTIONS (tuning runs), after
// the fixed ones so they override them.
void set_extra_ipopt_options(Ipopt::OptionsList& opts,
                             const std::vector<std::pair<std::string, std::string>>& extra_options) {
  auto all_options = extra_options;
  for (auto& option : ipopt_options_from_env("TERRASTRIDE_IPOPT_OPTIONS"))
    all_options.push_back(std::move(option));
  for (const auto& [k, v] : all_options) {
    // Numbers and integers are passed as such; anything else as a string option.
    char* end = nullptr;
    const long iv = std::strtol(v.c_str(), &end, 10);
    if (end && *end == '\0' && !v.empty()) {
      if (!opts.SetIntegerValue(k, static_cast<Ipopt::Index>(iv))) opts.SetNumericValue(k, iv);
      continue;
    }
    const double dv = std::strtod(v.c_str(), &end);
    if (end && *end == '\0' && !v.empty())
      opts.SetNumericValue(k, dv);
    else
      opts.SetStringValue(k, v);
  }
}

// The status of a solve that ended in Ipopt (not at a verified feasible iterate).
std::string ipopt_status_name(Ipopt::ApplicationReturnStatus st, const SrbdTnlp& nlp) {
  switch (st) {
    case Ipopt::Solve_Succeeded:
      return "optimal";
    case Ipopt::Solved_To_Acceptable_Level:
      return "acceptable";
    case Ipopt::Infeasible_Problem_Detected:
      return "infeasible";
    case Ipopt::Maximum_Iterations_Exceeded:
      return "max_iterations";
    case Ipopt::Maximum_CpuTime_Exceeded:
      return "time_limit";
    case Ipopt::User_Requested_Stop:
      return nlp.timed_out_ ? "time_limit" : nlp.stalled_ ? "stalled" : "stopped";
    case Ipopt::Diverging_Iterates:
      return "diverging";
    case Ipopt::Restoration_Failed:
      return "restoration_failed";
    case Ipopt::Search_Direction_Becomes_Too_Small:
      return "step_too_small";
    case Ipopt::Error_In_Step_Computation:
      return "step_failed";
    case Ipopt::Not_Enough_Degrees_Of_Freedom:
      return "too_few_degrees_of_freedom";
    case Ipopt::Invalid_Number_Detected:
      return "invalid_number";
    default:
      return "error";
  }
}

// The answer when another solve holds the solver and this one was told not to wait: the initial
// guess, judged.
SolveResult stopped_before_solve(const SrbdProblem& problem) {
  SolveResult stopped;
  stopped.status = "stopped";
  stopped.termination = "stopped before the solve (another solve held the solver)";
  stopped.x = const_cast<SrbdProblem&>(problem).initial_guess();
  stopped.max_violation = problem.max_violation(stopped.x);
  return stopped;
}

}  // namespace

SolveResult solve(const SrbdProblem& problem, const SolverOptions& options,
                  const std::vector<std::pair<std::string, std::string>>& extra_options) {
  const auto lock = acquire_solver(options);
  if (!lock.owns_lock()) return stopped_before_solve(problem);
  const auto t0 = std::chrono::steady_clock::now();
  Ipopt::SmartPtr<SrbdTnlp> nlp = new SrbdTnlp(problem, options);
  for (const auto& option : extra_options)
    if (option.first == "derivative_test") nlp->stop_before_jacobian_ = false;
  Ipopt::SmartPtr<Ipopt::IpoptApplication> app = IpoptApplicationFactory();
  auto opts = app->Options();
  set_ipopt_options(*opts, options);
  set_extra_ipopt_options(*opts, extra_options);
  SolveResult r;
  if (std::getenv("TERRASTRIDE_DEBUG_CHECKS"))
    for (const auto& [k, v] :
         problem.violation_by_kind(const_cast<SrbdProblem&>(problem).initial_guess()))
      std::fprintf(stderr, "initial violation %s %g\n", k.c_str(), v);
  Ipopt::ApplicationReturnStatus st = app->Initialize();
  if (st != Ipopt::Solve_Succeeded) {
    r.status = "error";
    r.ipopt_status = st;
    return r;
  }
  st = app->OptimizeTNLP(nlp);
  if (options.verbose && nlp->declined_jacobian_)
    std::printf("terrastride: iterate %d is verified feasible (largest violation %g): the solve "
                "stopped there by declining its Jacobian, hence Ipopt's evaluation error above\n",
                nlp->iterations_, nlp->feasible_violation_);
  r.ipopt_status = st;
  r.wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  r.iterations = nlp->iterations_;
  r.feasibility_iterations = nlp->iterations_;
  r.x = nlp->x_.empty() ? problem.lower() : nlp->x_;
  if (nlp->x_.empty()) r.x = const_cast<SrbdProblem&>(problem).initial_guess();
  if (nlp->stopped_feasible_) {
    // Stopped at a verified feasible point: for the feasibility problem that is a solution.
    r.x = nlp->feasible_x_;
    r.status = "optimal";
    r.termination = "feasible_point";
    r.success = true;
    r.max_violation = nlp->feasible_violation_;
    if (problem.has_objective() && !options.stop_at_first_feasible &&
        options.objective_max_iterations > 0)
      improve(problem, options, *app, nlp->elapsed(), &r);
    r.wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    return r;
  }
  r.termination = "ipopt";
  r.status = ipopt_status_name(st, *nlp);
  r.success = st == Ipopt::Solve_Succeeded || st == Ipopt::Solved_To_Acceptable_Level;
  r.max_violation = problem.max_violation(r.x);
  return r;
}

}  // namespace terrastride::planner
