// `terrastride query DIR --at X,Y [...]`: height, gradient and foothold safety at points of a map.
#include <cmath>
#include <filesystem>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <sstream>

#include "pasteable.hpp"
#include "terrastride/perception/point_cloud.hpp"
#include "terrastride/service/cli.hpp"
#include "terrastride/terrain/terrain_map.hpp"

namespace terrastride::service {
namespace {

struct QueryOptions {
  std::string dir;
  std::vector<std::string> at;
  double foot_radius = 0.0;
  bool foot_radius_given = false;  // else: the map's first radius (the robot's)
};

void run_query(const QueryOptions& o) {
  std::unique_ptr<terrain::TerrainMap> map;
  std::error_code ec;
  if (std::filesystem::is_regular_file(o.dir, ec))
    throw CommandError(o.dir + ": a file is not a map: map it first with `" + map_command(o.dir) +
                       "` (add the pose flags `map` asks for, if any) and query " +
                       shell_word(map_folder_for(o.dir)));
  try {
    map = terrain::load_terrain_dir(o.dir);
  } catch (const perception::InputError& e) {
    throw CommandError(e.what());
  }
  const auto radii = map->radii();
  if (o.foot_radius_given && !(o.foot_radius >= 0 && o.foot_radius <= 0.5))
    throw CommandError("--foot-radius: must be within [0, 0.5] m");
  if (radii.empty()) throw CommandError(o.dir + ": the map holds no safety layer");
  const double r = o.foot_radius_given ? o.foot_radius : radii.front();
  // Only radii whose layer the map holds, as the service answers: another radius would be a
  // distance transform over the whole grid, computed here and nowhere else.
  std::string list;
  bool known = false;
  for (double held : radii) {
    known = known || std::abs(held - r) < 1e-9;
    list += (list.empty() ? "" : ", ") + std::to_string(held);
  }
  if (!known)
    throw CommandError("--foot-radius: " + std::to_string(r) + " has no safety layer in " + o.dir +
                       " (available: " + list + "); map again with --foot-radius to add one");
  // Check every point before printing anything: no partial output on a bad query.
  std::vector<Eigen::Vector2d> points;
  const Eigen::Vector2d lo = map->min_corner(), hi = map->max_corner();
  for (const auto& text : o.at) {
    const Eigen::Vector2d p = parse_numbers(text, 2, "--at");
    if (p.x() < lo.x() || p.x() > hi.x() || p.y() < lo.y() || p.y() > hi.y()) {
      std::ostringstream os;
      os << "--at " << text << ": point is outside the map (x in [" << lo.x() << ", " << hi.x()
         << "], y in [" << lo.y() << ", " << hi.y() << "])";
      throw CommandError(os.str());
    }
    points.push_back(p);
  }
  std::ostringstream out;
  const auto finite_or_null = [](double v) { return std::isfinite(v) ? nlohmann::json(v) : nullptr; };
  for (const auto& p : points) {
    const terrain::PointAnswer a = map->answer(p.x(), p.y(), r);
    nlohmann::json line{{"x", p.x()},
                        {"y", p.y()},
                        {"height", a.ground.height},
                        {"gradient", {a.ground.gradient.x(), a.ground.gradient.y()}},
                        {"safe", a.safe},
                        {"margin", a.margin},
                        {"field_margin", a.field_margin},
                        {"observed", a.observed},
                        {"overhead", finite_or_null(a.overhead)},
                        {"free_height", finite_or_null(a.free_height)},
                        {"foot_radius", r}};
    if (!a.safe) line["unsafe_because"] = a.unsafe_because;
    out << line.dump() << "\n";
  }
  std::cout << out.str();
}

}  // namespace

void add_query_command(CLI::App& app) {
  auto o = std::make_shared<QueryOptions>();
  CLI::App* cmd = app.add_subcommand(
      "query", "Query a terrain map: one JSON object per point with height, gradient, safety and overhead");
  cmd->add_option("dir", o->dir, "Terrain directory written by `terrastride map`")->required();
  cmd->add_option("--at", o->at, "Query point X,Y (repeat for several)")->required();
  cmd->add_option("--foot-radius", o->foot_radius,
                  "Foot radius for safe/margin (m); default: the map's first radius");
  cmd->callback([o, cmd] {
    o->foot_radius_given = cmd->count("--foot-radius") > 0;
    run_query(*o);
  });
}

}  // namespace terrastride::service
