#include "terrastride/planner/polytope_model.hpp"

#include <yaml-cpp/yaml.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <mutex>
#include <sstream>

#include "terrastride/perception/atomic_output.hpp"
#include "terrastride/planner/polytope_core.hpp"
#include "terrastride/planner/solver_fork.hpp"

namespace terrastride::planner {
namespace core = polytope_core;
using Eigen::Vector3d;

LegCoordinates LegPolytopeModel::coordinates(const Vector3d& foot) const {
  const double h[4] = {hip.x(), hip.y(), hip.z(), hip_offset};
  LegCoordinates c;
  core::leg_coordinates(use_roll, h, foot, &c.gamma, &c.l, &c.alpha);
  return c;
}

namespace {

// Interpolated (theta, phi, d) of every facet and their partial derivatives in l and alpha.
struct Interpolated {
  std::array<double, 3 * kPolytopeFacets> value{}, d_l{}, d_alpha{};
};

Interpolated interpolate(const LegPolytopeModel& m, double l, double alpha) {
  Interpolated out;
  const int i = core::locate(m.l_knots, l);
  const double t = core::fraction(m.l_knots, i, l);
  const double dl = m.l_knots[i + 1] - m.l_knots[i];
  constexpr int kN = 3 * kPolytopeFacets;
  if (m.num_alpha() == 1) {
    const double* v0 = m.node(i, 0);
    const double* v1 = m.node(i + 1, 0);
    for (int k = 0; k < kN; ++k) {
      out.value[k] = (1 - t) * v0[k] + t * v1[k];
      out.d_l[k] = (v1[k] - v0[k]) / dl;
    }
    return out;
  }
  const int j = core::locate(m.alpha_knots, alpha);
  const double s = core::fraction(m.alpha_knots, j, alpha);
  const double da = m.alpha_knots[j + 1] - m.alpha_knots[j];
  const double* v00 = m.node(i, j);
  const double* v10 = m.node(i + 1, j);
  const double* v01 = m.node(i, j + 1);
  const double* v11 = m.node(i + 1, j + 1);
  for (int k = 0; k < kN; ++k) {
    out.value[k] =
        (1 - t) * (1 - s) * v00[k] + t * (1 - s) * v10[k] + (1 - t) * s * v01[k] + t * s * v11[k];
    out.d_l[k] = ((1 - s) * (v10[k] - v00[k]) + s * (v11[k] - v01[k])) / dl;
    out.d_alpha[k] = ((1 - t) * (v01[k] - v00[k]) + t * (v11[k] - v10[k])) / da;
  }
  return out;
}

}  // namespace

PolytopeFacets LegPolytopeModel::facets(const Vector3d& foot) const {
  const LegCoordinates c = coordinates(foot);
  const Interpolated in = interpolate(*this, c.l, c.alpha);
  PolytopeFacets f;
  const double cg = std::cos(c.gamma), sg = std::sin(c.gamma);
  const double ca = std::cos(c.alpha), sa = std::sin(c.alpha);
  for (int j = 0; j < kPolytopeFacets; ++j) {
    const Vector3d nl = core::local_normal(poles[j], in.value[3 * j], in.value[3 * j + 1]);
    f.normals[j] = core::rotate_cs(cg, sg, ca, sa, nl);
    f.offsets[j] = in.value[3 * j + 2];
  }
  return f;
}

Eigen::Matrix<double, kPolytopeFacets, 1> LegPolytopeModel::constraint(
    const Vector3d& foot, const Vector3d& force, Eigen::Matrix<double, kPolytopeFacets, 3>* dg_dp,
    Eigen::Matrix<double, kPolytopeFacets, 3>* dg_df) const {
  Eigen::Matrix<double, kPolytopeFacets, 1> g;
  const LegCoordinates c = coordinates(foot);
  const Interpolated in = interpolate(*this, c.l, c.alpha);
  const double cg = std::cos(c.gamma), sg = std::sin(c.gamma);
  const double ca = std::cos(c.alpha), sa = std::sin(c.alpha);

  // Chain p -> (gamma, l, alpha): gradients with respect to the foot position.
  const Vector3d v = foot - hip;
  Vector3d dgamma = Vector3d::Zero(), db;
  double b;
  if (use_roll) {
    const double rho2 = v.y() * v.y() + v.z() * v.z();
    const double rho = std::sqrt(rho2);
    dgamma = Vector3d(0, -v.z() / rho2, v.y() / rho2);
    db = Vector3d(0, v.y() / rho, v.z() / rho);
    b = rho - hip_offset;
  } else {
    db = Vector3d(0, 0, -1);
    b = -v.z() - hip_offset;
  }
  const double a = v.x();
  const Vector3d da_dp = Vector3d::UnitX();
  const Vector3d dl = (a * da_dp + b * db) / c.l;
  const Vector3d dalpha = (b * da_dp - a * db) / (c.l * c.l);

  for (int j = 0; j < kPolytopeFacets; ++j) {
    // One sine and cosine per angle serve the normal and its derivatives (evaluated often).
    const double ct = std::cos(in.value[3 * j]), st = std::sin(in.value[3 * j]);
    const double cp = std::cos(in.value[3 * j + 1]), sp = std::sin(in.value[3 * j + 1]);
    const int p = poles[j], c1 = (p + 1) % 3, c2 = (p + 2) % 3;
    Vector3d nl;
    nl[c1] = cp * ct;
    nl[c2] = cp * st;
    nl[p] = sp;
    // w = Ry(-alpha) nl, n = Rx(gamma) w.
    const Vector3d w(ca * nl[0] - sa * nl[2], nl[1], sa * nl[0] + ca * nl[2]);
    const Vector3d n(w[0], cg * w[1] - sg * w[2], sg * w[1] + cg * w[2]);
    g[j] = n.dot(force) - in.value[3 * j + 2];
    if (dg_df) dg_df->row(j) = n.transpose();
    if (!dg_dp) continue;
    Vector3d dnl_dtheta = Vector3d::Zero(), dnl_dphi = Vector3d::Zero();
    dnl_dtheta[c1] = -cp * st;
    dnl_dtheta[c2] = cp * ct;
    dnl_dphi[c1] = -sp * ct;
    dnl_dphi[c2] = -sp * st;
    dnl_dphi[p] = cp;
    const auto rotate = [&](const Vector3d& u) { return core::rotate_cs(cg, sg, ca, sa, u); };
    const Vector3d dn_dgamma(0, -sg * w[1] - cg * w[2], cg * w[1] - sg * w[2]);
    const Vector3d dw_dalpha(-sa * nl[0] - ca * nl[2], 0, ca * nl[0] - sa * nl[2]);
    const Vector3d dn_dalpha_rot(dw_dalpha[0], cg * dw_dalpha[1] - sg * dw_dalpha[2],
                                 sg * dw_dalpha[1] + cg * dw_dalpha[2]);
    const Vector3d dn_dl = rotate(dnl_dtheta * in.d_l[3 * j] + dnl_dphi * in.d_l[3 * j + 1]);
    const Vector3d dn_dalpha =
        dn_dalpha_rot + rotate(dnl_dtheta * in.d_alpha[3 * j] + dnl_dphi * in.d_alpha[3 * j + 1]);
    const double f_gamma = force.dot(dn_dgamma);
    const double f_l = force.dot(dn_dl) - in.d_l[3 * j + 2];
    const double f_alpha = force.dot(dn_dalpha) - in.d_alpha[3 * j + 2];
    dg_dp->row(j) = (f_gamma * dgamma + f_l * dl + f_alpha * dalpha).transpose();
  }
  return g;
}

std::array<Vector3d, kPolytopeVertices> LegPolytopeModel::vertices(const Vector3d& foot) const {
  const PolytopeFacets f = facets(foot);
  std::array<Vector3d, kPolytopeVertices> out;
  for (int k = 0; k < kPolytopeVertices; ++k) {
    const int r0 = core::vertex_facet(k, 0), r1 = core::vertex_facet(k, 1),
              r2 = core::vertex_facet(k, 2);
    out[k] = core::meet<double>(f.normals[r0], f.normals[r1], f.normals[r2], f.offsets[r0],
                                f.offsets[r1], f.offsets[r2]);
  }
  return out;
}

void LegPolytopeModel::validate() const {
  const std::string who = "polytope model of leg " + leg_name + ": ";
  auto increasing = [&](const std::vector<double>& k, const char* name, size_t min_size) {
    if (k.size() < min_size)
      throw std::invalid_argument(who + name + " needs at least " + std::to_string(min_size) +
                                  " knots");
    for (size_t i = 0; i < k.size(); ++i) {
      if (!std::isfinite(k[i])) throw std::invalid_argument(who + name + " has a non-finite knot");
      if (i > 0 && !(k[i] > k[i - 1]))
        throw std::invalid_argument(who + name + " must be strictly increasing");
    }
  };
  increasing(l_knots, "l_knots", 2);
  increasing(alpha_knots, "alpha_knots", 1);
  if (l_knots.front() <= 0) throw std::invalid_argument(who + "l_knots must be positive");
  const size_t expected = l_knots.size() * alpha_knots.size() * 3 * kPolytopeFacets;
  if (nodes.size() != expected)
    throw std::invalid_argument(who + "nodes has " + std::to_string(nodes.size()) +
                                " values, expected " + std::to_string(expected));
  for (double x : nodes)
    if (!std::isfinite(x)) throw std::invalid_argument(who + "nodes has a non-finite value");
  for (int p : poles)
    if (p < 0 || p > 2) throw std::invalid_argument(who + "poles must be 0, 1 or 2");
  if (!hip.allFinite() || !std::isfinite(hip_offset))
    throw std::invalid_argument(who + "hip is not finite");
}

const LegPolytopeModel& RobotPolytopeModel::leg(const std::string& name) const {
  for (const auto& l : legs)
    if (l.leg_name == name) return l;
  throw std::out_of_range("polytope model of robot " + robot + " has no leg '" + name + "'");
}

std::string leg_fingerprint(const robot::LegModel& leg) {
  // Numbers printed at 12 significant digits so the fingerprint survives a YAML round trip of the
  // robot file; FNV-1a 64 of that text.
  std::string text;
  char buf[64];
  auto add = [&](double x) {
    std::snprintf(buf, sizeof buf, "%.12g;", x);
    text += buf;
  };
  auto add3 = [&](const Vector3d& v) {
    for (int i = 0; i < 3; ++i) add(v[i]);
  };
  add3(leg.haa_origin);
  add(leg.l0);
  add(leg.l1);
  add(leg.l2);
  add(leg.side);
  add(leg.knee_sign);
  add3(leg.q_min);
  add3(leg.q_max);
  add3(leg.torque_limit);
  add3(leg.nominal_foot);
  add3(leg.range_of_motion);
  // The general leg's geometry (the in-plane leg's is all in l0, l1, l2 and side above: its
  // fingerprint stays what it was).
  if (leg.shape != robot::LegShape::in_plane) {
    for (int j = 0; j < 3; ++j) {
      add3(leg.joint_axis[j]);
      add3(leg.joint_offset[j]);
    }
  }
  uint64_t h = 1469598103934665603ull;
  for (unsigned char ch : text) {
    h ^= ch;
    h *= 1099511628211ull;
  }
  std::snprintf(buf, sizeof buf, "%016llx", static_cast<unsigned long long>(h));
  return buf;
}

std::string polytope_path_for(const robot::RobotModel& model) {
  namespace fs = std::filesystem;
  fs::path p(model.source_file);
  const std::string stem = p.stem().string();
  return (p.parent_path() / (stem + ".polytopes.yaml")).string();
}

void save_polytope_model(const RobotPolytopeModel& model, const robot::RobotModel& robot_model,
                         const std::string& path) {
  YAML::Emitter out;
  out.SetDoublePrecision(17);
  out << YAML::Comment(
      "Fitted force-polytope parameters (terrastride polytopes fit); see polytope_model.hpp.\n"
      "Nodes: one flow list per (l_knot, alpha_knot) node, alpha fastest, holding (theta, phi, d)\n"
      "for the facets +HAA, -HAA, +HFE, -HFE, +KFE, -KFE. Regenerate when the robot file changes.");
  out << YAML::BeginMap;
  out << YAML::Key << "robot" << YAML::Value << model.robot;
  out << YAML::Key << "variant" << YAML::Value << model.variant;
  out << YAML::Key << "fit" << YAML::Value << model.fit_summary;
  out << YAML::Key << "legs" << YAML::Value << YAML::BeginSeq;
  for (const auto& leg : model.legs) {
    const int idx = robot_model.leg_index(leg.leg_name);
    if (idx < 0)
      throw PolytopeFileError("cannot save " + path + ": robot " + robot_model.name +
                              " has no leg " + leg.leg_name);
    out << YAML::BeginMap;
    out << YAML::Key << "name" << YAML::Value << leg.leg_name;
    out << YAML::Key << "fingerprint" << YAML::Value << leg_fingerprint(robot_model.legs[idx]);
    out << YAML::Key << "use_roll" << YAML::Value << leg.use_roll;
    out << YAML::Key << "hip" << YAML::Value << YAML::Flow << YAML::BeginSeq << leg.hip.x()
        << leg.hip.y() << leg.hip.z() << YAML::EndSeq;
    out << YAML::Key << "hip_offset" << YAML::Value << leg.hip_offset;
    out << YAML::Key << "l_knots" << YAML::Value << YAML::Flow << leg.l_knots;
    out << YAML::Key << "alpha_knots" << YAML::Value << YAML::Flow << leg.alpha_knots;
    out << YAML::Key << "poles" << YAML::Value << YAML::Flow
        << std::vector<int>(leg.poles.begin(), leg.poles.end());
    out << YAML::Key << "nodes" << YAML::Value << YAML::BeginSeq;
    const size_t stride = 3 * kPolytopeFacets;
    for (size_t n = 0; n * stride < leg.nodes.size(); ++n) {
      out << YAML::Flow
          << std::vector<double>(leg.nodes.begin() + n * stride,
                                 leg.nodes.begin() + (n + 1) * stride);
    }
    out << YAML::EndSeq << YAML::EndMap;
  }
  out << YAML::EndSeq << YAML::EndMap;
  if (!out.good()) throw PolytopeFileError("cannot write " + path + ": " + out.GetLastError());

  // Nothing half-written: perception's writer replaces a regular file atomically (also behind a
  // symbolic link, which stays) and writes a FIFO or device through.
  try {
    perception::write_file_atomically(path, std::string(out.c_str()) + "\n");
  } catch (const perception::InputError& e) {
    throw PolytopeFileError(std::string("cannot write ") + e.what());
  }
}

RobotPolytopeModel load_polytope_model(const robot::RobotModel& robot_model,
                                       const std::string& path) {
  const std::string refit = "; run `terrastride polytopes fit --robot " +
                            robot::robot_argument(robot_model) + "`";
  if (!std::filesystem::exists(path))
    throw PolytopeFileError("force-polytope parameters " + path + " not found" + refit);
  YAML::Node root;
  try {
    root = YAML::LoadFile(path);
  } catch (const YAML::Exception& e) {
    throw PolytopeFileError(path + ": not valid YAML: " + e.what());
  }
  auto field = [&](const YAML::Node& node, const std::string& key, const std::string& where) {
    if (!node.IsMap() || !node[key])
      throw PolytopeFileError(path + ": " + where + "missing field '" + key + "'");
    return node[key];
  };
  RobotPolytopeModel model;
  try {
    model.robot = field(root, "robot", "").as<std::string>();
    model.variant = field(root, "variant", "").as<std::string>();
    if (root["fit"]) model.fit_summary = root["fit"].as<std::string>();
  } catch (const YAML::Exception& e) {
    throw PolytopeFileError(path + ": bad top-level field: " + e.what());
  }
  if (model.robot != robot_model.name)
    throw PolytopeFileError(path + ": fitted for robot '" + model.robot + "', not '" +
                            robot_model.name + "'" + refit);
  const YAML::Node legs = field(root, "legs", "");
  if (!legs.IsSequence()) throw PolytopeFileError(path + ": 'legs' must be a list");
  for (const auto& rleg : robot_model.legs) {
    YAML::Node node;
    bool found = false;
    for (size_t k = 0; k < legs.size() && !found; ++k) {
      const YAML::Node n = legs[k];
      if (n.IsMap() && n["name"] && n["name"].IsScalar() &&
          n["name"].as<std::string>() == rleg.name) {
        node = n;
        found = true;
      }
    }
    if (!found) throw PolytopeFileError(path + ": no parameters for leg " + rleg.name + refit);
    const std::string where = "leg " + rleg.name + ": ";
    LegPolytopeModel leg;
    leg.leg_name = rleg.name;
    std::string current_key;
    try {
      current_key = "fingerprint";
      const std::string fp = field(node, "fingerprint", where).as<std::string>();
      const std::string expected = leg_fingerprint(rleg);
      if (fp != expected)
        throw PolytopeFileError(path + " is stale for leg " + rleg.name + ": the robot file " +
                                robot_model.source_file + " changed since the fit (fingerprint " +
                                expected + ", file has " + fp + ")" + refit);
      current_key = "use_roll";
      leg.use_roll = field(node, "use_roll", where).as<bool>();
      current_key = "hip";
      const auto hip = field(node, "hip", where).as<std::vector<double>>();
      if (hip.size() != 3) throw PolytopeFileError(path + ": " + where + "'hip' needs 3 numbers");
      leg.hip = Vector3d(hip[0], hip[1], hip[2]);
      current_key = "hip_offset";
      leg.hip_offset = field(node, "hip_offset", where).as<double>();
      current_key = "l_knots";
      leg.l_knots = field(node, "l_knots", where).as<std::vector<double>>();
      current_key = "alpha_knots";
      leg.alpha_knots = field(node, "alpha_knots", where).as<std::vector<double>>();
      current_key = "poles";
      const auto poles = field(node, "poles", where).as<std::vector<int>>();
      if (poles.size() != kPolytopeFacets)
        throw PolytopeFileError(path + ": " + where + "'poles' needs 6 integers");
      std::copy(poles.begin(), poles.end(), leg.poles.begin());
      current_key = "nodes";
      const YAML::Node nodes = field(node, "nodes", where);
      if (!nodes.IsSequence()) throw PolytopeFileError(path + ": " + where + "'nodes' not a list");
      for (const auto& n : nodes) {
        const auto v = n.as<std::vector<double>>();
        if (v.size() != 3 * kPolytopeFacets)
          throw PolytopeFileError(path + ": " + where + "each node needs 18 numbers");
        leg.nodes.insert(leg.nodes.end(), v.begin(), v.end());
      }
    } catch (const YAML::Exception& e) {
      throw PolytopeFileError(path + ": " + where + "bad field '" + current_key + "': " + e.what());
    }
    try {
      leg.validate();
    } catch (const std::invalid_argument& e) {
      throw PolytopeFileError(path + ": " + e.what());
    }
    model.legs.push_back(std::move(leg));
  }
  return model;
}

namespace {
struct PolytopeCacheLock {};
}  // namespace

std::shared_ptr<const RobotPolytopeModel> shared_polytope_model(
    const robot::RobotModel& robot_model) {
  namespace fs = std::filesystem;
  const std::string path = polytope_path_for(robot_model);
  // What makes a parsed model valid for this robot: the file's version and the legs it was
  // checked against (load_polytope_model compares their fingerprints with the file's).
  std::string key = path + "\n" + robot_model.name;
  for (const auto& leg : robot_model.legs) key += "\n" + leg.name + ":" + leg_fingerprint(leg);
  std::error_code ec;
  const auto mtime = fs::last_write_time(path, ec);
  const auto size = ec ? std::uintmax_t{0} : fs::file_size(path, ec);
  struct Entry {
    fs::file_time_type mtime;
    std::uintmax_t size = 0;
    std::shared_ptr<const RobotPolytopeModel> model;
  };
  static std::map<std::string, Entry> cache;
  std::mutex& mu = fork_safe_mutex<PolytopeCacheLock>();
  if (!ec) {
    std::lock_guard<std::mutex> lock(mu);
    const auto it = cache.find(key);
    if (it != cache.end() && it->second.mtime == mtime && it->second.size == size)
      return it->second.model;
  }
  // A missing or unreadable file: load_polytope_model says what is wrong.
  auto model = std::make_shared<const RobotPolytopeModel>(load_polytope_model(robot_model, path));
  if (!ec) {
    std::lock_guard<std::mutex> lock(mu);
    cache[key] = Entry{mtime, size, model};
  }
  return model;
}

}  // namespace terrastride::planner
