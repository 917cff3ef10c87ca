// NPY writer/reader round trips and the atomic output helpers.
#include <gtest/gtest.h>

#include <fstream>
#include <sstream>
#include <vector>

#include "terrastride/perception/atomic_output.hpp"
#include "terrastride/perception/npy.hpp"
#include "test_util.hpp"

namespace terrastride::perception {
namespace {

using test::expect_input_error;
using test::ScratchDir;

std::string slurp(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

size_t entries(const std::filesystem::path& dir) {
  return static_cast<size_t>(std::distance(std::filesystem::directory_iterator(dir), {}));
}

TEST(Npy, RoundTripAllDtypes) {
  ScratchDir dir;
  const std::vector<float> f = {1.5f, -2.0f, 3.0f, 4.0f, 5.0f, 6.25f};
  const std::vector<double> d = {1e-300, 2.0, -3.5, 4.0};
  const std::vector<uint8_t> u = {0, 1, 255, 7, 8, 9, 10, 11, 12};
  write_npy(dir.file("f.npy"), f.data(), 2, 3);
  write_npy(dir.file("d.npy"), d.data(), 4, 1);
  write_npy(dir.file("u.npy"), u.data(), 3, 3);

  NpyArray a = read_npy(dir.file("f.npy"));
  EXPECT_EQ(a.dtype, "<f4");
  EXPECT_EQ(a.shape, (std::vector<size_t>{2, 3}));
  EXPECT_EQ(a.at(1, 2), 6.25);
  EXPECT_EQ(a.at(0, 1), -2.0);
  a = read_npy(dir.file("d.npy"));
  EXPECT_EQ(a.dtype, "<f8");
  EXPECT_EQ(a.rows(), 4u);
  EXPECT_EQ(a.cols(), 1u);
  EXPECT_EQ(a.at(0, 0), 1e-300);
  a = read_npy(dir.file("u.npy"));
  EXPECT_EQ(a.dtype, "|u1");
  EXPECT_EQ(a.at(0, 2), 255.0);
  EXPECT_EQ(a.at(2, 2), 12.0);
}

TEST(Npy, HeaderIsAlignedAndNumpyReadable) {
  ScratchDir dir;
  const std::vector<float> f(12, 0.0f);
  write_npy(dir.file("f.npy"), f.data(), 4, 3);
  const std::string bytes = slurp(dir.file("f.npy"));
  ASSERT_GE(bytes.size(), 10u);
  EXPECT_EQ(bytes.substr(0, 6), "\x93NUMPY");
  const size_t header_len = static_cast<unsigned char>(bytes[8]) |
                            (static_cast<size_t>(static_cast<unsigned char>(bytes[9])) << 8);
  // numpy requires the data to start on a 64-byte boundary and the header to end with '\n'.
  EXPECT_EQ((10 + header_len) % 64, 0u);
  EXPECT_EQ(bytes[10 + header_len - 1], '\n');
  EXPECT_NE(bytes.find("'shape': (4, 3)"), std::string::npos);
  EXPECT_EQ(bytes.size(), 10 + header_len + 48);
}

TEST(Npy, ReadsVersion2Header) {
  ScratchDir dir;
  std::string header = "{'descr': '<f8', 'fortran_order': False, 'shape': (1, 2), }";
  while ((12 + header.size() + 1) % 64) header += ' ';
  header += '\n';
  std::string bytes("\x93NUMPY\x02\x00", 8);
  for (int i = 0; i < 4; ++i) bytes += static_cast<char>((header.size() >> (8 * i)) & 0xff);
  bytes += header;
  const double v[2] = {3.0, -4.0};
  bytes.append(reinterpret_cast<const char*>(v), sizeof(v));
  test::write_text(dir.file("v2.npy"), bytes);
  const NpyArray a = read_npy(dir.file("v2.npy"));
  EXPECT_EQ(a.at(0, 1), -4.0);
}

TEST(Npy, ErrorsNameTheFile) {
  expect_input_error([] { read_npy("/no/such/layer.npy"); }, {"/no/such/layer.npy", "cannot open"});
  const float f[3] = {1, 2, 3};
  expect_input_error([&] { write_npy("/no/such/dir/layer.npy", f, 1, 3); },
                     {"/no/such/dir/layer.npy"});
}

TEST(AtomicFile, ReplacesExistingContentAndLeavesNoTemp) {
  ScratchDir dir;
  const std::string path = dir.file("a.txt");
  write_file_atomically(path, "first");
  write_file_atomically(path, "second, longer");
  EXPECT_EQ(slurp(path), "second, longer");
  EXPECT_EQ(entries(dir.path()), 1u);
}

TEST(AtomicFile, RefusesDirectoryTarget) {
  ScratchDir dir;
  std::filesystem::create_directory(dir.file("sub"));
  expect_input_error([&] { write_file_atomically(dir.file("sub"), "x"); }, {"sub", "directory"});
  EXPECT_EQ(entries(dir.path()), 1u);
}

TEST(AtomicDir, UncommittedLeavesNothing) {
  ScratchDir dir;
  const std::string out = dir.file("out");
  {
    AtomicOutputDir o(out);
    write_file_atomically(o.path() + "/terrain.json", "{}");
    EXPECT_FALSE(std::filesystem::exists(out));
    // Simulates an error part-way: the destructor runs without commit().
  }
  EXPECT_FALSE(std::filesystem::exists(out));
  EXPECT_EQ(entries(dir.path()), 0u);
}

TEST(AtomicDir, CommitCreatesAndReplaces) {
  ScratchDir dir;
  const std::string out = dir.file("nested/out");
  {
    AtomicOutputDir o(out);
    write_file_atomically(o.path() + "/a.txt", "old");
    std::filesystem::create_directory(o.path() + "/layers");
    o.commit();
    EXPECT_TRUE(o.committed());
  }
  EXPECT_EQ(slurp(out + "/a.txt"), "old");
  {
    AtomicOutputDir o(out + "/");  // a trailing slash means the same directory
    write_file_atomically(o.path() + "/b.txt", "new");
    EXPECT_EQ(slurp(out + "/a.txt"), "old");  // still the old output until commit
    o.commit();
  }
  EXPECT_FALSE(std::filesystem::exists(out + "/a.txt"));
  EXPECT_EQ(slurp(out + "/b.txt"), "new");
  EXPECT_EQ(entries(dir.path() / "nested"), 1u);  // no temp or backup directories left
}

TEST(AtomicDir, RefusesFileInTheWay) {
  ScratchDir dir;
  test::write_text(dir.file("f"), "x");
  expect_input_error([&] { AtomicOutputDir o(dir.file("f")); }, {"not a directory"});
}

}  // namespace
}  // namespace terrastride::perception
