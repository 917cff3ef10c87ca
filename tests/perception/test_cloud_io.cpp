// Reading the real scans in every supported format, the PCD round trip, and bad input.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
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
  for (size_t i = 0; i < c.points.size(); ++i) EXPECT_EQ(back.points[i], c.points[i]);
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
  ScratchDir dir;
  const PointCloud c =
      read_cloud(scan("terrain_understanding_mit/curb_w_grass.npy"), Eigen::Vector3d(0, 0, 0.1));
  write_pcd(c, dir.file("curb.pcd"));
  const PointCloud back = read_cloud(dir.file("curb.pcd"));
  EXPECT_EQ(back.points, c.points);
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

  // Hand-written headers: fortran order, 1-D, big endian, text garbage.
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
  npy_with("f.npy", "{'descr': '<f4', 'fortran_order': True, 'shape': (2, 3), }", 24);
  expect_input_error([&] { read_cloud(dir.file("f.npy")); }, {"f.npy", "Fortran order"});
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
  expect_input_error(
      [] {
        read_cloud(scan("octomap/scan.xyz"),
                   Eigen::Vector3d(0, std::numeric_limits<double>::quiet_NaN(), 0));
      },
      {"scan.xyz", "origin"});
}

}  // namespace
}  // namespace terrastride::perception
