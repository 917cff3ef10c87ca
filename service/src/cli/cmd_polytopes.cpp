// `terrastride polytopes fit|validate`: fit the interpolated force polytopes of a robot and measure
// them (rho_out, rho_in; see polytope_fit.hpp) on held-out foot positions against the paper's
// sagittal-only variant.
#include <algorithm>
#include <cstdio>
#include <iostream>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>

#include "terrastride/perception/atomic_output.hpp"
#include "terrastride/planner/polytope_fit.hpp"
#include "terrastride/planner/polytope_model.hpp"
#include "terrastride/robot/robot_model.hpp"
#include "terrastride/service/cli.hpp"

namespace terrastride::service {
namespace {

using nlohmann::json;
using planner::PolytopeQuality;

struct PolytopeOptions {
  std::string robot = "hyq";
  int samples = planner::PolytopeFitOptions().samples;
  uint64_t seed = 1;
  int l_refs = 7;
  int alpha_refs = 3;
  int threads = 2;
  int max_iterations = 60;
  double smoothness = planner::PolytopeFitOptions().smoothness;
  double box_scale = planner::PolytopeFitOptions().box_scale;
  std::string out;
  std::string file;
  bool json = false;
};

robot::RobotModel load(const std::string& name) {
  try {
    return robot::load_robot(robot::resolve_robot_path(name));
  } catch (const robot::RobotFileError& e) {
    throw CommandError(e.what());
  }
}

json quality_json(const PolytopeQuality& q) {
  return {{"samples", q.samples},
          {"rho_out_median", q.rho_out_median},
          {"rho_out_p95", q.rho_out_p95},
          {"rho_out_max", q.rho_out_max},
          {"rho_in_median", q.rho_in_median},
          {"rho_in_min", q.rho_in_min}};
}

void print_quality_row(const std::string& leg, const std::string& variant,
                       const PolytopeQuality& q) {
  std::printf(
      "  %-4s %-10s rho_out median %.4f  p95 %.4f  max %.4f   rho_in median %.4f  min %.4f\n",
      leg.c_str(), variant.c_str(), q.rho_out_median, q.rho_out_p95, q.rho_out_max, q.rho_in_median,
      q.rho_in_min);
}

void check_counts(const PolytopeOptions& o) {
  if (o.samples < 1)
    throw CommandError("--samples must be positive, got " + std::to_string(o.samples));
  if (o.l_refs < 2) throw CommandError("--l-refs must be at least 2");
  if (o.alpha_refs < 1) throw CommandError("--alpha-refs must be at least 1");
  if (!(o.box_scale > 0 && o.box_scale <= 3))
    throw CommandError("--box-scale must be in (0, 3], got " + std::to_string(o.box_scale));
  if (o.threads < 1) throw CommandError("--threads must be at least 1");
  if (o.max_iterations < 1) throw CommandError("--max-iterations must be at least 1");
}

void run_fit(const PolytopeOptions& o) {
  check_counts(o);
  const robot::RobotModel model = load(o.robot);
  const std::string path = o.out.empty() ? planner::polytope_path_for(model) : o.out;
  // Before the fit (seconds per leg): a missing or read-only folder, or a directory, device or
  // socket at the path, fails now.
  try {
    perception::check_output_file(path);
  } catch (const perception::InputError& e) {
    throw CommandError(std::string(o.out.empty() ? "" : "--out: ") + e.what());
  }
  planner::PolytopeFitOptions fo;
  fo.samples = o.samples;
  fo.seed = o.seed;
  fo.l_refs = o.l_refs;
  fo.alpha_refs = o.alpha_refs;
  fo.num_threads = o.threads;
  fo.max_iterations = o.max_iterations;
  fo.smoothness = o.smoothness;
  fo.box_scale = o.box_scale;
  std::vector<planner::LegFitReport> reports;
  planner::RobotPolytopeModel fitted;
  try {
    fitted = planner::fit_robot_polytopes(model, fo, &reports);
  } catch (const std::exception& e) {
    throw CommandError(std::string("polytope fit for robot ") + model.name + ": " + e.what());
  }
  fitted.fit_summary = planner::describe_fit(fo);
  try {
    planner::save_polytope_model(fitted, model, path);
  } catch (const planner::PolytopeFileError& e) {
    throw CommandError(e.what());
  }
  json out{{"robot", model.name}, {"file", path}, {"fit", fitted.fit_summary}, {"legs", json::array()}};
  for (const auto& r : reports) {
    out["legs"].push_back({{"leg", r.leg},
                           {"samples", r.samples},
                           {"iterations", r.iterations},
                           {"initial_cost", r.initial_cost},
                           {"final_cost", r.final_cost},
                           {"offset_scale", r.offset_scale},
                           {"wall_s", r.wall_s},
                           {"training", quality_json(r.training)}});
    // A twin leg's model is the other leg's, mirrored or translated (planner::find_leg_copy).
    if (!r.copied_from.empty()) out["legs"].back()["copied_from"] = r.copied_from;
    if (!r.started_from.empty()) out["legs"].back()["started_from"] = r.started_from;
  }
  if (o.json) {
    std::cout << out.dump() << "\n";
    return;
  }
  std::printf("fitted force polytopes of %s (%s) -> %s\n", model.name.c_str(), fitted.fit_summary.c_str(),
              path.c_str());
  for (const auto& r : reports) {
    if (!r.copied_from.empty()) {
      std::printf("  %-4s %s (not fitted)\n", r.leg.c_str(), r.copied_from.c_str());
    } else {
      std::printf("  %-4s %d iterations, cost %.4g -> %.4g, offset scale %.4f, %.2f s%s\n",
                  r.leg.c_str(), r.iterations, r.initial_cost, r.final_cost, r.offset_scale,
                  r.wall_s, r.started_from.empty() ? "" : (", started from " + r.started_from).c_str());
    }
    print_quality_row(r.leg, "training", r.training);
  }
}

// Quality of a model over pooled samples of several legs.
struct Pool {
  std::vector<double> out, in;
  PolytopeQuality summary() const {
    PolytopeQuality q;
    q.samples = static_cast<int>(out.size());
    if (out.empty()) return q;
    auto med = [](std::vector<double> v) {
      std::sort(v.begin(), v.end());
      const size_t n = v.size();
      return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
    };
    std::vector<double> s = out;
    std::sort(s.begin(), s.end());
    q.rho_out_median = med(out);
    q.rho_out_p95 = s[std::min(s.size() - 1, static_cast<size_t>(0.95 * s.size()))];
    q.rho_out_max = s.back();
    q.rho_in_median = med(in);
    q.rho_in_min = *std::min_element(in.begin(), in.end());
    return q;
  }
};

void run_validate(const PolytopeOptions& o) {
  check_counts(o);
  const robot::RobotModel model = load(o.robot);
  const std::string path = o.file.empty() ? planner::polytope_path_for(model) : o.file;
  planner::RobotPolytopeModel fitted;
  try {
    fitted = planner::load_polytope_model(model, path);
  } catch (const planner::PolytopeFileError& e) {
    throw CommandError(e.what());
  }
  json out{{"robot", model.name},
           {"file", path},
           {"held_out_samples_per_leg", o.samples},
           {"seed", o.seed},
           {"box_scale", o.box_scale},
           {"legs", json::array()}};
  std::map<std::string, Pool> pools;
  if (!o.json)
    std::printf("force polytopes of %s on %d held-out foot positions per leg (seed %llu), %s\n",
                model.name.c_str(), o.samples, static_cast<unsigned long long>(o.seed),
                path.c_str());
  for (size_t i = 0; i < model.legs.size(); ++i) {
    const auto& leg = model.legs[i];
    std::vector<Eigen::Vector3d> feet, reference_feet;
    try {
      feet = planner::sample_leg_workspace(leg, o.samples, o.seed + 7919 * i, o.box_scale);
      // The paper's references come from a separate sample set (its leg-length range).
      reference_feet =
          planner::sample_leg_workspace(leg, 500, o.seed + 104729 + 7919 * i, o.box_scale);
    } catch (const std::exception& e) {
      throw CommandError(e.what());
    }
    // Variants, from the paper's to ours; "paper_roll" is the ablation step in between.
    const std::vector<std::pair<std::string, planner::LegPolytopeModel>> variants = {
        {"ours", fitted.leg(leg.name)},
        {"paper", planner::paper_polytope_model(leg, reference_feet, false)},
        {"paper_roll", planner::paper_polytope_model(leg, reference_feet, true)}};
    json row{{"leg", leg.name}};
    for (const auto& [name, m] : variants) {
      Pool pool;
      for (const auto& p : feet) {
        pool.out.push_back(planner::polytope_rho_out(m, leg, p));
        pool.in.push_back(planner::polytope_rho_in(m, leg, p));
      }
      Pool& all = pools[name];
      all.out.insert(all.out.end(), pool.out.begin(), pool.out.end());
      all.in.insert(all.in.end(), pool.in.begin(), pool.in.end());
      const PolytopeQuality q = pool.summary();
      row[name] = quality_json(q);
      if (!o.json) print_quality_row(leg.name, name, q);
    }
    out["legs"].push_back(row);
  }
  out["all"] = json::object();
  for (const char* name : {"ours", "paper", "paper_roll"}) {
    const PolytopeQuality q = pools[name].summary();
    out["all"][name] = quality_json(q);
    if (!o.json) print_quality_row("all", name, q);
  }
  if (o.json) std::cout << out.dump() << "\n";
}

}  // namespace

void add_polytopes_command(CLI::App& app) {
  auto opts = std::make_shared<PolytopeOptions>();
  CLI::App* cmd = app.add_subcommand(
      "polytopes", "Fit and validate the interpolated force polytopes of a robot (paper III-A)");
  cmd->require_subcommand(1, 1);

  CLI::App* fit = cmd->add_subcommand(
      "fit", "Fit the force-polytope model with Ceres and write it next to the robot file");
  fit->add_option("--robot", opts->robot, "Robot name (data/robots/NAME.yaml) or file")
      ->capture_default_str();
  fit->add_option("--samples", opts->samples, "Training foot positions per leg")
      ->capture_default_str();
  fit->add_option("--seed", opts->seed, "Random seed of the samples")->capture_default_str();
  fit->add_option("--l-refs", opts->l_refs, "Reference leg lengths")->capture_default_str();
  fit->add_option("--alpha-refs", opts->alpha_refs, "Reference leg tilts")->capture_default_str();
  fit->add_option("--threads", opts->threads, "Ceres threads")->capture_default_str();
  fit->add_option("--max-iterations", opts->max_iterations, "Ceres iterations per round")
      ->capture_default_str();
  fit->add_option("--smoothness", opts->smoothness, "Weight of the reference-grid smoothness prior")
      ->capture_default_str();
  fit->add_option("--box-scale", opts->box_scale,
                  "Sample the range-of-motion box scaled by this around the nominal foot")
      ->capture_default_str();
  fit->add_option("--out", opts->out, "Output file (default: ROBOT.polytopes.yaml next to it)");
  fit->add_flag("--json", opts->json, "Print the figures as one JSON object");
  fit->callback([opts] { run_fit(*opts); });

  CLI::App* val = cmd->add_subcommand(
      "validate", "rho_out and rho_in on held-out foot positions, ours vs the paper's variant");
  auto vopts = std::make_shared<PolytopeOptions>();
  vopts->samples = 2000;
  vopts->seed = 20201;
  val->add_option("--robot", vopts->robot, "Robot name or file")->capture_default_str();
  val->add_option("--samples", vopts->samples, "Held-out foot positions per leg")
      ->capture_default_str();
  val->add_option("--seed", vopts->seed, "Random seed of the held-out samples")
      ->capture_default_str();
  val->add_option("--box-scale", vopts->box_scale,
                  "Sample the range-of-motion box scaled by this around the nominal foot")
      ->capture_default_str();
  val->add_option("--file", vopts->file, "Fitted parameters (default: next to the robot file)");
  val->add_flag("--json", vopts->json, "Print the figures as one JSON object");
  val->callback([vopts] { run_validate(*vopts); });
}

}  // namespace terrastride::service
