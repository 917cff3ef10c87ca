// Atomic file and directory output: write under a temporary name on the same filesystem, then
// rename, so readers (and a crash) only ever see the old or the complete new content; and never
// rename over, or delete, anything the tool did not write (see atomic_output.hpp for the rules).
#include "terrastride/perception/atomic_output.hpp"

#include <fcntl.h>
#include <fnmatch.h>
#include <signal.h>
#include <stdio.h>  // renameat2
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <climits>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <set>
#include <sstream>
#include <system_error>
#include <thread>
#include <utility>

#include "terrastride/perception/point_cloud.hpp"

namespace fs = std::filesystem;

namespace terrastride::perception {
namespace {

constexpr int kMaxSymlinkHops = 40;  // as the kernel's ELOOP limit
constexpr const char* kMarkerHeader = "terrastride output";

// Unique per process and call: pid + counter + clock, so parallel writers in one directory never
// collide (O_EXCL / mkdir catch the rest). remove_stale_temporaries() parses exactly this form.
std::string unique_suffix() {
  static std::atomic<unsigned long> counter{0};
  const auto ticks = std::chrono::steady_clock::now().time_since_epoch().count();
  return ".tmp-" + std::to_string(::getpid()) + "-" + std::to_string(counter++) + "-" +
         std::to_string(static_cast<unsigned long long>(ticks) % 1000000007ULL);
}

std::string errno_text(int err = errno) {
  return std::strerror(err);
}

fs::path parent_or_dot(const fs::path& p) {
  fs::path parent = p.parent_path();
  return parent.empty() ? fs::path(".") : parent;
}

bool all_digits(const std::string& s) {
  return !s.empty() && std::all_of(s.begin(), s.end(), [](char c) { return c >= '0' && c <= '9'; });
}

// `entry` == "." + name + ".tmp-PID-COUNTER-TICKS" with three digit runs: the PID, else -1.
long temporary_pid(const std::string& entry, const std::string& name) {
  const std::string prefix = "." + name + ".tmp-";
  if (entry.size() <= prefix.size() || entry.compare(0, prefix.size(), prefix) != 0) return -1;
  std::vector<std::string> parts;
  std::stringstream rest(entry.substr(prefix.size()));
  for (std::string part; std::getline(rest, part, '-');) parts.push_back(part);
  if (parts.size() != 3 || entry.back() == '-') return -1;
  for (const auto& p : parts)
    if (!all_digits(p)) return -1;
  if (parts[0].size() > 9) return -1;  // beyond any pid_t
  const long pid = std::stol(parts[0]);
  return pid > 0 ? pid : -1;
}

bool process_is_gone(long pid) {
  // EPERM means it exists (another user's): only ESRCH proves it is gone.
  return ::kill(static_cast<pid_t>(pid), 0) != 0 && errno == ESRCH;
}

// /dev/stdout, /dev/stderr, /dev/fd/N, /proc/self/fd/N, /proc/<our pid>/fd/N: N, else -1.
int descriptor_of(const std::string& path) {
  if (path == "/dev/stdout") return STDOUT_FILENO;
  if (path == "/dev/stderr") return STDERR_FILENO;
  for (const std::string& prefix : {std::string("/dev/fd/"), std::string("/proc/self/fd/"),
                                    "/proc/" + std::to_string(::getpid()) + "/fd/"}) {
    if (path.size() > prefix.size() && path.compare(0, prefix.size(), prefix) == 0) {
      const std::string n = path.substr(prefix.size());
      if (all_digits(n) && n.size() < 9) return std::stoi(n);
    }
  }
  return -1;
}

// Follows one symbolic link: its target, relative ones taken from the link's directory.
std::string follow_link(const std::string& link, const std::string& shown) {
  std::error_code ec;
  const fs::path to = fs::read_symlink(link, ec);
  if (ec) throw InputError(shown + ": cannot read the symbolic link " + link + ": " + ec.message());
  return (to.is_absolute() ? to : parent_or_dot(link) / to).string();
}

std::string shown_name(const OutputFile& f) {
  return f.target == f.path ? f.path : f.path + " (-> " + f.target + ")";
}

// Writes everything; a closed pipe gives EPIPE (SIGPIPE is blocked for the call and a SIGPIPE it
// raised is consumed), so the caller reports the path instead of dying silently. "" on success.
std::string write_all(int fd, const std::string& bytes) {
  sigset_t pipe_set, old_mask, pending;
  sigemptyset(&pipe_set);
  sigaddset(&pipe_set, SIGPIPE);
  const bool masked = ::pthread_sigmask(SIG_BLOCK, &pipe_set, &old_mask) == 0;
  const bool was_pending = sigpending(&pending) == 0 && sigismember(&pending, SIGPIPE) == 1;
  const char* data = bytes.data();
  size_t left = bytes.size();
  std::string problem;
  while (left > 0) {
    const ssize_t n = ::write(fd, data, left);
    if (n < 0) {
      const int err = errno;
      if (err == EINTR) continue;
      if (err == EPIPE && masked && !was_pending) {
        const timespec zero{0, 0};
        ::sigtimedwait(&pipe_set, nullptr, &zero);
      }
      problem = "write failed: " + errno_text(err);
      break;
    }
    if (n == 0) {
      problem = "write failed: nothing was written";
      break;
    }
    data += n;
    left -= static_cast<size_t>(n);
  }
  if (masked) ::pthread_sigmask(SIG_SETMASK, &old_mask, nullptr);
  return problem;
}

// The temporary directories of the AtomicOutputDirs alive in this process. A file written into one
// of them is not fsynced on its own: the directory's commit() fsyncs every file in it before the
// rename that publishes it, which is the same guarantee (no published name over unwritten data)
// for one journal commit instead of one per file (`terrastride map` of the 1 M-point scan writes 17
// files: `strace -f -T -e trace=fsync` showed 0.20 s of fsyncs one after another under load, 6 ms
// together; design.md §9).
std::mutex& pending_dirs_mutex() {
  static std::mutex m;
  return m;
}
std::vector<std::string>& pending_dirs() {
  static std::vector<std::string> dirs;
  return dirs;
}

void stop_deferring_syncs(const std::string& dir) {
  std::lock_guard<std::mutex> lock(pending_dirs_mutex());
  auto& dirs = pending_dirs();
  const auto it = std::find(dirs.begin(), dirs.end(), dir);
  if (it != dirs.end()) dirs.erase(it);
}

bool inside_pending_dir(const std::string& target) {
  std::lock_guard<std::mutex> lock(pending_dirs_mutex());
  for (const std::string& d : pending_dirs()) {
    if (target.size() > d.size() && target.compare(0, d.size(), d) == 0 && target[d.size()] == '/')
      return true;
  }
  return false;
}

// fsyncs every regular file under `dir` (symbolic links are not followed): starts the write-back
// of all of them, then waits for them from several threads at once. One fsync after another waits
// for one journal commit each on ext4 (10-20 ms each on this machine under load, 17 files for a
// map); concurrent ones share commits. Returns "" or the first problem.
std::string sync_tree(const std::string& dir) {
  std::vector<int> fds;
  std::string problem;
  std::error_code ec;
  for (fs::recursive_directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    if (!it->is_regular_file(ec) || it->is_symlink(ec)) continue;
    const int fd = ::open(it->path().c_str(), O_RDONLY | O_CLOEXEC | O_NOFOLLOW);
    if (fd < 0) {
      problem = it->path().string() + ": cannot open to sync: " + errno_text();
      break;
    }
    ::sync_file_range(fd, 0, 0, SYNC_FILE_RANGE_WRITE);  // a hint: errors surface in fsync
    fds.push_back(fd);
  }
  if (ec && problem.empty()) problem = dir + ": cannot list to sync: " + ec.message();
  std::vector<int> errors(fds.size(), 0);
  std::atomic<size_t> next{0};
  const auto work = [&] {
    for (size_t k; (k = next.fetch_add(1)) < fds.size();)
      if (::fsync(fds[k]) != 0) errors[k] = errno;
  };
  std::vector<std::thread> threads;
  for (size_t t = 1; t < std::min<size_t>(fds.size(), 16); ++t) {
    try {
      threads.emplace_back(work);
    } catch (const std::system_error&) {
      break;  // no more threads: the ones running (and this one) do the rest
    }
  }
  work();
  for (auto& th : threads) th.join();
  for (size_t k = 0; k < fds.size(); ++k) {
    if (errors[k] != 0 && problem.empty()) problem = "fsync failed: " + errno_text(errors[k]);
    ::close(fds[k]);
  }
  return problem;
}

// ----- directories ---------------------------------------------------------------------------

// The output directory after normalising "out/", "." and following symbolic links.
struct ResolvedDir {
  fs::path path;
  bool exists = false;
};

ResolvedDir resolve_output_dir(const std::string& given) {
  if (given.empty()) throw InputError("output directory path is empty");
  fs::path p(given);
  // "out/" has an empty filename; strip the trailing separator so the temp dir is a sibling.
  while (p.filename().empty() && p.has_parent_path() && p.parent_path() != p) p = p.parent_path();
  if (p.filename() == "." || p.filename() == "..") p = fs::absolute(p).lexically_normal();
  while (p.filename().empty() && p.has_parent_path() && p.parent_path() != p) p = p.parent_path();
  if (p.empty() || p.filename().empty() || p == p.root_path())
    throw InputError(given + ": not a usable output directory");
  std::string cur = p.string();
  for (int hops = 0;; ++hops) {
    struct stat st;
    if (::lstat(cur.c_str(), &st) != 0) {
      const int err = errno;
      if (err == ENOENT) return {fs::path(cur), false};
      throw InputError(given + ": cannot use it as the output directory: " + errno_text(err));
    }
    if (S_ISLNK(st.st_mode)) {
      if (hops >= kMaxSymlinkHops) throw InputError(given + ": too many levels of symbolic links");
      cur = follow_link(cur, given);
      continue;
    }
    if (!S_ISDIR(st.st_mode)) throw InputError(given + ": output exists and is not a directory");
    return {fs::path(cur), true};
  }
}

struct Marker {
  std::string command;
  std::set<std::string> entries;  // "d REL" and "f REL"
};

bool read_marker(const fs::path& dir, Marker* m) {
  std::error_code ec;
  if (!fs::is_regular_file(fs::symlink_status(dir / kOutputMarker, ec))) return false;
  std::ifstream in(dir / kOutputMarker);
  std::string line;
  if (!std::getline(in, line) || line != kMarkerHeader) return false;
  if (!std::getline(in, line) || line.rfind("command ", 0) != 0) return false;
  m->command = line.substr(8);
  while (std::getline(in, line)) {
    if (line.size() < 3 || (line[0] != 'd' && line[0] != 'f') || line[1] != ' ') return false;
    m->entries.insert(line);
  }
  return true;
}

// Lists `dir` for its marker: every regular file and directory, recursively, sorted.
std::string marker_text(const fs::path& dir, const std::string& command) {
  std::vector<std::string> lines;
  std::error_code ec;
  for (fs::recursive_directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    const fs::file_status s = it->symlink_status(ec);
    const std::string rel = it->path().lexically_relative(dir).generic_string();
    if (rel == kOutputMarker || rel.find('\n') != std::string::npos) continue;
    if (fs::is_directory(s)) lines.push_back("d " + rel);
    if (fs::is_regular_file(s)) lines.push_back("f " + rel);
  }
  if (ec) throw InputError(dir.string() + ": cannot list the new output: " + ec.message());
  std::sort(lines.begin(), lines.end());
  std::string text = std::string(kMarkerHeader) + "\ncommand " + command + "\n";
  for (const auto& l : lines) text += l + "\n";
  return text;
}

bool legacy_match(const std::string& pattern, const std::string& rel, bool is_dir) {
  const bool pattern_dir = !pattern.empty() && pattern.back() == '/';
  if (pattern_dir != is_dir) return false;
  const std::string p = pattern_dir ? pattern.substr(0, pattern.size() - 1) : pattern;
  // '*' stays within one component and does not match a leading '.' (hidden names).
  return ::fnmatch(p.c_str(), rel.c_str(), FNM_PATHNAME | FNM_PERIOD) == 0;
}

// Why `dir` (an existing directory) may not be replaced by `kind`'s output: "" when it may (see
// atomic_output.hpp), else the first entry terrastride did not write, or what could not be read.
std::string foreign_entry(const fs::path& dir, const OutputDirKind& kind) {
  Marker marker;
  const bool marked = read_marker(dir, &marker);
  std::vector<std::string> listed;
  if (!marked && kind.legacy_listed) {
    try {
      listed = kind.legacy_listed(dir.string());
    } catch (const std::exception&) {
      listed.clear();  // an unreadable listing recognises nothing more
    }
  }
  const auto known = [&](const std::string& rel, bool is_dir) {
    if (marked) return marker.entries.count((is_dir ? "d " : "f ") + rel) > 0;
    for (const auto& p : kind.legacy_entries)
      if (legacy_match(p, rel, is_dir)) return true;
    if (!is_dir)
      for (const auto& l : listed)
        if (l == rel) return true;
    return false;
  };
  bool empty = true;
  std::error_code ec;
  fs::recursive_directory_iterator it(dir, ec), end;
  for (; !ec && it != end; it.increment(ec)) {
    empty = false;
    const std::string rel = it->path().lexically_relative(dir).generic_string();
    if (marked && rel == kOutputMarker) continue;
    const fs::file_status s = it->symlink_status(ec);
    if (ec) break;
    const bool ok =
        (fs::is_directory(s) || fs::is_regular_file(s)) && known(rel, fs::is_directory(s));
    if (!ok) return "it holds '" + rel + "', which terrastride did not write";
  }
  if (ec) return "its content cannot be read (" + ec.message() + ")";
  if (empty || marked) return "";
  for (const auto& r : kind.legacy_required) {
    const bool want_dir = !r.empty() && r.back() == '/';
    const fs::file_status s = fs::symlink_status(dir / r, ec);
    if (want_dir ? !fs::is_directory(s) : !fs::is_regular_file(s))
      return "it has no " + r + ", so it is not an earlier `" + kind.command + "` output";
  }
  return "";
}

[[noreturn]] void refuse_dir(const std::string& given, const std::string& why) {
  throw InputError(given + ": refusing to replace this existing folder: " + why +
                   ". Only an empty folder or one terrastride wrote is replaced (replacing "
                   "deletes everything in it); choose an empty or new folder.");
}

// Creates and removes a temporary entry named for `name` in `dir`: proves that it is writable.
void probe_directory(const fs::path& dir, const std::string& name, const std::string& shown) {
  remove_stale_temporaries(dir.string(), name);
  const std::string probe = (dir / ("." + name + unique_suffix())).string();
  if (::mkdir(probe.c_str(), 0700) != 0)
    throw InputError(shown + ": cannot write in folder " + dir.string() + ": " + errno_text());
  ::rmdir(probe.c_str());
}

}  // namespace

// ----- single files ------------------------------------------------------------------------

OutputFile resolve_output_file(const std::string& path) {
  if (path.empty()) throw InputError("output path is empty");
  OutputFile f;
  f.path = path;
  std::string cur = path;
  for (int hops = 0;; ++hops) {
    f.target = cur;
    if (const int fd = descriptor_of(cur); fd >= 0) {
      const int flags = ::fcntl(fd, F_GETFL);
      if (flags < 0)
        throw InputError(shown_name(f) + ": descriptor " + std::to_string(fd) + " is not open");
      if ((flags & O_ACCMODE) == O_RDONLY)
        throw InputError(shown_name(f) + ": descriptor " + std::to_string(fd) +
                         " is not open for writing");
      f.kind = OutputFile::Kind::kDescriptor;
      f.fd = fd;
      return f;
    }
    struct stat st;
    if (::lstat(cur.c_str(), &st) != 0) {
      const int err = errno;
      if (err != ENOENT)
        throw InputError(shown_name(f) + ": cannot write file: " + errno_text(err));
      const fs::path dir = parent_or_dot(cur);
      struct stat ds;
      if (::stat(dir.c_str(), &ds) != 0)
        throw InputError(shown_name(f) + ": cannot write file, directory " + dir.string() +
                         " does not exist");
      if (!S_ISDIR(ds.st_mode))
        throw InputError(shown_name(f) + ": cannot write file, " + dir.string() +
                         " is not a directory");
      f.kind = OutputFile::Kind::kNew;
      return f;
    }
    if (S_ISLNK(st.st_mode)) {
      if (hops >= kMaxSymlinkHops)
        throw InputError(path + ": cannot write file: too many levels of symbolic links");
      cur = follow_link(cur, path);
      continue;
    }
    if (S_ISREG(st.st_mode)) {
      f.kind = OutputFile::Kind::kRegular;
      return f;
    }
    if (S_ISCHR(st.st_mode) || S_ISFIFO(st.st_mode)) {
      f.kind = OutputFile::Kind::kStream;
      return f;
    }
    if (S_ISDIR(st.st_mode))
      throw InputError(shown_name(f) + ": cannot write file, a directory exists with that name");
    const char* what = S_ISSOCK(st.st_mode)  ? "a socket"
                       : S_ISBLK(st.st_mode) ? "a block device"
                                             : "not a regular file";
    throw InputError(shown_name(f) + ": is " + std::string(what) +
                     "; refusing to write a file there (choose another path)");
  }
}

OutputFile check_output_file(const std::string& path) {
  OutputFile f = resolve_output_file(path);
  switch (f.kind) {
    case OutputFile::Kind::kNew:
    case OutputFile::Kind::kRegular: {
      const fs::path target(f.target);
      const fs::path dir = parent_or_dot(target);
      const std::string name = target.filename().string();
      remove_stale_temporaries(dir.string(), name);
      const std::string probe = (dir / ("." + name + unique_suffix())).string();
      const int fd = ::open(probe.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0600);
      if (fd < 0)
        throw InputError(shown_name(f) + ": cannot write in directory " + dir.string() + ": " +
                         errno_text());
      ::close(fd);
      ::unlink(probe.c_str());
      break;
    }
    case OutputFile::Kind::kStream:
      if (::access(f.target.c_str(), W_OK) != 0)
        throw InputError(shown_name(f) + ": not writable: " + errno_text());
      break;
    case OutputFile::Kind::kDescriptor:
      break;  // resolve_output_file checked that it is open for writing
  }
  return f;
}

void write_file_atomically(const std::string& path, const std::string& bytes) {
  const OutputFile f = resolve_output_file(path);
  if (f.kind == OutputFile::Kind::kDescriptor) {
    const std::string problem = write_all(f.fd, bytes);
    if (!problem.empty()) throw InputError(shown_name(f) + ": " + problem);
    return;
  }
  if (f.kind == OutputFile::Kind::kStream) {
    // Devices and pipes are written through: renaming a file over them would destroy them.
    const int fd = ::open(f.target.c_str(), O_WRONLY | O_CLOEXEC | O_NOCTTY);
    if (fd < 0) throw InputError(shown_name(f) + ": cannot open for writing: " + errno_text());
    std::string problem = write_all(fd, bytes);
    if (::close(fd) != 0 && problem.empty()) problem = "close failed: " + errno_text();
    if (!problem.empty()) throw InputError(shown_name(f) + ": " + problem);
    return;
  }
  // A regular file, or nothing yet: a temp file in the target's own directory (a symbolic link
  // stays a link; the file it points to is replaced), fsync, rename.
  const std::string temp = temporary_path_for(f.target);
  const int fd = ::open(temp.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0644);
  if (fd < 0) throw InputError(shown_name(f) + ": cannot create temporary file: " + errno_text());
  std::string problem;
  if (f.kind == OutputFile::Kind::kRegular) {
    struct stat st;  // keep the replaced file's permissions (a private 0600 file stays private)
    if (::stat(f.target.c_str(), &st) == 0) ::fchmod(fd, st.st_mode & 07777);
  }
  problem = write_all(fd, bytes);
  // fsync before rename: otherwise a crash can leave the new name pointing at an empty file.
  // Inside an AtomicOutputDir's temporary directory, its commit() fsyncs before publishing.
  if (problem.empty() && !inside_pending_dir(f.target) && ::fsync(fd) != 0)
    problem = "fsync failed: " + errno_text();
  if (::close(fd) != 0 && problem.empty()) problem = "close failed: " + errno_text();
  if (problem.empty() && ::rename(temp.c_str(), f.target.c_str()) != 0)
    problem = "rename failed: " + errno_text();
  if (!problem.empty()) {
    ::unlink(temp.c_str());
    throw InputError(shown_name(f) + ": " + problem);
  }
}

bool same_file_as_descriptor(const std::string& path, int fd) {
  if (descriptor_of(path) == fd) return true;
  struct stat a, b;
  if (::fstat(fd, &a) != 0 || ::stat(path.c_str(), &b) != 0) return false;
  return a.st_dev == b.st_dev && a.st_ino == b.st_ino;
}

int remove_stale_temporaries(const std::string& dir, const std::string& name) {
  if (name.empty()) return 0;
  std::vector<fs::path> stale;
  std::error_code ec;
  for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    const long pid = temporary_pid(it->path().filename().string(), name);
    if (pid > 0 && process_is_gone(pid)) stale.push_back(it->path());
  }
  int removed = 0;
  for (const auto& p : stale) {
    // remove_all never follows symbolic links: a link named like a temporary goes, not its target.
    if (fs::remove_all(p, ec) > 0 && !ec) ++removed;
  }
  return removed;
}

std::string temporary_path_for(const std::string& target) {
  const fs::path t(target);
  const fs::path dir = parent_or_dot(t);
  const std::string name = t.filename().string();
  remove_stale_temporaries(dir.string(), name);
  return (dir / ("." + name + unique_suffix())).string();
}

// ----- directories ---------------------------------------------------------------------------

void check_output_dir(const std::string& final_dir, const OutputDirKind& kind) {
  const ResolvedDir r = resolve_output_dir(final_dir);
  if (r.exists) {
    const std::string why = foreign_entry(r.path, kind);
    if (!why.empty()) refuse_dir(final_dir, why);
  }
  // The folder it goes into, or the nearest existing ancestor (AtomicOutputDir creates the rest).
  fs::path parent = parent_or_dot(r.path);
  std::string name = r.path.filename().string();
  std::error_code ec;
  while (!fs::exists(parent, ec) && parent_or_dot(parent) != parent) {
    name = parent.filename().string();
    parent = parent_or_dot(parent);
  }
  if (!fs::is_directory(parent, ec))
    throw InputError(final_dir + ": cannot create it: " + parent.string() + " is not a directory");
  probe_directory(parent, name, final_dir);
}

AtomicOutputDir::AtomicOutputDir(const std::string& final_dir, OutputDirKind kind)
    : kind_(std::move(kind)), final_dir_(final_dir) {
  const ResolvedDir r = resolve_output_dir(final_dir);
  if (r.exists) {
    const std::string why = foreign_entry(r.path, kind_);
    if (!why.empty()) refuse_dir(final_dir, why);
  }
  const fs::path parent = parent_or_dot(r.path);
  std::error_code ec;
  fs::create_directories(parent, ec);
  if (ec) throw InputError(final_dir + ": cannot create parent directory: " + ec.message());
  final_dir_ = r.path.string();
  temp_dir_ = temporary_path_for(final_dir_);
  if (::mkdir(temp_dir_.c_str(), 0755) != 0) {
    throw InputError(final_dir + ": cannot create temporary output directory: " + errno_text());
  }
  std::lock_guard<std::mutex> lock(pending_dirs_mutex());
  pending_dirs().push_back(temp_dir_);
}

AtomicOutputDir::~AtomicOutputDir() {
  stop_deferring_syncs(temp_dir_);
  if (!committed_) {
    std::error_code ec;
    fs::remove_all(temp_dir_, ec);  // best effort; never throw from a destructor
  }
}

void AtomicOutputDir::commit() {
  if (committed_) return;
  write_file_atomically((fs::path(temp_dir_) / kOutputMarker).string(),
                        marker_text(temp_dir_, kind_.command));
  // Every file's data on disk before the rename publishes the directory (see inside_pending_dir).
  stop_deferring_syncs(temp_dir_);
  if (const std::string problem = sync_tree(temp_dir_); !problem.empty())
    throw InputError(final_dir_ + ": " + problem);
  struct stat st;
  if (::lstat(final_dir_.c_str(), &st) != 0) {
    if (::rename(temp_dir_.c_str(), final_dir_.c_str()) != 0)
      throw InputError(final_dir_ + ": cannot move the new output into place: " + errno_text());
    committed_ = true;
    return;
  }
  // Something is there now: judged again, since it may have changed during the work.
  if (!S_ISDIR(st.st_mode)) throw InputError(final_dir_ + ": output exists and is not a directory");
  if (const std::string why = foreign_entry(final_dir_, kind_); !why.empty())
    refuse_dir(final_dir_, why);
  // rename(2) cannot replace a non-empty directory: swap the two atomically, so that at every
  // moment either the old or the complete new output is under final_dir; the old one then sits
  // under the temporary name (a stale temporary if this process dies now, removed next time).
  std::string old = temp_dir_;
  if (::renameat2(AT_FDCWD, temp_dir_.c_str(), AT_FDCWD, final_dir_.c_str(), RENAME_EXCHANGE) !=
      0) {
    const int err = errno;
    if (err != EINVAL && err != ENOSYS && err != ENOTSUP)
      throw InputError(final_dir_ + ": cannot move the new output into place: " + errno_text(err));
    // No exchange on this filesystem: move the old output aside, then the new one in.
    old = temporary_path_for(final_dir_);
    if (::rename(final_dir_.c_str(), old.c_str()) != 0)
      throw InputError(final_dir_ + ": cannot move the existing output aside: " + errno_text());
    if (::rename(temp_dir_.c_str(), final_dir_.c_str()) != 0) {
      const std::string problem = errno_text();
      ::rename(old.c_str(), final_dir_.c_str());  // restore the old output
      throw InputError(final_dir_ + ": cannot move the new output into place: " + problem);
    }
  }
  committed_ = true;
  std::error_code ec;
  if (foreign_entry(old, kind_).empty()) {
    fs::remove_all(old, ec);
    return;
  }
  // Someone added a file between the check and the swap: keep the old output, visibly.
  std::string kept = final_dir_ + ".previous";
  for (int k = 2; fs::exists(fs::symlink_status(kept, ec)); ++k)
    kept = final_dir_ + ".previous-" + std::to_string(k);
  ::rename(old.c_str(), kept.c_str());
  throw InputError(final_dir_ +
                   ": the new output is in place, but files appeared in the previous "
                   "one while it was replaced; it was kept as " +
                   kept);
}

}  // namespace terrastride::perception
