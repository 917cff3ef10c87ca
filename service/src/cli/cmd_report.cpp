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
#include <sstream>

#include "batch/batch.hpp"
#include "pasteable.hpp"
#include "report/report.hpp"
#include "report/report_file.hpp"
#include "report/terrain_input.hpp"
#include "terrastride/perception/atomic_output.hpp"
#include "terrastride/perception/octomap_input.hpp"
#include "terrastride/service/cli.hpp"
#include "terrastride/terrain/scenes.hpp"

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
  std::string shard;
  bool resume = false;
  bool timestamp = false;
};

std::vector<double> parse_radii(const std::string& text) {
  std::vector<double> radii;
  if (text.empty()) return radii;
  const int n = static_cast<int>(std::count(text.begin(), text.end(), ',')) + 1;
  const Eigen::VectorXd v = parse_numbers(text, n, "--foot-radius");
  for (int i = 0; i < n; ++i) radii.push_back(v[i]);
  return radii;
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

// One line per cloud input of the terrain (terrain.json's inputs[k].pose and .up): where its pose
// came from and how its up direction was found, so a map levelled by a guess or left unchecked
// says so beside "no problems found".
json terrain_input_notes(const json& info) {
  json notes = json::array();
  if (!info.is_object() || !info.contains("inputs")) return notes;
  const auto fixed = [](const json& v, int digits) {
    std::ostringstream os;
    os.setf(std::ios::fixed);
    os.precision(digits);
    os << v.get<double>();
    return os.str();
  };
  for (const json& in : info["inputs"]) {
    if (!in.contains("up") || !in.contains("path")) continue;
    const json& up = in["up"];
    std::string text = in["path"].get<std::string>() + ": ";
    const std::string from = up.value("from", "");
    if (from == "pose") {
      text += "posed (" + in["pose"].value("source", "") + ")";
    } else if (!up.contains("found")) {
      text += "z taken as up, unchecked (--up z)";
    } else if (!up["found"].get<bool>()) {
      text += "up not checked: " + up.value("problem", "");
    } else {
      text += from + ": dominant plane tilted " + fixed(up["tilt_deg"], 1) + " deg, sensor " +
              fixed(up["sensor_height"], 2) + " m from it, " +
              fixed(json(100 * up["inlier_share"].get<double>()), 0) + " % of the points";
    }
    notes.push_back(text);
  }
  return notes;
}

// Where the page's map and 3-D views open, by the page's own rule (service/report/template.html,
// `view`): the plans' base paths and footholds plus 1 m, clipped to the map, when the map spans
// more than three times that; else the whole map. Said on the command line so that a large map's
// report can be judged without a browser.
json report_view(const json& report) {
  const json& t = report["terrain"];
  if (!t.contains("x") || !t.contains("y") || t["x"].empty() || t["y"].empty()) return json();
  const std::vector<double> whole{t["x"].front().get<double>(), t["x"].back().get<double>(),
                                  t["y"].front().get<double>(), t["y"].back().get<double>()};
  double lo[2] = {1e300, 1e300}, hi[2] = {-1e300, -1e300};
  const auto add = [&](const json& x, const json& y) {
    if (!x.is_number() || !y.is_number()) return;
    const double p[2] = {x.get<double>(), y.get<double>()};
    for (int k = 0; k < 2; ++k) lo[k] = std::min(lo[k], p[k]), hi[k] = std::max(hi[k], p[k]);
  };
  for (const json& p : report["plans"]) {
    for (size_t i = 0; i < p["base"]["x"].size(); ++i) add(p["base"]["x"][i], p["base"]["y"][i]);
    for (const json& f : p["footholds"]) add(f["position"][0], f["position"][1]);
  }
  if (!(lo[0] <= hi[0])) return {{"zoomed", false}, {"whole", whole}, {"plan", whole}};
  const double margin = 1.0;
  const std::vector<double> plan{
      std::max(whole[0], lo[0] - margin), std::min(whole[1], hi[0] + margin),
      std::max(whole[2], lo[1] - margin), std::min(whole[3], hi[1] + margin)};
  const double whole_span = std::max(whole[1] - whole[0], whole[3] - whole[2]);
  const double plan_span = std::max(plan[1] - plan[0], plan[3] - plan[2]);
  return {{"zoomed", whole_span > 3 * plan_span}, {"whole", whole}, {"plan", plan}};
}

std::string extent_text(const json& box) {
  std::ostringstream os;
  os.setf(std::ios::fixed);
  os.precision(2);
  os << "x " << box[0].get<double>() << ".." << box[1].get<double>() << " m, y "
     << box[2].get<double>() << ".." << box[3].get<double>() << " m";
  return os.str();
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
          {"terrain_inputs", terrain_input_notes(report["terrain"]["info"])},
          {"view", report_view(report)},
          {"plans", plans}};
}

void print_summary(const json& s, bool as_json) {
  if (as_json) {
    std::cout << s.dump() << "\n";
    return;
  }
  std::cout << "safe fraction " << s["safe_fraction"] << " of observed cells (" << s["cells"]
            << " cells)\n";
  for (const json& note : s["terrain_inputs"])
    std::cout << "terrain input " << note.get<std::string>() << "\n";
  for (const json& p : s["problems"])
    std::cout << "PROBLEM " << p["plan"].get<std::string>() << ": " << p["text"].get<std::string>()
              << "\n";
  const json& view = s["view"];
  if (view.is_object() && !s["plans"].empty()) {
    if (view["zoomed"].get<bool>())
      std::cout << "view: the map and 3-D views open on the plans' surroundings, "
                << extent_text(view["plan"]) << ", of a map " << extent_text(view["whole"])
                << " (the whole map is one button away)\n";
    else
      std::cout << "view: the whole map, " << extent_text(view["whole"])
                << " (the plans' surroundings span a third of it or more)\n";
  }
  std::cout << (s["ok"].get<bool>() ? "no problems found"
                                    : std::to_string(s["problems"].size()) + " problems found")
            << "\nreport: " << s["html"].get<std::string>()
            << "\ndata:   " << s["json"].get<std::string>() << "\n";
}

// The report's two files must not replace what it reads: `report --plan flat.json --out
// flat.html` would write its flat.json over the plan.
void refuse_overwriting_inputs(const std::string& out, const std::vector<std::string>& plans,
                               const std::vector<std::string>& terrain) {
  const std::string json_path = fs::path(out).replace_extension(".json").string();
  auto same = [](const std::string& a, const std::string& b) {
    std::error_code ec;
    return fs::exists(a, ec) && fs::exists(b, ec) && fs::equivalent(a, b, ec);
  };
  auto check = [&](const std::string& input, const std::string& flag) {
    for (const std::string& written : {out, json_path})
      if (same(written, input))
        throw CommandError("--out " + out + ": the report would write " + written + ", which is the " +
                           flag + " input; choose another --out name");
  };
  for (const auto& p : plans) check(p, "--plan");
  for (const auto& t : terrain) check(t, "--terrain");
}

// A cloud the report could not map may need map's pose flags, of which report takes only
// --origin (and a refusal names them all): the map command to paste, then the folder to report.
std::string cloud_flags_hint(const std::vector<std::string>& terrain, const std::string& error) {
  for (const std::string& input : terrain) {
    std::error_code ec;
    if (!fs::is_regular_file(input, ec) || perception::is_octomap_file(input)) continue;
    if (error.rfind(input + ":", 0) != 0) continue;  // the error is not about this cloud
    return "\n(if it needs map's pose flags: report takes only --origin; for --viewpoint, "
           "--sensor-pose, --poses, --sensor-frame or --up, map the cloud first, `" +
           map_command(input) + "` with the flag added, then report --terrain " +
           shell_word(map_folder_for(input)) + ")";
  }
  return "";
}

// One report: OUT.html and OUT.json for --terrain and its --plan files.
void run_single(const ReportCommandOptions& o, const report::TerrainInputOptions& topts,
                const report::ReportOptions& ropts) {
  check_out_html(o.out);
  refuse_overwriting_inputs(o.out, o.plans, o.terrain);
  json rep;
  try {
    rep = report::make_report_file(o.terrain, o.plans, topts, ropts, o.out);
  } catch (const CommandError& e) {
    throw CommandError(e.what() + cloud_flags_hint(o.terrain, e.what()), e.exit_code());
  }
  const std::string json_path = fs::path(o.out).replace_extension(".json").string();
  print_summary(summary_json(rep, o.out, json_path), o.json_output);
}

// Batch mode: this process's share of the scans, each report committed on its own; exits 0 when
// every scan of the share has a report, kExitBatchScansFailed when some failed (recorded in the
// index), 1 when the batch could not run.
void run_batch(const ReportCommandOptions& o, const report::TerrainInputOptions& topts,
               const report::ReportOptions& ropts) {
  if (!o.plans.empty()) throw CommandError("--plan cannot be combined with --batch");
  report::BatchOptions b;
  b.source = o.batch;
  b.out = o.out;
  b.shard = report::parse_batch_shard(o.shard);
  b.resume = o.resume;
  b.timestamp = o.timestamp;
  b.terrain = topts;
  b.report = ropts;
  b.progress = [&](size_t k, size_t n, const std::string& name, bool skipped) {
    std::cerr << "[" << k << "/" << n << "] " << name << (skipped ? " (reported: skipped)" : "")
              << "\n";
  };
  const report::BatchResult r = report::run_report_batch(b);
  const json& index = r.index;
  if (o.json_output) {
    json out{{"scans", r.scans},
             {"shard", std::to_string(b.shard.index) + "/" + std::to_string(b.shard.count)},
             {"assigned", r.assigned},
             {"skipped", r.skipped},
             {"reported", r.reported},
             {"failed", r.failures},
             {"index", index}};
    std::cout << out.dump() << "\n";
  } else {
    const json& rows = index["reports"];
    for (size_t i = 0; i < rows.size(); ++i) {
      const json& row = rows[i];
      if (row.contains("pending"))
        std::cout << "  -  " << row["scan"].get<std::string>() << ": not run yet\n";
      else if (row.contains("error"))
        std::cout << "  -  " << row["scan"].get<std::string>() << ": failed\n";
      else
        std::cout << "  " << i + 1 << ". " << row["scan"].get<std::string>() << "  safe "
                  << row["safe_fraction"] << ", problems " << row["problems"] << "\n";
    }
    std::cout << "shard " << b.shard.index << "/" << b.shard.count << ": " << r.assigned
              << " scans, " << r.reported << " reported, " << r.skipped << " skipped, "
              << r.failures.size() << " failed; the batch: " << index["finished"] << " of "
              << r.scans << " reported, " << index["failed"] << " failed, " << index["pending"]
              << " not run yet\nindex: " << (fs::path(o.out) / "index.html").string() << "\n";
  }
  if (!r.failures.empty()) {
    std::string msg = std::to_string(r.failures.size()) + " of " + std::to_string(r.assigned) +
                      " scans failed (recorded in " + (fs::path(o.out) / "index.json").string() +
                      "; the others are reported):";
    for (const auto& f : r.failures) msg += "\n  " + f;
    throw CommandError(msg, kExitBatchScansFailed);
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
                  "an OctoMap (.bt, .ot) or a scene name (" + terrain::scene_names_text() + ")");
  cmd->add_option("--plan", o->plans, "plan.json files to show on the terrain (repeatable)");
  cmd->add_option("--batch", o->batch,
                  "A folder of scans (and/or map folders), or a manifest file (one scan file or "
                  "map folder per line): one report each, OUT/NAME/NAME.html, committed scan by "
                  "scan, plus OUT/index.html ranking them by safe fraction; --out is then the "
                  "output folder. Exit codes: 0 every scan of this shard reported, 3 some scans "
                  "failed (each recorded in index.json; the others reported), 1 the batch could "
                  "not run (bad --batch, --out or settings), 2 usage");
  cmd->add_option("--shard", o->shard,
                  "Batch: run only scans k with k mod N == I (scans in name order): I/N, or N "
                  "with I from JOB_COMPLETION_INDEX (Kubernetes Indexed Job) or "
                  "SLURM_ARRAY_TASK_ID - SLURM_ARRAY_TASK_MIN (Slurm job array). Any number of "
                  "shards may write into one --out at once");
  cmd->add_flag("--resume", o->resume,
                "Batch: skip scans whose report is already in --out (e.g. after a kill or a "
                "retried job); failed scans are run again");
  cmd->add_flag("--timestamp", o->timestamp,
                "Batch: stamp generated_utc and timings into the reports and index (without it "
                "the outputs are byte-reproducible)");
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
