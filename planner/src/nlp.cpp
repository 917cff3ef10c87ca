#include "terrastride/planner/nlp.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <mutex>
#include <stdexcept>

#include "initialization/initial_guess.hpp"
#include "terrastride/planner/feasibility.hpp"
#include "terrastride/planner/foothold_planarity.hpp"
#include "terrastride/planner/piece_math.hpp"
#include "terrastride/planner/trajectory.hpp"

namespace terrastride::planner {

namespace {

std::map<std::string, ConstraintSetBuilder>& registry() {
  // The feasibility sets (feasibility.hpp) are there from the start: no static initialisers.
  static std::map<std::string, ConstraintSetBuilder> r = builtin_constraint_sets();
  return r;
}
std::mutex& registry_mutex() {
  static std::mutex m;
  return m;
}

// Swing-clearance profile: the fraction of h_min demanded at time t into a swing of duration T.
// 0 at lift-off and touch-down (the foot must be allowed to leave and reach the ground), 1 from
// `ramp` after lift-off to `ramp` before touch-down, sin^2 in between so that the lower bound it
// puts on the foot height has a bounded second derivative.
double clearance_profile(double t, double T, double ramp) {
  const double edge = std::min(t, T - t);
  const double tau = std::min(ramp, 0.5 * T);
  if (!(tau > 0.0)) return edge > 0.0 ? 1.0 : 0.0;
  const double s = std::sin(0.5 * M_PI * std::clamp(edge / tau, 0.0, 1.0));
  return s * s;
}

}  // namespace

void register_constraint_set(const std::string& name, ConstraintSetBuilder builder) {
  std::lock_guard<std::mutex> lock(registry_mutex());
  registry()[name] = std::move(builder);
}

std::vector<std::string> constraint_set_names() {
  std::lock_guard<std::mutex> lock(registry_mutex());
  std::vector<std::string> names{"baseline"};
  for (const auto& [k, v] : registry())
    if (k != "baseline") names.push_back(k);
  names.push_back("all");  // kAllFeasibilitySets, expanded in the SrbdProblem constructor
  return names;
}

SrbdProblem::~SrbdProblem() = default;

SrbdProblem::SrbdProblem(const robot::RobotModel& robot, const terrain::HeightField& terrain,
                         const PhaseTimeline& timeline, const ProblemOptions& options,
                         const StartState* start_state)
    : robot_(robot), terrain_(terrain), timeline_(timeline), options_(options) {
  if (timeline_.feet.size() != robot_.legs.size())
    throw std::invalid_argument("timeline has " + std::to_string(timeline_.feet.size()) +
                                " feet, robot " + robot_.name + " has " +
                                std::to_string(robot_.legs.size()) + " legs");
  if (timeline_.num_intervals() < 1) throw std::invalid_argument("empty phase timeline");
  if (!(options_.segment_dt > 0.0)) throw std::invalid_argument("segment_dt must be > 0");
  layout_ = make_layout(static_cast<int>(robot_.legs.size()), timeline_, options_, &variables_);
  initialization::build_initial_guess({robot_, terrain_, timeline_, options_, layout_, start_state},
                                      &variables_);
  build_baseline();
  std::vector<std::string> sets;  // "all" expanded, implied sets added, each set once
  for (const auto& name : options_.constraints)
    if (name == "all")
      sets.insert(sets.end(), std::begin(kAllFeasibilitySets), std::end(kAllFeasibilitySets));
    else
      sets.push_back(name);
  for (const auto& [set, implied] : kImpliedFeasibilitySets)
    if (std::find(sets.begin(), sets.end(), set) != sets.end()) sets.push_back(implied);
  for (std::size_t i = 0; i < sets.size(); ++i) {
    const std::string& name = sets[i];
    if (name == "baseline" || std::find(sets.begin(), sets.begin() + i, name) != sets.begin() + i)
      continue;
    ConstraintSetBuilder b;
    {
      std::lock_guard<std::mutex> lock(registry_mutex());
      auto it = registry().find(name);
      if (it != registry().end()) b = it->second;
    }
    if (!b) {
      std::string names;
      for (const auto& n : constraint_set_names()) names += (names.empty() ? "" : ", ") + n;
      throw std::invalid_argument("constraint set '" + name + "' is not available (available: " +
                                  names + ")");
    }
    b(*this);
  }
}

int SrbdProblem::num_free_variables() const {
  int n = 0;
  for (std::size_t i = 0; i < variables_.lower.size(); ++i)
    n += variables_.lower[i] < variables_.upper[i];
  return n;
}

void SrbdProblem::add_piece(std::unique_ptr<Piece> piece) {
  row_offset_.push_back(num_rows_);
  nz_offset_.push_back(nnz_);
  num_rows_ += piece->rows();
  nnz_ += piece->rows() * static_cast<int>(piece->vars.size());
  pieces_.push_back(std::move(piece));
}

// ---------------------------------------------------------------------------------------------
// Baseline constraints

void SrbdProblem::build_baseline() {
  const Layout& L = layout_;
  const int S = L.num_segments;
  const int nf = static_cast<int>(robot_.legs.size());
  const double m = robot_.mass, mg = m * kGravity;
  const Eigen::Matrix3d inertia = robot_.inertia;
  const bool rot_free =
      robot_.base_dof_free[3] || robot_.base_dof_free[4] || robot_.base_dof_free[5];
  std::vector<int> lin_rows;
  for (int d = 0; d < 3; ++d)
    if (robot_.base_dof_free[d]) lin_rows.push_back(d);

  // Duration variable of segment s as a local index; the segment length is x[dur] * fraction.
  auto seg_duration = [&](LocalVars& lv, int s) { return lv.add(L.interval_var[L.seg_interval[s]]); };
  auto base_pos = [&](LocalVars& lv, int s, double sigma, bool value_only) {
    return add_hermite(lv, L.base[s], L.base[s] + 3, L.base[s + 1], L.base[s + 1] + 3, sigma,
                       value_only);
  };
  auto base_euler = [&](LocalVars& lv, int s, double sigma, bool value_only) {
    return add_hermite(lv, L.base[s] + 6, L.base[s] + 9, L.base[s + 1] + 6, L.base[s + 1] + 9,
                       sigma, value_only);
  };
  auto foot_spline = [&](LocalVars& lv, int f, int s, double sigma) {
    return add_hermite(lv, L.foot_pos[f][s], L.foot_vel[f][s], L.foot_pos[f][s + 1],
                       L.foot_vel[f][s + 1], sigma, true);
  };

  for (int s = 0; s < S; ++s) {
    const double frac = L.seg_fraction[s];
    // Linear dynamics at both ends of the segment: exact everywhere in it (see nlp.hpp).
    if (!lin_rows.empty())
      for (int side = 0; side < 2; ++side) {
        LocalVars lv;
        const double sigma = side;
        const HermiteLocal rp = base_pos(lv, s, sigma, false);
        const int dur = seg_duration(lv, s);
        std::vector<std::array<int, 3>> fl;
        for (int f = 0; f < nf; ++f)
          if (L.force[f][s][side] >= 0) fl.push_back(lv.add3(L.force[f][s][side]));
        std::vector<double> z(lin_rows.size(), 0.0);
        add_piece(make_piece("dynamics_linear", lv, z, z, [=](const auto* x, auto* g) {
          using T = std::decay_t<decltype(*g)>;
          const T h = x[dur] * frac;
          Vec3<T> a;
          hermite<T>(sigma, h, x, rp, nullptr, nullptr, &a);
          Vec3<T> r = m * a;
          r[2] += mg;
          for (const auto& fi : fl) r -= gather3(x, fi);
          for (std::size_t i = 0; i < lin_rows.size(); ++i) g[i] = r[lin_rows[i]] / mg;
        }));
      }
    // Angular dynamics at `angular_points` points (ends included).
    if (rot_free) {
      const int np = std::max(2, options_.angular_points);
      for (const double sigma : L.segment_points(s, np - 1, true)) {
        LocalVars lv;
        const HermiteLocal rp = base_pos(lv, s, sigma, true);
        const HermiteLocal ep = base_euler(lv, s, sigma, false);
        const int dur = seg_duration(lv, s);
        std::vector<std::array<int, 3>> fp, f0, f1;
        for (int f = 0; f < nf; ++f)
          if (L.contact[f][s]) {
            fp.push_back(lv.add3(L.foot_pos[f][s]));
            f0.push_back(sigma < 1.0 ? lv.add3(L.force[f][s][0]) : std::array<int, 3>{-1, -1, -1});
            f1.push_back(sigma > 0.0 ? lv.add3(L.force[f][s][1]) : std::array<int, 3>{-1, -1, -1});
          }
        const double scale = 1.0 / (0.1 * mg);
        // See angular_band. A cropped first segment's start was an interior point of the
        // previous plan's segment, so it keeps the band.
        const bool interior = (sigma > 0.0 && sigma < 1.0) || (s == 0 && L.first_segment_cropped > 0.0);
        const double band = interior ? options_.angular_band * scale : 0.0;
        add_piece(make_piece(
            "dynamics_angular", lv, std::vector<double>(3, -band), std::vector<double>(3, band),
            [=](const auto* x, auto* g) {
              using T = std::decay_t<decltype(*g)>;
              const T h = x[dur] * frac;
              Vec3<T> r, e, ed, edd, w, wd;
              hermite<T>(sigma, h, x, rp, &r, nullptr, nullptr);
              hermite<T>(sigma, h, x, ep, &e, &ed, &edd);
              euler_to_angular<T>(e, ed, edd, &w, &wd);
              const Eigen::Matrix<T, 3, 3> R = rotation_zyx<T>(e);
              const Eigen::Matrix<T, 3, 3> Iw = R * inertia.cast<T>() * R.transpose();
              const Vec3<T> Iww = Iw * w;
              Vec3<T> res = Iw * wd + w.cross(Iww);
              for (std::size_t i = 0; i < fp.size(); ++i) {
                const Vec3<T> f = (1.0 - sigma) * gather3(x, f0[i]) + sigma * gather3(x, f1[i]);
                res -= (gather3(x, fp[i]) - r).cross(f);
              }
              for (int i = 0; i < 3; ++i) g[i] = res[i] * scale;
            }));
      }
    }
    // Range of motion: foot in the box around its nominal position, in the base frame. Swing
    // feet move fast, so they get twice the points.
    for (int f = 0; f < nf; ++f) {
      const int nr = std::max(1, options_.rom_points) * (L.contact[f][s] ? 1 : 2);
      // The segment's end only in the last segment: the next segment's start covers it.
      for (const double sigma : L.segment_points(s, nr, s == S - 1)) {
        LocalVars lv;
        const HermiteLocal rp = base_pos(lv, s, sigma, true);
        const HermiteLocal ep = base_euler(lv, s, sigma, true);
        const HermiteLocal fpl = foot_spline(lv, f, s, sigma);
        const int dur = rp.needs_duration || ep.needs_duration || fpl.needs_duration
                            ? seg_duration(lv, s)
                            : -1;
        const Eigen::Vector3d nom = robot_.legs[f].nominal_foot, box = robot_.legs[f].range_of_motion;
        std::vector<double> lo{-box.x(), -box.y(), -box.z()}, hi{box.x(), box.y(), box.z()};
        add_piece(make_piece("range_of_motion", lv, lo, hi, [=](const auto* x, auto* g) {
          using T = std::decay_t<decltype(*g)>;
          const T h = dur >= 0 ? T(x[dur] * frac) : T(1.0);
          Vec3<T> r, e, p;
          hermite<T>(sigma, h, x, rp, &r, nullptr, nullptr);
          hermite<T>(sigma, h, x, ep, &e, nullptr, nullptr);
          hermite<T>(sigma, h, x, fpl, &p, nullptr, nullptr);
          const Vec3<T> pb_ = rotation_zyx<T>(e).transpose() * (p - r);
          for (int i = 0; i < 3; ++i) g[i] = pb_[i] - nom[i];
        }));
      }
    }
  }

  // Stance feet on the terrain.
  const terrain::HeightField* field = &terrain_;
  const double hmin = options_.swing_clearance, probe = options_.clearance_probe;
  for (const auto& st : L.stances) {
    if (st.fixed) continue;
    LocalVars lv;
    const auto p = lv.add3(st.pos_var);
    add_piece(make_piece("stance_height", lv, {0.0}, {0.0}, [=](const auto* x, auto* g) {
      g[0] = x[p[2]] - terrain_height(*field, x[p[0]], x[p[1]]);
    }));
  }

  // Footholds on locally planar terrain: |h(p + o) - h(p) - grad h(p) . o| <= tol at the four
  // probe offsets. Keeps feet off step edges, where the smoothed surface differs from the real
  // one and a lifting or landing foot would sweep through the edge.
  if (options_.foothold_planarity > 0.0 && probe > 0.0) {
    const double tol = options_.foothold_planarity;
    for (const auto& st : L.stances) {
      if (st.fixed) continue;
      LocalVars lv;
      const auto p = lv.add3(st.pos_var);
      std::vector<double> lo(4, -tol), hi(4, tol);
      add_piece(make_piece("foothold_planarity", lv, lo, hi, [=](const auto* x, auto* g) {
        foothold_planarity_residuals(*field, x[p[0]], x[p[1]], probe, g);
      }));
    }
  }

  // Friction pyramid and normal-force bounds at every force knot (linear in f for the fixed
  // foothold, so they hold along the whole linear force segment).
  const double mu = options_.friction;
  const double fmax = options_.max_normal_force_factor * mg;
  for (int f = 0; f < nf; ++f) {
    int last = -1;
    for (int s = 0; s < S; ++s)
      for (int side = 0; side < 2; ++side) {
        const int fv = L.force[f][s][side];
        if (fv < 0 || fv == last) continue;
        last = fv;
        LocalVars lv;
        const auto p = lv.add3(L.foot_pos[f][s]);
        const auto fi = lv.add3(fv);
        add_piece(make_piece(
            "friction", lv, {0.0, -kInf, -kInf, -kInf, -kInf}, {fmax / mg, 0.0, 0.0, 0.0, 0.0},
            [=](const auto* x, auto* g) {
              using T = std::decay_t<decltype(*g)>;
              Vec3<T> n, t1, t2;
              terrain_frame(*field, x[p[0]], x[p[1]], &n, &t1, &t2);
              const Vec3<T> force = gather3(x, fi) / mg;
              const T fn = n.dot(force), a = t1.dot(force), c = t2.dot(force);
              g[0] = fn;
              g[1] = a - mu * fn;
              g[2] = -a - mu * fn;
              g[3] = c - mu * fn;
              g[4] = -c - mu * fn;
            }));
      }
  }

  // Swing clearance: at `clearance_points` per segment, the foot must be h_min * profile above
  // the terrain under it AND above the terrain probed at +-probe in x and y around it. Probing
  // makes the bound conservative: between the points the foot moves less than the probe radius,
  // and a smoothed planning terrain underestimates a sharp step only near its edge.
  for (const auto& sw : L.swings) {
    const int f = sw.foot;
    const int np = std::max(1, options_.clearance_points);
    // Nominal times: with optimised timing the profile keeps its shape in swing fraction. A swing
    // under way at the start of a re-plan lifted off swing_elapsed before it.
    const double t0 = L.nominal_knot_time[sw.first_seg] -
                      (sw.first_seg == 0 ? timeline_.swing_elapsed_of(static_cast<std::size_t>(f)) : 0.0);
    const double swing_T = L.nominal_knot_time[sw.last_seg + 1] - t0;
    for (int s = sw.first_seg; s <= sw.last_seg; ++s)
      for (const double sigma : L.segment_points(s, np, false)) {
        if (s == sw.first_seg && sigma == 0.0) continue;  // lift-off knot
        const double t = L.nominal_knot_time[s] +
                         sigma * (L.nominal_knot_time[s + 1] - L.nominal_knot_time[s]) - t0;
        const double w = clearance_profile(t, swing_T, options_.clearance_ramp);
        LocalVars lv;
        const HermiteLocal fpl = foot_spline(lv, f, s, sigma);
        const int dur = fpl.needs_duration ? seg_duration(lv, s) : -1;
        const double frac = L.seg_fraction[s];
        const int nrow = probe > 0.0 ? 5 : 1;
        const double d = probe;
        std::vector<double> lo(nrow, hmin * w), hi(nrow, kInf);
        add_piece(make_piece("swing_clearance", lv, lo, hi, [=](const auto* x, auto* g) {
          using T = std::decay_t<decltype(*g)>;
          const T h = dur >= 0 ? T(x[dur] * frac) : T(1.0);
          Vec3<T> p;
          hermite<T>(sigma, h, x, fpl, &p, nullptr, nullptr);
          static const double ox[5] = {0, 1, -1, 0, 0}, oy[5] = {0, 0, 0, 1, -1};
          for (int i = 0; i < nrow; ++i)
            g[i] = p[2] - terrain_height(*field, p[0] + d * ox[i], p[1] + d * oy[i]);
        }));
      }
  }

  // Total duration fixed when the timing is optimised.
  if (options_.optimize_timing) {
    LocalVars lv;
    for (int v : L.interval_var) lv.add(v);
    const int n = static_cast<int>(L.interval_var.size());
    const double T = timeline_.duration();
    if (n <= kMaxPieceVars) {
      add_piece(make_piece("total_duration", lv, {T}, {T}, [=](const auto* x, auto* g) {
        using T_ = std::decay_t<decltype(*g)>;
        T_ sum = x[0];
        for (int i = 1; i < n; ++i) sum += x[i];
        g[0] = sum;
      }));
    } else {
      throw std::invalid_argument("too many gait intervals (" + std::to_string(n) +
                                  ") for timing optimisation; use fewer cycles");
    }
  }
}

// ---------------------------------------------------------------------------------------------
// Evaluation

void SrbdProblem::eval_constraints(const double* x, double* g) const {
  double xl[kMaxPieceVars];
  for (std::size_t i = 0; i < pieces_.size(); ++i) {
    const Piece& p = *pieces_[i];
    for (std::size_t k = 0; k < p.vars.size(); ++k) xl[k] = x[p.vars[k]];
    p.eval(xl, g + row_offset_[i]);
  }
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
  double xl[kMaxPieceVars];
  double g[64];
  for (std::size_t i = 0; i < pieces_.size(); ++i) {
    const Piece& p = *pieces_[i];
    for (std::size_t k = 0; k < p.vars.size(); ++k) xl[k] = x[p.vars[k]];
    p.eval_jacobian(xl, g, values + nz_offset_[i]);
  }
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

double SrbdProblem::duration(const std::vector<double>& x) const {
  double T = 0.0;
  for (int v : layout_.interval_var) T += x[v];
  return T;
}

std::vector<double> SrbdProblem::event_times(const std::vector<double>& x) const {
  std::vector<double> ev{0.0};
  for (int v : layout_.interval_var) ev.push_back(ev.back() + x[v]);
  return ev;
}

SrbdProblem::State SrbdProblem::evaluate(const std::vector<double>& x, double t) const {
  const Layout& L = layout_;
  const int S = L.num_segments;
  // Locate the segment (right-continuous: a knot belongs to the segment it starts).
  double t0 = 0.0;
  int s = 0;
  double h = x[L.interval_var[L.seg_interval[0]]] * L.seg_fraction[0];
  while (s < S - 1 && t >= t0 + h) {
    t0 += h;
    ++s;
    h = x[L.interval_var[L.seg_interval[s]]] * L.seg_fraction[s];
  }
  const double sigma = std::clamp((t - t0) / h, 0.0, 1.0);
  auto v3 = [&](int i) {
    return i < 0 ? Eigen::Vector3d::Zero().eval() : Eigen::Vector3d(x[i], x[i + 1], x[i + 2]);
  };
  State st;
  const int b0 = L.base[s], b1 = L.base[s + 1];
  hermite<double>(sigma, h, v3(b0), v3(b0 + 3), v3(b1), v3(b1 + 3), &st.pos, &st.vel, &st.acc);
  hermite<double>(sigma, h, v3(b0 + 6), v3(b0 + 9), v3(b1 + 6), v3(b1 + 9), &st.euler,
                  &st.euler_rate, &st.euler_acc);
  const int nf = static_cast<int>(robot_.legs.size());
  for (int f = 0; f < nf; ++f) {
    Eigen::Vector3d p, v;
    hermite<double>(sigma, h, v3(L.foot_pos[f][s]), v3(L.foot_vel[f][s]), v3(L.foot_pos[f][s + 1]),
                    v3(L.foot_vel[f][s + 1]), &p, &v, nullptr);
    st.foot_pos.push_back(p);
    st.foot_vel.push_back(v);
    st.contact.push_back(L.contact[f][s]);
    st.force.push_back(L.contact[f][s] ? ((1 - sigma) * v3(L.force[f][s][0]) +
                                          sigma * v3(L.force[f][s][1]))
                                             .eval()
                                       : Eigen::Vector3d::Zero().eval());
  }
  return st;
}

}  // namespace terrastride::planner
