// Helpers shared by the perception tests: paths to the real scans and a scratch directory.
#pragma once

#include <gtest/gtest.h>

#include <unistd.h>
#include <filesystem>
#include <fstream>
#include <string>

#include "terrastride/perception/point_cloud.hpp"

namespace terrastride::perception::test {

// Tests on the real scans skip, with a message, where ../shared is absent (a user's clone).
#define TERRASTRIDE_REQUIRE_SHARED_SCANS()                                            \
  if (!std::filesystem::is_directory(std::string(TERRASTRIDE_SHARED_DIR) + "/scans")) \
  GTEST_SKIP() << "no " << TERRASTRIDE_SHARED_DIR                                     \
               << "/scans (the shared scans folder is not "                           \
                  "beside this clone)"

inline std::string scan(const std::string& relative) {
  return std::string(TERRASTRIDE_SHARED_DIR) + "/scans/" + relative;
}

// A fresh directory per test, removed afterwards.
class ScratchDir {
 public:
  ScratchDir() {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    path_ = std::filesystem::temp_directory_path() /
            ("terrastride_perception_" + std::string(info->test_suite_name()) + "_" + info->name() +
             "_" + std::to_string(::getpid()));
    std::filesystem::remove_all(path_);
    std::filesystem::create_directories(path_);
  }
  ~ScratchDir() {
    std::error_code ec;
    std::filesystem::remove_all(path_, ec);
  }
  std::string file(const std::string& name) const { return (path_ / name).string(); }
  const std::filesystem::path& path() const { return path_; }

 private:
  std::filesystem::path path_;
};

inline void write_text(const std::string& path, const std::string& text) {
  std::ofstream(path, std::ios::binary) << text;
}

// Runs `f`, expects an InputError whose message contains every string in `needles`.
template <typename F>
void expect_input_error(F&& f, std::initializer_list<std::string> needles) {
  try {
    f();
    ADD_FAILURE() << "expected an InputError";
  } catch (const InputError& e) {
    const std::string msg = e.what();
    for (const auto& n : needles) {
      EXPECT_NE(msg.find(n), std::string::npos) << "message '" << msg << "' lacks '" << n << "'";
    }
  }
}

}  // namespace terrastride::perception::test
