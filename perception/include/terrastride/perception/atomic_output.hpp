// All-or-nothing output: nothing half-written is ever visible under the final name.
#pragma once

#include <string>

namespace terrastride::perception {

// Writes `bytes` to `path` via a temp file in the same directory, fsync and rename. Throws
// InputError naming the path on failure (the temp file is removed).
void write_file_atomically(const std::string& path, const std::string& bytes);

// A temp directory next to `final_dir` (same filesystem, so the rename is atomic); write files into
// path(), then commit() renames it to final_dir, replacing an existing directory there. If commit()
// was not called, the destructor removes the temp directory and final_dir is untouched.
class AtomicOutputDir {
 public:
  explicit AtomicOutputDir(const std::string& final_dir);
  ~AtomicOutputDir();
  AtomicOutputDir(const AtomicOutputDir&) = delete;
  AtomicOutputDir& operator=(const AtomicOutputDir&) = delete;

  const std::string& path() const { return temp_dir_; }  // where to write now
  const std::string& final_path() const { return final_dir_; }
  void commit();
  bool committed() const { return committed_; }

 private:
  std::string final_dir_;
  std::string temp_dir_;
  bool committed_ = false;
};

}  // namespace terrastride::perception
