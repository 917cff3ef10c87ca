// `terrastride check`: the post-hoc checks of a plan (docs/design.md §8) against a mapped
// terrain directory or an exact scene.
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <iomanip>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <sstream>

#include "common/simulation_run.hpp"
#include "common/terrain_source.hpp"
#include "pasteable.hpp"
#include "terrastride/collision/checks.hpp"
#include "terrastride/collision/octree_terrain.hpp"
#include "terrastride/perception/atomic_output.hpp"
#include "terrastride/perception/point_cloud.hpp"
#include "terrastride/planner/plan_io.hpp"
#include "terrastride/robot/robot_model.hpp"
#include "terrastride/service/cli.hpp"
#include "terrastride/terrain/scenes.hpp"
#include "terrastride/terrain/terrain_map.hpp"

namespace terrastride::service {
namespace {

using nlohmann::json;

// Exit code when the checks ran and at least one failed (1 = bad input, 2 = usage).
constexpr int kChecksFailed = 3;

struct CheckCliOptions {
  std::string plan;
  std::string robot;  // --robot: for a plan that carries no robot definition
  std::string terrain;
  double resolution = 0.01;
  std::string series;
  bool json = false;
  bool simulate = false;
};

json vec(const Eigen::Vector3d& v) {
  return json::array({v.x(), v.y(), v.z()});
}

// NaN (no IK) becomes null: JSON has no NaN.
json num(double v) {
  return std::isfinite(v) ? json(v) : json(nullptr);
}

json summary_json(const collision::CheckReport& rep, const std::string& plan,
                  const std::string& terrain) {
  static const char* kJoints[3] = {"HAA", "HFE", "KFE"};
  json out;
  out["plan"] = plan;
  out["terrain"] = terrain;
  out["passed"] = rep.passed();
  out["failures"] = rep.failures();
  json checks = json::object();
  for (const auto& [k, v] : rep.keys()) checks[k] = v;
  out["checks"] = checks;
  json legs = json::array();
  for (size_t i = 0; i < rep.torque.legs.size(); ++i) {
    const auto& t = rep.torque.legs[i];
    json leg{{"leg", t.leg},
             {"torque_ratio_max",
              {{"HAA", t.worst_ratio[0]}, {"HFE", t.worst_ratio[1]}, {"KFE", t.worst_ratio[2]}}},
             {"torque_violations", t.violating_samples}};
    json worst_t = json::object();
    for (int j = 0; j < 3; ++j)
      if (t.worst_sample[j] >= 0) worst_t[kJoints[j]] = rep.torque.time[t.worst_sample[j]];
    leg["torque_ratio_max_t"] = worst_t;
    if (rep.torque.velocity_checked) {
      const auto& v = t.worst_velocity_ratio;
      leg["velocity_ratio_max"] = {{"HAA", v[0]}, {"HFE", v[1]}, {"KFE", v[2]}};
      leg["velocity_violations"] = t.velocity_violating_samples;
    }
    if (rep.clearance) {
      const auto& c = rep.clearance->legs[i];
      leg["shin_min_distance_m"] = c.shin_min;
      leg["shin_collisions"] = c.shin_collision_samples;
      leg["shin_collisions_certain"] = c.shin_certain_samples;
      leg["shin_contacts_uncertain"] = c.shin_collision_samples - c.shin_certain_samples;
      leg["shin_min_certain_distance_m"] = c.shin_certain_min;
      if (c.shin_min_sample >= 0) leg["shin_min_t"] = rep.clearance->time[c.shin_min_sample];
      if (!c.thigh_distance.empty()) {
        leg["thigh_min_distance_m"] = c.thigh_min;
        leg["thigh_collisions"] = c.thigh_collision_samples;
        leg["thigh_collisions_certain"] = c.thigh_certain_samples;
        leg["thigh_contacts_uncertain"] = c.thigh_collision_samples - c.thigh_certain_samples;
        leg["thigh_min_certain_distance_m"] = c.thigh_certain_min;
      }
      leg["first_collision_t"] = c.first_collision_t >= 0 ? json(c.first_collision_t) : json();
      leg["first_certain_collision_t"] =
          c.first_certain_collision_t >= 0 ? json(c.first_certain_collision_t) : json();
    }
    legs.push_back(leg);
  }
  out["legs"] = legs;
  if (rep.torque.worst_sample >= 0)
    out["torque_worst"] = {{"leg", rep.torque.legs[rep.torque.worst_leg].leg},
                           {"joint", kJoints[rep.torque.worst_joint]},
                           {"t", rep.torque.time[rep.torque.worst_sample]},
                           {"ratio", rep.torque.ratio_max}};
  json issues = json::array();
  for (const auto& is : rep.kinematics.issues)
    issues.push_back({{"t", is.t}, {"leg", rep.torque.legs[is.leg].leg}, {"message", is.message}});
  out["kinematic_issues"] = issues;
  if (rep.clearance) {
    out["clearance"] = {
        {"octree_resolution_m", rep.clearance->octree_resolution},
        {"shin_exclusion_m", rep.clearance->shin_exclusion},
        {"fcl_queries", rep.clearance->fcl_queries},
        {"certain_queries", rep.clearance->certain_queries},
        // Empty: no certain solid, every voxel contact counts as a certain collision.
        {"certain_solid", rep.clearance->certain_source},
        {"certain_resolved_below_m", rep.clearance->certain_resolved_below},
        {"first_collision_t",
         rep.clearance->first_collision_t >= 0 ? json(rep.clearance->first_collision_t) : json()},
        {"first_certain_collision_t", rep.clearance->first_certain_collision_t >= 0
                                          ? json(rep.clearance->first_certain_collision_t)
                                          : json()}};
  }
  if (rep.trunk) {
    const auto& tr = *rep.trunk;
    out["trunk"] = {
        {"min_distance_m", tr.min_distance},
        {"min_t", tr.min_sample >= 0 ? json(tr.time[tr.min_sample]) : json()},
        {"min_certain_distance_m", tr.min_certain_distance},
        {"collisions", tr.collisions},
        {"collisions_certain", tr.collisions_certain},
        {"contacts_uncertain", tr.contacts_uncertain},
        {"deep_contact_depth_m", tr.deep_contact_depth},
        {"first_certain_collision_t",
         tr.first_certain_collision_t >= 0 ? json(tr.first_certain_collision_t) : json()},
        {"fcl_queries", tr.fcl_queries}};
  }
  if (rep.footholds) {
    json unsafe = json::array();
    for (const auto& f : rep.footholds->footholds) {
      if (f.safe()) continue;
      unsafe.push_back({{"leg", rep.torque.legs[f.leg].leg},
                        {"t_start", f.t_start},
                        {"t_end", f.t_end},
                        {"position", vec(f.position)},
                        {"margin_m", f.margin}});
    }
    out["footholds"] = {{"count", rep.footholds->footholds.size()},
                        {"unsafe", rep.footholds->unsafe},
                        {"foot_radius_m", rep.footholds->foot_radius},
                        {"margin_min_m", rep.footholds->worst_margin},
                        {"unsafe_list", unsafe}};
  }
  out["samples"] = rep.torque.time.size();
  out["wall_s"] = rep.wall_s;
  return out;
}

// Per-joint torque series (and per-leg clearance series) for reports and plots.
json series_json(const collision::CheckReport& rep, const robot::RobotModel& model) {
  json out;
  out["t"] = rep.torque.time;
  json legs = json::array();
  for (size_t i = 0; i < rep.torque.legs.size(); ++i) {
    const auto& t = rep.torque.legs[i];
    json tau = json::array(), ratio = json::array();
    for (int j = 0; j < 3; ++j) {
      json tj = json::array(), rj = json::array();
      for (size_t k = 0; k < t.tau.size(); ++k) {
        tj.push_back(num(t.tau[k][j]));
        rj.push_back(num(t.ratio[k][j]));
      }
      tau.push_back(tj);
      ratio.push_back(rj);
    }
    json leg{{"leg", t.leg},
             {"joints", {"HAA", "HFE", "KFE"}},
             {"torque_limit_Nm", vec(model.legs[i].torque_limit)},
             {"tau_Nm", tau},
             {"ratio", ratio}};
    if (rep.clearance) {
      const auto& c = rep.clearance->legs[i];
      json shin = json::array(), thigh = json::array();
      for (double d : c.shin_distance) shin.push_back(num(d));
      for (double d : c.thigh_distance) thigh.push_back(num(d));
      auto verdicts = [](const std::vector<collision::ContactVerdict>& v) {
        json out = json::array();
        for (auto x : v) out.push_back(static_cast<int>(x));
        return out;
      };
      json shin_c = json::array(), thigh_c = json::array();
      for (double d : c.shin_certain_distance) shin_c.push_back(num(d));
      for (double d : c.thigh_certain_distance) thigh_c.push_back(num(d));
      leg["shin_distance_m"] = shin;
      leg["shin_distance_exact"] = c.shin_exact;
      leg["shin_certain_distance_m"] = shin_c;
      // 0 clear, 1 touching voxels within the map's uncertainty, 2 certain collision.
      leg["shin_verdict"] = verdicts(c.shin_verdict);
      if (!c.thigh_distance.empty()) {
        leg["thigh_distance_m"] = thigh;
        leg["thigh_distance_exact"] = c.thigh_exact;
        leg["thigh_certain_distance_m"] = thigh_c;
        leg["thigh_verdict"] = verdicts(c.thigh_verdict);
      }
    }
    legs.push_back(leg);
  }
  out["legs"] = legs;
  return out;
}

void print_human(const collision::CheckReport& rep, const std::string& plan,
                 const std::string& terrain) {
  static const char* kJoints[3] = {"HAA", "HFE", "KFE"};
  std::cout << std::fixed << std::setprecision(3);
  std::cout << "plan     " << plan << " (" << rep.torque.time.size() << " samples, "
            << (rep.torque.time.empty() ? 0.0 : rep.torque.time.back()) << " s)\n";
  std::cout << "terrain  " << terrain << "\n\n";
  // Capsule columns: minimum distance to the occupied voxels, then samples in certain collision
  // "/" samples touching voxels only within the map's uncertainty.
  std::cout << "leg   torque ratio max (HAA HFE KFE)   viol.   shin min [m]  certain/unc.   thigh "
               "min [m]  certain/unc.\n";
  for (size_t i = 0; i < rep.torque.legs.size(); ++i) {
    const auto& t = rep.torque.legs[i];
    std::cout << std::left << std::setw(6) << t.leg << std::right << std::setw(8)
              << t.worst_ratio[0] << std::setw(8) << t.worst_ratio[1] << std::setw(8)
              << t.worst_ratio[2] << std::setw(14) << t.violating_samples;
    if (rep.clearance) {
      const auto& c = rep.clearance->legs[i];
      auto pair = [](int certain, int all) {
        return std::to_string(certain) + "/" + std::to_string(all - certain);
      };
      std::cout << std::setw(15) << c.shin_min << std::setw(15)
                << pair(c.shin_certain_samples, c.shin_collision_samples);
      if (!c.thigh_distance.empty())
        std::cout << std::setw(16) << c.thigh_min << std::setw(15)
                  << pair(c.thigh_certain_samples, c.thigh_collision_samples);
    }
    std::cout << "\n";
  }
  std::cout << "\n";
  if (rep.torque.velocity_worst_sample >= 0)
    std::cout << "worst speed   " << rep.torque.velocity_ratio_max << " x limit ("
              << rep.torque.legs[rep.torque.velocity_worst_leg].leg << " "
              << kJoints[rep.torque.velocity_worst_joint] << " at t = "
              << rep.torque.time[rep.torque.velocity_worst_sample] << " s)\n";
  else
    std::cout << "joint speeds  not checked: the robot file gives no velocity limits\n";
  if (rep.torque.worst_sample >= 0)
    std::cout << "worst torque  " << rep.torque.ratio_max << " x limit ("
              << rep.torque.legs[rep.torque.worst_leg].leg << " " << kJoints[rep.torque.worst_joint]
              << " at t = " << rep.torque.time[rep.torque.worst_sample] << " s)\n";
  if (rep.clearance) {
    const auto& cl = *rep.clearance;
    std::cout << "leg capsules  distance to the occupied voxels: shin min " << cl.shin_min_distance
              << " m, thigh min " << cl.thigh_min_distance
              << " m (clearances cap at the 0.1 m cutoff)\n";
    if (cl.certain_source.empty()) {
      std::cout << "              no surface estimate: every voxel contact counts as a collision\n";
    } else {
      // Resolved only below exact_below: a minimum at or above it is a lower bound.
      auto at_least = [&](double d) {
        std::ostringstream o;
        o << std::fixed << std::setprecision(3);
        if (d >= cl.certain_resolved_below - 1e-9) o << ">= ";
        o << d;
        return o.str();
      };
      std::cout << "              distance to the certain solid: shin min "
                << at_least(cl.shin_min_certain_distance) << " m, thigh min "
                << at_least(cl.thigh_min_certain_distance) << " m\n"
                << "              certain collisions: " << cl.shin_collisions_certain
                << " samples (shin), " << cl.thigh_collisions_certain
                << " (thigh); within the map's uncertainty (" << std::setprecision(2)
                << cl.octree_resolution << " m voxels): " << cl.shin_contacts_uncertain
                << " (shin), " << cl.thigh_contacts_uncertain << " (thigh)\n"
                << std::setprecision(3) << "              certain solid: " << cl.certain_source
                << "\n";
    }
  }
  if (rep.trunk) {
    const auto& tr = *rep.trunk;
    std::cout << "trunk box     distance to the occupied voxels: min " << tr.min_distance << " m";
    if (tr.min_sample >= 0) std::cout << " at t = " << tr.time[tr.min_sample] << " s";
    std::cout << "; certain collisions " << tr.collisions_certain
              << " samples, within the map's uncertainty " << tr.contacts_uncertain
              << " (contacts deeper than " << tr.deep_contact_depth
              << " m into the voxels count as certain)\n";
  } else if (rep.clearance) {
    std::cout << "trunk box     not checked: the robot file has no trunk (trunk: none)\n";
  }
  if (rep.footholds)
    std::cout << "footholds     " << rep.footholds->footholds.size() << " stances, "
              << rep.footholds->unsafe << " unsafe, worst margin " << std::setprecision(4)
              << rep.footholds->worst_margin << " m for r = " << rep.footholds->foot_radius
              << " m\n";
  std::cout << std::setprecision(3) << "checked in    " << rep.wall_s << " s\n\n";
  const auto failures = rep.failures();
  if (failures.empty()) {
    std::cout << "PASS: all checks passed\n";
  } else {
    std::cout << "FAIL:\n";
    for (const auto& f : failures) std::cout << "  - " << f << "\n";
  }
}

void run_check(const CheckCliOptions& o) {
  if (!std::isfinite(o.resolution) || o.resolution < 0.002 || o.resolution > 0.2)
    throw CommandError("--resolution: must be in [0.002, 0.2] m");
  if (!o.series.empty()) {
    // Before loading the terrain and running the checks: a bad --series path fails now.
    try {
      perception::check_output_file(o.series);
    } catch (const perception::InputError& e) {
      throw CommandError(std::string("--series: ") + e.what());
    }
  }
  PlanWithRobot loaded = read_plan_with_robot(o.plan, o.robot);
  const planner::Trajectory& traj = loaded.trajectory;
  const robot::RobotModel& model = loaded.robot;
  const TerrainSource source =
      load_terrain_source(o.terrain, /*smooth_scene=*/false, map_it_first(o.terrain));
  const collision::CheckTerrain view =
      check_terrain_for(source, model, traj, o.resolution, /*require_octomap=*/true);
  collision::CheckReport rep;
  try {
    rep = collision::run_checks(model, traj, view);
  } catch (const collision::TrajectoryError& e) {
    throw CommandError(o.plan + ": " + e.what());
  }
  if (!o.series.empty()) {
    try {
      perception::write_file_atomically(o.series, series_json(rep, model).dump() + "\n");
    } catch (const perception::InputError& e) {
      throw CommandError(std::string("--series: ") + e.what());
    }
  }
  auto failures = rep.failures();
  // --simulate: the simulated execution on the exact terrain joins the checks (the verdict as
  // `plan --simulate` records it); a "fail" is a failed check, a "warn" is reported only.
  planner::Trajectory simulated = traj;
  if (o.simulate) {
    const auto sim =
        add_simulation_check(model, *source.exact(), simulation::SimulationOptions{}, &simulated);
    failures.insert(failures.end(), sim.begin(), sim.end());
  }
  const json sim_summary =
      o.simulate ? simulated.extra["post_hoc"].value("simulation", json()) : json();
  if (o.json) {
    json out = summary_json(rep, o.plan, view.description);
    if (o.simulate) {
      out["simulation"] = sim_summary;
      for (const auto& [k, v] : simulated.checks)
        if (k.rfind("sim_", 0) == 0) out["checks"][k] = v;
      out["failures"] = failures;
      out["passed"] = failures.empty();
    }
    std::cout << out.dump() << "\n";
  } else {
    print_human(rep, o.plan, view.description);
    if (o.simulate) {
      std::cout << "\nsimulated execution (MuJoCo, 'terrastride simulate' for the details): ";
      if (sim_summary.contains("verdict")) {
        std::cout << sim_summary["verdict"].get<std::string>() << "\n";
        for (const auto& why : sim_summary["reasons"])
          std::cout << "  - " << why.get<std::string>() << "\n";
      } else {
        std::cout << "not run: " << sim_summary.value("error", std::string("?")) << "\n";
      }
    }
  }
  std::cout.flush();
  if (!failures.empty()) {
    std::string msg = std::to_string(failures.size()) + " check(s) failed: " + failures.front();
    if (failures.size() > 1) msg += " (and " + std::to_string(failures.size() - 1) + " more)";
    throw CommandError(msg, kChecksFailed);
  }
}

}  // namespace

void add_check_command(CLI::App& app) {
  auto opts = std::make_shared<CheckCliOptions>();
  CLI::App* cmd = app.add_subcommand(
      "check",
      "Post-hoc checks of a plan: joint torques along it (tau = M qdd + c + g - J^T f from IK of "
      "each foot), shin and thigh capsules against the terrain's OctoMap with FCL, and stance "
      "footholds against the foothold-safety margin.\n"
      "Exit codes: 0 all checks pass; 3 a check failed (torque above a limit, IK failure or joint "
      "out of range, certain leg collision, unsafe foothold; with --simulate a 'fail' verdict), "
      "named on stderr; 1 bad input; 2 usage.\n"
      "Leg capsules get a three-way verdict per sample: clear of the occupied voxels; touching "
      "voxels but clear of the solid the map is certain of (within the map's uncertainty: voxels "
      "reach up to one voxel above the surface, mixed pixels add some); or a certain collision. "
      "Only certain collisions fail the check (docs/leg-check.md).");
  cmd->add_option("plan", opts->plan, "plan.json written by 'terrastride plan'")
      ->required()
      ->check(CLI::ExistingFile);
  cmd->add_option("--robot", opts->robot,
                  "Robot name or file, for a plan written before plans carried their robot "
                  "(a plan that carries one is judged with it)");
  cmd->add_option("--terrain", opts->terrain,
                  "Terrain directory from 'terrastride map' (uses its octomap.bt and safety "
                  "margins), an OctoMap file (.bt, .ot) or a scene name (exact analytic terrain, "
                  "voxelised for the leg check: " + terrain::scene_names_text() + ")")
      ->required();
  cmd->add_option("--resolution", opts->resolution,
                  "Voxel size (m) used to voxelise a scene for the leg check")
      ->capture_default_str();
  cmd->add_option("--series", opts->series,
                  "Also write the per-joint torque series and per-leg clearance series as JSON");
  cmd->add_flag("--json", opts->json, "Print the results as one JSON object");
  cmd->add_flag("--simulate", opts->simulate,
                "Also execute the plan in MuJoCo on the same terrain (as 'terrastride simulate'); "
                "a 'fail' verdict is a failed check (exit 3), a 'warn' is reported only");
  cmd->callback([opts] { run_check(*opts); });
}

}  // namespace terrastride::service
