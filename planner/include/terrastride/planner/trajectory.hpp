// A planned motion sampled in time: the content of plan.json (see docs/formats.md, "plan.json").
// Everything in the world frame; forces are those the ground exerts on the foot.
#pragma once

#include <Eigen/Core>
#include <map>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

namespace terrastride::planner {

struct BaseState {
  Eigen::Vector3d position = Eigen::Vector3d::Zero();
  Eigen::Vector3d euler_zyx = Eigen::Vector3d::Zero();  // yaw, pitch, roll
  Eigen::Vector3d linear_velocity = Eigen::Vector3d::Zero();
  Eigen::Vector3d angular_velocity = Eigen::Vector3d::Zero();  // world frame
  Eigen::Vector3d linear_acceleration = Eigen::Vector3d::Zero();
  Eigen::Vector3d angular_acceleration = Eigen::Vector3d::Zero();
};

struct FootState {
  Eigen::Vector3d position = Eigen::Vector3d::Zero();
  Eigen::Vector3d velocity = Eigen::Vector3d::Zero();
  Eigen::Vector3d force = Eigen::Vector3d::Zero();
  bool contact = false;
};

struct TrajectorySample {
  double t = 0.0;
  BaseState base;
  std::vector<FootState> feet;  // in the order of Trajectory::feet
};

struct SolverStats {
  std::string status;  // optimal, infeasible, time_limit, ...
  int iterations = 0;
  double wall_s = 0.0;
  int n_variables = 0;
  int n_constraints = 0;
};

struct Trajectory {
  std::string robot;
  // The robot file's text the plan was made with (plan.json "robot_file", with its content hash);
  // empty in plans written before plans carried their robot, which name a shipped robot.
  std::string robot_definition;
  std::string gait;
  double duration = 0.0;
  double sample_dt = 0.01;
  std::vector<std::string> feet;  // LF, RF, LH, RH
  std::vector<TrajectorySample> samples;
  SolverStats solver;
  // Post-hoc and dense checks by name (plan.json "checks"); a check that does not apply is absent.
  std::map<std::string, double> checks;
  // Further top-level plan.json keys (phases, terrain, constraints, detailed check series...):
  // written and read back as they are, so tools can add keys without this struct knowing them.
  nlohmann::json extra = nlohmann::json::object();
};

}  // namespace terrastride::planner
