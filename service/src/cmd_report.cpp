// `terrastride report`: the offline foothold-safety report (one self-contained HTML page and a JSON
// file with every number it shows), for one terrain and its plans, or for a folder of scans (batch
// mode: one report per scan and an index page ranking them by safe fraction).
#include <algorithm>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>

#include "report/report.hpp"
#include "report/report_file.hpp"
#include "report/terrain_input.hpp"
#include "terrastride/perception/atomic_output.hpp"
#include "terrastride/service/cli.hpp"

namespace terrastride::service {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

struct ReportCommandOptions {
  std::vector<std::string> terrain;
  std::vector<std::string> plans;
  std::string batch;
  std::string out;
  std::string radii;
  double resolution = 0.02;
  std::string origin;
  std::string robot = "hyq";
  std::string title;
  bool json_output = false;
  bool simulate = false;
};

std::vector<double> parse_radii(const std::string& text) {
  std::vector<double> radii;
  if (text.empty()) return radii;
  const int n = static_cast<int>(std::count(text.begin(), text.end(), ',')) + 1;
  const Eigen::VectorXd v = parse_numbers(text, n, "--foot-radius");
  for (int i = 0; i < n; ++i) radii.push_back(v[i]);
  return radii;
}

bool is_scan_file(const fs::path& p) {
  std::string ext = p.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return std::tolower(c); });
  return ext == ".pcd" || ext == ".ply" || ext == ".xyz" || ext == ".npy";
}

void check_out_html(const std::string& out) {
  if (fs::path(out).extension() != ".html")
    throw CommandError("--out " + out +
                       ": the report is an .html file (report.json is written beside it)");
  const fs::path parent = fs::absolute(out).parent_path();
  if (!fs::is_directory(parent))
    throw CommandError("--out " + out + ": folder " + parent.string() + " does not exist");
  // Both files can be written (not a directory, socket, read-only folder...): checked before the
  // terrain is mapped, not after.
  try {
    perception::check_output_file(out);
    perception::check_output_file(fs::path(out).replace_extension(".json").string());
  } catch (const perception::InputError& e) {
    throw CommandError(std::string("--out: ") + e.what());
  }
}

// What `report --batch --out DIR` writes, for perception::AtomicOutputDir. Outputs of versions
// before the marker file are recognised by index.json and index.html plus exactly the reports
// index.json lists (NAME.html and the NAME.json beside it), so a folder that merely holds some
// .html/.json files is never taken for one.
perception::OutputDirKind batch_output_kind() {
  perception::OutputDirKind kind{
      "report --batch", {"index.json", "index.html"}, {"index.json", "index.html"}, {}};
  kind.legacy_listed = [](const std::string& dir) {
    std::vector<std::string> names;
    std::ifstream in(fs::path(dir) / "index.json");
    const json index = json::parse(in);
    for (const json& row : index.at("reports")) {
      const std::string html = row.at("html").get<std::string>();
      if (html.find('/') != std::string::npos || fs::path(html).extension() != ".html") continue;
      names.push_back(html);
      names.push_back(fs::path(html).replace_extension(".json").string());
    }
    return names;
  };
  return kind;
}

json summary_json(const json& report, const std::string& html, const std::string& json_path) {
  json plans = json::array();
  for (const json& p : report["plans"]) {
    json s{{"name", p["name"]},
           {"solver_status", p["solver"]["status"]},
           {"footholds", p["footholds"].size()}};
    for (const auto& [k, v] : p["checks"].items()) s[k] = v;
    const json& sim = p["simulation"];
    if (sim.contains("verdict"))
      s["simulation_verdict"] = sim["verdict"];
    else if (sim.contains("recorded"))
      s["simulation_verdict"] = sim["recorded"]["verdict"];
    plans.push_back(s);
  }
  return {{"html", html},
          {"json", json_path},
          {"ok", report["ok"]},
          {"problems", report["problems"]},
          {"safe_fraction", report["terrain"]["safe_fraction"]},
          {"observed_fraction", report["terrain"]["observed_fraction"]},
          {"cells", report["terrain"]["cells"]},
          {"plans", plans}};
}

void print_summary(const json& s, bool as_json) {
  if (as_json) {
    std::cout << s.dump() << "\n";
    return;
  }
  std::cout << "safe fraction " << s["safe_fraction"] << " of observed cells (" << s["cells"]
            << " cells)\n";
  for (const json& p : s["problems"])
    std::cout << "PROBLEM " << p["plan"].get<std::string>() << ": " << p["text"].get<std::string>()
              << "\n";
  std::cout << (s["ok"].get<bool>() ? "no problems found"
                                    : std::to_string(s["problems"].size()) + " problems found")
            << "\nreport: " << s["html"].get<std::string>()
            << "\ndata:   " << s["json"].get<std::string>() << "\n";
}

// One report: OUT.html and OUT.json for --terrain and its --plan files.
void run_single(const ReportCommandOptions& o, const report::TerrainInputOptions& topts,
                const report::ReportOptions& ropts) {
  check_out_html(o.out);
  const json rep = report::make_report_file(o.terrain, o.plans, topts, ropts, o.out);
  const std::string json_path = fs::path(o.out).replace_extension(".json").string();
  print_summary(summary_json(rep, o.out, json_path), o.json_output);
}

// Batch mode: one report per scan of the --batch folder, and the index ranking them.
void run_batch(const ReportCommandOptions& o, const report::TerrainInputOptions& topts,
               report::ReportOptions ropts) {
  if (!o.plans.empty()) throw CommandError("--plan cannot be combined with --batch");
  if (!fs::is_directory(o.batch)) throw CommandError("--batch " + o.batch + ": not a folder");
  // Before mapping every scan: refuse an --out folder holding anything but an earlier report
  // (e.g. --out equal to --batch, the scans themselves), and an unwritable one.
  try {
    perception::check_output_dir(o.out, batch_output_kind());
  } catch (const perception::InputError& e) {
    throw CommandError(std::string("--out: ") + e.what());
  }
  // One scan per name: files NAME.ext, NAME.1.ext, NAME.2.ext ... (one per sensor pose, as the
  // scan simulator writes them) are mapped together; map folders are scans of their own.
  std::map<std::string, std::vector<std::string>> groups;
  for (const auto& entry : fs::directory_iterator(o.batch)) {
    const fs::path p = entry.path();
    const std::string name = p.filename().string();
    if (entry.is_regular_file() && is_scan_file(p))
      groups[name.substr(0, name.find('.'))].push_back(p.string());
    else if (entry.is_directory() && report::is_terrain_dir(p.string()))
      groups[name].push_back(p.string());
  }
  std::vector<std::pair<std::string, std::vector<std::string>>> scans(groups.begin(), groups.end());
  for (auto& [name, files] : scans) std::sort(files.begin(), files.end());
  if (scans.empty())
    throw CommandError("--batch " + o.batch +
                       ": no scans (.pcd, .ply, .xyz, .npy) or terrain folders in it");
  perception::AtomicOutputDir out_dir(o.out, batch_output_kind());
  json rows = json::array();
  std::vector<std::string> failed;
  for (size_t i = 0; i < scans.size(); ++i) {
    const std::string& stem = scans[i].first;
    const std::vector<std::string>& files = scans[i].second;
    std::cerr << "[" << i + 1 << "/" << scans.size() << "] " << stem << "\n";
    const std::string html_name = stem + ".html";
    json files_json = json::array();
    for (const auto& f : files) files_json.push_back(f);
    json row_json{{"scan", stem}, {"files", files_json}, {"html", html_name}};
    try {
      ropts.title = "terrastride foothold-safety report: " + stem;
      const json rep = report::make_report_file(files, {}, topts, ropts,
                                                (fs::path(out_dir.path()) / html_name).string());
      const json& t = rep["terrain"];
      row_json["safe_fraction"] = t["safe_fraction"];
      row_json["observed_fraction"] = t["observed_fraction"];
      row_json["cells"] = t["cells"];
      row_json["height_min_m"] = t["height_min_m"];
      row_json["height_max_m"] = t["height_max_m"];
      row_json["problems"] = rep["problems"].size();
    } catch (const std::exception& e) {
      row_json["error"] = e.what();
      failed.push_back(stem + ": " + e.what());
    }
    rows.push_back(row_json);
  }
  // Rank: best safe fraction first; failed scans last.
  std::stable_sort(rows.begin(), rows.end(), [](const json& a, const json& b) {
    const double fa = a.contains("error") ? -1.0 : a["safe_fraction"].get<double>();
    const double fb = b.contains("error") ? -1.0 : b["safe_fraction"].get<double>();
    return fa > fb;
  });
  json index{{"source", o.batch},
             {"foot_radius_m", topts.foot_radius},
             {"generated_utc", report::utc_now()},
             {"reports", rows}};
  perception::write_file_atomically((fs::path(out_dir.path()) / "index.json").string(),
                                    index.dump(1) + "\n");
  perception::write_file_atomically((fs::path(out_dir.path()) / "index.html").string(),
                                    report::render_index_html(index));
  out_dir.commit();
  if (o.json_output) {
    std::cout << index.dump() << "\n";
  } else {
    for (size_t i = 0; i < rows.size(); ++i) {
      const json& r = rows[i];
      if (r.contains("error"))
        std::cout << "  -  " << r["scan"].get<std::string>() << ": failed\n";
      else
        std::cout << "  " << i + 1 << ". " << r["scan"].get<std::string>() << "  safe "
                  << r["safe_fraction"] << ", problems " << r["problems"] << "\n";
    }
    std::cout << "index: " << (fs::path(o.out) / "index.html").string() << "\n";
  }
  if (failed.size() == scans.size())
    throw CommandError("--batch " + o.batch + ": every scan failed; first: " + failed.front());
  if (!failed.empty()) {
    std::string msg = std::to_string(failed.size()) + " of " + std::to_string(scans.size()) +
                      " scans failed (the others are in " + o.out + "):";
    for (const auto& f : failed) msg += "\n  " + f;
    throw CommandError(msg);
  }
}

void run_report(const ReportCommandOptions& o) {
  if (o.terrain.empty() == o.batch.empty())
    throw CommandError("give either --terrain (one report) or --batch DIR (a folder of scans)");
  if (!(o.resolution >= 0.002 && o.resolution <= 1.0))
    throw CommandError("--resolution " + std::to_string(o.resolution) + ": outside [0.002, 1] m");
  report::TerrainInputOptions topts;
  topts.radii = parse_radii(o.radii);
  topts.resolution = o.resolution;
  topts.foot_radius = report::robot_foot_radius(o.robot);
  if (!o.origin.empty()) topts.origin = Eigen::Vector3d(parse_numbers(o.origin, 3, "--origin"));
  report::ReportOptions ropts;
  ropts.robot = o.robot;
  ropts.simulate = o.simulate;
  if (!o.title.empty()) ropts.title = o.title;
  // Fail early (before any mapping) when the page's assets are missing.
  (void)report::render_index_html(json{{"reports", json::array()}});

  if (o.batch.empty())
    run_single(o, topts, ropts);
  else
    run_batch(o, topts, ropts);
}

}  // namespace

void add_report_command(CLI::App& app) {
  auto o = std::make_shared<ReportCommandOptions>();
  CLI::App* cmd = app.add_subcommand(
      "report",
      "Offline foothold-safety report: one self-contained HTML page (no network needed) and a JSON "
      "file with every number it shows");
  cmd->add_option("--terrain", o->terrain,
                  "A folder written by `terrastride map`, point-cloud files (PCD, PLY, XYZ, NPY), "
                  "an OctoMap (.bt, .ot) or a scene name (flat, pallet_10, pallet_15, eur_pallet, stairs, gap)");
  cmd->add_option("--plan", o->plans, "plan.json files to show on the terrain (repeatable)");
  cmd->add_option("--batch", o->batch,
                  "A folder of scans (and/or map folders): one report each plus index.html ranking "
                  "them by safe fraction; --out is then the output folder");
  cmd->add_option("--out", o->out,
                  "report.html (report.json beside it), or the batch output folder")
      ->required();
  cmd->add_option("--foot-radius", o->radii,
                  "Foot radii for the safety masks, e.g. 0.02,0.05 (default: the map's, or "
                  "0.02,0.04,0.06; the robot's is always added)");
  cmd->add_option("--resolution", o->resolution, "Grid cell for scenes and clouds (m)")
      ->capture_default_str();
  cmd->add_option("--origin", o->origin, "Sensor origin X,Y,Z of the clouds (as map's --origin)");
  cmd->add_option("--robot", o->robot, "Robot for terrain-only reports (foot radius)")
      ->capture_default_str();
  cmd->add_option("--title", o->title, "Title of the page");
  cmd->add_flag("--json", o->json_output, "Print the summary as one JSON object");
  cmd->add_flag("--simulate", o->simulate,
                "Execute every --plan in MuJoCo on the terrain (a scene's exact boxes, a map's "
                "planning surface) and add the \"Simulated execution\" section: tracking error, "
                "torques against the limits, contact events, verdict");
  cmd->callback([o] { run_report(*o); });
}

}  // namespace terrastride::service
