// Where a constraint Jacobian's time goes: builds the pallet_15 11 s crawl problem
// (exact scene, its 2 cm smoothed map) with the given constraint sets and times, at the initial
// guess, the whole eval_jacobian (both threads, as Ipopt calls it) and eval_constraints, then each
// piece kind's Jacobians on one thread.
//   bench_jacobian [--sets all|baseline|SET,...] [--scene pallet_15] [--repeat 20]
// Prints per kind: pieces, rows, local variables (mean, max), Jacobian nonzeros, of them the
// entries that are exactly zero at the guess and at a perturbed guess (a row that does not
// depend on one of its piece's variables: an entry of the KKT system all the same), the kind's
// Jacobian time per call (median of --repeat, ms) and per piece (us), and its values alone (ms).
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include "terrastride/planner/gait.hpp"
#include "terrastride/planner/nlp.hpp"
#include "terrastride/planner/options.hpp"
#include "terrastride/robot/robot_model.hpp"
#include "terrastride/terrain/scenes.hpp"
#include "terrastride/terrain/terrain_map.hpp"

using namespace terrastride;

namespace {

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0.0 : v[v.size() / 2];
}

template <class F>
double seconds_of(const F& f) {
  const auto t0 = std::chrono::steady_clock::now();
  f();
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

}  // namespace

int main(int argc, char** argv) {
  std::string sets = "all", scene_name = "pallet_15";
  int repeat = 20;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--sets" && i + 1 < argc)
      sets = argv[++i];
    else if (a == "--scene" && i + 1 < argc)
      scene_name = argv[++i];
    else if (a == "--repeat" && i + 1 < argc)
      repeat = std::max(1, std::atoi(argv[++i]));
    else {
      std::fprintf(stderr, "usage: bench_jacobian [--sets all] [--scene pallet_15] [--repeat 20]\n");
      return 2;
    }
  }
  const auto robot = robot::load_robot(robot::resolve_robot_path("hyq"));
  auto scene = terrain::make_scene(scene_name);
  auto smooth = terrain::TerrainMap::from_scene(*scene, 0.02, {});
  planner::PlannerOptions o;
  o.gait = "crawl";
  o.cycles = 3;
  o.duration = 11.0;
  o.has_goal = true;
  o.goal = Eigen::Vector3d(scene->goal().x(), scene->goal().y(), 0.0);
  o.constraints.clear();
  std::stringstream ss(sets);
  for (std::string item; std::getline(ss, item, ',');) o.constraints.push_back(item);
  std::vector<std::string> feet;
  for (const auto& leg : robot.legs) feet.push_back(leg.name);
  const auto timeline =
      planner::make_timeline(planner::load_gait(planner::resolve_gait_path(o.gait)), feet,
                             o.cycles, o.duration);
  planner::SrbdProblem problem(robot, *smooth, timeline, o);
  const std::vector<double> x = problem.initial_guess();
  std::vector<double> g(problem.num_constraints()), jac(problem.jacobian_nonzeros());

  std::vector<double> whole, values;
  for (int k = 0; k < repeat; ++k) {
    whole.push_back(seconds_of([&] { problem.eval_jacobian(x.data(), jac.data()); }));
    values.push_back(seconds_of([&] { problem.eval_constraints(x.data(), g.data()); }));
  }
  std::printf("%s on %s: %d variables, %d rows, %d Jacobian nonzeros, %zu pieces\n", sets.c_str(),
              scene_name.c_str(), problem.num_variables(), problem.num_constraints(),
              problem.jacobian_nonzeros(), problem.pieces().size());
  std::printf("eval_jacobian (as Ipopt calls it) %.3f ms, eval_constraints %.3f ms (medians of %d)\n",
              1e3 * median(whole), 1e3 * median(values), repeat);

  // Entries zero at the guess and at a guess moved by up to 1 mm (or mrad, or N) per variable.
  std::vector<double> jac_moved(jac.size()), x_moved = x;
  problem.eval_jacobian(x.data(), jac.data());
  for (std::size_t i = 0; i < x_moved.size(); ++i)
    x_moved[i] += 1e-3 * std::sin(12.9898 * static_cast<double>(i + 1));
  problem.eval_jacobian(x_moved.data(), jac_moved.data());
  struct Kind {
    int pieces = 0, rows = 0, nnz = 0, zeros = 0, max_vars = 0;
    long vars = 0;
    std::vector<const planner::Piece*> list;
  };
  std::map<std::string, Kind> kinds;
  int nz_offset = 0;
  for (const auto& p : problem.pieces()) {
    Kind& k = kinds[p->kind];
    const int entries = p->rows() * static_cast<int>(p->vars.size());
    for (int z = nz_offset; z < nz_offset + entries; ++z)
      k.zeros += jac[z] == 0.0 && jac_moved[z] == 0.0;
    nz_offset += entries;
    ++k.pieces;
    k.rows += p->rows();
    const int n = static_cast<int>(p->vars.size());
    k.vars += n;
    k.max_vars = std::max(k.max_vars, n);
    k.nnz += n * p->rows();
    k.list.push_back(p.get());
  }
  std::printf("%-22s %6s %6s %6s %5s %8s %7s %9s %9s %9s\n", "kind", "pieces", "rows", "vars",
              "max", "nnz", "zeros", "jac_ms", "us/piece", "values_ms");
  double total = 0.0, total_values = 0.0;
  double xl[planner::kMaxPieceVars], gl[64];
  std::vector<double> jl(64 * planner::kMaxPieceVars);
  for (const auto& [name, k] : kinds) {
    std::vector<double> t;
    for (int r = 0; r < repeat; ++r)
      t.push_back(seconds_of([&] {
        for (const planner::Piece* p : k.list) {
          for (std::size_t i = 0; i < p->vars.size(); ++i) xl[i] = x[p->vars[i]];
          p->eval_jacobian(xl, gl, jl.data());
        }
      }));
    const double ms = 1e3 * median(t);
    total += ms;
    std::vector<double> tv;  // the kind's values alone: what its Jacobian costs beyond them is AD
    for (int r = 0; r < repeat; ++r)
      tv.push_back(seconds_of([&] {
        for (const planner::Piece* p : k.list) {
          for (std::size_t i = 0; i < p->vars.size(); ++i) xl[i] = x[p->vars[i]];
          p->eval(xl, gl);
        }
      }));
    total_values += 1e3 * median(tv);
    std::printf("%-22s %6d %6d %6.1f %5d %8d %7d %9.3f %9.2f %9.3f\n", name.c_str(), k.pieces,
                k.rows, static_cast<double>(k.vars) / k.pieces, k.max_vars, k.nnz, k.zeros, ms,
                1e3 * ms / k.pieces, 1e3 * median(tv));
  }
  int zeros = 0;
  for (const auto& entry : kinds) zeros += entry.second.zeros;
  std::printf("%-22s %6s %6s %6s %5s %8d %7d %9.3f %9s %9.3f (one thread)\n", "sum", "", "", "", "",
              problem.jacobian_nonzeros(), zeros, total, "", total_values);
  return 0;
}
