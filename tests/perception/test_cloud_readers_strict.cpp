// Bad point cloud files through read_npy and through the CLI: `terrastride map` must stop with the
// reader's message and write nothing. (The per-format cases are in test_cloud_io.cpp.)
#include <gtest/gtest.h>

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "support/run_command.hpp"
#include "terrastride/perception/npy.hpp"
#include "test_util.hpp"

namespace terrastride::perception {
namespace {

using test::expect_input_error;
using test::ScratchDir;
using test::write_text;

void write_raw_npy(const std::string& path, const std::string& dict, const std::string& payload) {
  std::string header = dict;
  while ((10 + header.size() + 1) % 64) header += ' ';
  header += '\n';
  std::string bytes("\x93NUMPY\x01\x00", 8);
  bytes += static_cast<char>(header.size() & 0xff);
  bytes += static_cast<char>(header.size() >> 8);
  write_text(path, bytes + header + payload);
}

template <typename T>
std::string bytes_of(const std::vector<T>& v) {
  return std::string(reinterpret_cast<const char*>(v.data()), v.size() * sizeof(T));
}

TEST(NpyStrictRead, FortranOrderIsReorderedToRows) {
  ScratchDir dir;
  // A (2, 3) array [[1, 2, 3], [4, 5, 6]] stored column by column.
  write_raw_npy(dir.file("f.npy"), "{'descr': '<i4', 'fortran_order': True, 'shape': (2, 3), }",
                bytes_of(std::vector<int32_t>{1, 4, 2, 5, 3, 6}));
  const NpyArray a = read_npy(dir.file("f.npy"));
  EXPECT_FALSE(a.fortran_order);
  ASSERT_EQ(a.shape, (std::vector<size_t>{2, 3}));
  for (size_t r = 0; r < 2; ++r) {
    for (size_t c = 0; c < 3; ++c) EXPECT_EQ(a.at(r, c), static_cast<double>(r * 3 + c + 1));
  }
  // 1-D: the same bytes either way.
  write_raw_npy(dir.file("v.npy"), "{'descr': '<f8', 'fortran_order': True, 'shape': (2,), }",
                bytes_of(std::vector<double>{7, 8}));
  EXPECT_EQ(read_npy(dir.file("v.npy")).at(1, 0), 8.0);
}

TEST(NpyStrictRead, DataLongerOrShorterThanTheShapeIsAnError) {
  ScratchDir dir;
  write_raw_npy(dir.file("long.npy"), "{'descr': '<f8', 'fortran_order': False, 'shape': (2, 2), }",
                bytes_of(std::vector<double>{1, 2, 3, 4, 5}));
  expect_input_error([&] { read_npy(dir.file("long.npy")); },
                     {"long.npy", "8 bytes after the data", "(32 bytes)"});
  write_raw_npy(dir.file("short.npy"),
                "{'descr': '<f8', 'fortran_order': False, 'shape': (2, 2), }",
                bytes_of(std::vector<double>{1, 2, 3}));
  expect_input_error([&] { read_npy(dir.file("short.npy")); }, {"short.npy", "truncated"});
  write_raw_npy(dir.file("st.npy"),
                "{'descr': [('x', '<f4'), ('y', '<f4')], 'fortran_order': False, 'shape': (1,), }",
                bytes_of(std::vector<float>{1, 2}));
  expect_input_error([&] { read_npy(dir.file("st.npy")); }, {"st.npy", "structured dtype"});
}

TEST(CloudCli, MapOfABadCloudFailsWithTheReadersMessageAndWritesNothing) {
  ScratchDir dir;
  const std::string cloud = dir.file("bad.pcd");
  write_text(cloud,
             "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 3\nHEIGHT 1\n"
             "POINTS 3\nDATA ascii\n0 0 0\n5 abc 0\n1 1 0\n");
  const std::string out = dir.file("map");
  const test_support::CommandResult r = test_support::run_terrastride(
      "map " + test_support::shell_quote(cloud) + " --out " + test_support::shell_quote(out));
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.err.find("bad.pcd: line 11: field 'y': 'abc' is not a number"), std::string::npos)
      << r.all();
  EXPECT_FALSE(std::filesystem::exists(out));
  // Nothing else (no temporary output directory) next to the cloud either.
  EXPECT_EQ(std::distance(std::filesystem::directory_iterator(dir.path()), {}), 1) << r.all();
}

}  // namespace
}  // namespace terrastride::perception
