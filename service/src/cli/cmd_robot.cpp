// `terrastride robot`: inspect a robot file, forward/inverse kinematics, exact force polytopes.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <iostream>
#include <map>
#include <sstream>
#include <vector>
#include <memory>
#include <nlohmann/json.hpp>

#include "terrastride/perception/atomic_output.hpp"
#include "terrastride/planner/polytope_fit.hpp"
#include "terrastride/planner/polytope_model.hpp"
#include "terrastride/robot/leg_kinematics.hpp"
#include "terrastride/robot/robot_model.hpp"
#include "terrastride/robot/urdf_import.hpp"
#include "terrastride/service/cli.hpp"

namespace terrastride::service {
namespace {

using nlohmann::json;
using robot::RobotModel;

json vec_json(const Eigen::Vector3d& v) { return json::array({v.x(), v.y(), v.z()}); }

const char* leg_shape_name(robot::LegShape shape) {
  switch (shape) {
    case robot::LegShape::in_plane: return "in_plane";
    case robot::LegShape::lateral_offset: return "lateral_offset";
    case robot::LegShape::general: return "general";
  }
  return "?";
}

RobotModel load(const std::string& name) {
  try {
    return robot::load_robot(robot::resolve_robot_path(name));
  } catch (const robot::RobotFileError& e) {
    throw CommandError(e.what());
  }
}

const robot::LegModel& pick_leg(const RobotModel& model, const std::string& leg) {
  const int i = model.leg_index(leg);
  if (i < 0) {
    std::string names;
    for (const auto& l : model.legs) names += (names.empty() ? "" : ", ") + l.name;
    throw CommandError("--leg: robot " + model.name + " has no leg '" + leg + "' (legs: " + names +
                       ")");
  }
  return model.legs[i];
}

struct RobotOptions {
  std::string robot = "hyq";
  std::string leg = "LF";
  std::string q;
  std::string foot;
  // robot import
  std::string urdf;
  std::string out;
  std::string name;
  std::string feet;
  double nominal_height = 0.0;
  std::vector<std::string> joint_ranges;
  std::vector<std::string> efforts, velocities;
  double foot_radius = 0.0;
  bool no_fit = false;
};

// "A,B,C=VALUE" -> each joint's (or joint kind's) value; `flag` and `unit` name it in errors.
void add_joint_values(const std::string& spec, const std::string& flag, const std::string& unit,
                      std::map<std::string, double>* values) {
  const size_t eq = spec.find('=');
  double v = 0;
  try {
    if (eq == std::string::npos || eq == 0) throw std::invalid_argument("no =");
    size_t used = 0;
    v = std::stod(spec.substr(eq + 1), &used);
    if (used != spec.size() - eq - 1) throw std::invalid_argument("trailing");
  } catch (const std::exception&) {
    throw CommandError(flag + " '" + spec + "': expected JOINT[,JOINT...]=VALUE (" + unit +
                       "; JOINT a URDF joint name or haa, hfe, kfe for that joint of every leg)");
  }
  std::stringstream names(spec.substr(0, eq));
  std::string joint;
  while (std::getline(names, joint, ','))
    if (!joint.empty()) (*values)[joint] = v;
}

// "A,B,C=MIN:MAX" (degrees) -> each joint's range.
void add_joint_ranges(const std::string& spec,
                      std::map<std::string, std::pair<double, double>>* ranges) {
  const size_t eq = spec.find('=');
  const size_t colon = spec.find(':', eq == std::string::npos ? 0 : eq);
  if (eq == std::string::npos || colon == std::string::npos)
    throw CommandError("--joint-range '" + spec + "': expected JOINT[,JOINT...]=MIN:MAX (degrees)");
  double lo = 0, hi = 0;
  try {
    size_t used = 0;
    lo = std::stod(spec.substr(eq + 1, colon - eq - 1), &used);
    if (used != colon - eq - 1) throw std::invalid_argument("trailing");
    hi = std::stod(spec.substr(colon + 1), &used);
    if (used != spec.size() - colon - 1) throw std::invalid_argument("trailing");
  } catch (const std::exception&) {
    throw CommandError("--joint-range '" + spec + "': MIN and MAX must be numbers (degrees)");
  }
  std::stringstream names(spec.substr(0, eq));
  std::string joint;
  while (std::getline(names, joint, ','))
    if (!joint.empty()) (*ranges)[joint] = {lo, hi};
}

// `robot import`: the robot file from the URDF, then its force polytopes fitted beside it, so
// the robot is ready for every constraint set. Nothing is written when either fails.
void run_import(const RobotOptions& opts, bool height_given, bool foot_radius_given) {
  robot::UrdfImportOptions o;
  o.name = opts.name;
  if (o.name.empty()) {
    std::string base = opts.out.substr(opts.out.find_last_of('/') + 1);
    if (base.size() > 5 && base.substr(base.size() - 5) == ".yaml") base.resize(base.size() - 5);
    o.name = base;
  }
  if (!opts.feet.empty()) {
    std::stringstream list(opts.feet);
    std::string f;
    while (std::getline(list, f, ','))
      if (!f.empty()) o.feet.push_back(f);
  }
  if (height_given) o.nominal_height = opts.nominal_height;
  if (foot_radius_given) o.foot_radius = opts.foot_radius;
  for (const auto& spec : opts.joint_ranges) add_joint_ranges(spec, &o.joint_range_deg);
  for (const auto& spec : opts.efforts) add_joint_values(spec, "--effort", "N m", &o.effort);
  for (const auto& spec : opts.velocities)
    add_joint_values(spec, "--velocity", "rad/s", &o.velocity);
  o.command = "terrastride robot import " + opts.urdf + " --out " + opts.out;
  if (!opts.name.empty()) o.command += " --name " + opts.name;
  if (!opts.feet.empty()) o.command += " --foot-link " + opts.feet;
  if (o.foot_radius) o.command += " --foot-radius " + std::to_string(*o.foot_radius);
  if (o.nominal_height) o.command += " --nominal-height " + std::to_string(*o.nominal_height);
  for (const auto& spec : opts.joint_ranges) o.command += " --joint-range " + spec;
  for (const auto& spec : opts.efforts) o.command += " --effort " + spec;
  for (const auto& spec : opts.velocities) o.command += " --velocity " + spec;
  robot::UrdfImport result;
  try {
    result = robot::import_urdf(opts.urdf, o);
  } catch (const robot::UrdfImportError& e) {
    throw CommandError(e.what());
  }
  // The model as it will load from --out (its polytope file's path derives from that path).
  robot::RobotModel model;
  try {
    model = robot::parse_robot(result.yaml, opts.out);
  } catch (const robot::RobotFileError& e) {
    throw CommandError(e.what());
  }
  const std::string polytopes = planner::polytope_path_for(model);
  try {
    perception::check_output_file(opts.out);
    if (!opts.no_fit) perception::check_output_file(polytopes);
  } catch (const perception::InputError& e) {
    throw CommandError("--out: " + std::string(e.what()));
  }
  for (const auto& n : result.notes) std::cout << "read: " << n << "\n";
  for (const auto& d : result.defaults) std::cout << "default: " << d << "\n";
  planner::RobotPolytopeModel fitted;
  std::vector<planner::LegFitReport> reports;
  const auto t0 = std::chrono::steady_clock::now();
  if (!opts.no_fit) {
    try {
      fitted = planner::fit_robot_polytopes(model, planner::PolytopeFitOptions(), &reports);
      fitted.fit_summary = planner::describe_fit(planner::PolytopeFitOptions());
    } catch (const std::exception& e) {
      throw CommandError("force-polytope fit for robot " + model.name + ": " + e.what() +
                         " (nothing written)");
    }
  }
  const double fit_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  try {
    if (!opts.no_fit) planner::save_polytope_model(fitted, model, polytopes);
    perception::write_file_atomically(opts.out, result.yaml);
  } catch (const std::exception& e) {
    throw CommandError("--out " + opts.out + ": " + e.what());
  }
  std::cout << "wrote " << opts.out << " (robot " << o.name << ")\n";
  if (opts.no_fit) {
    std::cout << "force polytopes not fitted (--no-fit): `plan --constraints all` needs them; run "
                 "`terrastride polytopes fit --robot "
              << robot::robot_argument(model) << "`\n";
    return;
  }
  double worst = 0, median = 0;
  std::string copied;
  for (const auto& r : reports) {
    worst = std::max(worst, r.training.rho_out_max);
    median = std::max(median, r.training.rho_out_median);
    if (!r.copied_from.empty())
      copied += (copied.empty() ? "; " : ", ") + r.leg + " = " + r.copied_from;
    if (!r.started_from.empty())
      copied += (copied.empty() ? "; " : ", ") + r.leg + " fitted from " + r.started_from;
  }
  std::printf("wrote %s (force polytopes of %zu legs fitted in %.2f s%s; rho_out median %.4f, "
              "max %.4f on the training feet; `terrastride polytopes validate --robot %s` "
              "measures them on held-out feet)\n",
              polytopes.c_str(), reports.size(), fit_s, copied.c_str(), median, worst,
              robot::robot_argument(model).c_str());
}

}  // namespace

void add_robot_command(CLI::App& app) {
  auto opts = std::make_shared<RobotOptions>();
  CLI::App* cmd = app.add_subcommand(
      "robot", "Inspect a robot model: parameters, leg kinematics and exact force polytopes");
  cmd->require_subcommand(1, 1);

  CLI::App* show = cmd->add_subcommand("show", "Print the validated robot parameters as JSON");
  show->add_option("--robot", opts->robot, "Robot name (data/robots/NAME.yaml) or path to a file")
      ->capture_default_str();
  show->callback([opts] {
    const RobotModel model = load(opts->robot);
    json out{{"name", model.name},
             {"file", model.source_file},
             {"mass", model.mass},
             {"nominal_base_height", model.nominal_base_height},
             {"foot_radius", model.foot_radius},
             {"legs", json::array()}};
    for (const auto& leg : model.legs) {
      // The general leg (docs/design.md §4.2): joint offsets and axes at q = 0 in the base frame,
      // whatever the file's keys; HyQ's l0/l1/l2 only where they mean what they say (in-plane).
      const auto& d = leg.joint_offset;
      const auto& a = leg.joint_axis;
      json item{{"name", leg.name},
                {"shape", leg_shape_name(leg.shape)},
                {"knee", leg.knee_sign < 0 ? "backward" : "forward"},
                {"haa_origin", vec_json(leg.haa_origin)},
                {"geometry",
                 {{"haa_to_hfe", vec_json(d[0])},
                  {"hfe_to_kfe", vec_json(d[1])},
                  {"kfe_to_foot", vec_json(d[2])},
                  {"axes", {{"haa", vec_json(a[0])}, {"hfe", vec_json(a[1])}, {"kfe", vec_json(a[2])}}}}},
                {"link_lengths", {{"haa_to_hfe", d[0].norm()}, {"thigh", d[1].norm()}, {"shank", d[2].norm()}}},
                {"q_min", vec_json(leg.q_min)},
                {"q_max", vec_json(leg.q_max)},
                {"torque_limit", vec_json(leg.torque_limit)},
                {"nominal_foot", vec_json(leg.nominal_foot)}};
      if (leg.shape == robot::LegShape::in_plane) item["lengths"] = {leg.l0, leg.l1, leg.l2};
      if ((leg.velocity_limit.array() > 0).any()) item["velocity_limit"] = vec_json(leg.velocity_limit);
      out["legs"].push_back(item);
    }
    out["trunk"] = model.trunk ? json{{"size", vec_json(model.trunk->size)},
                                      {"center", vec_json(model.trunk->center)}}
                               : json(nullptr);
    std::cout << out.dump(2) << "\n";
  });

  CLI::App* fk = cmd->add_subcommand(
      "fk", "Foot position, knee position, Jacobian and exact force polytope at joint angles");
  fk->add_option("--robot", opts->robot, "Robot name or file")->capture_default_str();
  fk->add_option("--leg", opts->leg, "Leg name (LF, RF, LH, RH for HyQ)")->capture_default_str();
  fk->add_option("--q", opts->q, "Joint angles HAA,HFE,KFE in radians")->required();
  fk->callback([opts] {
    const RobotModel model = load(opts->robot);
    const auto& leg = pick_leg(model, opts->leg);
    const Eigen::Vector3d q = parse_numbers(opts->q, 3, "--q");
    const auto poly = robot::exact_force_polytope(leg, q);
    json vertices = json::array();
    for (const auto& v : poly.vertices) vertices.push_back(vec_json(v));
    json out{{"leg", leg.name},
             {"q", vec_json(q)},
             {"foot", vec_json(robot::foot_position(leg, q))},
             {"knee", vec_json(robot::knee_position(leg, q))},
             {"force_polytope_vertices", vertices}};
    std::cout << out.dump() << "\n";
  });

  CLI::App* ik = cmd->add_subcommand("ik", "Joint angles for a foot position in the base frame");
  ik->add_option("--robot", opts->robot, "Robot name or file")->capture_default_str();
  ik->add_option("--leg", opts->leg, "Leg name")->capture_default_str();
  ik->add_option("--foot", opts->foot, "Foot position X,Y,Z in the base frame (m)")->required();
  ik->callback([opts] {
    const RobotModel model = load(opts->robot);
    const auto& leg = pick_leg(model, opts->leg);
    const auto res = robot::inverse_kinematics(leg, parse_numbers(opts->foot, 3, "--foot"));
    if (!res.ok()) throw CommandError(res.message);
    std::cout << json{{"leg", leg.name}, {"q", vec_json(res.q)}}.dump() << "\n";
  });

  CLI::App* import = cmd->add_subcommand(
      "import",
      "Write a robot file from a URDF (urdfdom): four HAA-HFE-KFE leg chains ending in a foot "
      "sphere, limits, inertias and collision radii; prints the defaults it used for what a URDF "
      "does not hold (nominal stance, range-of-motion box, shin model). Writes nothing on error.");
  import->add_option("urdf", opts->urdf, "The URDF file")->required();
  import->add_option("--out", opts->out, "The robot file to write (e.g. data/robots/NAME.yaml)")
      ->required();
  import->add_option("--name", opts->name, "The robot's name (default: --out's file name without .yaml)");
  import->add_option("--feet,--foot-link", opts->feet,
                     "Foot links, comma-separated (default: every link three revolute joints "
                     "below the base with a sphere collision; with --foot-radius also the leaf "
                     "link fixed below each leg's last joint)");
  import->add_option("--foot-radius", opts->foot_radius,
                     "Foot sphere radius, m, for feet without a sphere collision (mesh feet): the "
                     "foot link's frame origin is the sphere's centre");
  import->add_option("--nominal-height", opts->nominal_height,
                     "Base height above flat ground in the nominal stance, m (default: 75 % of the "
                     "feet's drop below the HAA joints at q = 0)");
  import->add_option("--joint-range", opts->joint_ranges,
                     "JOINT[,JOINT...]=MIN:MAX in degrees: replaces the URDF's range (required "
                     "for placeholder ranges, e.g. ANYmal C's +-540 deg); repeatable");
  import->add_option("--effort", opts->efforts,
                     "JOINT[,JOINT...]=N_M: replaces the URDF's effort limit (required for missing "
                     "or placeholder efforts, above 3 x weight x stretched leg length); JOINT may "
                     "be haa, hfe or kfe for that joint of every leg; repeatable");
  import->add_option("--velocity", opts->velocities,
                     "JOINT[,JOINT...]=RAD_PER_S: replaces the URDF's velocity limit (required for "
                     "missing or placeholder velocities, a stretched-leg foot speed above 25 m/s); "
                     "JOINT may be haa, hfe or kfe; repeatable");
  import->add_flag("--no-fit", opts->no_fit,
                   "Do not fit the force polytopes (ROBOT.polytopes.yaml beside --out), which "
                   "`plan --constraints all` needs");
  import->callback([opts, import] { run_import(*opts, import->count("--nominal-height") > 0,
                                               import->count("--foot-radius") > 0); });
}

}  // namespace terrastride::service
