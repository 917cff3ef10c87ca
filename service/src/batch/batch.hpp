// Foothold-safety reports over an archive of scans (`terrastride report --batch`), built to run
// as many processes at once (a Kubernetes Indexed Job, a Slurm job array) over one output folder
// and to survive being killed: docs/design.md §9.3.
//
// The output folder OUT holds
//   .terrastride-batch      the settings every process must share (JSON; also the index lock)
//   NAME/                   one folder per scan, renamed into place whole (AtomicOutputDir):
//     summary.json          the scan's row of the index (figures, or the error that stopped it)
//     NAME.html, NAME.json  the scan's report (absent when the scan failed)
//   index.json, index.html  every scan of the input ranked by safe fraction, rebuilt from the
//                           summaries that exist each time a process finishes its share
// Without a time stamp (the default) every file is a function of the inputs and settings alone,
// so a batch killed and resumed, or split over shards, ends byte-identical to one uninterrupted run.
#pragma once

#include <functional>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "report/report.hpp"
#include "report/terrain_input.hpp"

namespace terrastride::service::report {

// One scan of a batch: its name (the files' common stem, or the map folder's name) and its files
// (NAME.ext, NAME.1.ext, ... one per sensor pose, mapped together; or one map folder).
struct BatchScan {
  std::string name;
  std::vector<std::string> files;
};

// The scans of `source`: a folder (scan files .pcd .ply .xyz .npy grouped by stem, and map
// folders; hidden entries skipped) or a manifest file (one scan file or map folder per line,
// relative to the manifest's folder; blank lines and lines starting with '#' ignored). Sorted by
// name. Throws CommandError naming `source` (and the line) when it cannot be read, holds no scan,
// or two entries of different folders share a name.
std::vector<BatchScan> list_batch_scans(const std::string& source);

// Which part of the work this process does: scan k (in name order) belongs to shard k mod count.
struct BatchShard {
  int index = 0;
  int count = 1;
};

// Parses --shard: "I/N" (0 <= I < N), or "N" with I taken from the environment
// (JOB_COMPLETION_INDEX of a Kubernetes Indexed Job, else SLURM_ARRAY_TASK_ID minus
// SLURM_ARRAY_TASK_MIN of a Slurm job array, so arrays numbered from 1 work too); "" is the whole
// batch (0/1), whatever the environment says. Throws CommandError naming --shard.
BatchShard parse_batch_shard(const std::string& text);

struct BatchOptions {
  std::string source;  // --batch: folder or manifest
  std::string out;     // the output folder
  BatchShard shard;
  bool resume = false;      // skip scans whose report is already in OUT
  bool timestamp = false;   // stamp generated_utc and timings (outputs then differ run to run)
  TerrainInputOptions terrain;
  ReportOptions report;
  // Called before each scan of this shard is mapped ("[3/20] NAME" lines on stderr in the CLI).
  std::function<void(size_t position, size_t total, const std::string& name, bool skipped)>
      progress;
};

struct BatchResult {
  size_t scans = 0;       // in the whole batch
  size_t assigned = 0;    // to this shard
  size_t skipped = 0;     // of those, already reported (--resume)
  size_t reported = 0;    // of those, reported by this run
  std::vector<std::string> failures;  // "NAME: message" of this run's failed scans
  nlohmann::json index;               // the index as this process last wrote it
};

// Runs this process's share of the batch. Throws CommandError (nothing attempted) when the batch
// cannot run: unreadable source, OUT not an earlier batch output of the same settings, OUT not
// writable. A scan that fails is recorded (its summary holds the error) and the run goes on.
BatchResult run_report_batch(const BatchOptions& options);

}  // namespace terrastride::service::report
