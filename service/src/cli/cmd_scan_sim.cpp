// `terrastride scan-sim`: a simulated recorded scan of a scene of docs/design.md §11.
//
// The depth sensor rides on the robot as it approaches the start, so one scan is written per sensor
// pose: --out FILE.pcd holds the first pose, FILE.1.pcd, FILE.2.pcd ... the others. As a depth
// camera's driver saves them, the points are in the camera's frame (--frame sensor: its body,
// x forward, z up; --frame optical: z forward, y down) with the camera's pose as VIEWPOINT, which
// `map` and PCL's viewers apply; --frame world writes world-frame points without a VIEWPOINT.
// Map them together with `terrastride map FILE*.pcd`.
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>

#include "terrastride/perception/atomic_output.hpp"
#include "terrastride/perception/cloud_io.hpp"
#include "terrastride/service/cli.hpp"
#include "terrastride/terrain/scan_sim.hpp"
#include "terrastride/terrain/scenes.hpp"

namespace terrastride::service {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

struct ScanSimOptions {
  std::string scene;
  double height = 0.8;
  double pitch = 40.0;
  double roll = 0.0;
  double yaw = 0.0;
  std::string frame = "sensor";
  bool no_viewpoint = false;
  int poses = 3;
  unsigned seed = 1;
  std::string out;
  bool json = false;
};

std::string lower(std::string s) {
  for (auto& c : s) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return s;
}

// Writes each scan into its file in the frame --frame names; returns the pose of each file's
// frame.
std::vector<perception::SensorPose> write_scans(const ScanSimOptions& o,
                                                const std::vector<terrain::SimulatedScan>& scans,
                                                const std::vector<perception::OutputFile>& finals) {
  // The frame each file's points are written in (write_pcd re-expresses the world-frame scan).
  std::vector<perception::PointCloud> world_only(scans.size());
  std::vector<perception::SensorPose> frames(scans.size());
  for (size_t k = 0; k < scans.size(); ++k) {
    frames[k] = scans[k].sensor;
    if (o.frame == "optical")
      frames[k].orientation = (frames[k].orientation * perception::optical_in_body()).normalized();
    world_only[k].points = scans[k].cloud.points;
  }
  const auto write = [&](size_t k, const std::string& path) {
    if (o.frame == "world") {
      perception::write_pcd(world_only[k], path);
    } else if (o.no_viewpoint) {
      // The points in the camera's frame, but no pose in the file: what a driver that does
      // not fill VIEWPOINT writes.
      perception::PointCloud local;
      const Eigen::Matrix3d rt = frames[k].orientation.toRotationMatrix().transpose();
      for (const Eigen::Vector3f& p : scans[k].cloud.points)
        local.points.push_back((rt * (p.cast<double>() - frames[k].position)).cast<float>());
      perception::write_pcd(local, path);
    } else {
      perception::write_pcd(scans[k].cloud, path, &frames[k]);
    }
  };
  std::vector<std::string> temps(scans.size());
  auto cleanup = [&] {
    for (const auto& t : temps)
      if (!t.empty()) ::unlink(t.c_str());
  };
  const auto renamed = [](const perception::OutputFile& f) {
    return f.kind == perception::OutputFile::Kind::kNew ||
           f.kind == perception::OutputFile::Kind::kRegular;
  };
  try {
    for (size_t k = 0; k < scans.size(); ++k) {
      if (!renamed(finals[k])) continue;
      temps[k] = perception::temporary_path_for(finals[k].target);
      write(k, temps[k]);
    }
    for (size_t k = 0; k < scans.size(); ++k) {
      if (!renamed(finals[k])) continue;
      if (::rename(temps[k].c_str(), finals[k].target.c_str()) != 0)
        throw perception::InputError(finals[k].path + ": rename failed: " + std::strerror(errno));
      temps[k].clear();
    }
    for (size_t k = 0; k < scans.size(); ++k)
      if (!renamed(finals[k])) write(k, finals[k].path);
  } catch (const std::exception& e) {
    cleanup();
    throw CommandError("--out: cannot write '" + o.out + "': " + e.what());
  }

  return frames;
}

void run_scan_sim(const ScanSimOptions& o) {
  std::unique_ptr<terrain::Scene> scene;
  try {
    scene = terrain::make_scene(o.scene);
  } catch (const perception::InputError& e) {
    throw CommandError(std::string("--scene: ") + e.what());
  }
  const fs::path out(o.out);
  if (lower(out.extension().string()) != ".pcd")
    throw CommandError("--out: '" + o.out + "' must name a .pcd file");
  const fs::path dir = out.has_parent_path() ? out.parent_path() : fs::path(".");
  if (!fs::is_directory(dir))
    throw CommandError("--out: directory '" + dir.string() + "' does not exist");
  if (o.poses < 1 || o.poses > 8) throw CommandError("--poses: must be between 1 and 8");
  if (o.frame != "sensor" && o.frame != "optical" && o.frame != "world")
    throw CommandError("--frame: '" + o.frame + "' is not 'sensor', 'optical' or 'world'");
  // Every file this run writes (FILE.pcd, FILE.1.pcd, ...), checked before the simulation.
  std::vector<perception::OutputFile> finals;
  for (int k = 0; k < o.poses; ++k) {
    fs::path f = out;
    if (k > 0) f.replace_extension("." + std::to_string(k) + ".pcd");
    try {
      finals.push_back(perception::check_output_file(f.string()));
    } catch (const perception::InputError& e) {
      throw CommandError(std::string("--out: ") + e.what());
    }
  }

  terrain::DepthSensorOptions so;
  so.height = o.height;
  so.pitch_deg = o.pitch;
  so.roll_deg = o.roll;
  so.yaw_deg = o.yaw;
  so.seed = o.seed;
  // Sensor positions along the approach, from 1 m behind the start to just behind it.
  so.sensor_x.clear();
  for (int k = 0; k < o.poses; ++k)
    so.sensor_x.push_back(o.poses == 1 ? -0.6 : -1.0 + 0.8 * k / (o.poses - 1));
  std::vector<terrain::SimulatedScan> scans;
  try {
    scans = terrain::simulate_scans(*scene, so);
  } catch (const perception::InputError& e) {
    throw CommandError(std::string("--height/--pitch/--roll/--yaw: ") + e.what());
  }

  if (scans.size() != finals.size())
    throw CommandError("scan-sim: " + std::to_string(scans.size()) + " scans for " +
                       std::to_string(finals.size()) + " poses");

  // Write every pose to a temporary name first (beside the file it replaces, a symbolic link's
  // target included), then rename them all: nothing half-written. A device or pipe is written
  // through afterwards instead (renaming over it would destroy it). Temporaries of a killed run
  // are removed by the next one (perception::temporary_path_for).
  const std::vector<perception::SensorPose> frames = write_scans(o, scans, finals);

  json files = json::array();
  for (size_t k = 0; k < scans.size(); ++k) {
    const auto& c = scans[k].cloud;
    const auto& q = frames[k].orientation;
    files.push_back({{"path", finals[k].path},
                     {"points", c.points.size()},
                     {"origin", {c.sensor_origin->x(), c.sensor_origin->y(), c.sensor_origin->z()}},
                     {"frame", o.frame},
                     {"viewpoint", o.frame != "world" && !o.no_viewpoint},
                     // The pose of the frame the points are in (X,Y,Z,QX,QY,QZ,QW for
                     // `map --sensor-pose`).
                     {"pose",
                      {frames[k].position.x(), frames[k].position.y(), frames[k].position.z(),
                       q.x(), q.y(), q.z(), q.w()}},
                     {"pixels", scans[k].pixels},
                     {"dropped", scans[k].dropped},
                     {"mixed_pixels", scans[k].mixed}});
  }
  if (o.json) {
    std::cout << json{{"scene", scene->name()}, {"seed", o.seed}, {"files", files}}.dump() << "\n";
    return;
  }
  std::cout << scene->describe() << "\n";
  for (const auto& f : files)
    std::cout << "wrote " << f["path"].get<std::string>() << ": " << f["points"] << " points from ("
              << f["origin"][0] << ", " << f["origin"][1] << ", " << f["origin"][2] << "), "
              << f["dropped"] << " dropped, " << f["mixed_pixels"] << " mixed pixels\n";
}

}  // namespace

void add_scan_sim_command(CLI::App& app) {
  auto o = std::make_shared<ScanSimOptions>();
  CLI::App* cmd = app.add_subcommand(
      "scan-sim",
      "Simulate a recorded scan of a scene: a robot-mounted depth camera (noise, dropouts, mixed "
      "pixels) at a few poses; FILE.pcd holds the first pose, FILE.1.pcd ... the others, each "
      "in the camera's frame with its pose as VIEWPOINT");
  cmd->add_option("--scene", o->scene, "Scene: " + terrain::scene_names_text())->required();
  cmd->add_option("--height", o->height, "Sensor height above the ground (m)")
      ->capture_default_str();
  cmd->add_option("--pitch", o->pitch, "Sensor pitch down from horizontal (degrees)")
      ->capture_default_str();
  cmd->add_option("--roll", o->roll, "Sensor roll about its optical axis (degrees)")
      ->capture_default_str();
  cmd->add_option("--yaw", o->yaw, "Sensor yaw about the vertical (degrees)")
      ->capture_default_str();
  cmd->add_option("--frame", o->frame,
                  "Frame of the written points: 'sensor' (the camera body: x forward, y left, z "
                  "up), 'optical' (REP 103: z forward, x right, y down), both with the camera's "
                  "pose as VIEWPOINT; 'world' (world-frame points, no VIEWPOINT)")
      ->capture_default_str();
  cmd->add_flag("--no-viewpoint", o->no_viewpoint,
                "Write the sensor- or optical-frame points without their pose (PCL's default "
                "VIEWPOINT), as a driver that records none does");
  cmd->add_option("--poses", o->poses, "Number of sensor poses along the approach (1-8)")
      ->capture_default_str();
  cmd->add_option("--seed", o->seed, "Random seed (same seed, same scan)")->capture_default_str();
  cmd->add_option("--out", o->out, "Output PCD file")->required();
  cmd->add_flag("--json", o->json, "Print the summary as one JSON object");
  cmd->callback([o] { run_scan_sim(*o); });
}

}  // namespace terrastride::service
