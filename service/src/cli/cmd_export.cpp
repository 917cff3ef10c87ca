// `terrastride export`: a terrain, a plan and its simulation as one MCAP file for Foxglove or
// Lichtblick (service/src/export/foxglove_export.hpp; docs/export.md).
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>

#include "export/foxglove_export.hpp"
#include "terrastride/service/cli.hpp"

namespace terrastride::service {

void add_export_command(CLI::App& app) {
  auto o = std::make_shared<foxglove::ExportOptions>();
  auto radii = std::make_shared<std::string>();
  auto as_json = std::make_shared<bool>(false);
  CLI::App* cmd = app.add_subcommand(
      "export",
      "A terrain, optionally a plan and its simulated execution, as one MCAP file that Foxglove "
      "and Lichtblick open and play, and a layout for them: the relief coloured by safety margin, "
      "height grid, occupied voxels, the input clouds, the robot's links on /tf frames, contact "
      "forces, joint and foot numbers to plot, the checks' and the simulation's findings as log "
      "messages (docs/export.md)");
  cmd->add_option("--terrain", o->terrain,
                  "A folder written by `terrastride map`, point-cloud files, an OctoMap (.bt, .ot) "
                  "or a scene name")
      ->required();
  cmd->add_option("--plan", o->plan, "plan.json made on this terrain");
  cmd->add_option("--sim", o->sim,
                  "The plan's simulation: `terrastride simulate PLAN --out sim.json`");
  cmd->add_option("--out", o->out, "The .mcap file (written atomically)")->required();
  cmd->add_option("--resolution", o->resolution, "Grid cell for scenes and clouds (m)")
      ->capture_default_str();
  cmd->add_option("--foot-radius", *radii, "Safety-margin layers, e.g. 0.02,0.05");
  cmd->add_option("--compression", o->compression, "Chunk compression: zstd or none")
      ->capture_default_str();
  cmd->add_option("--start-time", o->start_time,
                  "Unix time (s) of t = 0 (default: a bag-built map's first cloud stamp, else "
                  "2025-01-01T00:00:00Z)");
  cmd->add_option("--layout", o->layout,
                  "The Foxglove layout file to write (default: beside --out, NAME.layout.json)");
  cmd->add_option("--bag-frame", o->bag_frame,
                  "Draw the clouds of the bags a map folder was built from, placed in this fixed "
                  "frame (the `map --frame` it was built with)");
  cmd->add_option("--max-points", o->max_points, "Input-cloud points drawn at most")
      ->capture_default_str();
  cmd->add_flag("--json", *as_json, "Print the summary as one JSON object");
  cmd->callback([o, radii, as_json] {
    if (!radii->empty()) {
      const int n = static_cast<int>(std::count(radii->begin(), radii->end(), ',')) + 1;
      const Eigen::VectorXd v = parse_numbers(*radii, n, "--foot-radius");
      for (int i = 0; i < n; ++i) o->radii.push_back(v[i]);
    }
    const foxglove::ExportSummary s = foxglove::export_foxglove(*o);
    nlohmann::json topics = s.messages_per_topic;
    if (*as_json) {
      std::cout << nlohmann::json{{"out", o->out},
                                  {"bytes", s.bytes},
                                  {"messages", s.messages},
                                  {"chunks", s.chunks},
                                  {"topics", topics},
                                  {"voxels", s.voxels},
                                  {"footholds", s.footholds},
                                  {"shin_contacts", s.shin_contacts},
                                  {"duration_s", s.duration_s},
                                  {"voxel_messages", s.voxel_messages},
                                  {"relief_triangles", s.relief_triangles},
                                  {"relief_cells", s.relief_cells},
                                  {"grid_decimation", s.grid_decimation},
                                  {"points", s.points},
                                  {"points_in", s.points_in},
                                  {"logs", s.logs},
                                  {"largest_message", s.largest_message},
                                  {"largest_topic", s.largest_topic},
                                  {"epoch_s", s.epoch_s},
                                  {"layout", s.layout}}
                       .dump()
                << "\n";
      return;
    }
    for (const auto& [topic, n] : s.messages_per_topic)
      std::cout << "  " << topic << ": " << n << " messages\n";
    std::cout << s.messages << " messages in " << s.chunks << " chunks, " << s.bytes
              << " bytes: " << o->out << " (largest message " << s.largest_message << " bytes, "
              << s.largest_topic << "); layout " << s.layout << "\n";
  });
}

}  // namespace terrastride::service
