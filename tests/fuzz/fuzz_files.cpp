// libFuzzer target for the file readers of `terrastride map` besides the bags (fuzz_bag):
// - OctoMap binary (.bt) and full (.ot) files, by their first line: read_octomap_bytes (the body
//   walk before OctoMap's recursive reader), then the support cloud of a tree read;
// - NPY (by its magic): read_npy and read_cloud;
// - PLY (starting "ply") and anything else as PCD: read_cloud, i.e. the header and body checks
//   that run before PCL (in the fuzz build, without PCL, they are all that runs: the read then
//   stops with "needs PCL"; the regular suite's replay, FileFuzzCorpus.Replay, goes on into PCL).
// Every failure must be an InputError. Build and run: tests/fuzz/run.sh.
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <iostream>
#include <string>

#include "terrastride/perception/cloud_io.hpp"
#include "terrastride/perception/npy.hpp"
#include "terrastride/perception/octomap_input.hpp"

namespace {

namespace pe = terrastride::perception;

struct ScratchDir {
  std::string path;
  ScratchDir() {
    const char* base = std::getenv("TMPDIR");
    path = std::string(base && *base ? base : "/tmp") + "/fuzz-files-XXXXXX";
    if (!::mkdtemp(path.data())) std::abort();
  }
  ~ScratchDir() {
    std::error_code ec;
    std::filesystem::remove_all(path, ec);
  }
};

std::string write_scratch(std::string_view data, const std::string& extension) {
  static const ScratchDir dir;
  const std::string path = dir.path + "/in" + extension;
  FILE* f = std::fopen(path.c_str(), "wb");
  if (!f) std::abort();
  std::fwrite(data.data(), 1, data.size(), f);
  std::fclose(f);
  return path;
}

void exercise_octomap(std::string_view data, bool binary) {
  // Debian's liboctomap prints every read and write on std::cerr ("Reading octree type OcTree"):
  // thousands of lines a second, drowning libFuzzer's own.
  struct QuietCerr {
    std::streambuf* saved = std::cerr.rdbuf(nullptr);
    ~QuietCerr() { std::cerr.rdbuf(saved); }
  } quiet;
  try {
    const auto tree = pe::read_octomap_bytes(binary ? "in.bt" : "in.ot", std::string(data), binary);
    // Coarse leaves expand to many voxels: a small cap keeps every input's memory bounded.
    (void)pe::octree_support_cloud(*tree, "in", nullptr, 1'000'000);
  } catch (const pe::InputError&) {
  }
}

void exercise_cloud(std::string_view data, const std::string& extension) {
  const std::string path = write_scratch(data, extension);
  try {
    const pe::PointCloud cloud = pe::read_cloud(path);
    for (const auto& p : cloud.points)
      if (!p.allFinite()) __builtin_trap();  // read_cloud drops non-finite points
  } catch (const pe::InputError&) {
  }
  if (extension != ".npy") return;
  try {
    (void)pe::read_npy(path);
  } catch (const pe::InputError&) {
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view bytes(reinterpret_cast<const char*>(data), size);
  const auto starts = [&](std::string_view prefix) { return bytes.substr(0, prefix.size()) == prefix; };
  if (starts("# Octomap OcTree binary file"))
    exercise_octomap(bytes, true);
  else if (starts("# Octomap OcTree file"))
    exercise_octomap(bytes, false);
  else if (starts("\x93NUMPY"))
    exercise_cloud(bytes, ".npy");
  else if (starts("ply"))
    exercise_cloud(bytes, ".ply");
  else
    exercise_cloud(bytes, ".pcd");
  return 0;
}
