// `terrastride robot`: inspect a robot file, forward/inverse kinematics, exact force polytopes.
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>

#include "terrastride/robot/leg_kinematics.hpp"
#include "terrastride/robot/robot_model.hpp"
#include "terrastride/service/cli.hpp"

namespace terrastride::service {
namespace {

using nlohmann::json;
using robot::RobotModel;

json vec_json(const Eigen::Vector3d& v) { return json::array({v.x(), v.y(), v.z()}); }

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
};

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
    json out{{"name", model.name}, {"file", model.source_file}, {"mass", model.mass},
             {"foot_radius", model.foot_radius}, {"legs", json::array()}};
    for (const auto& leg : model.legs) {
      out["legs"].push_back({{"name", leg.name},
                             {"haa_origin", vec_json(leg.haa_origin)},
                             {"lengths", {leg.l0, leg.l1, leg.l2}},
                             {"q_min", vec_json(leg.q_min)},
                             {"q_max", vec_json(leg.q_max)},
                             {"torque_limit", vec_json(leg.torque_limit)},
                             {"nominal_foot", vec_json(leg.nominal_foot)}});
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
}

}  // namespace terrastride::service
