// A rosbag2 folder: what `ros2 bag record` writes, a directory with metadata.yaml and one or more
// storage files (.mcap or .db3; several when the recorder splits by size or duration). Read as
// one recording: the files in the order metadata.yaml lists them (their time order), one after the
// other, so a reader's two passes (tf, then clouds) see /tf_static from the first split and the
// /tf samples on both sides of a split boundary. One file is open at a time.
#include <yaml-cpp/yaml.h>

#include <filesystem>

#include "bag/bag_readers.hpp"

namespace terrastride::perception::bag {
namespace {

namespace fs = std::filesystem;

// The storage files of the folder, from metadata.yaml's rosbag2_bagfile_information:
// relative_file_paths (or files[].path). Versions before 4 (Foxy) wrote them relative to the
// folder's parent ("run/run_0.db3"), later ones relative to the folder ("run_0.mcap").
std::vector<std::string> storage_files(const std::string& folder) {
  const fs::path metadata = fs::path(folder) / "metadata.yaml";
  YAML::Node info;
  try {
    info = YAML::LoadFile(metadata.string())["rosbag2_bagfile_information"];
  } catch (const YAML::Exception& e) {
    throw InputError(metadata.string() + ": not readable as YAML: " + e.what());
  }
  if (!info || !info.IsMap())
    throw InputError(metadata.string() +
                     ": no rosbag2_bagfile_information (not a rosbag2 folder's metadata)");
  std::vector<std::string> names;
  try {
    if (const YAML::Node rel = info["relative_file_paths"]; rel && rel.IsSequence()) {
      for (const auto& n : rel) names.push_back(n.as<std::string>());
    } else if (const YAML::Node files = info["files"]; files && files.IsSequence()) {
      for (const auto& f : files) names.push_back(f["path"].as<std::string>());
    }
  } catch (const YAML::Exception& e) {
    throw InputError(metadata.string() + ": relative_file_paths: " + e.what());
  }
  if (names.empty())
    throw InputError(metadata.string() + ": lists no storage files (relative_file_paths)");
  std::vector<std::string> paths;
  const fs::path dir = fs::absolute(folder).lexically_normal();
  for (const std::string& name : names) {
    const fs::path rel(name);
    if (rel.is_absolute() || rel.empty())
      throw InputError(metadata.string() + ": storage file '" + name +
                       "' is not a path relative to the folder");
    std::error_code ec;
    fs::path p = fs::path(folder) / rel;
    if (!fs::exists(p, ec)) {
      const fs::path older = dir.parent_path() / rel;  // metadata version < 4
      if (fs::exists(older, ec)) p = older;
    }
    if (!fs::exists(p, ec))
      throw InputError(metadata.string() + ": storage file '" + name + "' is missing from " +
                       folder + " (a split of the recording cannot be skipped: its transforms "
                       "place the clouds after it)");
    if (!is_bag_file(p.string()) || fs::is_directory(p, ec))
      throw InputError(metadata.string() + ": storage file '" + name +
                       "' is not a .mcap or .db3 file");
    paths.push_back(p.string());
  }
  return paths;
}

class FolderReader : public BagReader {
 public:
  explicit FolderReader(const std::string& folder)
      : BagReader(folder), files_(storage_files(folder)) {
    // The first file decides the format and, for MCAP/.db3, knows its topics after opening.
    auto first = open_bag(files_.front());
    format_ = first->format();
    merge_topics(*first);
  }

  void read(const std::function<bool(const BagTopic&)>& want,
            const std::function<void(const BagMessage&)>& on) override {
    damage_ = {};
    for (std::size_t k = 0; k < files_.size(); ++k) {
      std::unique_ptr<BagReader> reader = open_bag(files_[k]);
      if (reader->format() != format_)
        throw InputError(path_ + ": " + files_[k] + " is " + reader->format() + ", " +
                         files_.front() + " " + format_ + " (one recording has one storage format)");
      reader->read(want, on);
      merge_topics(*reader);
      const BagDamage& d = reader->damage();
      const std::string name = fs::path(files_[k]).filename().string();
      for (const std::string& p : d.problems) damage_.problems.push_back(name + ": " + p);
      damage_.skipped_bytes += d.skipped_bytes;
      damage_.file_bytes += d.file_bytes;
    }
  }

  std::vector<BagTopic> topics() const override { return topics_; }
  std::string format() const override { return format_; }

 private:
  void merge_topics(const BagReader& reader) {
    for (const BagTopic& t : reader.topics()) {
      bool known = false;
      for (const BagTopic& have : topics_) known = known || have.name == t.name;
      if (!known) topics_.push_back(t);
    }
  }

  std::vector<std::string> files_;
  std::string format_;
  std::vector<BagTopic> topics_;
};

}  // namespace

bool is_rosbag2_folder(const std::string& path) {
  std::error_code ec;
  return fs::is_directory(path, ec) && fs::is_regular_file(fs::path(path) / "metadata.yaml", ec);
}

std::unique_ptr<BagReader> open_rosbag2_folder(const std::string& path) {
  return std::make_unique<FolderReader>(path);
}

}  // namespace terrastride::perception::bag
