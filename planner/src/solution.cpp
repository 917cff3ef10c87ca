// The continuous-time solution: a point x of the problem read as the base, feet and forces at any
// time t (SrbdProblem::evaluate), and its duration and event times (optimised timing moves them).
#include <algorithm>
#include <vector>

#include "terrastride/planner/nlp.hpp"
#include "terrastride/planner/piece_math.hpp"

namespace terrastride::planner {

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
    st.force.push_back(
        L.contact[f][s] ? ((1 - sigma) * v3(L.force[f][s][0]) + sigma * v3(L.force[f][s][1])).eval()
                        : Eigen::Vector3d::Zero().eval());
  }
  return st;
}

}  // namespace terrastride::planner
