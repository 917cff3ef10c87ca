// `terrastride map`: clouds -> cleaned clouds -> OctoMap + height grid -> smoothed field and
// foothold-safety layers, written atomically as DIR/terrain.json, DIR/octomap.bt, DIR/layers/*.npy.
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <exception>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <sstream>
#include <thread>
#include <vector>

#include "terrastride/perception/atomic_output.hpp"
#include "terrastride/perception/cloud_io.hpp"
#include "terrastride/perception/filters.hpp"
#include "terrastride/perception/octomap_fusion.hpp"
#include "terrastride/service/cli.hpp"
#include "terrastride/terrain/terrain_map.hpp"

namespace terrastride::service {
namespace {

using nlohmann::json;
using Clock = std::chrono::steady_clock;

struct MapOptions {
  std::vector<std::string> clouds;
  std::string origin;
  double resolution = 0.02;
  std::vector<double> foot_radii{0.02, 0.05, 0.10};
  // OctoMap voxels: ray casting cost grows with range / voxel size. 2 cm was measured against 5 cm
  // (2026-11-22, 2 cores under load): 10-15x the OctoMap time on every shipped scan (0.05-0.1 s ->
  // 0.6-1.3 s for data/scans, 0.2 -> 1.7 s for 1 M points), ~10x the octomap.bt size, and 4.6 s /
  // 0.4 GB -> 17-26 s / 1.8 GB for ../shared/scans/octomap/scan.xyz; so 5 cm stays the default and
  // finer voxels are an option (--octomap-resolution) for small scans.
  double octomap_resolution = 0.05;
  // Rays longer than this are cut there (OctoMap's maxrange: free space carved up to it, the far
  // hit not marked). 0 = off, today's behaviour: the height grid cannot tell which far returns
  // matter, so dropping them stays the caller's choice.
  double octomap_max_range = 0.0;
  double voxel = 0.0;
  int outlier_k = 8;
  double outlier_stddev = 2.0;
  // Outlier removal judges cells of this size by their centroids (0 = every point, as PCL's
  // StatisticalOutlierRemoval does on its own): per-point removal costs ~2.5 us a point.
  double outlier_voxel = 0.01;
  double max_step = terrain::SafetyOptions{}.max_step;
  double max_slope = terrain::SafetyOptions{}.max_slope;
  std::string out;
  bool json = false;
};

// Stage progress on stderr, only for a terminal and only for inputs large enough to wait for.
class Progress {
 public:
  explicit Progress(bool enabled) : enabled_(enabled) {}
  void stage(const std::string& what) {
    if (!enabled_) return;
    std::cerr << "\r\033[K[map] " << what << std::flush;
  }
  void done() {
    if (enabled_) std::cerr << "\r\033[K" << std::flush;
  }

 private:
  bool enabled_;
};

double seconds_since(Clock::time_point t) {
  return std::chrono::duration<double>(Clock::now() - t).count();
}

// Runs body(k) for k in [0, n) on up to one thread per core. Each k must write only its own
// results. When calls fail, the exception of the lowest k is rethrown (the same error as a loop).
template <class Body>
void parallel_for(size_t n, const Body& body) {
  const size_t workers = std::min<size_t>(n, std::max(1u, std::thread::hardware_concurrency()));
  std::vector<std::exception_ptr> errors(n);
  std::atomic<size_t> next{0};
  const auto work = [&] {
    for (size_t k; (k = next.fetch_add(1)) < n;) {
      try {
        body(k);
      } catch (...) {
        errors[k] = std::current_exception();
      }
    }
  };
  std::vector<std::thread> threads;
  for (size_t w = 1; w < workers; ++w) threads.emplace_back(work);
  work();
  for (auto& th : threads) th.join();
  for (const auto& e : errors)
    if (e) std::rethrow_exception(e);
}

// What `map --out` writes, for perception::AtomicOutputDir: outputs of versions before the marker
// file are recognised by their names (every version wrote all three of terrain.json, octomap.bt
// and layers/, so a folder that merely holds a terrain.json is not taken for one).
perception::OutputDirKind map_output_kind() {
  return {"map",
          {"terrain.json", "octomap.bt", "layers/"},
          {"terrain.json", "octomap.bt", "layers/", "layers/*.npy"},
          {}};
}

std::string fmt(double v, int precision = 3) {
  std::ostringstream os;
  os << std::fixed << std::setprecision(precision) << v;
  return os.str();
}

void run_map(const MapOptions& o) {
  // Validate every option before reading anything.
  if (o.clouds.empty()) throw CommandError("no input clouds given");
  if (!std::isfinite(o.resolution) || o.resolution < 0.002 || o.resolution > 1.0)
    throw CommandError("--resolution: " + std::to_string(o.resolution) +
                       " m is outside the accepted range [0.002, 1] m");
  const double octo_res = o.octomap_resolution;
  if (!std::isfinite(octo_res) || octo_res < 0.005 || octo_res > 1.0)
    throw CommandError("--octomap-resolution: must be in [0.005, 1] m");
  if (!std::isfinite(o.octomap_max_range) || o.octomap_max_range < 0)
    throw CommandError("--octomap-max-range: " + std::to_string(o.octomap_max_range) +
                       " m is not a finite number >= 0 (0 = no limit)");
  if (o.foot_radii.empty()) throw CommandError("--foot-radius: at least one radius is needed");
  for (double r : o.foot_radii)
    if (!std::isfinite(r) || r < 0 || r > 0.5)
      throw CommandError("--foot-radius: " + std::to_string(r) + " m is outside [0, 0.5] m");
  if (!(o.voxel >= 0) || !std::isfinite(o.voxel))
    throw CommandError("--voxel: must be >= 0 (0 = off)");
  if (o.outlier_k < 0) throw CommandError("--outlier-k: must be >= 0 (0 = off)");
  if (!(o.outlier_voxel >= 0) || !std::isfinite(o.outlier_voxel))
    throw CommandError("--outlier-voxel: must be >= 0 (0 = judge every point)");
  if (!(o.max_step > 0) || !(o.max_slope > 0))
    throw CommandError("--max-step/--max-slope: must be positive");
  std::optional<Eigen::Vector3d> origin;
  if (!o.origin.empty()) origin = Eigen::Vector3d(parse_numbers(o.origin, 3, "--origin"));
  if (o.out.empty()) throw CommandError("--out: an output directory is required");
  {
    const std::filesystem::path parent =
        std::filesystem::absolute(std::filesystem::path(o.out)).parent_path();
    if (!std::filesystem::is_directory(parent))
      throw CommandError("--out: parent directory '" + parent.string() + "' does not exist");
  }
  // Before reading and fusing the clouds (seconds to minutes): an existing folder that is not an
  // earlier output (e.g. the folder of the scans themselves) or an unwritable one fails now.
  try {
    perception::check_output_dir(o.out, map_output_kind());
  } catch (const perception::InputError& e) {
    throw CommandError("--out: " + std::string(e.what()));
  }

  const auto t_start = Clock::now();
  json timings;
  size_t file_bytes = 0;
  for (const auto& c : o.clouds) {
    std::error_code ec;
    const auto s = std::filesystem::file_size(c, ec);
    if (!ec) file_bytes += s;
  }
  Progress progress(isatty(STDERR_FILENO) && file_bytes > 8u * 1024 * 1024);

  // Read.
  auto t = Clock::now();
  std::vector<perception::PointCloud> clouds;
  json inputs = json::array();
  size_t points_in = 0, non_finite = 0;
  for (size_t k = 0; k < o.clouds.size(); ++k) {
    progress.stage("reading " + o.clouds[k] + " (" + std::to_string(k + 1) + "/" +
                   std::to_string(o.clouds.size()) + ")");
    perception::ReadStats rs;
    perception::PointCloud c;
    try {
      c = perception::read_cloud(o.clouds[k], origin, &rs);
    } catch (const perception::InputError& e) {
      throw CommandError(e.what());
    }
    points_in += rs.points_in_file;
    non_finite += rs.non_finite;
    json in{{"path", o.clouds[k]}, {"points", rs.points_in_file}, {"non_finite", rs.non_finite}};
    if (c.sensor_origin)
      in["origin"] = {c.sensor_origin->x(), c.sensor_origin->y(), c.sensor_origin->z()};
    inputs.push_back(in);
    clouds.push_back(std::move(c));
  }
  timings["read_s"] = seconds_since(t);

  // Clean, and build the OctoMap beside it. Each cloud is cleaned on its own (outlier statistics
  // are per cloud), so the clouds are spread over the cores; every result lands in its own slot,
  // hence the same output as in order. The OctoMap only reads cleaned clouds: its thread starts
  // now and inserts cloud k (in input order, as build_octomap does) as soon as k is cleaned, so a
  // core left without a cloud to clean (3 clouds on 2 cores) works on the OctoMap meanwhile; this
  // thread then builds the grid, the smoothed field and the safety layers beside the rest of it.
  // OctoMap: ray casting is the expensive part, so rays go to one point per OctoMap voxel (a
  // voxel-grid filtered copy): the same occupied voxels and nearly the same carved free space.
  t = Clock::now();
  progress.stage("cleaning " + std::to_string(clouds.size()) +
                 " cloud(s) and building the OctoMap");
  perception::CloudFilterOptions fo;
  fo.voxel_size = static_cast<float>(o.voxel);
  fo.outlier_neighbours = o.outlier_k;
  fo.outlier_stddev = o.outlier_stddev;
  fo.outlier_voxel = static_cast<float>(o.outlier_voxel);

  std::mutex cleaned_mutex;
  std::condition_variable cleaned_cv;
  std::vector<char> cleaned(clouds.size(), 0);
  bool cleaning_failed = false;
  std::unique_ptr<octomap::OcTree> tree;
  std::exception_ptr octomap_error;
  double octomap_s = 0;
  std::thread octomap_thread([&] {
    auto t0 = Clock::now();  // octomap_s counts the work, not the waits for cleaned clouds
    try {
      perception::OctoMapOptions oo;
      oo.resolution = octo_res;
      oo.max_range = o.octomap_max_range > 0 ? o.octomap_max_range : -1.0;
      auto built = perception::build_octomap({}, oo);  // validates the options
      perception::CloudFilterOptions vo;
      vo.voxel_size = static_cast<float>(octo_res);
      for (size_t k = 0; k < clouds.size(); ++k) {
        {
          octomap_s += seconds_since(t0);
          std::unique_lock<std::mutex> lock(cleaned_mutex);
          cleaned_cv.wait(lock, [&] { return cleaned[k] || cleaning_failed; });
          if (!cleaned[k]) return;  // cleaning failed: that error is reported
          t0 = Clock::now();
        }
        perception::insert_into_octomap(*built, perception::filter_cloud(clouds[k], vo),
                                        oo.max_range, oo.discretize);
      }
      tree = std::move(built);
    } catch (const perception::InputError& e) {
      octomap_error = std::make_exception_ptr(CommandError(e.what()));
    } catch (...) {
      octomap_error = std::current_exception();
    }
    octomap_s += seconds_since(t0);
  });
  const auto mark_cleaned = [&](size_t k, bool ok) {
    {
      std::lock_guard<std::mutex> lock(cleaned_mutex);
      if (ok)
        cleaned[k] = 1;
      else
        cleaning_failed = true;
    }
    cleaned_cv.notify_all();
  };
  try {
    parallel_for(clouds.size(), [&](size_t k) {
      try {
        clouds[k] = perception::filter_cloud(clouds[k], fo);
      } catch (const perception::InputError& e) {
        mark_cleaned(k, false);
        throw CommandError(e.what());
      } catch (...) {
        mark_cleaned(k, false);
        throw;
      }
      mark_cleaned(k, true);
    });
  } catch (...) {
    mark_cleaned(0, false);  // whatever failed, the OctoMap thread must not wait for more clouds
    octomap_thread.join();
    throw;
  }
  size_t kept = 0;
  for (size_t k = 0; k < clouds.size(); ++k) {
    kept += clouds[k].points.size();
    inputs[k]["kept"] = clouds[k].points.size();
  }
  timings["filter_s"] = seconds_since(t);
  if (kept == 0) {
    octomap_thread.join();
    throw CommandError("no points left after cleaning the input clouds");
  }
  progress.stage("height grid, foothold safety and OctoMap");

  // Height grid, smoothed field, safety layers.
  t = Clock::now();
  std::unique_ptr<terrain::TerrainMap> map;
  std::exception_ptr map_error;
  try {
    terrain::HeightGridOptions go;
    go.resolution = o.resolution;
    terrain::HeightGrid grid = terrain::build_height_grid(clouds, go);
    timings["grid_s"] = seconds_since(t);
    t = Clock::now();
    terrain::SafetyOptions so;
    so.max_step = o.max_step;
    so.max_slope = o.max_slope;
    map = std::make_unique<terrain::TerrainMap>(std::move(grid), o.foot_radii, so);
    timings["safety_s"] = seconds_since(t);
  } catch (const perception::InputError& e) {
    map_error = std::make_exception_ptr(
        CommandError("--resolution/--foot-radius: " + std::string(e.what())));
  } catch (...) {
    map_error = std::current_exception();
  }
  octomap_thread.join();
  if (map_error) std::rethrow_exception(map_error);
  if (octomap_error) std::rethrow_exception(octomap_error);
  timings["octomap_s"] = octomap_s;

  // Write everything into a temporary directory, then rename it into place.
  t = Clock::now();
  progress.stage("writing " + o.out);
  json meta;
  json summary;
  try {
    perception::AtomicOutputDir out(o.out, map_output_kind());
    meta = terrain::write_terrain_layers(*map, out.path());
    perception::write_octomap(*tree, out.path() + "/octomap.bt");
    const auto& g = map->grid();
    meta["octomap"] = {
        {"file", "octomap.bt"}, {"resolution", octo_res}, {"leaf_nodes", tree->getNumLeafNodes()}};
    if (o.octomap_max_range > 0) meta["octomap"]["max_range"] = o.octomap_max_range;
    meta["inputs"] = inputs;
    meta["statistics"]["points_in"] = points_in;
    meta["statistics"]["non_finite"] = non_finite;
    meta["statistics"]["points_kept"] = kept;
    meta["statistics"]["noise_sigma"] = g.noise_sigma;
    timings["write_s"] = seconds_since(t);
    timings["total_s"] = seconds_since(t_start);
    meta["timings"] = timings;
    perception::write_file_atomically(out.path() + "/terrain.json", meta.dump(2) + "\n");
    out.commit();
  } catch (const perception::InputError& e) {
    throw CommandError("--out: " + std::string(e.what()));
  }
  progress.done();

  const auto& g = map->grid();
  json safe = json::array();
  for (const auto& r : meta["safety"]["radii"])
    safe.push_back({{"radius", r["radius"]}, {"safe_fraction", r["safe_fraction"]}});
  summary = {{"out", o.out},
             {"points_in", points_in},
             {"points_kept", kept},
             {"cells", g.geometry.size()},
             {"grid", {g.geometry.nx, g.geometry.ny}},
             {"resolution", g.geometry.resolution},
             {"observed_cells", g.observed_cells},
             {"noise_sigma", g.noise_sigma},
             {"safe", safe},
             {"timings", timings}};
  if (o.json) {
    std::cout << summary.dump() << "\n";
    return;
  }
  std::cout << "terrain map written to " << o.out << "\n"
            << "  points: " << points_in << " in, " << non_finite << " non-finite, " << kept
            << " kept after cleaning\n"
            << "  grid: " << g.geometry.nx << " x " << g.geometry.ny << " cells of "
            << g.geometry.resolution << " m, " << g.observed_cells << " observed, "
            << g.filled_cells << " filled, sensor noise " << fmt(g.noise_sigma * 1000, 1)
            << " mm\n";
  for (const auto& s : safe)
    std::cout << "  safe for foot radius " << s["radius"].get<double>()
              << " m: " << fmt(100.0 * s["safe_fraction"].get<double>(), 1) << " % of cells\n";
  std::cout << "  time: read " << fmt(timings["read_s"]) << " s, clean " << fmt(timings["filter_s"])
            << " s, grid " << fmt(timings["grid_s"]) << " s, safety " << fmt(timings["safety_s"])
            << " s, OctoMap " << fmt(timings["octomap_s"]) << " s, write "
            << fmt(timings["write_s"]) << " s, total " << fmt(timings["total_s"]) << " s\n";
}

}  // namespace

void add_map_command(CLI::App& app) {
  auto o = std::make_shared<MapOptions>();
  CLI::App* cmd = app.add_subcommand(
      "map",
      "Build a terrain map from point clouds (PCD, PLY, XYZ, NPY): OctoMap, height grid, smoothed "
      "field and foothold-safety layers in DIR");
  cmd->add_option("clouds", o->clouds, "Input clouds")->required();
  cmd->add_option("--origin", o->origin,
                  "Sensor origin X,Y,Z for all clouds (overrides a PCD VIEWPOINT)");
  cmd->add_option("--resolution", o->resolution, "Height grid cell size (m)")
      ->capture_default_str();
  cmd->add_option("--foot-radius", o->foot_radii,
                  "Foot radius for the safety layers (m); repeat or comma-separate for several")
      ->delimiter(',')
      ->capture_default_str();
  cmd->add_option("--octomap-resolution", o->octomap_resolution, "OctoMap voxel size (m)")
      ->capture_default_str();
  cmd->add_option("--octomap-max-range", o->octomap_max_range,
                  "Cut OctoMap rays at this range (m): faster on long-range scans, but hits "
                  "beyond it are not marked occupied; 0 = no limit")
      ->capture_default_str();
  cmd->add_option("--voxel", o->voxel, "Voxel-grid downsampling of the input (m); 0 = off")
      ->capture_default_str();
  cmd->add_option("--outlier-k", o->outlier_k, "Statistical outlier removal neighbours (0 = off)")
      ->capture_default_str();
  cmd->add_option("--outlier-stddev", o->outlier_stddev, "Statistical outlier removal threshold")
      ->capture_default_str();
  cmd->add_option("--outlier-voxel", o->outlier_voxel,
                  "Outlier removal judges cells of this size (m) by their centroids and keeps or "
                  "drops their points together; 0 = judge every point (slow on dense clouds)")
      ->capture_default_str();
  cmd->add_option("--max-step", o->max_step, "Largest raw step in a safe foot disk (m)")
      ->capture_default_str();
  cmd->add_option("--max-slope", o->max_slope, "Largest slope (tan) of a safe foothold")
      ->capture_default_str();
  cmd->add_option("--out", o->out, "Output directory")->required();
  cmd->add_flag("--json", o->json, "Print the summary as one JSON object");
  cmd->callback([o] { run_map(*o); });
}

}  // namespace terrastride::service
