// Sensor poses of cloud files: the pose strings and poses files, a PCD's VIEWPOINT as PCL means
// it (the points in the sensor frame, world = R p + t), the writer's round trip through a sensor
// frame, and the dominant plane that stands in for gravity when no pose is given.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <limits>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "terrastride/perception/cloud_io.hpp"
#include "terrastride/perception/sensor_pose.hpp"
#include "terrastride/perception/support_plane.hpp"
#include "test_util.hpp"

namespace terrastride::perception {
namespace {

using test::expect_input_error;
using test::ScratchDir;
using test::write_text;

TEST(SensorPose, ParsesRosOrderAndRefusesBadValues) {
  const SensorPose p = parse_sensor_pose("1,2,3,0,0,0.7071068,0.7071068", "--sensor-pose");
  EXPECT_EQ(p.position, Eigen::Vector3d(1, 2, 3));
  // A quarter turn about z: x -> y.
  EXPECT_TRUE((p.orientation * Eigen::Vector3d::UnitX()).isApprox(Eigen::Vector3d::UnitY(), 1e-6));
  EXPECT_NEAR(p.orientation.norm(), 1.0, 1e-15);  // normalised within the tolerance
  EXPECT_NO_THROW(parse_sensor_pose("1 2 3 0 0 0 1", "x"));
  expect_input_error([] { parse_sensor_pose("1,2,3,0,0,1", "--sensor-pose"); },
                     {"--sensor-pose", "expected 7 numbers", "got 6"});
  expect_input_error([] { parse_sensor_pose("1,2,3,0,0,0,1,5", "--sensor-pose"); },
                     {"--sensor-pose", "got 8"});
  expect_input_error([] { parse_sensor_pose("1,2,nan,0,0,0,1", "--sensor-pose"); },
                     {"--sensor-pose", "'nan' is not a finite number"});
  expect_input_error([] { parse_sensor_pose("1,2,3,0,0,0,1m", "--sensor-pose"); },
                     {"--sensor-pose", "'1m'"});
  expect_input_error([] { parse_sensor_pose("1,2,3,0,0,0,0", "--sensor-pose"); },
                     {"--sensor-pose", "quaternion is zero"});
  // Euler angles typed where a quaternion belongs.
  expect_input_error([] { parse_sensor_pose("0,0,0,0,0.7,0,1", "--sensor-pose"); },
                     {"--sensor-pose", "norm 1.22", "QX,QY,QZ,QW"});
  expect_input_error([] { parse_sensor_pose("", "--sensor-pose"); }, {"got 0"});
}

TEST(SensorPose, TransformDropsPointsThatLeaveFloatRange) {
  std::vector<Eigen::Vector3f> pts = {{1, 0, 0}, {3e38f, 3e38f, 0}};
  SensorPose pose;
  pose.position = Eigen::Vector3d(0, 0, 1);
  pose.orientation = Eigen::AngleAxisd(M_PI / 4, Eigen::Vector3d::UnitZ());
  EXPECT_EQ(transform_points(pts, pose), 1u);  // 4.2e38 along y is beyond float
  ASSERT_EQ(pts.size(), 1u);
  EXPECT_TRUE(pts[0].isApprox(Eigen::Vector3f(0.70710678f, 0.70710678f, 1), 1e-6f));
}

TEST(SensorPose, OpticalFrameFollowsRep103) {
  const Eigen::Quaterniond q = optical_in_body();
  // Optical z (depth) is the body's x (forward), optical x (right) is -y, optical y (down) -z.
  EXPECT_TRUE((q * Eigen::Vector3d::UnitZ()).isApprox(Eigen::Vector3d::UnitX(), 1e-12));
  EXPECT_TRUE((q * Eigen::Vector3d::UnitX()).isApprox(-Eigen::Vector3d::UnitY(), 1e-12));
  EXPECT_TRUE((q * Eigen::Vector3d::UnitY()).isApprox(-Eigen::Vector3d::UnitZ(), 1e-12));
}

TEST(PosesFile, ReadsLinesAndNamesTheBadOne) {
  ScratchDir dir;
  write_text(dir.file("poses.txt"),
             "# camera poses\n\n"
             "a.pcd 1 2 3 0 0 0 1   # first\n"
             "/abs/b.xyz, 0, 0, 1, 0, 0, 0.7071068, 0.7071068\n");
  const auto lines = read_poses_file(dir.file("poses.txt"));
  ASSERT_EQ(lines.size(), 2u);
  EXPECT_EQ(lines[0].path, "a.pcd");
  EXPECT_EQ(lines[0].line, 3u);
  EXPECT_EQ(lines[0].resolved, std::filesystem::weakly_canonical(dir.file("a.pcd")).string());
  EXPECT_EQ(lines[1].resolved, "/abs/b.xyz");
  EXPECT_EQ(lines[1].pose.position, Eigen::Vector3d(0, 0, 1));

  write_text(dir.file("short.txt"), "a.pcd 1 2 3 0 0 0 1\nb.pcd 1 2 3 0 0 1\n");
  expect_input_error([&] { read_poses_file(dir.file("short.txt")); },
                     {"short.txt: line 2", "expected a path and 7 numbers", "got 6"});
  write_text(dir.file("nan.txt"), "a.pcd 1 2 3 0 0 0 1\n\nb.pcd 1 nan 3 0 0 0 1\n");
  expect_input_error([&] { read_poses_file(dir.file("nan.txt")); }, {"nan.txt: line 3", "'nan'"});
  write_text(dir.file("quat.txt"), "a.pcd 1 2 3 0 0 0 2\n");
  expect_input_error([&] { read_poses_file(dir.file("quat.txt")); },
                     {"quat.txt: line 1", "norm 2"});
  write_text(dir.file("dup.txt"), "a.pcd 1 2 3 0 0 0 1\n./a.pcd 1 2 3 0 0 0 1\n");
  expect_input_error([&] { read_poses_file(dir.file("dup.txt")); },
                     {"dup.txt: line 2", "already has a pose on line 1"});
  write_text(dir.file("empty.txt"), "# nothing\n");
  expect_input_error([&] { read_poses_file(dir.file("empty.txt")); }, {"names no cloud"});
  expect_input_error([&] { read_poses_file(dir.file("missing.txt")); },
                     {"missing.txt", "cannot open"});
}

// A PCD with the given VIEWPOINT line and points, in ASCII.
std::string ascii_pcd(const std::string& viewpoint, const std::vector<Eigen::Vector3f>& points,
                      bool marker = false) {
  std::ostringstream os;
  os << "# .PCD v0.7\n";
  if (marker)
    os << "# terrastride: points in the sensor frame, VIEWPOINT = its pose (world = R p + t)\n";
  os << "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH " << points.size()
     << "\nHEIGHT 1\nVIEWPOINT " << viewpoint << "\nPOINTS " << points.size() << "\nDATA ascii\n";
  for (const auto& p : points) os << p.x() << " " << p.y() << " " << p.z() << "\n";
  return os.str();
}

TEST(Viewpoint, RotationIsAppliedAsPclMeansIt) {
  ScratchDir dir;
  // A camera 1 m up, its optical frame: a point 2 m ahead (optical z) is 2 m along world x.
  const Eigen::Quaterniond q = optical_in_body();
  std::ostringstream vp;
  vp << "0 0 1 " << q.w() << " " << q.x() << " " << q.y() << " " << q.z();
  write_text(dir.file("cam.pcd"), ascii_pcd(vp.str(), {{0, 0, 2}, {0, 0.5f, 2}}, true));
  const PointCloud c = read_cloud(dir.file("cam.pcd"));
  ASSERT_EQ(c.points.size(), 2u);
  EXPECT_TRUE(c.points[0].isApprox(Eigen::Vector3f(2, 0, 1), 1e-6f)) << c.points[0].transpose();
  // Optical y is down.
  EXPECT_TRUE(c.points[1].isApprox(Eigen::Vector3f(2, 0, 0.5f), 1e-6f)) << c.points[1].transpose();
  ASSERT_TRUE(c.sensor_origin);
  EXPECT_EQ(*c.sensor_origin, Eigen::Vector3d(0, 0, 1));
  // Without the marker, read_cloud returns the points as written; the pose is the VIEWPOINT.
  write_text(dir.file("plain.pcd"), ascii_pcd(vp.str(), {{0, 0, 2}}));
  const CloudFileRead plain = read_cloud_file(dir.file("plain.pcd"));
  EXPECT_FALSE(plain.viewpoint_marked);
  const auto sensor = file_sensor(plain, "plain.pcd", ViewpointUse::kDefault);
  ASSERT_TRUE(sensor);
  EXPECT_TRUE(sensor->rotation_known);
  EXPECT_TRUE(sensor->pose.orientation.isApprox(q, 1e-6));
  EXPECT_EQ(read_cloud(dir.file("plain.pcd")).points[0], Eigen::Vector3f(0, 0, 2));
  // A VIEWPOINT quaternion that is not a rotation is refused, naming it.
  write_text(dir.file("bad.pcd"), ascii_pcd("0 0 1 2 0 0 0", {{0, 0, 2}}));
  expect_input_error([&] { read_cloud(dir.file("bad.pcd")); }, {"bad.pcd: VIEWPOINT", "norm 2"});
}

TEST(Viewpoint, PositionWithoutRotationIsAmbiguousUnlessMarked) {
  ScratchDir dir;
  // What the writer of earlier versions wrote: world-frame points, the sensor position.
  write_text(dir.file("old.pcd"), ascii_pcd("-1 0 0.8 1 0 0 0", {{1, 0, 0}}));
  const CloudFileRead file = read_cloud_file(dir.file("old.pcd"));
  expect_input_error(
      [&] { file_sensor(file, "old.pcd", ViewpointUse::kDefault); },
      {"old.pcd", "VIEWPOINT -1 0 0.8 1 0 0 0", "--viewpoint origin", "--viewpoint pose"});
  const auto as_position = file_sensor(file, "old.pcd", ViewpointUse::kPosition);
  ASSERT_TRUE(as_position);
  EXPECT_FALSE(as_position->rotation_known);
  EXPECT_TRUE(as_position->pose.position.isApprox(Eigen::Vector3d(-1, 0, 0.8), 1e-7));
  const auto as_pose = file_sensor(file, "old.pcd", ViewpointUse::kPose);
  ASSERT_TRUE(as_pose);
  EXPECT_TRUE(as_pose->rotation_known);
  // Marked by the writer: a pose, whatever its rotation.
  write_text(dir.file("new.pcd"), ascii_pcd("-1 0 0.8 1 0 0 0", {{2, 0, -0.8f}}, true));
  const PointCloud c = read_cloud(dir.file("new.pcd"));
  EXPECT_TRUE(c.points[0].isApprox(Eigen::Vector3f(1, 0, 0), 1e-6f));
  // World-frame points with a rotated VIEWPOINT, read as a position: the rotation is not applied.
  write_text(dir.file("rot.pcd"), ascii_pcd("0 0 1 0 1 0 0", {{1, 0, 0}}));
  const auto rot =
      file_sensor(read_cloud_file(dir.file("rot.pcd")), "rot.pcd", ViewpointUse::kPosition);
  ASSERT_TRUE(rot);
  EXPECT_FALSE(rot->rotation_known);
  EXPECT_EQ(rot->pose.position, Eigen::Vector3d(0, 0, 1));
}

TEST(WritePcd, SensorFrameRoundTrip) {
  ScratchDir dir;
  PointCloud world;
  world.points = {{2, 0.5f, 0}, {1.5f, -0.25f, 0.1f}, {3, 1, 0.4f}};
  world.sensor_origin = Eigen::Vector3d(-1, 0.2, 0.8);
  SensorPose frame;
  frame.position = *world.sensor_origin;
  frame.orientation = Eigen::AngleAxisd(0.7, Eigen::Vector3d::UnitY()) * optical_in_body();
  write_pcd(world, dir.file("s.pcd"), &frame);
  // The file holds sensor-frame points and the pose...
  const CloudFileRead file = read_cloud_file(dir.file("s.pcd"));
  ASSERT_TRUE(file.viewpoint);
  EXPECT_TRUE(file.viewpoint_marked);
  EXPECT_TRUE(file.viewpoint->orientation.isApprox(frame.orientation, 1e-6));
  const Eigen::Vector3d local =
      frame.orientation.inverse() * (world.points[0].cast<double>() - frame.position);
  EXPECT_TRUE(file.points[0].cast<double>().isApprox(local, 1e-6));
  // ...and reads back as the world-frame cloud, within float rounding.
  const PointCloud back = read_cloud(dir.file("s.pcd"));
  ASSERT_EQ(back.points.size(), world.points.size());
  for (size_t i = 0; i < world.points.size(); ++i)
    EXPECT_LT((back.points[i] - world.points[i]).norm(), 2e-6f) << i;
}

// Points on a plane through `origin` with normal `n`, a 2 m square every 2 cm.
std::vector<Eigen::Vector3f> plane_points(const Eigen::Vector3d& n, const Eigen::Vector3d& origin) {
  const Eigen::Vector3d u = n.unitOrthogonal(), v = n.cross(u).normalized();
  std::vector<Eigen::Vector3f> pts;
  for (int i = -50; i < 50; ++i)
    for (int j = -50; j < 50; ++j)
      pts.push_back((origin + 0.02 * i * u + 0.02 * j * v).cast<float>());
  return pts;
}

TEST(SupportPlane, TiltAndSensorSideOfTheDominantPlane) {
  const double deg = M_PI / 180;
  // A floor seen from 0.8 m above, as a camera pitched 31 deg sees it in its own frame.
  const Eigen::Vector3d n(std::sin(31 * deg), 0, std::cos(31 * deg));
  auto pts = plane_points(n, -0.8 * n);
  // Clutter: a box of random points, fewer than the plane's.
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(-1, 1);
  for (int i = 0; i < 800; ++i) pts.emplace_back(u(rng), u(rng), u(rng));
  SupportPlane p = estimate_support_plane(pts, Eigen::Vector3d::Zero());
  ASSERT_TRUE(p.found) << p.problem;
  EXPECT_NEAR(p.tilt_deg, 31.0, 0.5);
  EXPECT_NEAR(p.sensor_height, 0.8, 0.01);
  EXPECT_FALSE(p.sensor_in_plane);
  EXPECT_GT(p.inlier_share, 0.5);
  EXPECT_NEAR(p.normal().norm(), 1.0, 1e-9);
  EXPECT_NEAR(p.coefficients.head<3>().dot(-0.8 * n) + p.coefficients[3], 0.0, 0.01);
  // The same plane seen from below: the normal turns to the sensor, past 90 deg.
  p = estimate_support_plane(pts, -2.0 * n);
  ASSERT_TRUE(p.found);
  EXPECT_NEAR(p.tilt_deg, 180.0 - 31.0, 0.5);
  EXPECT_NEAR(p.sensor_height, 1.2, 0.01);
  // The sensor in the plane: the normal is taken upwards.
  p = estimate_support_plane(pts, -0.8 * n);
  ASSERT_TRUE(p.found);
  EXPECT_TRUE(p.sensor_in_plane);
  EXPECT_NEAR(p.tilt_deg, 31.0, 0.5);
}

TEST(SupportPlane, NoDominantPlaneIsAnOutcomeNotAnError) {
  std::vector<Eigen::Vector3f> few = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
  SupportPlane p = estimate_support_plane(few, Eigen::Vector3d(0, 0, 1));
  EXPECT_FALSE(p.found);
  EXPECT_NE(p.problem.find("too few points"), std::string::npos) << p.problem;
  // A cube of random points holds no plane.
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(-2, 2);
  std::vector<Eigen::Vector3f> cube;
  for (int i = 0; i < 20000; ++i) cube.emplace_back(u(rng), u(rng), u(rng));
  p = estimate_support_plane(cube, Eigen::Vector3d(0, 0, 5));
  EXPECT_FALSE(p.found);
  EXPECT_NE(p.problem.find("no dominant plane"), std::string::npos) << p.problem;
  EXPECT_THROW(estimate_support_plane(cube, Eigen::Vector3d(0, 0, NAN)), InputError);
  std::vector<Eigen::Vector3f> none;
  EXPECT_FALSE(estimate_support_plane(none, Eigen::Vector3d::Zero()).found);
}

}  // namespace
}  // namespace terrastride::perception
