// `report --batch`: one report per scan, each committed on its own, any number of processes over
// one output folder (batch.hpp describes the folder).
#include "batch/batch.hpp"

#include "terrastride/terrain/terrain_open.hpp"

#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>
#include <zlib.h>

#include <algorithm>
#include <cerrno>
#include <cstdlib>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <set>

#include "report/report_file.hpp"
#include "terrastride/perception/atomic_output.hpp"
#include "terrastride/perception/json_input.hpp"
#include "terrastride/service/cli.hpp"

namespace terrastride::service::report {

namespace fs = std::filesystem;
using nlohmann::json;

namespace {

constexpr const char* kBatchMarker = ".terrastride-batch";
constexpr const char* kSummaryName = "summary.json";

bool is_scan_file(const fs::path& p) {
  std::string ext = p.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return std::tolower(c); });
  return ext == ".pcd" || ext == ".ply" || ext == ".xyz" || ext == ".npy";
}

// NAME of NAME.ext and NAME.1.ext (the scan simulator's extra poses).
std::string scan_stem(const std::string& file_name) {
  return file_name.substr(0, file_name.find('.'));
}

std::string trim(const std::string& s) {
  const auto b = s.find_first_not_of(" \t\r");
  if (b == std::string::npos) return "";
  return s.substr(b, s.find_last_not_of(" \t\r") - b + 1);
}

// Adds `path` to `groups` (name → files, and the folder they come from).
void add_scan_path(std::map<std::string, BatchScan>& groups,
                   std::map<std::string, std::string>& folder_of, const fs::path& path,
                   bool is_dir, const std::string& where) {
  const std::string file_name = path.filename().string();
  const std::string name = is_dir ? file_name : scan_stem(file_name);
  if (name.empty())
    throw CommandError(where + ": " + path.string() + " has no name before its first '.'");
  const std::string folder = path.parent_path().lexically_normal().string();
  auto [it, fresh] = folder_of.emplace(name, folder);
  if (!fresh && it->second != folder)
    throw CommandError(where + ": two scans are named '" + name + "' (in " + it->second +
                       " and in " + folder + "); each scan's report is a folder named after it");
  BatchScan& scan = groups[name];
  scan.name = name;
  if (is_dir && !scan.files.empty())
    throw CommandError(where + ": '" + name + "' is both a map folder and scan files");
  for (const auto& f : scan.files)
    if (f == path.string()) throw CommandError(where + ": " + f + " is listed twice");
  scan.files.push_back(path.string());
}

json read_json_file(const fs::path& p) {
  std::ifstream in(p);
  if (!in) return nullptr;
  try {
    return perception::parse_json_input(in);
  } catch (const std::exception&) {
    return nullptr;
  }
}

// The settings every process writing into one output folder must share.
json batch_settings(const BatchOptions& o) {
  json radii = json::array();
  for (double r : o.terrain.radii) radii.push_back(r);
  json origin = nullptr;
  if (o.terrain.origin) origin = {o.terrain.origin->x(), o.terrain.origin->y(), o.terrain.origin->z()};
  return {{"source", o.source},
          {"robot", o.report.robot},
          {"foot_radius_m", o.terrain.foot_radius},
          {"radii_m", radii},
          {"resolution_m", o.terrain.resolution},
          {"origin", origin},
          {"timestamp", o.timestamp}};
}

std::string marker_text(const json& settings) {
  return json{{"format", "terrastride-batch/1"}, {"settings", settings}}.dump(1) + "\n";
}

[[noreturn]] void refuse_out(const std::string& out, const std::string& why) {
  throw CommandError("--out " + out + ": " + why);
}

// Checks that the marker of `dir` names the same settings.
void check_marker(const std::string& out, const fs::path& marker, const json& settings) {
  const json m = read_json_file(marker);
  if (!m.is_object() || m.value("format", "") != "terrastride-batch/1" ||
      !m.contains("settings"))
    refuse_out(out, marker.string() + " is not a batch marker terrastride wrote");
  const json& theirs = m["settings"];
  for (const auto& [key, value] : settings.items()) {
    const json other = theirs.contains(key) ? theirs[key] : json(nullptr);
    if (other != value)
      refuse_out(out, "this folder holds a batch made with " + key + " = " + other.dump() +
                          ", not " + value.dump() +
                          "; every process writing into one folder must use the same --batch "
                          "and settings (choose another --out for other settings)");
  }
}

// Creates OUT (atomically: a temporary folder holding the marker, renamed into place) or checks
// that the existing OUT is a batch output of the same settings (an empty folder is adopted).
void prepare_out(const std::string& out, const json& settings) {
  const std::string text = marker_text(settings);
  std::error_code ec;
  fs::path dir = fs::path(out);
  if (fs::is_symlink(fs::symlink_status(dir, ec))) {
    dir = fs::canonical(dir, ec);
    if (ec) refuse_out(out, "cannot resolve the link: " + ec.message());
  }
  const fs::file_status st = fs::status(dir, ec);
  {  // a killed run's half-made OUT (its temporary folder beside it)
    const fs::path abs = fs::absolute(dir);
    perception::remove_stale_temporaries(abs.parent_path().string(), abs.filename().string());
  }
  if (!fs::exists(st)) {
    const fs::path parent = dir.parent_path().empty() ? fs::path(".") : dir.parent_path();
    fs::create_directories(parent, ec);
    if (ec) refuse_out(out, "cannot create its parent folder: " + ec.message());
    const std::string temp = perception::temporary_path_for(fs::absolute(dir).string());
    if (::mkdir(temp.c_str(), 0755) != 0)
      refuse_out(out, std::string("cannot create it: ") + std::strerror(errno));
    try {
      perception::write_file_atomically((fs::path(temp) / kBatchMarker).string(), text);
    } catch (const std::exception& e) {
      fs::remove_all(temp, ec);
      refuse_out(out, e.what());
    }
    if (::rename(temp.c_str(), fs::absolute(dir).c_str()) != 0) {
      const int err = errno;
      fs::remove_all(temp, ec);
      // Another process (a shard started at the same moment) created it first: join it below.
      if (err != EEXIST && err != ENOTEMPTY)
        refuse_out(out, std::string("cannot create it: ") + std::strerror(err));
    }
  } else if (!fs::is_directory(st)) {
    refuse_out(out, "exists and is not a folder");
  }
  const fs::path marker = dir / kBatchMarker;
  if (!fs::exists(fs::symlink_status(marker, ec))) {
    // An existing folder without the marker: adopted only when empty (the marker is linked into
    // place, so of two processes adopting it at once exactly one writes it).
    for (const auto& e : fs::directory_iterator(dir, ec)) {
      const std::string name = e.path().filename().string();
      if (name.rfind("." + std::string(kBatchMarker), 0) == 0) continue;  // a racing temporary
      refuse_out(out, "refusing to write into this existing folder: it holds '" + name +
                          "', which terrastride did not write (a batch output folder is made by "
                          "terrastride); choose an empty or new folder");
    }
    if (ec) refuse_out(out, "cannot list it: " + ec.message());
    const std::string temp = perception::temporary_path_for(marker.string());
    try {
      perception::write_file_atomically(temp, text);
    } catch (const std::exception& e) {
      refuse_out(out, e.what());
    }
    const int linked = ::link(temp.c_str(), marker.c_str());
    const int err = errno;
    ::unlink(temp.c_str());
    if (linked != 0 && err != EEXIST)
      refuse_out(out, std::string("cannot write ") + marker.string() + ": " + std::strerror(err));
  }
  check_marker(out, marker, settings);
  if (::access(dir.c_str(), W_OK) != 0)
    refuse_out(out, std::string("cannot write in it: ") + std::strerror(errno));
}

// Temporaries of killed runs in OUT (any name), in one pass over the folder: those of live
// processes (other shards at work) are kept by remove_stale_temporaries.
void remove_stale_temporaries_in(const fs::path& dir) {
  std::set<std::string> names;
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(dir, ec)) {
    const std::string n = e.path().filename().string();
    const auto tmp = n.rfind(".tmp-");
    if (n.size() > 1 && n[0] == '.' && tmp != std::string::npos && tmp > 1)
      names.insert(n.substr(1, tmp - 1));
  }
  for (const auto& n : names) perception::remove_stale_temporaries(dir.string(), n);
}

perception::OutputDirKind scan_dir_kind() {
  return {"report --batch (one scan)", {}, {}, {}};
}

// The committed summary of scan `name`, or null when it has none (not run, or killed before its
// folder was renamed into place).
json read_summary(const fs::path& out, const std::string& name) {
  const fs::path dir = out / name;
  std::error_code ec;
  if (!fs::is_regular_file(dir / perception::kOutputMarker, ec)) return nullptr;
  json s = read_json_file(dir / kSummaryName);
  return s.is_object() ? s : json(nullptr);
}

// A report file's digest: its size and CRC-32. Recorded in the scan's summary when it is
// committed, so that a resumed batch notices a report truncated or altered since (a full disk, a
// copy cut short, a hand edit) instead of trusting any file that exists.
json file_digest(const fs::path& file) {
  std::ifstream in(file, std::ios::binary);
  if (!in) return nullptr;
  uLong crc = crc32(0L, Z_NULL, 0);
  uint64_t bytes = 0;
  std::vector<char> buffer(1 << 16);
  while (in) {
    in.read(buffer.data(), static_cast<std::streamsize>(buffer.size()));
    const std::streamsize n = in.gcount();
    if (n <= 0) break;
    crc = crc32(crc, reinterpret_cast<const Bytef*>(buffer.data()), static_cast<uInt>(n));
    bytes += static_cast<uint64_t>(n);
  }
  if (in.bad()) return nullptr;
  char hex[9];
  std::snprintf(hex, sizeof hex, "%08lx", static_cast<unsigned long>(crc));
  return {{"bytes", bytes}, {"crc32", hex}};
}

std::vector<std::string> report_file_names(const std::string& name) {
  return {name + ".html", name + ".json"};
}

// Why scan `name`'s committed report cannot be trusted, or "" when every file matches the digest
// recorded at its commit.
std::string report_damage(const fs::path& out, const std::string& name, const json& summary) {
  const json digests = summary.value("digests", json(nullptr));
  if (!digests.is_object()) return "its summary records no file digests";
  for (const std::string& file : report_file_names(name)) {
    const json now = file_digest(out / name / file);
    if (now.is_null()) return file + " is missing";
    const json recorded = digests.value(file, json(nullptr));
    if (now != recorded)
      return file + " is " + now["bytes"].dump() + " bytes with CRC-32 " +
             now["crc32"].get<std::string>() + ", committed as " +
             (recorded.is_object() ? recorded.value("bytes", json(nullptr)).dump() + " bytes with "
                                     "CRC-32 " + recorded.value("crc32", std::string("?"))
                                   : std::string("nothing"));
  }
  return "";
}

// On --resume: true when scan `name` has a committed report whose files match their digests.
// A committed report found damaged is said so on stderr and reported again.
bool is_reported(const fs::path& out, const std::string& name) {
  const fs::path dir = out / name;
  std::error_code ec;
  if (!fs::is_regular_file(dir / perception::kOutputMarker, ec)) return false;
  const json s = read_summary(out, name);
  if (s.is_null()) {
    std::cerr << "report --batch --resume: " << name << ": its committed summary "
              << (dir / kSummaryName).string() << " is unreadable: reporting it again\n";
    return false;
  }
  if (s.contains("error")) return false;
  const std::string damage = report_damage(out, name, s);
  if (damage.empty()) return true;
  std::cerr << "report --batch --resume: " << name << ": its committed report is damaged ("
            << damage << "): reporting it again\n";
  return false;
}

json files_json(const BatchScan& scan) {
  json files = json::array();
  for (const auto& f : scan.files) files.push_back(f);
  return files;
}

// Maps and reports one scan into OUT/NAME (renamed into place whole). Returns the error message,
// "" when reported.
std::string report_one_scan(const fs::path& out, const BatchScan& scan, const BatchOptions& o) {
  json row{{"scan", scan.name}, {"files", files_json(scan)},
           {"html", scan.name + "/" + scan.name + ".html"}};
  std::string error;
  try {
    perception::AtomicOutputDir dir((out / scan.name).string(), scan_dir_kind());
    const fs::path html = fs::path(dir.path()) / (scan.name + ".html");
    try {
      ReportOptions ropts = o.report;
      ropts.title = "terrastride foothold-safety report: " + scan.name;
      ropts.clock_fields = o.timestamp;
      const json rep = make_report_file(scan.files, {}, o.terrain, ropts, html.string());
      const json& t = rep["terrain"];
      row["safe_fraction"] = t["safe_fraction"];
      row["observed_fraction"] = t["observed_fraction"];
      row["cells"] = t["cells"];
      row["height_min_m"] = t["height_min_m"];
      row["height_max_m"] = t["height_max_m"];
      row["problems"] = rep["problems"].size();
    } catch (const std::exception& e) {
      error = e.what();
      row["error"] = error;
      row.erase("html");
      std::error_code ec;  // a report half-made (JSON written, page not) is not kept
      fs::remove(html, ec);
      fs::remove(fs::path(html).replace_extension(".json"), ec);
    }
    if (error.empty()) {
      json digests = json::object();
      for (const std::string& file : report_file_names(scan.name))
        digests[file] = file_digest(fs::path(dir.path()) / file);
      row["digests"] = digests;
    }
    perception::write_file_atomically((fs::path(dir.path()) / kSummaryName).string(),
                                      row.dump(1) + "\n");
    dir.commit();
  } catch (const std::exception& e) {
    // The scan's folder itself could not be written: the index shows it as not run.
    return error.empty() ? std::string("cannot write its report: ") + e.what()
                         : error + " (and its summary could not be written: " + e.what() + ")";
  }
  return error;
}

double rank_key(const json& row) {
  if (row.contains("pending")) return -3.0;
  if (row.contains("error")) return -2.0;
  const json& f = row["safe_fraction"];
  return f.is_number() ? f.get<double>() : -1.0;  // no safety layer for the robot's foot
}

// Locks the batch marker (flock: released when the descriptor closes, also on a kill).
class MarkerLock {
 public:
  explicit MarkerLock(const fs::path& marker) {
    fd_ = ::open(marker.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd_ < 0)
      throw CommandError(marker.string() + ": cannot open to lock: " + std::strerror(errno));
    while (::flock(fd_, LOCK_EX) != 0) {
      if (errno != EINTR) {
        const int err = errno;
        ::close(fd_);
        throw CommandError(marker.string() + ": cannot lock: " + std::strerror(err));
      }
    }
  }
  ~MarkerLock() { ::close(fd_); }
  MarkerLock(const MarkerLock&) = delete;
  MarkerLock& operator=(const MarkerLock&) = delete;

 private:
  int fd_ = -1;
};

// Rebuilds index.json and index.html from the summaries in OUT, under the marker's lock, so that
// the last process to finish writes an index that sees every scan.
json rebuild_index(const fs::path& out, const std::vector<BatchScan>& scans,
                   const BatchOptions& o) {
  MarkerLock lock(out / kBatchMarker);
  json rows = json::array();
  size_t finished = 0, failed = 0, pending = 0;
  for (const BatchScan& scan : scans) {
    json row = read_summary(out, scan.name);
    if (row.is_object()) row.erase("digests");  // for resuming, not for the index's readers
    if (row.is_null()) {
      row = {{"scan", scan.name}, {"files", files_json(scan)}, {"pending", true}};
      ++pending;
    } else if (row.contains("error")) {
      ++failed;
    } else {
      ++finished;
    }
    rows.push_back(std::move(row));
  }
  // Best safe fraction first, then failed scans, then those not run yet; ties in name order.
  std::stable_sort(rows.begin(), rows.end(),
                   [](const json& a, const json& b) { return rank_key(a) > rank_key(b); });
  json index{{"format", "terrastride-batch-index/1"},
             {"source", o.source},
             {"foot_radius_m", o.terrain.foot_radius},
             {"scans", scans.size()},
             {"finished", finished},
             {"failed", failed},
             {"pending", pending},
             {"complete", pending == 0},
             {"reports", rows}};
  if (o.timestamp) index["generated_utc"] = utc_now();
  perception::write_file_atomically((out / "index.json").string(), index.dump(1) + "\n");
  perception::write_file_atomically((out / "index.html").string(), render_index_html(index));
  return index;
}

int parse_count(const std::string& text, const std::string& what) {
  if (text.empty() || text.size() > 9 ||
      !std::all_of(text.begin(), text.end(), [](unsigned char c) { return std::isdigit(c); }))
    throw CommandError(what + ": '" + text + "' is not a whole number");
  return std::stoi(text);
}

}  // namespace

std::vector<BatchScan> list_batch_scans(const std::string& source) {
  std::map<std::string, BatchScan> groups;
  std::map<std::string, std::string> folder_of;
  std::error_code ec;
  const std::string where = "--batch " + source;
  if (fs::is_directory(source, ec)) {
    std::vector<fs::directory_entry> entries;
    for (const auto& e : fs::directory_iterator(source, ec)) entries.push_back(e);
    if (ec) throw CommandError(where + ": cannot list it: " + ec.message());
    for (const auto& e : entries) {
      const fs::path p = e.path();
      if (p.filename().string().rfind('.', 0) == 0) continue;  // hidden (and temporaries)
      if (e.is_regular_file(ec) && is_scan_file(p))
        add_scan_path(groups, folder_of, p, false, where);
      else if (e.is_directory(ec) && terrain::is_terrain_folder(p.string()))
        add_scan_path(groups, folder_of, p, true, where);
    }
    if (groups.empty())
      throw CommandError(where + ": no scans (.pcd, .ply, .xyz, .npy) or terrain folders in it");
  } else if (fs::is_regular_file(source, ec)) {
    std::ifstream in(source);
    if (!in) throw CommandError(where + ": cannot read the manifest");
    const fs::path base = fs::path(source).parent_path();
    std::string line;
    for (int number = 1; std::getline(in, line); ++number) {
      line = trim(line);
      if (line.empty() || line[0] == '#') continue;
      const std::string at = where + " line " + std::to_string(number);
      const fs::path p = fs::path(line).is_absolute() || base.empty() ? fs::path(line)
                                                                      : base / line;
      if (fs::is_directory(p, ec)) {
        if (!terrain::is_terrain_folder(p.string()))
          throw CommandError(at + ": " + p.string() +
                             " is a folder but not one `terrastride map` wrote (no terrain.json)");
        add_scan_path(groups, folder_of, p, true, at);
      } else if (fs::is_regular_file(p, ec)) {
        if (!is_scan_file(p))
          throw CommandError(at + ": " + p.string() +
                             " is not a scan file (.pcd, .ply, .xyz, .npy) or a map folder");
        add_scan_path(groups, folder_of, p, false, at);
      } else {
        throw CommandError(at + ": " + p.string() + " does not exist");
      }
    }
    if (groups.empty()) throw CommandError(where + ": the manifest lists no scans");
  } else {
    throw CommandError(where + ": not a folder of scans or a manifest file");
  }
  std::vector<BatchScan> scans;
  for (auto& [name, scan] : groups) {
    std::sort(scan.files.begin(), scan.files.end());
    scans.push_back(std::move(scan));
  }
  return scans;
}

BatchShard parse_batch_shard(const std::string& text) {
  BatchShard shard;
  if (text.empty()) return shard;
  const auto slash = text.find('/');
  if (slash != std::string::npos) {
    shard.index = parse_count(text.substr(0, slash), "--shard " + text + " (index)");
    shard.count = parse_count(text.substr(slash + 1), "--shard " + text + " (count)");
  } else {
    shard.count = parse_count(text, "--shard " + text + " (count)");
    const char* k8s = std::getenv("JOB_COMPLETION_INDEX");
    const char* slurm = std::getenv("SLURM_ARRAY_TASK_ID");
    if (k8s && *k8s) {
      shard.index = parse_count(k8s, "--shard " + text + ": JOB_COMPLETION_INDEX");
    } else if (slurm && *slurm) {
      shard.index = parse_count(slurm, "--shard " + text + ": SLURM_ARRAY_TASK_ID");
      const char* min = std::getenv("SLURM_ARRAY_TASK_MIN");
      if (min && *min) {
        const int first = parse_count(min, "--shard " + text + ": SLURM_ARRAY_TASK_MIN");
        if (shard.index < first)
          throw CommandError("--shard " + text + ": SLURM_ARRAY_TASK_ID " + slurm +
                             " is below SLURM_ARRAY_TASK_MIN " + min);
        shard.index -= first;
      }
    } else {
      throw CommandError("--shard " + text +
                         ": a count alone takes the index from JOB_COMPLETION_INDEX (Kubernetes "
                         "Indexed Job) or SLURM_ARRAY_TASK_ID (Slurm job array), and neither is "
                         "set; give --shard I/N");
    }
  }
  if (shard.count < 1) throw CommandError("--shard " + text + ": the count must be at least 1");
  if (shard.index >= shard.count)
    throw CommandError("--shard " + text + ": index " + std::to_string(shard.index) +
                       " is not below the count " + std::to_string(shard.count) +
                       " (indices run from 0)");
  return shard;
}

BatchResult run_report_batch(const BatchOptions& o) {
  const std::vector<BatchScan> scans = list_batch_scans(o.source);
  prepare_out(o.out, batch_settings(o));
  fs::path out = fs::path(o.out);
  std::error_code ec;
  if (fs::is_symlink(fs::symlink_status(out, ec))) out = fs::canonical(out);
  remove_stale_temporaries_in(out);

  BatchResult result;
  result.scans = scans.size();
  std::vector<const BatchScan*> mine;
  for (size_t k = 0; k < scans.size(); ++k)
    if (static_cast<int>(k % static_cast<size_t>(o.shard.count)) == o.shard.index)
      mine.push_back(&scans[k]);
  result.assigned = mine.size();
  for (size_t k = 0; k < mine.size(); ++k) {
    const BatchScan& scan = *mine[k];
    const bool skip = o.resume && is_reported(out, scan.name);
    if (o.progress) o.progress(k + 1, mine.size(), scan.name, skip);
    if (skip) {
      ++result.skipped;
      continue;
    }
    const std::string error = report_one_scan(out, scan, o);
    if (error.empty())
      ++result.reported;
    else
      result.failures.push_back(scan.name + ": " + error);
  }
  result.index = rebuild_index(out, scans, o);
  return result;
}

}  // namespace terrastride::service::report
