#include "terrastride/perception/sensor_pose.hpp"

#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "terrastride/perception/point_cloud.hpp"

namespace terrastride::perception {
namespace {

bool is_separator(char c) {
  return c == ' ' || c == '\t' || c == ',' || c == '\r';
}

// The values of "a, b c": each must be a whole finite number.
std::vector<double> numbers(const std::string& text, const std::string& what) {
  std::vector<double> out;
  size_t i = 0;
  while (i < text.size()) {
    while (i < text.size() && is_separator(text[i])) ++i;
    if (i >= text.size()) break;
    size_t j = i;
    while (j < text.size() && !is_separator(text[j])) ++j;
    std::string_view token(text.data() + i, j - i);
    if (token.size() > 1 && token[0] == '+' && token[1] != '-') token.remove_prefix(1);
    double v = 0;
    const auto [end, err] = std::from_chars(token.data(), token.data() + token.size(), v);
    if (err != std::errc() || end != token.data() + token.size() || !std::isfinite(v))
      throw InputError(what + ": '" + std::string(text.data() + i, j - i) +
                       "' is not a finite number");
    out.push_back(v);
    i = j;
  }
  return out;
}

SensorPose pose_from(const std::vector<double>& v, const std::string& what) {
  SensorPose pose;
  pose.position = Eigen::Vector3d(v[0], v[1], v[2]);
  pose.orientation = checked_quaternion(v[3], v[4], v[5], v[6], what);
  return pose;
}

}  // namespace

size_t transform_points(std::vector<Eigen::Vector3f>& points, const SensorPose& pose) {
  const Eigen::Matrix3d r = pose.orientation.toRotationMatrix();
  size_t kept = 0;
  for (const Eigen::Vector3f& p : points) {
    const Eigen::Vector3f q = (r * p.cast<double>() + pose.position).cast<float>();
    if (q.allFinite()) points[kept++] = q;
  }
  const size_t dropped = points.size() - kept;
  points.resize(kept);
  return dropped;
}

Eigen::Quaterniond optical_in_body() {
  return Eigen::Quaterniond(0.5, -0.5, 0.5, -0.5);
}

Eigen::Quaterniond checked_quaternion(double x, double y, double z, double w,
                                      const std::string& what) {
  const Eigen::Quaterniond q(w, x, y, z);
  if (!q.coeffs().allFinite()) throw InputError(what + ": the quaternion is not finite");
  const double norm = q.norm();
  if (norm == 0.0) throw InputError(what + ": the quaternion is zero (no rotation is 0,0,0,1)");
  // Typed quaternions carry 4-6 decimals, hence a norm off by up to ~1e-4; farther off is not a
  // rounding of a rotation but a wrong value (Euler angles, swapped fields).
  if (std::abs(norm - 1.0) > 1e-3) {
    std::ostringstream os;
    os << what << ": the quaternion (x, y, z, w) = (" << x << ", " << y << ", " << z << ", " << w
       << ") has norm " << norm
       << ", not 1 (only norms within 0.001 of 1 are normalised); the order is QX,QY,QZ,QW";
    throw InputError(os.str());
  }
  return q.normalized();
}

SensorPose parse_sensor_pose(const std::string& text, const std::string& what) {
  const std::vector<double> v = numbers(text, what);
  if (v.size() != 7)
    throw InputError(what + ": expected 7 numbers X,Y,Z,QX,QY,QZ,QW, got " +
                     std::to_string(v.size()) + " in '" + text + "'");
  return pose_from(v, what);
}

std::vector<PoseLine> read_poses_file(const std::string& path) {
  namespace fs = std::filesystem;
  std::ifstream in(path);
  if (!in) throw InputError(path + ": cannot open the poses file: " + std::strerror(errno));
  const fs::path folder = fs::absolute(fs::path(path)).parent_path();
  std::vector<PoseLine> lines;
  std::string line;
  size_t line_no = 0;
  while (std::getline(in, line)) {
    ++line_no;
    const std::string where = path + ": line " + std::to_string(line_no);
    if (line.find('\0') != std::string::npos)
      throw InputError(where + ": binary data: not a poses file");
    const size_t hash = line.find('#');
    if (hash != std::string::npos) line.resize(hash);
    size_t i = 0;
    while (i < line.size() && is_separator(line[i])) ++i;
    if (i == line.size()) continue;
    size_t j = i;
    while (j < line.size() && line[j] != ' ' && line[j] != '\t') ++j;
    PoseLine p;
    p.path = line.substr(i, j - i);
    if (p.path.size() > 1 && p.path.back() == ',') p.path.pop_back();  // "PATH, X, Y, ..."
    p.line = line_no;
    const std::vector<double> v = numbers(line.substr(j), where);
    if (v.size() != 7)
      throw InputError(where + ": expected a path and 7 numbers X Y Z QX QY QZ QW, got " +
                       std::to_string(v.size()) + " numbers after '" + p.path + "'");
    p.pose = pose_from(v, where);
    const fs::path file(p.path);
    std::error_code ec;
    const fs::path full = file.is_absolute() ? file : folder / file;
    const fs::path canonical = fs::weakly_canonical(full, ec);
    p.resolved = (ec ? full.lexically_normal() : canonical).string();
    for (const PoseLine& earlier : lines)
      if (earlier.resolved == p.resolved)
        throw InputError(where + ": " + p.path + " already has a pose on line " +
                         std::to_string(earlier.line));
    lines.push_back(std::move(p));
  }
  if (in.bad()) throw InputError(path + ": read error");
  if (lines.empty()) throw InputError(path + ": the poses file names no cloud");
  return lines;
}

}  // namespace terrastride::perception
