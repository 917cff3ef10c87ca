// TERRASTRIDE_DEBUG_STEPS (planner/src/solver.cpp): which rows cut Ipopt's steps.
#pragma once

#include <IpDenseVector.hpp>
#include <IpExpansionMatrix.hpp>
#include <IpIpoptCalculatedQuantities.hpp>
#include <IpIpoptData.hpp>
#include <IpOrigIpoptNLP.hpp>
#include <IpTNLPAdapter.hpp>

#include <algorithm>
#include <cstdio>
#include <limits>
#include <map>
#include <set>
#include <string>
#include <vector>

#include "terrastride/planner/nlp.hpp"

namespace terrastride::planner {

// Which bounds cut each step. Ipopt's step length is the fraction-to-the-boundary rule's: alpha_pr = tau min_i gap_i / (-dgap_i) over the slacks of the
// inequality rows and the variables' distances to their bounds, taken over the gaps of the
// previous iterate and the search direction that led to the current one. This prints, per
// iteration, the rows/variables whose ratio gap/(-dgap) is below 1 (a full step would cross their
// bound) counted per piece kind, and the smallest ratios with their kind: the rows that block.
class StepBlockers {
 public:
  explicit StepBlockers(const SrbdProblem& p) : p_(p) {
    for (std::size_t i = 0; i < p.pieces().size(); ++i)
      for (int r = 0; r < p.pieces()[i]->rows(); ++r) {
        row_kind_.push_back(&p.pieces()[i]->kind);
        row_piece_.push_back(static_cast<int>(i));
      }
    // Which foot and knot each variable belongs to, to say where a blocking row is (a stance
    // foothold, shared by its knots, by its first knot).
    const Layout& L = p.layout();
    var_knot_.assign(p.num_variables(), -1);
    var_foot_.assign(p.num_variables(), -1);
    for (std::size_t k = 0; k < L.base.size(); ++k)
      for (int d = 0; d < 12; ++d) var_knot_[L.base[k] + d] = static_cast<int>(k);
    for (std::size_t f = 0; f < L.foot_pos.size(); ++f)
      for (std::size_t k = 0; k < L.foot_pos[f].size(); ++k)
        for (const int v : {L.foot_pos[f][k], L.foot_vel[f][k]})
          for (int d = 0; v >= 0 && d < 3; ++d)
            if (var_foot_[v + d] < 0) {
              var_foot_[v + d] = static_cast<int>(f);
              var_knot_[v + d] = static_cast<int>(k);
            }
  }
  // "LF k40-52": the feet and the span of knots a row's piece reads.
  std::string where(int row) const {
    std::set<int> feet;
    int k0 = std::numeric_limits<int>::max(), k1 = -1;
    for (const int v : p_.pieces()[row_piece_[row]]->vars) {
      if (var_foot_[v] >= 0) feet.insert(var_foot_[v]);
      if (var_knot_[v] < 0) continue;
      k0 = std::min(k0, var_knot_[v]);
      k1 = std::max(k1, var_knot_[v]);
    }
    std::string out;
    for (const int f : feet)
      out += (f < static_cast<int>(p_.robot().legs.size()) ? p_.robot().legs[f].name
                                                           : std::to_string(f)) + " ";
    if (k1 >= 0) out += "k" + std::to_string(k0) + (k1 > k0 ? "-" + std::to_string(k1) : "");
    return out;
  }
  void observe(Ipopt::Index iter, double alpha_pr, const Ipopt::IpoptData* data,
               Ipopt::IpoptCalculatedQuantities* cq) {
    using Ipopt::SmartPtr;
    using Ipopt::Vector;
    if (data == nullptr || cq == nullptr) return;
    auto* orig = dynamic_cast<Ipopt::OrigIpoptNLP*>(Ipopt::GetRawPtr(cq->GetIpoptNLP()));
    if (orig == nullptr) return;
    auto* adapter = dynamic_cast<Ipopt::TNLPAdapter*>(Ipopt::GetRawPtr(orig->nlp()));
    if (adapter == nullptr) return;
    if (row_of_d_.empty()) map_indices(*adapter, *data, *cq);
    const auto delta = data->delta();
    if (have_previous_ && Ipopt::IsValid(delta)) {
      // A bound's ratio gap/(-dgap), what it is ("KIND row N (FEET kA-B)" or "variable bound var
      // N") and its row (-1 for a variable's bound or an unmapped row).
      struct Ratio {
        double ratio;
        std::string text;
        int row;
        bool operator<(const Ratio& o) const {
          return ratio < o.ratio || (ratio == o.ratio && text < o.text);
        }
      };
      std::vector<Ratio> ratios;
      std::map<std::string, int> blocking;
      auto scan = [&](const Vector& gap, const Ipopt::Matrix& P, const Vector& dir, double sign,
                      const std::vector<int>& orig_index, bool rows) {
        SmartPtr<Vector> dgap = gap.MakeNew();
        P.TransMultVector(sign, dir, 0.0, *dgap);
        const auto* ex = dynamic_cast<const Ipopt::ExpansionMatrix*>(&P);
        const auto* g = dynamic_cast<const Ipopt::DenseVector*>(&gap);
        const auto* dg = dynamic_cast<const Ipopt::DenseVector*>(Ipopt::GetRawPtr(dgap));
        if (ex == nullptr || g == nullptr || dg == nullptr) return;
        const double* gv = g->ExpandedValues();
        const double* dv = dg->ExpandedValues();
        const Ipopt::Index* pos = ex->ExpandedPosIndices();
        for (Ipopt::Index i = 0; i < gap.Dim(); ++i) {
          if (!(dv[i] < 0.0)) continue;
          const double ratio = gv[i] / -dv[i];
          const int o = orig_index[pos[i]];
          const std::string what = rows ? (o >= 0 ? *row_kind_[o] : std::string("?"))
                                        : std::string("variable bound");
          if (ratio < 1.0) ++blocking[what];
          ratios.push_back({ratio,
                            what + " " + (rows ? "row " : "var ") + std::to_string(o) +
                                (rows && o >= 0 ? " (" + where(o) + ")" : ""),
                            rows ? o : -1});
        }
      };
      const SmartPtr<const Vector> ds = delta->s(), dx = delta->x();
      scan(*prev_s_L_, *orig->Pd_L(), *ds, 1.0, row_of_d_, true);
      scan(*prev_s_U_, *orig->Pd_U(), *ds, -1.0, row_of_d_, true);
      scan(*prev_x_L_, *orig->Px_L(), *dx, 1.0, var_of_x_, false);
      scan(*prev_x_U_, *orig->Px_U(), *dx, -1.0, var_of_x_, false);
      std::sort(ratios.begin(), ratios.end());
      // The blocking rows' values before and after the step, with their bounds.
      std::vector<double> x(p_.num_variables()), g(p_.num_constraints());
      adapter->ResortX(*data->curr()->x(), x.data());
      p_.eval_constraints(x.data(), g.data());
      const auto lo = p_.row_lower(), hi = p_.row_upper();
      for (std::size_t i = 0; i < ratios.size() && i < 3; ++i) {
        const int row = ratios[i].row;
        if (row < 0) continue;
        char text[160];
        std::snprintf(text, sizeof text, " [%.4g -> %.4g in %.4g, %.4g]", prev_g_[row], g[row],
                      lo[row], hi[row]);
        ratios[i].text += text;
      }
      prev_g_ = g;
      std::fprintf(stderr, "step %d alpha_pr %.3g: would cross their bound at a full step:",
                   static_cast<int>(iter), alpha_pr);
      for (const auto& [k, n] : blocking) std::fprintf(stderr, " %s %d", k.c_str(), n);
      std::fprintf(stderr, "\n  smallest gap/(-dgap):");
      for (std::size_t i = 0; i < ratios.size() && i < 8; ++i)
        std::fprintf(stderr, " %s %.3g;", ratios[i].text.c_str(), ratios[i].ratio);
      std::fprintf(stderr, "\n");
    }
    if (prev_g_.empty()) {
      std::vector<double> x(p_.num_variables());
      adapter->ResortX(*data->curr()->x(), x.data());
      prev_g_.resize(p_.num_constraints());
      p_.eval_constraints(x.data(), prev_g_.data());
    }
    prev_s_L_ = cq->curr_slack_s_L()->MakeNewCopy();
    prev_s_U_ = cq->curr_slack_s_U()->MakeNewCopy();
    prev_x_L_ = cq->curr_slack_x_L()->MakeNewCopy();
    prev_x_U_ = cq->curr_slack_x_U()->MakeNewCopy();
    have_previous_ = true;
  }

 private:
  // Internal inequality index -> our row, internal variable index -> our variable (the adapter
  // resorts a vector whose entries are their own index + 1).
  void map_indices(Ipopt::TNLPAdapter& adapter, const Ipopt::IpoptData& data,
                   Ipopt::IpoptCalculatedQuantities& cq) {
    const int m = p_.num_constraints(), n = p_.num_variables();
    Ipopt::SmartPtr<Ipopt::Vector> c = cq.curr_c()->MakeNew(), d = cq.curr_d()->MakeNew();
    c->Set(0.0);
    auto* dd = dynamic_cast<Ipopt::DenseVector*>(Ipopt::GetRawPtr(d));
    std::vector<double> g(m);
    if (dd != nullptr) {
      double* v = dd->Values();
      for (Ipopt::Index i = 0; i < d->Dim(); ++i) v[i] = i + 1;
      adapter.ResortG(*c, *d, g.data());
      row_of_d_.assign(d->Dim(), -1);
      for (int r = 0; r < m; ++r)
        if (g[r] > 0.5) row_of_d_[static_cast<int>(g[r] - 0.5)] = r;
    }
    Ipopt::SmartPtr<Ipopt::Vector> x = data.curr()->x()->MakeNew();
    auto* xd = dynamic_cast<Ipopt::DenseVector*>(Ipopt::GetRawPtr(x));
    std::vector<double> xo(n);
    if (xd != nullptr) {
      double* v = xd->Values();
      for (Ipopt::Index i = 0; i < x->Dim(); ++i) v[i] = i + 1;
      adapter.ResortX(*x, xo.data());
      var_of_x_.assign(x->Dim(), -1);
      for (int j = 0; j < n; ++j)
        if (p_.lower()[j] < p_.upper()[j] && xo[j] > 0.5 && xo[j] < x->Dim() + 0.5)
          var_of_x_[static_cast<int>(xo[j] - 0.5)] = j;
    }
  }
  const SrbdProblem& p_;
  std::vector<const std::string*> row_kind_;
  std::vector<int> row_piece_;
  std::vector<double> prev_g_;
  std::vector<int> var_knot_, var_foot_;  // per variable: its knot and foot, -1 for none
  std::vector<int> row_of_d_, var_of_x_;
  bool have_previous_ = false;
  Ipopt::SmartPtr<Ipopt::Vector> prev_s_L_, prev_s_U_, prev_x_L_, prev_x_U_;
};

}  // namespace terrastride::planner
