// Reading the real scans in every supported format, the PCD round trip, and bad input.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

#include "terrastride/perception/cloud_io.hpp"
#include "terrastride/perception/npy.hpp"
#include "test_util.hpp"

namespace terrastride::perception {
namespace {

using test::expect_input_error;
using test::scan;
using test::ScratchDir;
using test::write_text;

struct Bounds {
  Eigen::Vector3f lo = Eigen::Vector3f::Constant(std::numeric_limits<float>::max());
  Eigen::Vector3f hi = Eigen::Vector3f::Constant(-std::numeric_limits<float>::max());
  Eigen::Vector3f extent() const { return hi - lo; }
};
Bounds bounds(const PointCloud& c) {
  Bounds b;
  for (const auto& p : c.points) {
    b.lo = b.lo.cwiseMin(p);
    b.hi = b.hi.cwiseMax(p);
  }
  return b;
}

TEST(ReadCloud, RealBinaryPcdWithViewpoint) {
  TERRASTRIDE_REQUIRE_SHARED_SCANS();
  ReadStats stats;
  const PointCloud c =
      read_cloud(scan("anybotics_samples/grid_map_pcl_input_cloud.pcd"), std::nullopt, &stats);
  EXPECT_EQ(c.points.size(), 56423u);
  EXPECT_EQ(stats.points_in_file, 56423u);
  EXPECT_EQ(stats.non_finite, 0u);
  // The file's VIEWPOINT is "23.6795 -2.25992 0 0.694123 ...": not identity-zero, so it is kept.
  ASSERT_TRUE(c.sensor_origin.has_value());
  EXPECT_NEAR(c.sensor_origin->x(), 23.6795, 1e-4);
  EXPECT_NEAR(c.sensor_origin->y(), -2.25992, 1e-5);
  EXPECT_NEAR(c.sensor_origin->z(), 0.0, 1e-9);
  // README: a noisy flat plane, 2.55 x 1.33 x 0.14 m.
  const Bounds b = bounds(c);
  EXPECT_NEAR(b.extent().x(), 2.55, 0.02);
  EXPECT_NEAR(b.extent().y(), 1.33, 0.02);
  EXPECT_NEAR(b.extent().z(), 0.14, 0.02);
}

TEST(ReadCloud, RealBinaryPlyWithExtraFields) {
  TERRASTRIDE_REQUIRE_SHARED_SCANS();
  const PointCloud c = read_cloud(scan("anybotics_samples/elevation_mapping_maze.ply"));
  EXPECT_EQ(c.points.size(), 25809u);
  EXPECT_FALSE(c.sensor_origin.has_value());
  // README: walls about 1.05 m high on a floor, 5.9 x 5.1 m. Wrong field offsets (normals,
  // curvature, intensity interleaved) would scramble these extents.
  const Bounds b = bounds(c);
  EXPECT_NEAR(b.extent().x(), 5.9, 0.1);
  EXPECT_NEAR(b.extent().y(), 5.1, 0.1);
  EXPECT_GT(b.extent().z(), 1.0f);  // walls ~1.05 m over a slightly uneven floor
  EXPECT_LT(b.extent().z(), 1.25f);
}

TEST(ReadCloud, RealXyzText) {
  TERRASTRIDE_REQUIRE_SHARED_SCANS();
  const PointCloud c = read_cloud(scan("octomap/scan.xyz"));
  EXPECT_EQ(c.points.size(), 88206u);
  EXPECT_FALSE(c.sensor_origin.has_value());
  EXPECT_EQ(c.source, scan("octomap/scan.xyz"));
  // First line of the file.
  EXPECT_NEAR(c.points[0].x(), -0.0434742f, 1e-6);
  EXPECT_NEAR(c.points[0].y(), -4.82982f, 1e-5);
  EXPECT_NEAR(c.points[0].z(), 0.499645f, 1e-6);
  const Bounds b = bounds(c);
  EXPECT_GT(b.hi.x(), 26.0f);
  EXPECT_LT(b.lo.y(), -14.0f);
  EXPECT_GT(b.hi.y(), 15.0f);
}

TEST(ReadCloud, RealNpyFloat32) {
  TERRASTRIDE_REQUIRE_SHARED_SCANS();
  const struct {
    const char* file;
    size_t points;
  } cases[] = {{"curb_w_grass.npy", 18353}, {"grid_stairs.npy", 13754}, {"grid_water.npy", 14923}};
  for (const auto& tc : cases) {
    SCOPED_TRACE(tc.file);
    const PointCloud c = read_cloud(scan(std::string("terrain_understanding_mit/") + tc.file));
    EXPECT_EQ(c.points.size(), tc.points);
    const Bounds b = bounds(c);
    // Each is a strip 20 cm wide in y.
    EXPECT_GE(b.lo.y(), -0.11f);
    EXPECT_LE(b.hi.y(), 0.11f);
    EXPECT_LT(b.hi.z(), 0.05f);
  }
}

TEST(ReadCloud, OriginArgumentOverridesFile) {
  TERRASTRIDE_REQUIRE_SHARED_SCANS();
  const Eigen::Vector3d o(1, 2, 3);
  const PointCloud pcd = read_cloud(scan("anybotics_samples/grid_map_pcl_input_cloud.pcd"), o);
  ASSERT_TRUE(pcd.sensor_origin);
  EXPECT_EQ(*pcd.sensor_origin, o);
  const PointCloud npy = read_cloud(scan("terrain_understanding_mit/grid_water.npy"), o);
  ASSERT_TRUE(npy.sensor_origin);
  EXPECT_EQ(*npy.sensor_origin, o);
}

TEST(WritePcd, RoundTripWithOrigin) {
  ScratchDir dir;
  PointCloud c;
  c.points = {{0, 0, 0}, {1.5f, -2.25f, 3.125f}, {1e-7f, -1e6f, 42.0f}};
  c.sensor_origin = Eigen::Vector3d(0.25, -1.5, 0.75);
  const std::string path = dir.file("cloud.pcd");
  write_pcd(c, path);
  const PointCloud back = read_cloud(path);
  ASSERT_EQ(back.points.size(), c.points.size());
  // The file holds the points relative to the origin (PCL's VIEWPOINT): back within float
  // rounding of that subtraction.
  for (size_t i = 0; i < c.points.size(); ++i)
    EXPECT_LE((back.points[i] - c.points[i]).cwiseAbs().maxCoeff(),
              1e-7f * std::max(1.0f, c.points[i].cwiseAbs().maxCoeff()))
        << i;
  ASSERT_TRUE(back.sensor_origin);
  EXPECT_TRUE(back.sensor_origin->isApprox(*c.sensor_origin, 1e-7));
  // No temp files left next to the output.
  EXPECT_EQ(std::distance(std::filesystem::directory_iterator(dir.path()), {}), 1);
}

TEST(WritePcd, RoundTripWithoutOriginKeepsNone) {
  ScratchDir dir;
  PointCloud c;
  c.points = {{1, 2, 3}, {4, 5, 6}};
  write_pcd(c, dir.file("a.pcd"));
  EXPECT_FALSE(read_cloud(dir.file("a.pcd")).sensor_origin.has_value());
}

TEST(WritePcd, RoundTripOfRealScan) {
  TERRASTRIDE_REQUIRE_SHARED_SCANS();
  ScratchDir dir;
  const PointCloud c =
      read_cloud(scan("terrain_understanding_mit/curb_w_grass.npy"), Eigen::Vector3d(0, 0, 0.1));
  write_pcd(c, dir.file("curb.pcd"));
  const PointCloud back = read_cloud(dir.file("curb.pcd"));
  ASSERT_EQ(back.points.size(), c.points.size());
  float worst = 0;
  for (size_t i = 0; i < c.points.size(); ++i)
    worst = std::max(worst, (back.points[i] - c.points[i]).cwiseAbs().maxCoeff());
  EXPECT_LT(worst, 1e-6f);  // float rounding of the points relative to the origin
  ASSERT_TRUE(back.sensor_origin);
  EXPECT_NEAR(back.sensor_origin->z(), 0.1, 1e-7);  // PCD stores the viewpoint as float32
}

TEST(WritePcd, UnwritableDirectoryIsAnError) {
  PointCloud c;
  c.points = {{1, 2, 3}};
  expect_input_error([&] { write_pcd(c, "/nonexistent-dir-xyz/out.pcd"); },
                     {"/nonexistent-dir-xyz/out.pcd", "does not exist"});
}

TEST(ReadCloud, XyzCommentsExtraColumnsAndNaN) {
  ScratchDir dir;
  const std::string path = dir.file("c.xyz");
  write_text(path,
             "# a comment line\n"
             "1 2 3\n"
             "\n"
             "  4\t5  6   255 0 0   # colour columns and a trailing comment\n"
             "nan 1 2\n"
             "+7,8,-9e-1\r\n"
             "1 inf 2\n"
             "10 11 12");  // no final newline
  ReadStats stats;
  const PointCloud c = read_cloud(path, std::nullopt, &stats);
  ASSERT_EQ(c.points.size(), 4u);
  EXPECT_EQ(stats.points_in_file, 6u);
  EXPECT_EQ(stats.non_finite, 2u);
  EXPECT_EQ(c.points[1], Eigen::Vector3f(4, 5, 6));
  EXPECT_EQ(c.points[2], Eigen::Vector3f(7, 8, -0.9f));
  EXPECT_EQ(c.points[3], Eigen::Vector3f(10, 11, 12));
}

TEST(ReadCloud, NaNMixedIntoNpyAndPcdIsDroppedAndCounted) {
  ScratchDir dir;
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const std::vector<float> data = {1, 2, 3, nan, 0, 0, 4, 5, 6, 0, nan, 0, 7, 8, 9};
  write_npy(dir.file("m.npy"), data.data(), 5, 3);
  ReadStats stats;
  PointCloud c = read_cloud(dir.file("m.npy"), std::nullopt, &stats);
  EXPECT_EQ(c.points.size(), 3u);
  EXPECT_EQ(stats.non_finite, 2u);
  EXPECT_EQ(c.points[2], Eigen::Vector3f(7, 8, 9));

  PointCloud with_nan;
  with_nan.points = {{1, 2, 3}, {nan, nan, nan}, {4, 5, 6}};
  write_pcd(with_nan, dir.file("m.pcd"));
  c = read_cloud(dir.file("m.pcd"), std::nullopt, &stats);
  EXPECT_EQ(c.points.size(), 2u);
  EXPECT_EQ(stats.points_in_file, 3u);
  EXPECT_EQ(stats.non_finite, 1u);
}

TEST(ReadCloud, NpyFloat64AndWideRows) {
  ScratchDir dir;
  const std::vector<double> data = {1, 2, 3, 99, 4, 5, 6, 99};  // (2, 4): 4th column ignored
  write_npy(dir.file("d.npy"), data.data(), 2, 4);
  const PointCloud c = read_cloud(dir.file("d.npy"));
  ASSERT_EQ(c.points.size(), 2u);
  EXPECT_EQ(c.points[1], Eigen::Vector3f(4, 5, 6));
}

// ---- bad input: every error names the file and the problem ----

TEST(ReadCloudErrors, MissingFile) {
  expect_input_error([] { read_cloud("/no/such/cloud.pcd"); }, {"/no/such/cloud.pcd", "not found"});
}

TEST(ReadCloudErrors, UnknownExtension) {
  ScratchDir dir;
  write_text(dir.file("cloud.las"), "1 2 3\n");
  expect_input_error([&] { read_cloud(dir.file("cloud.las")); },
                     {"cloud.las", "unknown point cloud extension '.las'"});
  write_text(dir.file("noext"), "1 2 3\n");
  expect_input_error([&] { read_cloud(dir.file("noext")); }, {"noext", "unknown"});
}

TEST(ReadCloudErrors, Directory) {
  ScratchDir dir;
  std::filesystem::create_directory(dir.file("d.pcd"));
  expect_input_error([&] { read_cloud(dir.file("d.pcd")); }, {"d.pcd", "directory"});
}

TEST(ReadCloudErrors, EmptyFileInEveryFormat) {
  ScratchDir dir;
  for (const char* name : {"e.pcd", "e.ply", "e.xyz", "e.txt", "e.npy"}) {
    SCOPED_TRACE(name);
    write_text(dir.file(name), "");
    expect_input_error([&] { read_cloud(dir.file(name)); }, {name, "empty"});
  }
}

TEST(ReadCloudErrors, NoPoints) {
  ScratchDir dir;
  write_text(dir.file("c.xyz"), "# only a comment\n\n");
  expect_input_error([&] { read_cloud(dir.file("c.xyz")); }, {"c.xyz", "no points"});
  write_npy(dir.file("z.npy"), static_cast<const float*>(nullptr), 0, 3);
  expect_input_error([&] { read_cloud(dir.file("z.npy")); }, {"z.npy", "no points"});
  write_pcd(PointCloud{}, dir.file("z.pcd"));
  expect_input_error([&] { read_cloud(dir.file("z.pcd")); }, {"z.pcd"});
}

TEST(ReadCloudErrors, AllNaN) {
  ScratchDir dir;
  write_text(dir.file("n.xyz"), "nan nan nan\nnan 1 2\n");
  expect_input_error([&] { read_cloud(dir.file("n.xyz")); },
                     {"n.xyz", "all 2 points are non-finite"});
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const std::vector<float> data(9, nan);
  write_npy(dir.file("n.npy"), data.data(), 3, 3);
  expect_input_error([&] { read_cloud(dir.file("n.npy")); }, {"n.npy", "non-finite"});
  PointCloud c;
  c.points = {{nan, 0, 0}};
  write_pcd(c, dir.file("n.pcd"));
  expect_input_error([&] { read_cloud(dir.file("n.pcd")); }, {"n.pcd", "non-finite"});
}

TEST(ReadCloudErrors, TextGarbageNamedPcdOrPly) {
  ScratchDir dir;
  write_text(dir.file("g.pcd"), "this is not a point cloud\njust some words\n");
  expect_input_error([&] { read_cloud(dir.file("g.pcd")); }, {"g.pcd", "not a PCD file"});
  write_text(dir.file("g.ply"), "hello world\n");
  expect_input_error([&] { read_cloud(dir.file("g.ply")); }, {"g.ply", "not a PLY file"});
}

TEST(ReadCloudErrors, CorruptPcdAndPly) {
  ScratchDir dir;
  // Header promises 100 binary points, data has 2.
  write_text(
      dir.file("t.pcd"),
      "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 100\n"
      "HEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 100\nDATA binary\n012345678901234567890123");
  expect_input_error([&] { read_cloud(dir.file("t.pcd")); }, {"t.pcd", "promises 100 points"});
  // A lying header must not make the reader allocate what it promises (2e9 points = 24 GB).
  write_text(dir.file("huge.pcd"),
             "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 2000000000\n"
             "HEIGHT 1\nPOINTS 2000000000\nDATA binary\n0123");
  expect_input_error([&] { read_cloud(dir.file("huge.pcd")); }, {"huge.pcd", "truncated"});
  write_text(dir.file("huge.ply"),
             "ply\nformat binary_little_endian 1.0\nelement vertex 2000000000\nproperty float x\n"
             "property float y\nproperty float z\nend_header\n0123456789");
  expect_input_error([&] { read_cloud(dir.file("huge.ply")); }, {"huge.ply", "truncated"});
  // A PCD without x/y/z fields.
  write_text(dir.file("f.pcd"),
             "VERSION 0.7\nFIELDS a b c\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 1\n"
             "HEIGHT 1\nPOINTS 1\nDATA ascii\n1 2 3\n");
  expect_input_error([&] { read_cloud(dir.file("f.pcd")); }, {"f.pcd", "'x'"});
  write_text(dir.file("t.ply"),
             "ply\nformat binary_little_endian 1.0\nelement vertex 50\nproperty float x\n"
             "property float y\nproperty float z\nend_header\n0123456789");
  expect_input_error([&] { read_cloud(dir.file("t.ply")); }, {"t.ply", "promises 50 points"});
  // Ascii PLY with double coordinates reads fine.
  write_text(dir.file("a.ply"),
             "ply\nformat ascii 1.0\nelement vertex 2\nproperty double x\nproperty double y\n"
             "property double z\nend_header\n1 2 3\n4 5 6\n");
  EXPECT_EQ(read_cloud(dir.file("a.ply")).points.back(), Eigen::Vector3f(4, 5, 6));
}

// Counts and sizes beyond 2^53, fractional or written as exponents of nothing: each is named, in
// every header field that holds one (a PLY count of 6.7e54 once reached an undefined conversion).
TEST(ReadCloudErrors, HeaderCountsThatAreNotWholeNumbers) {
  ScratchDir dir;
  const std::vector<std::string> bad = {"6.66667e+54", "9007199254740993", "1e3", "2.5", "-3", "inf", "nan", "0x10", "+4"};
  for (const std::string& v : bad) {
    for (const char* format : {"ascii", "binary_little_endian"}) {
      write_text(dir.file("c.ply"), "ply\nformat " + std::string(format) + " 1.0\nelement vertex " +
                                        v + "\nproperty float x\nproperty float y\n"
                                            "property float z\nend_header\n1 2 3\n");
      expect_input_error([&] { read_cloud(dir.file("c.ply")); },
                         {"c.ply", "bad number '" + v + "'", "whole decimal numbers"});
    }
    // Every numeric PCD header entry: SIZE, COUNT, WIDTH, HEIGHT, POINTS.
    const std::vector<std::pair<std::string, std::string>> pcd_lines = {
        {"SIZE 4 4 4", "SIZE 4 " + v + " 4"}, {"COUNT 1 1 1", "COUNT 1 1 " + v},
        {"WIDTH 1", "WIDTH " + v},           {"HEIGHT 1", "HEIGHT " + v},
        {"POINTS 1", "POINTS " + v}};
    for (const auto& [good, hostile] : pcd_lines) {
      std::string text =
          "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 1\nHEIGHT 1\n"
          "POINTS 1\nDATA ascii\n1 2 3\n";
      text.replace(text.find(good), good.size(), hostile);
      write_text(dir.file("c.pcd"), text);
      expect_input_error([&] { read_cloud(dir.file("c.pcd")); },
                         {"c.pcd", "bad number '" + v + "'"});
    }
  }
}

TEST(ReadCloudErrors, BinaryOrMalformedText) {
  ScratchDir dir;
  write_text(dir.file("b.xyz"), std::string("\x93NUMPY\x01\x00\x00", 9));
  expect_input_error([&] { read_cloud(dir.file("b.xyz")); }, {"b.xyz", "binary"});
  write_text(dir.file("w.xyz"), "1 2 3\n4 five 6\n");
  expect_input_error([&] { read_cloud(dir.file("w.xyz")); }, {"w.xyz", "line 2"});
  write_text(dir.file("s.txt"), "1 2 3\n4 5\n");
  expect_input_error([&] { read_cloud(dir.file("s.txt")); }, {"s.txt", "line 2", "3 columns"});
}

TEST(ReadCloudErrors, NpyWrongDtypeShapeOrder) {
  ScratchDir dir;
  const std::vector<uint8_t> bytes(9, 1);
  write_npy(dir.file("u8.npy"), bytes.data(), 3, 3);
  expect_input_error([&] { read_cloud(dir.file("u8.npy")); }, {"u8.npy", "dtype '|u1'"});
  const std::vector<float> two(6, 1.0f);
  write_npy(dir.file("n2.npy"), two.data(), 3, 2);
  expect_input_error([&] { read_cloud(dir.file("n2.npy")); }, {"n2.npy", "shape (3, 2)"});

  // Hand-written headers: 1-D, big endian, truncated, text garbage.
  const auto npy_with = [&](const std::string& name, const std::string& dict, size_t payload) {
    std::string header = dict;
    while ((10 + header.size() + 1) % 64) header += ' ';
    header += '\n';
    std::string bytes("\x93NUMPY\x01\x00", 8);
    bytes += static_cast<char>(header.size() & 0xff);
    bytes += static_cast<char>(header.size() >> 8);
    bytes += header + std::string(payload, '\0');
    write_text(dir.file(name), bytes);
  };
  npy_with("one.npy", "{'descr': '<f4', 'fortran_order': False, 'shape': (6,), }", 24);
  expect_input_error([&] { read_cloud(dir.file("one.npy")); }, {"one.npy", "shape (6,)"});
  npy_with("be.npy", "{'descr': '>f4', 'fortran_order': False, 'shape': (2, 3), }", 24);
  expect_input_error([&] { read_cloud(dir.file("be.npy")); }, {"be.npy", "'>f4'"});
  npy_with("tr.npy", "{'descr': '<f4', 'fortran_order': False, 'shape': (1000, 3), }", 24);
  expect_input_error([&] { read_cloud(dir.file("tr.npy")); }, {"tr.npy", "truncated"});
  npy_with("bad.npy", "{'descr': '<f4', 'shape': (2, 3), }", 24);
  expect_input_error([&] { read_cloud(dir.file("bad.npy")); }, {"bad.npy", "malformed NPY header"});
  write_text(dir.file("txt.npy"), "1 2 3\n4 5 6\n");
  expect_input_error([&] { read_cloud(dir.file("txt.npy")); }, {"txt.npy", "not an NPY file"});
}

TEST(ReadCloudErrors, NonFiniteOriginArgument) {
  TERRASTRIDE_REQUIRE_SHARED_SCANS();
  expect_input_error(
      [] {
        read_cloud(scan("octomap/scan.xyz"),
                   Eigen::Vector3d(0, std::numeric_limits<double>::quiet_NaN(), 0));
      },
      {"scan.xyz", "origin"});
}

// ---- strict readers: a body that disagrees with its header is an error ----
//
// PCL reads an unparsable ASCII value as 0 (PCD) or NaN (PLY), skips PCD lines with the wrong
// number of values, and ignores points beyond the header's count. Each case below used to give a
// wrong cloud (or a vague "PCL reader failed") without a word.

// A 10-line ASCII PCD header with x y z float fields: body line k is file line 10 + k.
std::string ascii_pcd(size_t points, const std::string& body) {
  const std::string n = std::to_string(points);
  return "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\n"
         "TYPE F F F\nCOUNT 1 1 1\nWIDTH " +
         n + "\nHEIGHT 1\nPOINTS " + n + "\nDATA ascii\n" + body;
}

// A 7-line ASCII PLY header with float x y z: body line k is file line 7 + k.
std::string ascii_ply(size_t points, const std::string& body) {
  return "ply\nformat ascii 1.0\nelement vertex " + std::to_string(points) +
         "\nproperty float x\nproperty float y\nproperty float z\nend_header\n" + body;
}

std::string float_bytes(const std::vector<float>& v) {
  return std::string(reinterpret_cast<const char*>(v.data()), v.size() * sizeof(float));
}

TEST(StrictCloudReaders, PcdNonNumericValueNamesLineAndField) {
  ScratchDir dir;
  write_text(dir.file("abc.pcd"), ascii_pcd(3, "1 2 3\n5 abc 0\n4 5 6\n"));
  expect_input_error([&] { read_cloud(dir.file("abc.pcd")); },
                     {"abc.pcd", "line 12", "field 'y'", "'abc' is not a number"});
  // A number followed by garbage: PCL would read its numeric prefix.
  write_text(dir.file("pre.pcd"), ascii_pcd(2, "1 2 3\n4 5 6.5cm\n"));
  expect_input_error([&] { read_cloud(dir.file("pre.pcd")); },
                     {"pre.pcd", "line 12", "field 'z'", "'6.5cm'"});
}

TEST(StrictCloudReaders, PcdPointCountMustMatchTheData) {
  ScratchDir dir;
  // More points than declared: PCL stops after POINTS and drops the rest.
  write_text(dir.file("more.pcd"), ascii_pcd(2, "1 2 3\n4 5 6\n7 8 9\n10 11 12\n\n"));
  expect_input_error([&] { read_cloud(dir.file("more.pcd")); },
                     {"more.pcd", "header says 2 points", "2 more line(s)", "from line 13"});
  // Fewer: the data ends early.
  write_text(dir.file("less.pcd"), ascii_pcd(5, "1 2 3\n4 5 6\n7 8 9\n"));
  expect_input_error([&] { read_cloud(dir.file("less.pcd")); },
                     {"less.pcd", "header says 5 points, data ends after 3", "line 13"});
  // A huge count with a tiny body is refused without allocating what the header promises.
  write_text(dir.file("huge.pcd"), ascii_pcd(2000000000, "1 2 3\n"));
  expect_input_error([&] { read_cloud(dir.file("huge.pcd")); },
                     {"huge.pcd", "header says 2000000000 points, data ends after 1"});
  // WIDTH x HEIGHT must be POINTS.
  std::string text = ascii_pcd(3, "1 2 3\n4 5 6\n7 8 9\n");
  text.replace(text.find("POINTS 3"), 8, "POINTS 4");
  write_text(dir.file("wh.pcd"), text);
  expect_input_error([&] { read_cloud(dir.file("wh.pcd")); },
                     {"wh.pcd", "WIDTH 3 x HEIGHT 1 is not POINTS 4"});
}

TEST(StrictCloudReaders, PcdLineWithWrongValueCountIsNamed) {
  ScratchDir dir;
  // PCL skipped such a line and took the next one as the point ("1 1 1" here).
  write_text(dir.file("skip.pcd"), ascii_pcd(3, "1 2 3\n4 5\n7 8 9\n1 1 1\n"));
  expect_input_error([&] { read_cloud(dir.file("skip.pcd")); },
                     {"skip.pcd", "line 12", "expected 3 values (x y z), found 2"});
  // Truncated in the middle of a line: said so instead of "PCL reader failed".
  write_text(dir.file("cut.pcd"), ascii_pcd(3, "1 2 3\n4 5 6\n7.2"));
  expect_input_error([&] { read_cloud(dir.file("cut.pcd")); },
                     {"cut.pcd", "line 13", "expected 3 values (x y z), found 1", "truncated"});
  // Commas are not PCD separators.
  write_text(dir.file("csv.pcd"), ascii_pcd(1, "1,2,3\n"));
  expect_input_error([&] { read_cloud(dir.file("csv.pcd")); }, {"csv.pcd", "line 11", "found 1"});
}

TEST(StrictCloudReaders, PcdHeaderInconsistencyIsNamed) {
  ScratchDir dir;
  std::string text = ascii_pcd(1, "1 2 3\n");
  text.replace(text.find("SIZE 4 4 4"), 10, "SIZE 4 4");
  write_text(dir.file("size.pcd"), text);
  expect_input_error([&] { read_cloud(dir.file("size.pcd")); },
                     {"size.pcd", "3 FIELDS but 2 SIZE entries"});
  text = ascii_pcd(1, "1 2 3\n");
  text.replace(text.find("DATA ascii"), 10, "DATA text");
  write_text(dir.file("data.pcd"), text);
  expect_input_error([&] { read_cloud(dir.file("data.pcd")); },
                     {"data.pcd", "DATA 'text' is not ascii, binary or binary_compressed"});
}

TEST(StrictCloudReaders, RealWorldAsciiPcdStillReads) {
  ScratchDir dir;
  // An organised 2 x 2 cloud as PCL writes it: extra fields (intensity, packed rgb, a COUNT 2
  // field), NaN points, CRLF line ends, a header comment, blank lines at the end.
  write_text(dir.file("org.pcd"),
             "# .PCD v0.7 - Point Cloud Data file format\r\nVERSION 0.7\r\n"
             "FIELDS x y z intensity rgb ring\r\nSIZE 4 4 4 4 4 2\r\nTYPE F F F F F U\r\n"
             "COUNT 1 1 1 1 1 2\r\nWIDTH 2\r\nHEIGHT 2\r\nVIEWPOINT 0 0 0 1 0 0 0\r\n"
             "POINTS 4\r\nDATA ascii\r\n"
             "1 2 3 0.5 4.2108e+06 7 8\r\n"
             "nan nan nan 0 0 0 0\r\n"
             "-4.5 +5 6e-1 12 1.1e-38 1 2\r\n"
             "NaN NaN NaN 0 0 0 0\r\n\r\n\r\n");
  ReadStats stats;
  const PointCloud c = read_cloud(dir.file("org.pcd"), std::nullopt, &stats);
  ASSERT_EQ(c.points.size(), 2u);
  EXPECT_EQ(stats.non_finite, 2u);
  EXPECT_EQ(c.points[0], Eigen::Vector3f(1, 2, 3));
  EXPECT_EQ(c.points[1], Eigen::Vector3f(-4.5f, 5, 0.6f));
  // No final newline after the last point (the old size estimate refused this).
  write_text(dir.file("nonl.pcd"), ascii_pcd(3, "1 2 3\n4 5 6\n7 8 9"));
  EXPECT_EQ(read_cloud(dir.file("nonl.pcd")).points.back(), Eigen::Vector3f(7, 8, 9));
}

TEST(StrictCloudReaders, BinaryPcdLongerThanItsHeader) {
  ScratchDir dir;
  const std::string header =
      "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 2\nHEIGHT 1\n"
      "POINTS 2\nDATA binary\n";
  // Three points of data under a header that says two: the third would be dropped.
  write_text(dir.file("more.pcd"), header + float_bytes({1, 2, 3, 4, 5, 6, 7, 8, 9}));
  expect_input_error([&] { read_cloud(dir.file("more.pcd")); },
                     {"more.pcd", "header says 2 points", "12 more bytes", "room for 1 more"});
  // Zero padding after the data, as old PCL versions wrote (the real grid_map sample has it),
  // and a stray final newline are fine.
  write_text(dir.file("pad.pcd"),
             header + float_bytes({1, 2, 3, 4, 5, 6}) + std::string(4096, '\0'));
  EXPECT_EQ(read_cloud(dir.file("pad.pcd")).points.size(), 2u);
  write_text(dir.file("nl.pcd"), header + float_bytes({1, 2, 3, 4, 5, 6}) + "\n");
  EXPECT_EQ(read_cloud(dir.file("nl.pcd")).points.size(), 2u);
}

TEST(StrictCloudReaders, CompressedPcdSizesMustMatchTheHeader) {
  ScratchDir dir;
  const auto u32 = [](uint32_t v) { return std::string(reinterpret_cast<const char*>(&v), 4); };
  const auto pcd = [&](size_t points, const std::vector<float>& soa) {
    // LZF: a control byte c < 32 is a literal run of c + 1 bytes. binary_compressed stores the
    // fields one after the other (all x, then all y, then all z).
    const std::string raw = float_bytes(soa);
    const std::string lzf = std::string(1, static_cast<char>(raw.size() - 1)) + raw;
    const std::string n = std::to_string(points);
    return "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH " + n +
           "\nHEIGHT 1\nPOINTS " + n + "\nDATA binary_compressed\n" + u32(lzf.size()) +
           u32(raw.size()) + lzf;
  };
  write_text(dir.file("ok.pcd"), pcd(2, {1, 4, 2, 5, 3, 6}));
  const PointCloud c = read_cloud(dir.file("ok.pcd"));
  ASSERT_EQ(c.points.size(), 2u);
  EXPECT_EQ(c.points[1], Eigen::Vector3f(4, 5, 6));
  // The compressed block holds 3 points, the header says 2.
  write_text(dir.file("more.pcd"), pcd(2, {1, 4, 7, 2, 5, 8, 3, 6, 9}));
  expect_input_error(
      [&] { read_cloud(dir.file("more.pcd")); },
      {"more.pcd", "header says 2 points (24 bytes)", "unpacks to 36 bytes (3 points)"});
  std::string cut = pcd(2, {1, 4, 2, 5, 3, 6});
  cut.resize(cut.size() - 5);
  write_text(dir.file("cut.pcd"), cut);
  expect_input_error([&] { read_cloud(dir.file("cut.pcd")); }, {"cut.pcd", "truncated"});
}

TEST(StrictCloudReaders, PlyNonNumericValueNamesLineAndProperty) {
  ScratchDir dir;
  // PCL read 'abc' as NaN, so the point vanished as "non-finite".
  write_text(dir.file("abc.ply"), ascii_ply(3, "1 2 3\n5 abc 0\n4 5 6\n"));
  expect_input_error(
      [&] { read_cloud(dir.file("abc.ply")); },
      {"abc.ply", "line 9", "point 2 of 3", "property 'y'", "'abc' is not a number"});
}

TEST(StrictCloudReaders, PlyVertexCountMustMatchTheData) {
  ScratchDir dir;
  write_text(dir.file("more.ply"), ascii_ply(3, "1 2 3\n4 5 6\n7 8 9\n1 1 1\n\n"));
  expect_input_error([&] { read_cloud(dir.file("more.ply")); },
                     {"more.ply", "header says 3 points", "1 more line(s)", "from line 11"});
  write_text(dir.file("less.ply"), ascii_ply(5, "1 2 3\n4 5 6\n7 8 9\n"));
  expect_input_error([&] { read_cloud(dir.file("less.ply")); },
                     {"less.ply", "header says 5 points, data ends after 3"});
  write_text(dir.file("short.ply"), ascii_ply(3, "1 2 3\n4 5\n7 8 9\n"));
  expect_input_error([&] { read_cloud(dir.file("short.ply")); },
                     {"short.ply", "line 9", "point 2 of 3", "expected 3 values, found 2"});
  // A blank line inside the data is a missing point, not a separator.
  write_text(dir.file("blank.ply"), ascii_ply(3, "1 2 3\n\n4 5 6\n7 8 9\n"));
  expect_input_error([&] { read_cloud(dir.file("blank.ply")); },
                     {"blank.ply", "line 9", "expected 3 values, found 0"});
}

TEST(StrictCloudReaders, PlyWithFacesCommentsAndCrlfStillReads) {
  ScratchDir dir;
  const std::string header =
      "ply\r\nformat ascii 1.0\r\ncomment made by hand\r\nelement vertex 3\r\n"
      "property float x\r\nproperty float y\r\nproperty float z\r\nproperty uchar red\r\n"
      "element face 1\r\nproperty list uchar int vertex_indices\r\nend_header\r\n";
  write_text(dir.file("mesh.ply"), header + "1 2 3 255\r\n4 5 6 0\r\n7 8 9 12\r\n3 0 1 2\r\n\r\n");
  const PointCloud c = read_cloud(dir.file("mesh.ply"));
  ASSERT_EQ(c.points.size(), 3u);
  EXPECT_EQ(c.points[2], Eigen::Vector3f(7, 8, 9));
  // No final newline (the old size estimate refused this).
  write_text(dir.file("nonl.ply"), ascii_ply(3, "1 2 3\n4 5 6\n7 8 9"));
  EXPECT_EQ(read_cloud(dir.file("nonl.ply")).points.size(), 3u);
  // A face list with a bad length or too few indices.
  write_text(dir.file("face.ply"), header + "1 2 3 255\r\n4 5 6 0\r\n7 8 9 12\r\nx 0 1 2\r\n");
  expect_input_error([&] { read_cloud(dir.file("face.ply")); },
                     {"face.ply", "line 15", "'face' 1 of 1", "length 'x'"});
  write_text(dir.file("face2.ply"), header + "1 2 3 255\r\n4 5 6 0\r\n7 8 9 12\r\n3 0 1\r\n");
  expect_input_error([&] { read_cloud(dir.file("face2.ply")); },
                     {"face2.ply", "line 15", "expected 4 values, found 3"});
}

TEST(StrictCloudReaders, BinaryPlyLongerThanItsHeader) {
  ScratchDir dir;
  const std::string header =
      "ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty float x\n"
      "property float y\nproperty float z\nend_header\n";
  write_text(dir.file("more.ply"), header + float_bytes({1, 2, 3, 4, 5, 6, 7, 8, 9}));
  expect_input_error([&] { read_cloud(dir.file("more.ply")); },
                     {"more.ply", "header says 2 points", "12 more bytes"});
  write_text(dir.file("ok.ply"), header + float_bytes({1, 2, 3, 4, 5, 6}));
  EXPECT_EQ(read_cloud(dir.file("ok.ply")).points.back(), Eigen::Vector3f(4, 5, 6));
}

TEST(StrictCloudReaders, XyzNamesTheColumnAndKeepsTinyValues) {
  ScratchDir dir;
  write_text(dir.file("w.xyz"), "1 2 3\n4 five 6\n");
  expect_input_error([&] { read_cloud(dir.file("w.xyz")); },
                     {"w.xyz", "line 2", "column 2 (y)", "'five' is not a number"});
  write_text(dir.file("pm.xyz"), "+-1 2 3\n");
  expect_input_error([&] { read_cloud(dir.file("pm.xyz")); },
                     {"pm.xyz", "line 1", "column 1 (x)", "'+-1'"});
  // Below float's range is zero, not "non-finite" (from_chars<float> calls it out of range).
  write_text(dir.file("tiny.xyz"), "1 2 1e-50\n4 5 -3e-300\n");
  ReadStats stats;
  const PointCloud c = read_cloud(dir.file("tiny.xyz"), std::nullopt, &stats);
  ASSERT_EQ(c.points.size(), 2u);
  EXPECT_EQ(stats.non_finite, 0u);
  EXPECT_EQ(c.points[0].z(), 0.0f);
  EXPECT_EQ(c.points[1].z(), 0.0f);
}

// Writes an NPY v1 file with the given header dict and payload.
void write_raw_npy(const std::string& path, const std::string& dict, const std::string& payload) {
  std::string header = dict;
  while ((10 + header.size() + 1) % 64) header += ' ';
  header += '\n';
  std::string bytes("\x93NUMPY\x01\x00", 8);
  bytes += static_cast<char>(header.size() & 0xff);
  bytes += static_cast<char>(header.size() >> 8);
  write_text(path, bytes + header + payload);
}

TEST(StrictCloudReaders, NpyTransposedShapeIsRefused) {
  ScratchDir dir;
  // Five points stored as rows x, y, z: read as (N, >=3) this made 3 points of the first columns.
  const std::vector<float> xyz_rows = {1, 2, 3, 4, 5, 10, 20, 30, 40, 50, 7, 7, 7, 7, 7};
  write_npy(dir.file("t.npy"), xyz_rows.data(), 3, 5);
  expect_input_error([&] { read_cloud(dir.file("t.npy")); },
                     {"t.npy", "shape (3, 5)", "more columns than rows", "transpose"});
  write_npy(dir.file("t4.npy"), xyz_rows.data(), 3, 4);
  expect_input_error([&] { read_cloud(dir.file("t4.npy")); }, {"t4.npy", "shape (3, 4)"});
  // (3, 3) is three points; (N, 4) is N points with an extra column.
  write_npy(dir.file("sq.npy"), xyz_rows.data(), 3, 3);
  EXPECT_EQ(read_cloud(dir.file("sq.npy")).points.size(), 3u);
}

TEST(StrictCloudReaders, NpyFortranOrderIsReadAsRows) {
  ScratchDir dir;
  // np.save(path, a.T) of a (3, 2) C array writes shape (2, 3) in Fortran order: column by
  // column, i.e. x0 x1 y0 y1 z0 z1.
  write_raw_npy(dir.file("f.npy"), "{'descr': '<f4', 'fortran_order': True, 'shape': (2, 3), }",
                float_bytes({1, 4, 2, 5, 3, 6}));
  const PointCloud c = read_cloud(dir.file("f.npy"));
  ASSERT_EQ(c.points.size(), 2u);
  EXPECT_EQ(c.points[0], Eigen::Vector3f(1, 2, 3));
  EXPECT_EQ(c.points[1], Eigen::Vector3f(4, 5, 6));
}

TEST(StrictCloudReaders, NpyStructuredDtypeAndTrailingDataAreRefused) {
  ScratchDir dir;
  write_raw_npy(dir.file("s.npy"),
                "{'descr': [('x', '<f4'), ('y', '<f4'), ('z', '<f4')], 'fortran_order': False, "
                "'shape': (2,), }",
                float_bytes({1, 2, 3, 4, 5, 6}));
  expect_input_error([&] { read_cloud(dir.file("s.npy")); }, {"s.npy", "structured dtype"});
  // Two points of data, but the header's shape says one: the second would be lost.
  write_raw_npy(dir.file("x.npy"), "{'descr': '<f4', 'fortran_order': False, 'shape': (1, 3), }",
                float_bytes({1, 2, 3, 4, 5, 6}));
  expect_input_error([&] { read_cloud(dir.file("x.npy")); },
                     {"x.npy", "12 bytes after the data", "(12 bytes)"});
  // Integer coordinates and half floats are not clouds.
  write_raw_npy(dir.file("i.npy"), "{'descr': '<i4', 'fortran_order': False, 'shape': (1, 3), }",
                std::string(12, '\0'));
  expect_input_error([&] { read_cloud(dir.file("i.npy")); }, {"i.npy", "dtype '<i4'"});
  write_raw_npy(dir.file("h.npy"), "{'descr': '<f2', 'fortran_order': False, 'shape': (1, 3), }",
                std::string(6, '\0'));
  expect_input_error([&] { read_cloud(dir.file("h.npy")); }, {"h.npy", "'<f2'"});
}

}  // namespace
}  // namespace terrastride::perception
