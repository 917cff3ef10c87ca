#include "terrastride/terrain/scan_sim.hpp"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <random>
#include <sstream>

#include "terrastride/terrain/scenes.hpp"

namespace terrastride::terrain {
namespace {

using perception::InputError;

void require(bool ok, const std::string& what) {
  if (!ok) throw InputError("scan simulator: " + what);
}

}  // namespace

std::vector<SimulatedScan> simulate_scans(const Scene& scene, const DepthSensorOptions& o) {
  require(std::isfinite(o.height) && o.height >= 0.1 && o.height <= 5.0,
          "sensor height must be in [0.1, 5] m");
  require(std::isfinite(o.pitch_deg) && o.pitch_deg >= 0 && o.pitch_deg <= 90,
          "pitch must be in [0, 90] degrees");
  require(std::isfinite(o.roll_deg) && std::abs(o.roll_deg) <= 180 && std::isfinite(o.yaw_deg) &&
              std::abs(o.yaw_deg) <= 180,
          "roll and yaw must be in [-180, 180] degrees");
  require(o.hfov_deg > 0 && o.hfov_deg < 170 && o.vfov_deg > 0 && o.vfov_deg < 170,
          "field of view must be in (0, 170) degrees");
  require(o.columns > 0 && o.rows > 0 && o.columns <= 4096 && o.rows <= 4096,
          "image size must be 1..4096 pixels per side");
  require(o.max_range > 0 && o.noise_a >= 0 && o.noise_b >= 0, "range and noise must be >= 0");
  require(o.dropout >= 0 && o.dropout <= 1 && o.mixed_pixel >= 0 && o.mixed_pixel <= 1,
          "probabilities must be in [0, 1]");
  require(!o.sensor_x.empty(), "at least one sensor pose is needed");

  std::mt19937_64 rng(o.seed);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  std::normal_distribution<double> gauss(0.0, 1.0);
  constexpr double deg = M_PI / 180.0;
  // Camera body frame: x forward (optical axis), y left, z up; pitched down about y.
  // The pitch alone as its own matrix: the shipped scans' rays, bit for bit.
  const Eigen::Matrix3d pitch =
      Eigen::AngleAxisd(o.pitch_deg * deg, Eigen::Vector3d::UnitY()).matrix();
  const Eigen::Matrix3d R =
      o.roll_deg == 0 && o.yaw_deg == 0
          ? pitch
          : Eigen::Matrix3d(Eigen::AngleAxisd(o.yaw_deg * deg, Eigen::Vector3d::UnitZ()) * pitch *
                            Eigen::AngleAxisd(o.roll_deg * deg, Eigen::Vector3d::UnitX()));
  const Eigen::Quaterniond body(R);
  const double tan_h = std::tan(0.5 * o.hfov_deg * deg), tan_v = std::tan(0.5 * o.vfov_deg * deg);
  const double ground = scene.height(0.0, 0.0);  // the robot stands on the ground at the start

  std::vector<SimulatedScan> scans;
  for (double sx : o.sensor_x) {
    require(std::isfinite(sx), "sensor positions must be finite");
    SimulatedScan scan;
    const Eigen::Vector3d origin(sx, 0.0, ground + o.height);
    scan.cloud.sensor_origin = origin;
    scan.sensor = {origin, body};
    std::ostringstream src;
    src << "simulated " << scene.name() << " scan from (" << origin.transpose() << ")";
    scan.cloud.source = src.str();
    // Pinhole rays through pixel (u, v) offsets in pixel units.
    auto ray = [&](double u, double v) {
      const double a = (2.0 * u / o.columns - 1.0) * tan_h;  // left positive
      const double b = (1.0 - 2.0 * v / o.rows) * tan_v;     // up positive
      return Eigen::Vector3d(R * Eigen::Vector3d(1.0, -a, b).normalized());
    };
    for (int v = 0; v < o.rows; ++v) {
      for (int u = 0; u < o.columns; ++u) {
        ++scan.pixels;
        const Eigen::Vector3d d = ray(u + 0.5, v + 0.5);
        const auto hit = scene.ray_cast(origin, d, o.max_range);
        // Four sub-rays find depth edges inside the pixel footprint.
        double near = hit ? hit->range : o.max_range, far = near;
        bool any_miss = !hit;
        for (double du : {0.25, 0.75})
          for (double dv : {0.25, 0.75}) {
            const auto h = scene.ray_cast(origin, ray(u + du, v + dv), o.max_range);
            if (!h) {
              any_miss = true;
              continue;
            }
            near = std::min(near, h->range);
            far = std::max(far, h->range);
          }
        double range;
        if (!any_miss && far - near > o.edge_jump && uni(rng) < o.mixed_pixel) {
          // A flying pixel: the sensor averages the foreground and the background.
          range = near + uni(rng) * (far - near);
          ++scan.mixed;
        } else if (hit) {
          const double incidence = std::acos(std::clamp(-d.dot(hit->normal), -1.0, 1.0)) / deg;
          double p_drop = o.dropout;
          if (incidence > o.grazing_deg)
            p_drop = std::max(p_drop, (incidence - o.grazing_deg) / (90.0 - o.grazing_deg));
          if (uni(rng) < p_drop) {
            ++scan.dropped;
            continue;
          }
          range = hit->range;
        } else {
          continue;  // nothing within range: no return
        }
        range += (o.noise_a + o.noise_b * range * range) * gauss(rng);
        if (range <= 0 || range > o.max_range) {
          ++scan.dropped;
          continue;
        }
        scan.cloud.points.push_back((origin + range * d).cast<float>());
      }
    }
    scans.push_back(std::move(scan));
  }
  return scans;
}

}  // namespace terrastride::terrain
