// Atomic file and directory output: write under a temporary name on the same filesystem, then
// rename, so readers (and a crash) only ever see the old or the complete new content.
#include "terrastride/perception/atomic_output.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <system_error>

#include "terrastride/perception/point_cloud.hpp"

namespace fs = std::filesystem;

namespace terrastride::perception {
namespace {

// Unique per process and call: pid + counter + clock, so parallel writers in one directory never
// collide (O_EXCL / mkdir catch the rest).
std::string unique_suffix() {
  static std::atomic<unsigned long> counter{0};
  const auto ticks = std::chrono::steady_clock::now().time_since_epoch().count();
  return ".tmp-" + std::to_string(::getpid()) + "-" + std::to_string(counter++) + "-" +
         std::to_string(static_cast<unsigned long long>(ticks) % 1000000007ULL);
}

std::string errno_text() {
  return std::strerror(errno);
}

fs::path parent_or_dot(const fs::path& p) {
  fs::path parent = p.parent_path();
  return parent.empty() ? fs::path(".") : parent;
}

}  // namespace

void write_file_atomically(const std::string& path, const std::string& bytes) {
  if (path.empty()) throw InputError("output path is empty");
  const fs::path target(path);
  std::error_code ec;
  if (fs::is_directory(target, ec)) {
    throw InputError(path + ": cannot write file, a directory exists with that name");
  }
  const fs::path dir = parent_or_dot(target);
  if (!fs::is_directory(dir, ec)) {
    throw InputError(path + ": cannot write file, directory " + dir.string() + " does not exist");
  }
  const std::string temp = (dir / ("." + target.filename().string() + unique_suffix())).string();
  const int fd = ::open(temp.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0644);
  if (fd < 0) throw InputError(path + ": cannot create temporary file: " + errno_text());
  const char* data = bytes.data();
  size_t left = bytes.size();
  bool ok = true;
  std::string problem;
  while (left > 0) {
    const ssize_t n = ::write(fd, data, left);
    if (n < 0) {
      if (errno == EINTR) continue;
      ok = false;
      problem = "write failed: " + errno_text();
      break;
    }
    data += n;
    left -= static_cast<size_t>(n);
  }
  // fsync before rename: otherwise a crash can leave the new name pointing at an empty file.
  if (ok && ::fsync(fd) != 0) {
    ok = false;
    problem = "fsync failed: " + errno_text();
  }
  if (::close(fd) != 0 && ok) {
    ok = false;
    problem = "close failed: " + errno_text();
  }
  if (ok && ::rename(temp.c_str(), path.c_str()) != 0) {
    ok = false;
    problem = "rename failed: " + errno_text();
  }
  if (!ok) {
    ::unlink(temp.c_str());
    throw InputError(path + ": " + problem);
  }
}

AtomicOutputDir::AtomicOutputDir(const std::string& final_dir) : final_dir_(final_dir) {
  if (final_dir.empty()) throw InputError("output directory path is empty");
  fs::path final_path(final_dir);
  // "out/" has an empty filename; strip the trailing separator so the temp dir is a sibling.
  if (final_path.filename().empty()) final_path = final_path.parent_path();
  if (final_path.empty()) throw InputError(final_dir + ": not a usable output directory");
  std::error_code ec;
  if (fs::exists(final_path, ec) && !fs::is_directory(final_path, ec)) {
    throw InputError(final_dir + ": output exists and is not a directory");
  }
  const fs::path parent = parent_or_dot(final_path);
  fs::create_directories(parent, ec);
  if (ec) throw InputError(final_dir + ": cannot create parent directory: " + ec.message());
  final_dir_ = final_path.string();
  temp_dir_ = (parent / ("." + final_path.filename().string() + unique_suffix())).string();
  if (::mkdir(temp_dir_.c_str(), 0755) != 0) {
    throw InputError(final_dir + ": cannot create temporary output directory: " + errno_text());
  }
}

AtomicOutputDir::~AtomicOutputDir() {
  if (!committed_) {
    std::error_code ec;
    fs::remove_all(temp_dir_, ec);  // best effort; never throw from a destructor
  }
}

void AtomicOutputDir::commit() {
  if (committed_) return;
  std::error_code ec;
  // rename(2) cannot replace a non-empty directory, so an existing output is first moved aside;
  // at every moment either the old or the complete new directory is under final_dir.
  std::string backup;
  if (fs::exists(final_dir_, ec)) {
    backup = temp_dir_ + ".old";
    if (::rename(final_dir_.c_str(), backup.c_str()) != 0) {
      throw InputError(final_dir_ + ": cannot move the existing output aside: " + errno_text());
    }
  }
  if (::rename(temp_dir_.c_str(), final_dir_.c_str()) != 0) {
    const std::string problem = errno_text();
    if (!backup.empty()) ::rename(backup.c_str(), final_dir_.c_str());  // restore the old output
    throw InputError(final_dir_ + ": cannot move the new output into place: " + problem);
  }
  committed_ = true;
  if (!backup.empty()) fs::remove_all(backup, ec);
}

}  // namespace terrastride::perception
