#include "terrastride/planner/nlp.hpp"

#include <algorithm>
#include <exception>
#include <stdexcept>
#include <thread>

#include "costs/costs.hpp"
#include "initialization/initial_guess.hpp"
#include "terrastride/planner/piece_math.hpp"

namespace terrastride::planner {

SrbdProblem::~SrbdProblem() = default;

SrbdProblem::SrbdProblem(const robot::RobotModel& robot, const terrain::HeightField& terrain,
                         const PhaseTimeline& timeline, const ProblemOptions& options,
                         const StartState* start_state, const StartState* end_state)
    : robot_(robot),
      terrain_(terrain),
      timeline_(timeline),
      options_(options),
      starts_at_rest_(start_state == nullptr),
      ends_at_rest_(end_state == nullptr) {
  if (timeline_.feet.size() != robot_.legs.size())
    throw std::invalid_argument("timeline has " + std::to_string(timeline_.feet.size()) +
                                " feet, robot " + robot_.name + " has " +
                                std::to_string(robot_.legs.size()) + " legs");
  if (timeline_.num_intervals() < 1) throw std::invalid_argument("empty phase timeline");
  if (!(options_.segment_dt > 0.0)) throw std::invalid_argument("segment_dt must be > 0");
  layout_ = make_layout(static_cast<int>(robot_.legs.size()), timeline_, options_, &variables_);
  initialization::build_initial_guess({robot_, terrain_, timeline_, options_, layout_, start_state},
                                      &variables_);
  // Which variables the measured start fixes, before a pinned horizon end fixes more: add_piece
  // tells the start's own excess (a piece constant by the start alone) from the end's by them.
  if (start_state) {
    fixed_by_start_.resize(variables_.lower.size());
    for (std::size_t i = 0; i < fixed_by_start_.size(); ++i)
      fixed_by_start_[i] = !(variables_.lower[i] < variables_.upper[i]);
  }
  if (end_state) pin_end_state(*end_state);
  add_constraint_sets(*this, options_.constraints);
  // After the guess and before any warm start: the costs take their nominal path from the guess.
  build_objective(*this);
}

void SrbdProblem::pin_end_state(const StartState& end) {
  const int g = layout_.base[layout_.num_segments];
  for (int d = 0; d < 3; ++d) {
    if (robot_.base_dof_free[d]) {
      variables_.fix(g + d, end.position[d]);
      variables_.fix(g + 3 + d, end.linear_velocity[d]);
    }
    if (robot_.base_dof_free[3 + d]) {
      variables_.fix(g + 6 + d, end.euler_zyx[d]);
      variables_.fix(g + 9 + d, end.euler_rates[d]);
    }
  }
  // The feet at the end too (those the start does not fix): the next step continues from here on
  // the reference, whose forces and base beyond this end were planned on its own footholds.
  for (std::size_t f = 0; f < end.foot_position.size() && f < layout_.foot_pos.size(); ++f) {
    const int pv = layout_.foot_pos[f][layout_.num_segments];
    if (pv >= 0 && variables_.lower[pv] < variables_.upper[pv])
      for (int d = 0; d < 3; ++d) variables_.fix(pv + d, end.foot_position[f][d]);
  }
  // And the forces there, when it has them: the next step's guess continues with the
  // reference's, so a force of this plan's own at its end would break the splice's dynamics.
  for (std::size_t f = 0; f < end.foot_force.size() && f < layout_.force.size(); ++f) {
    const int fv = layout_.force[f][layout_.num_segments - 1][1];
    if (fv >= 0 && variables_.lower[fv] < variables_.upper[fv])
      for (int d = 0; d < 3; ++d) variables_.fix(fv + d, end.foot_force[f][d]);
  }
}

int SrbdProblem::num_free_variables() const {
  int n = 0;
  for (std::size_t i = 0; i < variables_.lower.size(); ++i)
    n += variables_.lower[i] < variables_.upper[i];
  return n;
}

void SrbdProblem::add_piece(std::unique_ptr<Piece> piece) {
  if (!starts_at_rest_) {
    bool constant = true;
    for (int v : piece->vars) constant &= !(variables_.lower[v] < variables_.upper[v]);
    if (constant) {
      // A fixed variable's initial value is its value (Variables::fix).
      double xl[kMaxPieceVars];
      for (std::size_t k = 0; k < piece->vars.size(); ++k) xl[k] = variables_.initial[piece->vars[k]];
      std::vector<double> g(piece->rows());
      piece->eval(xl, g.data());
      double excess = 0.0;
      for (int r = 0; r < piece->rows(); ++r)
        excess = std::max({excess, piece->lb[r] - g[r], g[r] - piece->ub[r]});
      if (excess > 0.0) {
        // Reported above round-off (the verified-feasible tolerance): as the start's when the start
        // alone fixes every variable of the piece, else as the pinned horizon end's (a stance
        // foothold the start fixes is shared with the end's knot, whose base the end pins).
        if (excess > kConstantExcessReportMin) {
          bool by_start = true;
          for (int v : piece->vars)
            by_start = by_start && static_cast<std::size_t>(v) < fixed_by_start_.size() &&
                       fixed_by_start_[v];
          double& largest = (by_start ? start_excess_ : end_excess_)[piece->kind];
          largest = std::max(largest, excess);
        }
        return;
      }
    }
  }
  row_offset_.push_back(num_rows_);
  nz_offset_.push_back(nnz_);
  num_rows_ += piece->rows();
  nnz_ += piece->rows() * static_cast<int>(piece->vars.size());
  pieces_.push_back(std::move(piece));
}

// ---------------------------------------------------------------------------------------------
// Evaluation

// Pieces are independent: each reads x and writes only its own rows (and Jacobian entries), so a
// large problem evaluates them on two threads, the even-numbered pieces on one and the odd-numbered
// on the other: the families are built one after another (the baseline's, then polytope, shin_ik
// ...), and their costs per piece differ by an order of magnitude, so alternating pieces balances
// the two threads where contiguous halves did not (pallet_15 all: 0.46 G against 0.97 G
// instructions per solve). Small problems stay on one thread (a thread's start costs some tens of
// microseconds). The values are those of one thread, bit for bit.
namespace {
constexpr int kParallelMinNonzeros = 20000;

// body(first, stride) evaluates pieces first, first + stride, ...
template <class Body>
void run_on_two_threads(int nnz, const Body& body) {
  if (nnz < kParallelMinNonzeros || std::thread::hardware_concurrency() < 2) {
    body(0, 1);
    return;
  }
  // A piece that throws (e.g. bad input to the terrain) throws from here as it did on one thread.
  std::exception_ptr other_error, own_error;
  std::thread other([&] {
    try {
      body(1, 2);
    } catch (...) {
      other_error = std::current_exception();
    }
  });
  try {
    body(0, 2);
  } catch (...) {
    own_error = std::current_exception();
  }
  other.join();
  if (own_error) std::rethrow_exception(own_error);
  if (other_error) std::rethrow_exception(other_error);
}

}  // namespace

void SrbdProblem::eval_constraints(const double* x, double* g) const {
  run_on_two_threads(nnz_, [&](std::size_t first, std::size_t stride) {
    double xl[kMaxPieceVars];
    for (std::size_t i = first; i < pieces_.size(); i += stride) {
      const Piece& p = *pieces_[i];
      for (std::size_t k = 0; k < p.vars.size(); ++k) xl[k] = x[p.vars[k]];
      p.eval(xl, g + row_offset_[i]);
    }
  });
}

void SrbdProblem::jacobian_structure(int* rows, int* cols) const {
  for (std::size_t i = 0; i < pieces_.size(); ++i) {
    const Piece& p = *pieces_[i];
    const int n = static_cast<int>(p.vars.size());
    int z = nz_offset_[i];
    for (int r = 0; r < p.rows(); ++r)
      for (int c = 0; c < n; ++c) {
        rows[z] = row_offset_[i] + r;
        cols[z] = p.vars[c];
        ++z;
      }
  }
}

void SrbdProblem::eval_jacobian(const double* x, double* values) const {
  run_on_two_threads(nnz_, [&](std::size_t first, std::size_t stride) {
    double xl[kMaxPieceVars];
    double g[64];
    for (std::size_t i = first; i < pieces_.size(); i += stride) {
      const Piece& p = *pieces_[i];
      for (std::size_t k = 0; k < p.vars.size(); ++k) xl[k] = x[p.vars[k]];
      p.eval_jacobian(xl, g, values + nz_offset_[i]);
    }
  });
}

std::vector<double> SrbdProblem::row_lower() const {
  std::vector<double> v;
  for (const auto& p : pieces_) v.insert(v.end(), p->lb.begin(), p->lb.end());
  return v;
}
std::vector<double> SrbdProblem::row_upper() const {
  std::vector<double> v;
  for (const auto& p : pieces_) v.insert(v.end(), p->ub.begin(), p->ub.end());
  return v;
}

double SrbdProblem::max_violation(const std::vector<double>& x) const {
  std::vector<double> g(num_rows_);
  eval_constraints(x.data(), g.data());
  return max_violation(x, g);
}

double SrbdProblem::max_violation(const std::vector<double>& x, const std::vector<double>& g) const {
  const auto lo = row_lower(), hi = row_upper();
  double v = 0.0;
  for (int i = 0; i < num_rows_; ++i) v = std::max({v, lo[i] - g[i], g[i] - hi[i]});
  for (std::size_t i = 0; i < x.size(); ++i)
    v = std::max({v, variables_.lower[i] - x[i], x[i] - variables_.upper[i]});
  return v;
}

std::map<std::string, double> SrbdProblem::violation_by_kind(const std::vector<double>& x) const {
  std::vector<double> g(num_rows_);
  eval_constraints(x.data(), g.data());
  std::map<std::string, double> out;
  for (std::size_t i = 0; i < pieces_.size(); ++i) {
    double& v = out[pieces_[i]->kind];
    for (int r = 0; r < pieces_[i]->rows(); ++r) {
      const double gi = g[row_offset_[i] + r];
      v = std::max({v, pieces_[i]->lb[r] - gi, gi - pieces_[i]->ub[r]});
    }
  }
  return out;
}

}  // namespace terrastride::planner
