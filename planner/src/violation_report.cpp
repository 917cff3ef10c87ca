// violated_families / describe_violations (violation_report.hpp): pieces are mapped back to feet
// and times through the layout of the variables they read, so every family is described without
// its builder having to record anything.
#include "terrastride/planner/violation_report.hpp"

#include <algorithm>
#include <cstdio>
#include <map>
#include <set>

namespace terrastride::planner {

namespace {

// What one variable is: its foot (-1: none) and the knots it belongs to (-1: none, e.g. a
// duration); `timed` is false for a stance foothold, shared by all the knots of its stance.
struct VarInfo {
  int foot = -1;
  int k0 = -1, k1 = -1;
  bool timed = true;
};

std::vector<VarInfo> variable_info(const SrbdProblem& p) {
  const Layout& L = p.layout();
  std::vector<VarInfo> info(p.num_variables());
  auto mark = [&](int v, int n, int foot, int k, bool timed) {
    if (v < 0) return;
    for (int i = v; i < v + n && i < static_cast<int>(info.size()); ++i) {
      VarInfo& vi = info[i];
      vi.foot = foot;
      vi.timed = timed;
      vi.k0 = vi.k0 < 0 ? k : std::min(vi.k0, k);
      vi.k1 = std::max(vi.k1, k);
    }
  };
  for (int k = 0; k < static_cast<int>(L.base.size()); ++k) mark(L.base[k], 12, -1, k, true);
  for (std::size_t f = 0; f < L.foot_pos.size(); ++f) {
    const int foot = static_cast<int>(f);
    for (int k = 0; k < static_cast<int>(L.foot_pos[f].size()); ++k) {
      const bool stance = (k > 0 && L.contact[f][k - 1]) ||
                          (k < L.num_segments && L.contact[f][k]);
      mark(L.foot_pos[f][k], 3, foot, k, !stance);
      mark(L.foot_vel[f][k], 3, foot, k, true);
    }
    for (int s = 0; s < static_cast<int>(L.force[f].size()); ++s) {
      mark(L.force[f][s][0], 3, foot, s, true);
      mark(L.force[f][s][1], 3, foot, s + 1, true);
    }
  }
  return info;
}

std::string format_time(double t) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.2f", t);
  return buf;
}

}  // namespace

std::vector<FamilyViolation> violated_families(const SrbdProblem& p, const std::vector<double>& x,
                                               double tolerance) {
  const Layout& L = p.layout();
  // Knot times of this solution (optimised timing moves them).
  std::vector<double> knot_t(L.num_segments + 1, 0.0);
  for (int s = 0; s < L.num_segments; ++s)
    knot_t[s + 1] = knot_t[s] + x[L.interval_var[L.seg_interval[s]]] * L.seg_fraction[s];
  const std::vector<VarInfo> info = variable_info(p);
  struct PieceHit {
    double violation;
    std::set<int> feet;
    int k0, k1;
  };
  std::map<std::string, std::vector<PieceHit>> hits;
  std::vector<double> xl, g;
  for (const auto& piece : p.pieces()) {
    xl.resize(piece->vars.size());
    g.resize(piece->rows());
    for (std::size_t i = 0; i < xl.size(); ++i) xl[i] = x[piece->vars[i]];
    piece->eval(xl.data(), g.data());
    double v = 0.0;
    for (int r = 0; r < piece->rows(); ++r)
      v = std::max({v, piece->lb[r] - g[r], g[r] - piece->ub[r]});
    if (!(v > tolerance)) continue;
    PieceHit h{v, {}, -1, -1};
    int u0 = -1, u1 = -1;  // the knots of untimed (stance foothold) variables
    for (int gv : piece->vars) {
      const VarInfo& vi = info[gv];
      if (vi.foot >= 0) h.feet.insert(vi.foot);
      if (vi.k0 < 0) continue;
      int& a = vi.timed ? h.k0 : u0;
      int& b = vi.timed ? h.k1 : u1;
      a = a < 0 ? vi.k0 : std::min(a, vi.k0);
      b = std::max(b, vi.k1);
    }
    if (h.k0 < 0) {
      h.k0 = u0;
      h.k1 = u1;
    }
    hits[piece->kind].push_back(h);
  }
  const auto& legs = p.robot().legs;
  std::vector<FamilyViolation> out;
  for (const auto& [kind, list] : hits) {
    FamilyViolation fv;
    fv.kind = kind;
    for (const auto& h : list) fv.violation = std::max(fv.violation, h.violation);
    std::set<int> feet;
    int k0 = -1, k1 = -1;
    for (const auto& h : list) {
      if (h.violation < 0.5 * fv.violation) continue;
      feet.insert(h.feet.begin(), h.feet.end());
      if (h.k0 < 0) continue;
      k0 = k0 < 0 ? h.k0 : std::min(k0, h.k0);
      k1 = std::max(k1, h.k1);
    }
    for (int f : feet) fv.feet.push_back(legs[f].name);
    if (k0 >= 0) {
      fv.t_begin = knot_t[k0];
      fv.t_end = knot_t[k1];
    } else {
      fv.t_begin = 0.0;
      fv.t_end = knot_t.back();
    }
    out.push_back(fv);
  }
  std::sort(out.begin(), out.end(), [](const FamilyViolation& a, const FamilyViolation& b) {
    return a.violation > b.violation;
  });
  return out;
}

std::string describe_violations(const std::vector<FamilyViolation>& families, int max_families) {
  std::string text;
  for (int i = 0; i < static_cast<int>(families.size()) && i < max_families; ++i) {
    const FamilyViolation& f = families[i];
    char v[32];
    std::snprintf(v, sizeof v, "%.3g", f.violation);
    text += (i ? "; " : "") + f.kind + " by " + v;
    if (!f.feet.empty()) {
      text += " on ";
      for (std::size_t j = 0; j < f.feet.size(); ++j) text += (j ? ", " : "") + f.feet[j];
    }
    text += " at t = " + format_time(f.t_begin);
    if (f.t_end > f.t_begin) text += "-" + format_time(f.t_end);
    text += " s";
  }
  if (static_cast<int>(families.size()) > max_families)
    text += " (and " + std::to_string(families.size() - max_families) + " more famil" +
            (families.size() - max_families > 1 ? "ies" : "y") + ")";
  return text;
}

}  // namespace terrastride::planner
