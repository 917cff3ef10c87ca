// What simulation.cpp (the model building) and simulation_run.cpp (a run: stepping, controller,
// verdict) share: the terrain and robot as MJCF, the loaded MuJoCo model, and the run itself. Not
// part of the library's interface (simulation.hpp).
#pragma once

#include <mujoco/mujoco.h>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <functional>
#include <memory>
#include <string>

#include "terrastride/simulation/simulation.hpp"

namespace terrastride::simulation::internal {

constexpr double kGravity = 9.81;

// Numbers in the generated MJCF (17 significant digits: the model is exactly the robot file's).
std::string fmt(double v);
std::string fmt(const Eigen::Vector3d& v);
// Numbers in messages (4 significant digits).
std::string fmt_short(double v);

// The terrain as MJCF: `asset` (inside <asset>) and `geoms` (world geoms), plus what to do with
// the loaded model (a heightfield's data is written after loading).
struct TerrainMjcf {
  std::string asset;
  std::string geoms;
  std::function<void(mjModel*)> after_load;
  int filled_cells = 0;
  std::string description;
  // Contact pairs a robot geom can make with the terrain geoms: a scene's few boxes and its plane
  // make at most 8 contacts per pair (box-box), a heightfield up to 50 per pair (prisms); 0: no
  // terrain (the robot alone).
  int terrain_geoms = 0;
  bool heightfield = false;
};

// The whole model: options, the terrain, the robot at `pos`/`quat` with its actuators.
std::string full_mjcf(const robot::RobotModel& model, const TerrainMjcf* terrain,
                      const SimulationOptions& o, const Eigen::Vector3d& pos,
                      const Eigen::Quaterniond& quat);

// The generated model, loaded through MuJoCo's virtual file system (2.2.2 has no
// mj_addBufferVFS: an empty VFS file is made and the text copied into it).
struct Model {
  mjModel* m = nullptr;
  mjData* d = nullptr;
  ~Model() {
    if (d) mj_deleteData(d);
    if (m) mj_deleteModel(m);
  }
};

std::unique_ptr<Model> load_model(const std::string& xml);

// One run of `plan` on the terrain: `scene` is the field (its normals place the feet), `terrain`
// its MJCF (simulation_run.cpp).
SimulationReport simulate(const robot::RobotModel& model, const planner::Trajectory& plan,
                          const terrain::HeightField& scene, const TerrainMjcf& terrain,
                          const SimulationOptions& o);

}  // namespace terrastride::simulation::internal
