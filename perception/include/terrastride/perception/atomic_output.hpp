// All-or-nothing output that never destroys what the tool did not write: nothing half-written is
// ever visible under the final name, and an existing path is only replaced when that is safe.
#pragma once

#include <functional>
#include <string>
#include <vector>

#include "terrastride/perception/point_cloud.hpp"  // InputError, thrown by everything here

namespace terrastride::perception {

// ---------------------------------------------------------------------------------------------
// Single files.
//
// What an output file path is, after following symbolic links (each link is followed to its
// target, relative targets from the link's directory; the links themselves stay links):
//   kNew       nothing there (a dangling link writes its target): created atomically.
//   kRegular   a regular file: replaced atomically (temp file in the TARGET's directory, fsync,
//              rename); its permission bits are kept.
//   kStream    a character device or a FIFO (/dev/null, a terminal, a named pipe): written through,
//              never renamed over. Opening a FIFO waits for a reader, as a shell redirect does.
//   kDescriptor /dev/stdout, /dev/stderr, /dev/fd/N, /proc/self/fd/N: written to the process's
//              own descriptor N, whatever it is (pipe, terminal, or a file opened with > or >>),
//              sharing its offset, so `--out /dev/stdout > f` and `>> f` do what the shell says.
// Anything else (a directory, a socket, a block device, a link loop) is refused.
struct OutputFile {
  enum class Kind { kNew, kRegular, kStream, kDescriptor };
  std::string path;    // as given
  std::string target;  // after following links (== path when there are none)
  Kind kind = Kind::kNew;
  int fd = -1;  // kDescriptor only
};

// Classifies `path` as above without writing anything; throws InputError naming the path when it
// cannot be an output file.
OutputFile resolve_output_file(const std::string& path);

// resolve_output_file, then proves the file can be written without touching it: for kNew/kRegular
// a probe file is created (and removed) in the target's directory, so a missing or read-only
// directory is reported now; for the others the device or descriptor must be writable. Commands
// call this before long work so that a bad --out fails in milliseconds, not after the work.
OutputFile check_output_file(const std::string& path);

// Writes `bytes` to `path` as resolve_output_file describes. Throws InputError naming the path on
// failure (ENOSPC on /dev/full: "PATH: write failed: No space left on device"); a temporary file
// is removed on failure. A reader that closes a pipe early gives an error, not SIGPIPE.
void write_file_atomically(const std::string& path, const std::string& bytes);

// True when `path` names the same open file as descriptor `fd` (e.g. --out /dev/stdout, or the
// terminal or file that standard output is): the caller then keeps its own messages off that fd.
bool same_file_as_descriptor(const std::string& path, int fd);

// Temporaries are named `.NAME.tmp-PID-COUNTER-TICKS` beside their final NAME (all digits). A
// killed run leaves them behind: this removes, in `dir`, the temporaries of `name` whose PID is
// no longer a running process (kill(PID, 0) fails with ESRCH). Entries of live processes, of
// other names, or not matching the pattern exactly are never touched. Every writer here calls it
// before creating its own temporary; returns how many entries it removed. Caveat: a process in
// another PID namespace writing into the same directory looks dead from here.
int remove_stale_temporaries(const std::string& dir, const std::string& name);

// A fresh temporary path for the final file `target` (in its directory, after removing stale
// temporaries of the same name), for callers that rename several files into place together.
std::string temporary_path_for(const std::string& target);

// ---------------------------------------------------------------------------------------------
// Directories.
//
// Every directory AtomicOutputDir commits holds a marker file, kOutputMarker, listing the
// command and every entry the tool wrote (paths relative to the directory, one a line). An
// existing directory at the output path is replaced only when it is
//   1. empty, or
//   2. marked, and every entry in it (recursively) is one the marker lists with the same type
//      (file / directory; symbolic links never count as written), so files a user added to an
//      output since are never deleted; the command named in the marker may differ (all of its
//      content was written by terrastride), or
//   3. unmarked but recognisably the output of an older terrastride of this command: every
//      `legacy_required` entry is there and every entry matches `legacy_entries` (or the names
//      `legacy_listed` reads from the directory).
// Otherwise it is refused, naming the directory, the first entry that terrastride did not write,
// and what to do (an empty or new folder). An existing non-directory is always refused. A symbolic
// link to a directory is followed: the directory it points to is the output, the link stays.
inline constexpr const char* kOutputMarker = ".terrastride-output";

struct OutputDirKind {
  std::string command;  // written into the marker, e.g. "map"
  // Recognising outputs of older versions (no marker). Paths are relative and '/'-separated; a
  // trailing '/' means a directory, '*' matches any characters within one path component.
  std::vector<std::string> legacy_required;
  std::vector<std::string> legacy_entries;
  // Optional: more exact legacy entries read from the directory itself (e.g. the reports an index
  // file lists); throwing or returning nothing adds nothing.
  std::function<std::vector<std::string>(const std::string& dir)> legacy_listed;
};

// Checks, before any work, that `final_dir` may be written as `kind`'s output: it is missing,
// empty, or replaceable by the rules above, and the directory it goes into is writable (probed
// with a temporary directory; missing parents are fine when their nearest existing ancestor is
// writable, as AtomicOutputDir creates them). Throws InputError naming the directory otherwise.
void check_output_dir(const std::string& final_dir, const OutputDirKind& kind);

// A temp directory next to `final_dir` (same filesystem, so the rename is atomic); write files into
// path(), then commit() writes the marker and renames it to final_dir, replacing an existing
// directory there only by the rules above (checked in the constructor and again in commit(), which
// swaps the two atomically with renameat2(RENAME_EXCHANGE) where the filesystem has it). If
// commit() was not called, the destructor removes the temp directory and final_dir is untouched.
// Files written into path() with write_file_atomically are not fsynced one by one: commit() fsyncs
// every regular file under path() together (one journal commit) before the rename.
class AtomicOutputDir {
 public:
  AtomicOutputDir(const std::string& final_dir, OutputDirKind kind);
  ~AtomicOutputDir();
  AtomicOutputDir(const AtomicOutputDir&) = delete;
  AtomicOutputDir& operator=(const AtomicOutputDir&) = delete;

  const std::string& path() const { return temp_dir_; }  // where to write now
  const std::string& final_path() const { return final_dir_; }
  void commit();
  bool committed() const { return committed_; }

 private:
  OutputDirKind kind_;
  std::string final_dir_;  // after following links
  std::string temp_dir_;
  bool committed_ = false;
};

}  // namespace terrastride::perception
