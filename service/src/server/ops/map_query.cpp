// map.query: height, gradient, safety margin and "observed" for a batch of (x, y) points on the
// published map (inline: it runs on the I/O thread and never waits for an update).
#include <cmath>
#include <sstream>
#include <string>
#include <vector>

#include "server/backend.hpp"

namespace terrastride::service {

namespace pc = protocol::code;
using nlohmann::json;
using protocol::ProtocolError;

namespace {

constexpr std::size_t kMaxQueryPoints = 10000;

// One point's answer as a JSON object, appended to `text`.
void append_answer(std::string& text, double x, double y, const terrain::PointAnswer& a) {
  text += "{\"x\":";
  protocol::append_json_number(text, x);
  text += ",\"y\":";
  protocol::append_json_number(text, y);
  text += ",\"height\":";
  protocol::append_json_number(text, a.ground.height);
  text += ",\"gradient\":[";
  protocol::append_json_number(text, a.ground.gradient.x());
  text += ',';
  protocol::append_json_number(text, a.ground.gradient.y());
  text += "],\"safe\":";
  text += a.safe ? "true" : "false";
  text += ",\"margin\":";
  protocol::append_json_number(text, a.margin);
  text += ",\"field_margin\":";
  protocol::append_json_number(text, a.field_margin);
  text += ",\"observed\":";
  text += a.observed ? "true" : "false";
  // JSON has no infinity: nothing overhead is null.
  text += ",\"overhead\":";
  if (std::isfinite(a.overhead)) {
    protocol::append_json_number(text, a.overhead);
  } else {
    text += "null";
  }
  text += ",\"free_height\":";
  if (std::isfinite(a.free_height)) {
    protocol::append_json_number(text, a.free_height);
  } else {
    text += "null";
  }
  if (!a.safe) text += ",\"unsafe_because\":" + json(a.unsafe_because).dump();
  text += '}';
}

OpResult map_query(Backend& backend, OpContext& ctx) {
  const json& h = ctx.request.header;
  const double foot_radius = protocol::get_number(h, "foot_radius", backend.robot().foot_radius);
  if (!(foot_radius >= 0) || foot_radius > 0.5)  // as `terrastride query --foot-radius`
    throw ProtocolError(pc::kBadRequest, "\"foot_radius\" must be within [0, 0.5] m");
  std::vector<double> xy;
  if (const auto* a = ctx.request.find("points")) {
    const auto f = protocol::read_floats(*a, 2, /*require_finite=*/true);
    xy.assign(f.begin(), f.end());
  } else {
    const auto it = h.find("points");
    if (it == h.end() || !it->is_array())
      throw ProtocolError(pc::kBadRequest,
                          "map.query needs \"points\": [[x, y], ...] or a float32 attachment "
                          "\"points\" of shape [N, 2]");
    if (it->size() > kMaxQueryPoints)
      throw ProtocolError(pc::kBadRequest, "map.query: " + std::to_string(it->size()) +
                                               " points exceed the batch limit of " +
                                               std::to_string(kMaxQueryPoints));
    xy.reserve(2 * it->size());
    for (std::size_t i = 0; i < it->size(); ++i) {
      const json& p = (*it)[i];
      if (!p.is_array() || p.size() != 2 || !p[0].is_number() || !p[1].is_number())
        throw ProtocolError(pc::kBadRequest,
                            "points[" + std::to_string(i) + "] must be [x, y] (two numbers)");
      const double x = p[0].get<double>(), y = p[1].get<double>();
      if (!std::isfinite(x) || !std::isfinite(y))
        throw ProtocolError(pc::kBadRequest, "points[" + std::to_string(i) + "] is not finite");
      xy.push_back(x);
      xy.push_back(y);
    }
  }
  if (xy.size() / 2 > kMaxQueryPoints)
    throw ProtocolError(pc::kBadRequest, "map.query: " + std::to_string(xy.size() / 2) +
                                             " points exceed the batch limit of " +
                                             std::to_string(kMaxQueryPoints));
  const auto m = backend.map();  // one snapshot for the whole batch
  if (!m) throw ProtocolError(pc::kNoMap, "no terrain map loaded: send map.update first");
  // A scanned map answers only for the radii whose safety layers it holds: computing a new
  // layer takes a distance transform over the whole grid, not a query's budget.
  const auto* grid_map = dynamic_cast<const terrain::TerrainMap*>(m->field.get());
  if (grid_map) {
    const auto radii = grid_map->radii();
    bool known = false;
    std::string list;
    for (double r : radii) {
      known = known || std::abs(r - foot_radius) < 1e-9;
      list += (list.empty() ? "" : ", ") + std::to_string(r);
    }
    if (!known)
      throw ProtocolError(pc::kBadRequest,
                          "\"foot_radius\" " + std::to_string(foot_radius) +
                              " has no safety layer in this map (available: " + list +
                              "); send map.update with \"foot_radii\" to add one");
    // Outside a scanned map nothing is known: refused, as `terrastride query` refuses it
    // (an analytic scene is defined everywhere and answers).
    const Eigen::Vector2d lo = grid_map->min_corner(), hi = grid_map->max_corner();
    for (std::size_t i = 0; i + 1 < xy.size(); i += 2)
      if (xy[i] < lo.x() || xy[i] > hi.x() || xy[i + 1] < lo.y() || xy[i + 1] > hi.y()) {
        std::ostringstream os;
        os << "points[" << i / 2 << "] (" << xy[i] << ", " << xy[i + 1]
           << ") is outside the map (x in [" << lo.x() << ", " << hi.x() << "], y in [" << lo.y()
           << ", " << hi.y() << "])";
        throw ProtocolError(pc::kBadRequest, os.str());
      }
  }
  // The reply is written as text directly: building a JSON tree of N objects costs more than
  // the terrain queries themselves.
  OpResult r;
  std::string text;
  text.reserve(64 + 160 * (xy.size() / 2));
  text += "{\"generation\":" + std::to_string(m->generation) + ",\"results\":[";
  for (std::size_t i = 0; i + 1 < xy.size(); i += 2) {
    const double x = xy[i], y = xy[i + 1];
    terrain::PointAnswer a;
    if (grid_map) {
      a = grid_map->answer(x, y, foot_radius);
    } else {
      a.ground = m->field->sample(x, y);
      a.margin = a.field_margin = m->field->safety_margin(x, y, foot_radius).margin;
      a.observed = m->field->observed(x, y);
      a.safe = a.observed && a.margin > 0.0;
      a.overhead = m->field->overhead(x, y);
      if (std::isfinite(a.overhead)) a.free_height = a.overhead - a.ground.height;
      if (!a.safe) a.unsafe_because = a.observed ? "not a safe foothold" : "not observed";
    }
    if (i) text += ',';
    append_answer(text, x, y, a);
  }
  text += "]}";
  backend.count_query(xy.size() / 2);
  r.result_text = std::move(text);
  return r;
}

}  // namespace

void add_map_query_operation(Backend& backend, OperationRegistry& registry) {
  Backend* b = &backend;
  registry.add({"map.query", OpKind::kInline,
                "height, gradient, safety margin for a batch of (x, y) points",
                [b](OpContext& c) { return map_query(*b, c); },
                std::vector<std::string>{"points", "foot_radius"},
                std::vector<std::string>{"points"}});
}

}  // namespace terrastride::service
