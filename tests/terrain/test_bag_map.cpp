// Bags as map input: the fixtures of tests/fixtures/bags (written by independent
// writers: @mcap/core + @foxglove/rosmsg2-serialization, Python's sqlite3, Debian's
// python3-rosbag; see tests/fixtures/bags/README.md) give the same map as the same clouds as
// loose PCD files with their sensor origins; bad bags fail clearly or say what they skipped.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <sstream>

#include "perception/test_util.hpp"
#include "terrastride/perception/bag.hpp"
#include "terrastride/perception/bag_clouds.hpp"
#include "terrastride/terrain/map_build.hpp"

namespace terrastride {
namespace {

using perception::test::expect_input_error;
using perception::test::ScratchDir;

std::string fixture(const std::string& name) {
  return std::string(TERRASTRIDE_SOURCE_DIR) + "/tests/fixtures/bags/" + name;
}

std::vector<std::string> pcd_files() {
  std::ifstream list(fixture("pcd/list.txt"));
  std::vector<std::string> files;
  for (std::string line; std::getline(list, line);)
    if (!line.empty()) files.push_back(fixture("pcd/" + line));
  return files;
}

perception::BagCloudOptions both_lidars() {
  perception::BagCloudOptions o;
  o.topics = {"/points", "/points_rear"};
  o.fixed_frame = "odom";
  return o;
}

std::string read_bytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

class BagFixture : public ::testing::TestWithParam<std::string> {};

TEST_P(BagFixture, SameMapAsTheEquivalentPcdFiles) {
  const std::vector<std::string> pcds = pcd_files();
  ASSERT_EQ(pcds.size(), 18u);
  // The PCDs hold world-frame points and the whole sensor pose as VIEWPOINT: its position only.
  terrain::CloudPoseOptions world_frame;
  world_frame.viewpoint = perception::ViewpointUse::kPosition;
  terrain::MapInput loose = terrain::read_map_clouds(pcds, world_frame);
  terrain::BagMapInput bag = terrain::read_map_bags({fixture(GetParam())}, both_lidars());
  ASSERT_EQ(bag.input.clouds.size(), loose.clouds.size());
  // Both in one order: /points (lidar_NN.pcd) by stamp, then /points_rear (lidar_rear_NN.pcd).
  // Bags order messages of the same log time differently (rosbag by connection).
  const auto by_source = [](std::vector<perception::PointCloud>& clouds) {
    std::sort(clouds.begin(), clouds.end(),
              [](const auto& a, const auto& b) { return a.source < b.source; });
  };
  by_source(bag.input.clouds);
  by_source(loose.clouds);
  const auto& st = bag.stats.at(0);
  EXPECT_FALSE(st.damage.damaged());
  EXPECT_EQ(st.topics.at("/points").used, 9u);
  EXPECT_EQ(st.topics.at("/points").non_finite, 252u);  // the organised cloud's dropouts
  EXPECT_EQ(st.topics.at("/points_rear").non_finite, 0u);
  for (size_t k = 0; k < loose.clouds.size(); ++k) {
    const auto& a = bag.input.clouds[k];
    const auto& b = loose.clouds[k];
    ASSERT_EQ(a.points.size(), b.points.size()) << k;
    ASSERT_TRUE(a.sensor_origin && b.sensor_origin);
    // The origin from the interpolated tf, the PCD's from the generator's exact pose.
    EXPECT_LT((*a.sensor_origin - *b.sensor_origin).norm(), 1e-6) << k;
    for (size_t i = 0; i < a.points.size(); ++i)
      ASSERT_LT((a.points[i] - b.points[i]).norm(), 1e-5f) << "cloud " << k << " point " << i;
  }
  const terrain::MapBuild from_bag = terrain::build_terrain_map(std::move(bag.input.clouds));
  const terrain::MapBuild from_pcd = terrain::build_terrain_map(std::move(loose.clouds));
  const terrain::HeightGrid& g = from_bag.map->grid();
  const terrain::HeightGrid& h = from_pcd.map->grid();
  ASSERT_EQ(g.geometry.nx, h.geometry.nx);
  ASSERT_EQ(g.geometry.ny, h.geometry.ny);
  size_t observed_differs = 0;
  double worst = 0;
  for (size_t k = 0; k < g.geometry.size(); ++k) {
    observed_differs += g.observed[k] != h.observed[k];
    worst = std::max(worst, static_cast<double>(std::abs(g.elevation[k] - h.elevation[k])));
  }
  for (size_t k = 0; k < g.geometry.size(); ++k)
    if (g.observed[k] != h.observed[k] || std::abs(g.elevation[k] - h.elevation[k]) > 1e-3) {
      const int i = static_cast<int>(k / g.geometry.ny), j = static_cast<int>(k % g.geometry.ny);
      ADD_FAILURE() << "cell " << g.geometry.center(i, j).transpose() << ": observed "
                    << int(g.observed[k]) << " vs " << int(h.observed[k]) << ", elevation "
                    << g.elevation[k] << " vs " << h.elevation[k] << ", count " << g.count[k]
                    << " vs " << h.count[k] << ", support " << g.support[k] << " vs "
                    << h.support[k];
    }
  EXPECT_EQ(observed_differs, 0u);
  EXPECT_LE(worst, 1e-3);
  EXPECT_EQ(from_bag.octree->getNumLeafNodes(), from_pcd.octree->getNumLeafNodes());
}

INSTANTIATE_TEST_SUITE_P(Formats, BagFixture,
                         ::testing::Values("scan_zstd.mcap", "scan_lz4.mcap", "scan.db3",
                                           "scan.bag", "split"),
                         [](const auto& info) {
                           std::string n = info.param;
                           for (char& c : n)
                             if (!std::isalnum(static_cast<unsigned char>(c))) c = '_';
                           return n;
                         });

TEST(BagInput, CloudWithoutTransformFailsNamingFramesAndTime) {
  perception::BagCloudOptions o = both_lidars();
  o.topics = {"/camera/points"};
  for (const std::string name : {"scan_zstd.mcap", "scan.db3", "scan.bag"})
    expect_input_error([&] { terrain::read_map_bags({fixture(name)}, o); },
                       {name, "/camera/points", "'camera'", "'odom'", "1700000000.500000000"});
  // A fixed frame no transform names.
  o = both_lidars();
  o.fixed_frame = "map";
  expect_input_error([&] { terrain::read_map_bags({fixture("scan_lz4.mcap")}, o); },
                     {"'lidar'", "'map'", "no /tf or /tf_static message names frame 'map'"});
}

TEST(BagInput, RefusesTopicsItCannotMap) {
  perception::BagCloudOptions o = both_lidars();
  o.topics = {"/velodyne_points"};
  expect_input_error([&] { terrain::read_map_bags({fixture("scan_zstd.mcap")}, o); },
                     {"no topic /velodyne_points", "/points", "/points_rear"});
  o.topics = {"/tf"};
  expect_input_error([&] { terrain::read_map_bags({fixture("scan.db3")}, o); },
                     {"/tf", "tf2_msgs/TFMessage", "not sensor_msgs/PointCloud2"});
  // A time window with no cloud in it.
  o = both_lidars();
  o.start = 5.0;
  expect_input_error([&] { terrain::read_map_bags({fixture("scan.bag")}, o); },
                     {"no cloud selected", "outside the time window"});
}

// Window bounds beyond int64's nanoseconds saturate (1e300 s was an undefined conversion to
// int64_t); a bound that is not a number is refused.
TEST(BagInput, HugeWindowBoundsSaturateAndNaNIsRefused) {
  perception::BagCloudOptions o = both_lidars();
  o.topics = {"/points"};
  o.start = -1e300;
  o.end = 1e300;
  const auto all = terrain::read_map_bags({fixture("scan_zstd.mcap")}, o);
  EXPECT_EQ(all.stats[0].topics.at("/points").used, 9u);
  EXPECT_EQ(all.stats[0].topics.at("/points").outside_window, 0u);
  o.start = 1e300;
  o.end = std::nullopt;
  expect_input_error([&] { terrain::read_map_bags({fixture("scan_zstd.mcap")}, o); },
                     {"no cloud selected", "outside the time window"});
  o.start = std::nan("");
  expect_input_error([&] { terrain::read_map_bags({fixture("scan_zstd.mcap")}, o); },
                     {"scan_zstd.mcap: the time window's start and end must be finite"});
}

TEST(BagInput, WindowAndEverySelectClouds) {
  perception::BagCloudOptions o = both_lidars();
  o.topics = {"/points"};
  o.start = 0.5;  // s after the first message (1700000000.001)
  o.end = 1.3;
  const auto a = terrain::read_map_bags({fixture("scan_zstd.mcap")}, o);
  // Clouds logged at 0.014 + 0.2 k s: k = 3..6 lie in [0.501, 1.301].
  EXPECT_EQ(a.stats[0].topics.at("/points").used, 4u);
  EXPECT_EQ(a.stats[0].topics.at("/points").outside_window, 5u);
  o = both_lidars();
  o.every = 4;
  const auto b = terrain::read_map_bags({fixture("scan_zstd.mcap")}, o);
  EXPECT_EQ(b.stats[0].topics.at("/points").used, 3u);  // clouds 0, 4, 8
  EXPECT_EQ(b.stats[0].topics.at("/points").skipped_every, 6u);
}

TEST(BagInput, TruncatedMcapMapsWhatIsCompleteAndSaysWhatWasSkipped) {
  ScratchDir dir;
  const std::string bytes = read_bytes(fixture("scan_zstd.mcap"));
  const std::string cut = dir.file("cut.mcap");
  std::ofstream(cut, std::ios::binary) << bytes.substr(0, bytes.size() * 6 / 10);
  const auto in = terrain::read_map_bags({cut}, both_lidars());
  const auto& st = in.stats.at(0);
  ASSERT_TRUE(st.damage.damaged());
  EXPECT_NE(st.damage.problems[0].find("truncated at byte"), std::string::npos)
      << st.damage.problems[0];
  EXPECT_GT(st.damage.skipped_bytes, 0u);
  const size_t used = st.topics.at("/points").used + st.topics.at("/points_rear").used;
  EXPECT_GT(used, 0u);
  EXPECT_LT(used, 18u);
  // What was read is exactly the complete file's first clouds.
  const auto whole = terrain::read_map_bags({fixture("scan_zstd.mcap")}, both_lidars());
  for (size_t k = 0; k < in.input.clouds.size(); ++k)
    EXPECT_EQ(in.input.clouds[k].points, whole.input.clouds[k].points) << k;
}

TEST(BagInput, CorruptChunkIsSkippedAndNamed) {
  ScratchDir dir;
  std::string bytes = read_bytes(fixture("scan_lz4.mcap"));
  // Scribble over the middle of the file: inside some chunk's compressed records.
  for (size_t i = bytes.size() / 2; i < bytes.size() / 2 + 64; ++i) bytes[i] = '\x5a';
  const std::string bad = dir.file("bad.mcap");
  std::ofstream(bad, std::ios::binary) << bytes;
  try {
    const auto in = terrain::read_map_bags({bad}, both_lidars());
    ASSERT_TRUE(in.stats[0].damage.damaged());
    EXPECT_NE(in.stats[0].damage.problems[0].find("corrupt chunk at byte"), std::string::npos)
        << in.stats[0].damage.problems[0];
  } catch (const perception::InputError& e) {
    // The scribble may also land in a record length: then the file's structure is broken, and
    // the error says where.
    EXPECT_NE(std::string(e.what()).find("bad.mcap"), std::string::npos) << e.what();
  }
}

// The chunks of an MCAP file (opcode 0x06): where each starts, and where its CRC and its
// compressed records lie.
struct McapChunk {
  size_t start, crc_at, records_at, records_len;
};
std::vector<McapChunk> mcap_chunks(const std::string& bytes) {
  std::vector<McapChunk> chunks;
  const auto u64 = [&](size_t at) {
    uint64_t v;
    std::memcpy(&v, bytes.data() + at, 8);
    return static_cast<size_t>(v);
  };
  for (size_t pos = 8; pos + 9 <= bytes.size();) {
    const auto opcode = static_cast<uint8_t>(bytes[pos]);
    const size_t length = u64(pos + 1);
    if (opcode == 0x06) {
      const size_t content = pos + 9, crc_at = content + 24;
      uint32_t compression_len;
      std::memcpy(&compression_len, bytes.data() + crc_at + 4, 4);
      const size_t records_len_at = crc_at + 8 + compression_len;
      chunks.push_back({pos, crc_at, records_len_at + 8, u64(records_len_at)});
    }
    if (opcode == 0x0f || opcode == 0x02) break;  // DataEnd, Footer
    pos += 9 + length;
  }
  return chunks;
}

// A chunk that fails its CRC, or whose compressed bytes are not zstd / lz4 at all, takes the
// channels it defines with it: the error says which chunk is corrupt and why, rather than only
// "no topic /points (PointCloud2 topics: none)".
TEST(BagInput, CorruptChunksAreNamedWhenTheyHideTheTopics) {
  ScratchDir dir;
  for (const std::string fixture_name : {"scan_zstd.mcap", "scan_lz4.mcap"}) {
    const std::string good = read_bytes(fixture(fixture_name));
    const std::vector<McapChunk> chunks = mcap_chunks(good);
    ASSERT_GT(chunks.size(), 2u) << fixture_name;
    // Every chunk's CRC off by one bit.
    std::string crc = good;
    for (const auto& c : chunks) crc[c.crc_at] ^= 1;
    const std::string crc_path = dir.file("crc_" + fixture_name);
    std::ofstream(crc_path, std::ios::binary) << crc;
    expect_input_error([&] { terrain::read_map_bags({crc_path}, both_lidars()); },
                       {crc_path, "corrupt chunk at byte " + std::to_string(chunks[0].start),
                        "CRC mismatch", "no topic /points"});
    // Every chunk's compressed records replaced by bytes that are no compressed stream.
    std::string fake = good;
    for (const auto& c : chunks)
      for (size_t k = 0; k < c.records_len; ++k) fake[c.records_at + k] = static_cast<char>(k * 7);
    const std::string fake_path = dir.file("fake_" + fixture_name);
    std::ofstream(fake_path, std::ios::binary) << fake;
    expect_input_error([&] { terrain::read_map_bags({fake_path}, both_lidars()); },
                       {fake_path, "corrupt chunk at byte " + std::to_string(chunks[0].start),
                        "decompression failed", "no topic /points"});
    // Only the first chunk corrupt (it defines the channels): named all the same.
    std::string first = good;
    first[chunks[0].crc_at] ^= 1;
    const std::string first_path = dir.file("first_" + fixture_name);
    std::ofstream(first_path, std::ios::binary) << first;
    expect_input_error([&] { terrain::read_map_bags({first_path}, both_lidars()); },
                       {first_path, "chunk at byte " + std::to_string(chunks[0].start)});
  }
}

TEST(BagInput, NotABagAndBrokenBagsFailClearly) {
  ScratchDir dir;
  for (const std::string name : {"text.mcap", "text.db3", "text.bag"}) {
    perception::test::write_text(dir.file(name), "these are not the bytes of a bag\n");
    expect_input_error([&] { perception::open_bag(dir.file(name))->read({}, [](const auto&) {}); },
                       {name});
  }
  expect_input_error([&] { perception::open_bag(dir.file("none.mcap")); },
                     {"none.mcap", "not found"});
  // A ROS 1 bag cut in half has lost its index (at the end of the file).
  const std::string bag = read_bytes(fixture("scan.bag"));
  std::ofstream(dir.file("cut.bag"), std::ios::binary) << bag.substr(0, bag.size() / 2);
  expect_input_error([&] { perception::open_bag(dir.file("cut.bag")); }, {"cut.bag", "reindex"});
  // A .db3 cut in half: SQLite either refuses it or stops part-way, and says so.
  const std::string db = read_bytes(fixture("scan.db3"));
  std::ofstream(dir.file("cut.db3"), std::ios::binary) << db.substr(0, db.size() / 2);
  try {
    const auto in = terrain::read_map_bags({dir.file("cut.db3")}, both_lidars());
    EXPECT_TRUE(in.stats[0].damage.damaged());
  } catch (const perception::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("cut.db3"), std::string::npos) << e.what();
  }
}

// ROS 1 bags whose lengths or positions lie (tests/fuzz/make_file_seeds.py writes them): each is
// an error naming the file and what is wrong, before librosbag sees it (a message length past
// its chunk made librosbag read gigabytes past its buffer: SIGSEGV; others were read as if
// whole). The tiny bags they are made from open.
TEST(BagInput, HostileRos1BagsAreRefusedNamingTheProblem) {
  const std::string seeds = std::string(TERRASTRIDE_SOURCE_DIR) + "/tests/fuzz/corpus_bag/";
  for (const char* name : {"tiny_none.bag", "tiny_bz2.bag"})
    EXPECT_EQ(perception::list_bag(seeds + name).topics.size(), 1u) << name;
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"huge_header_len.bag", "a record header of 4294967280 bytes runs past the end"},
      {"huge_data_len.bag", "record data of 2147483647 bytes runs past the end"},
      {"huge_chunk_size.bag", "a chunk claiming 4294967040 bytes uncompressed"},
      {"chunk_size_mismatch.bag", "an uncompressed chunk of 222 bytes claiming 1048576"},
      {"index_past_end.bag", "index position 1099511627776 is not the start of a record"},
      {"chunk_info_past_end.bag", "chunk info naming byte 8589934592, where no chunk starts"},
      {"index_offset_past_chunk.bag", "index entry 0 points at byte 1073741824 of its chunk"},
      {"inner_header_len.bag", "a record header runs past the chunk's end"},
      {"inner_data_len.bag", "record data runs past the chunk's end"},
      {"fake_bz2.bag", "a bz2 chunk that does not decompress to the 222 bytes"}};
  for (const auto& [name, problem] : cases)
    expect_input_error([&] { perception::open_bag(seeds + name); }, {seeds + name, problem});
}

// SQLite opens a .db3 through a "file:" URI: a name with '?', '#', '%' or a space must still name
// the file (it used to be cut at the '?' or decoded at the '%').
TEST(BagInput, Db3WithUriCharactersInItsNameOpens) {
  ScratchDir dir;
  const std::string db = read_bytes(fixture("scan.db3"));
  const size_t clouds =
      terrain::read_map_bags({fixture("scan.db3")}, both_lidars()).input.clouds.size();
  ASSERT_GT(clouds, 0u);
  for (const std::string name : {"run?mode=rw.db3", "run#1.db3", "50%41.db3", "two words.db3"}) {
    std::ofstream(dir.file(name), std::ios::binary) << db;
    const auto in = terrain::read_map_bags({dir.file(name)}, both_lidars());
    EXPECT_EQ(in.input.clouds.size(), clouds) << name;
    EXPECT_FALSE(in.stats[0].damage.damaged()) << name;
  }
}

// A split rosbag2 recording (tests/fixtures/bags/split: metadata.yaml and three .mcap files,
// /tf_static only in the first) is read as one recording, in metadata.yaml's order: the same
// clouds as the unsplit file (and, in BagFixture, the same map as the PCDs).
TEST(BagInput, SplitRosbag2FolderIsOneRecording) {
  const terrain::BagMapInput whole =
      terrain::read_map_bags({fixture("scan_zstd.mcap")}, both_lidars());
  const terrain::BagMapInput split = terrain::read_map_bags({fixture("split")}, both_lidars());
  ASSERT_EQ(split.input.clouds.size(), whole.input.clouds.size());
  for (size_t k = 0; k < whole.input.clouds.size(); ++k) {
    EXPECT_EQ(split.input.clouds[k].points, whole.input.clouds[k].points) << k;
    EXPECT_EQ(*split.input.clouds[k].sensor_origin, *whole.input.clouds[k].sensor_origin) << k;
  }
  EXPECT_EQ(split.stats[0].format, "mcap");
  EXPECT_EQ(split.stats[0].static_transforms, whole.stats[0].static_transforms);
  EXPECT_TRUE(perception::is_bag_file(fixture("split")));
  // A later split alone cannot place its clouds: /tf_static is in the first file.
  expect_input_error(
      [&] { terrain::read_map_bags({fixture("split/split_1.mcap")}, both_lidars()); },
      {"split_1.mcap", "'odom'"});
}

// Streaming (terrain::stream_map_bags): clouds cleaned as they are read are the clouds
// build_terrain_map cleans; a per-cell cap bounds the points kept by the map's cells, however
// often the ground is seen again (here: the same recording given twice).
TEST(BagInput, StreamingCleansAsBuildDoesAndTheCellCapBoundsPoints) {
  terrain::BagMapInput read = terrain::read_map_bags({fixture("scan_zstd.mcap")}, both_lidars());
  terrain::MapBuildOptions no_octomap;
  no_octomap.octomap.reset();
  const terrain::MapBuild built = terrain::build_terrain_map(read.input.clouds, no_octomap);
  terrain::BagStreamOptions stream;  // the default cleaning, no cap
  const terrain::StreamedBagInput all =
      terrain::stream_map_bags({fixture("scan_zstd.mcap")}, both_lidars(), stream);
  ASSERT_EQ(all.bags.input.clouds.size(), built.clouds.size());
  for (size_t k = 0; k < built.clouds.size(); ++k)
    ASSERT_EQ(all.bags.input.clouds[k].points, built.clouds[k].points) << k;
  EXPECT_EQ(all.points_cleaned, built.points_kept);
  EXPECT_EQ(all.points_over_cap, 0u);
  EXPECT_EQ(all.bags.input.sources.files.size(), built.clouds.size());

  const auto count_cells = [](const std::vector<perception::PointCloud>& clouds) {
    std::map<std::pair<int64_t, int64_t>, size_t> n;
    for (const auto& c : clouds)
      for (const auto& p : c.points)
        ++n[{static_cast<int64_t>(std::floor(p.x() / 0.02)),
             static_cast<int64_t>(std::floor(p.y() / 0.02))}];
    return n;
  };
  stream.max_cell_points = 3;
  const terrain::StreamedBagInput once =
      terrain::stream_map_bags({fixture("scan_zstd.mcap")}, both_lidars(), stream);
  const terrain::StreamedBagInput twice = terrain::stream_map_bags(
      {fixture("scan_zstd.mcap"), fixture("scan_zstd.mcap")}, both_lidars(), stream);
  const auto cells_once = count_cells(once.bags.input.clouds);
  const auto cells_twice = count_cells(twice.bags.input.clouds);
  EXPECT_EQ(cells_once.size(), count_cells(all.bags.input.clouds).size());  // no cell lost
  EXPECT_EQ(cells_twice.size(), cells_once.size());
  EXPECT_EQ(once.cells, cells_once.size());
  size_t kept_twice = 0;
  for (const auto& [cell, n] : cells_twice) {
    EXPECT_LE(n, 3u);
    kept_twice += n;
  }
  EXPECT_GT(once.points_over_cap, 0u);
  EXPECT_EQ(twice.points_cleaned, 2 * once.points_cleaned);
  EXPECT_LE(kept_twice, 3 * cells_once.size());  // bounded by the cells, not by the input
  EXPECT_EQ(kept_twice + twice.points_over_cap, twice.points_cleaned);
  // A cleaning option the filter refuses fails the stream (and stops its thread).
  stream.cleaning->outlier_stddev = -1;
  expect_input_error(
      [&] { terrain::stream_map_bags({fixture("scan_zstd.mcap")}, both_lidars(), stream); }, {});
}

TEST(BagInput, BrokenRosbag2FoldersFailClearly) {
  ScratchDir dir;
  const std::filesystem::path folder = dir.file("run");
  std::filesystem::create_directories(folder);
  expect_input_error([&] { perception::open_bag(folder.string()); }, {"run", "metadata.yaml"});
  EXPECT_FALSE(perception::is_bag_file(folder.string()));
  for (const char* f : {"split_0.mcap", "split_2.mcap"})
    std::filesystem::copy_file(fixture(std::string("split/") + f), folder / f);
  std::filesystem::copy_file(fixture("split/metadata.yaml"), folder / "metadata.yaml");
  expect_input_error([&] { terrain::read_map_bags({folder.string()}, both_lidars()); },
                     {"metadata.yaml", "'split_1.mcap'", "missing"});
  perception::test::write_text((folder / "metadata.yaml").string(),
                               "rosbag2_bagfile_information: [1, 2\n");
  expect_input_error([&] { perception::open_bag(folder.string()); }, {"metadata.yaml", "YAML"});
  perception::test::write_text((folder / "metadata.yaml").string(), "something_else: 1\n");
  expect_input_error([&] { perception::open_bag(folder.string()); },
                     {"metadata.yaml", "rosbag2_bagfile_information"});
  perception::test::write_text(
      (folder / "metadata.yaml").string(),
      "rosbag2_bagfile_information:\n  relative_file_paths:\n    - /etc/passwd\n");
  expect_input_error([&] { perception::open_bag(folder.string()); }, {"not a path relative"});
  // Foxy's metadata (version < 4) names the files relative to the folder's parent.
  perception::test::write_text(
      (folder / "metadata.yaml").string(),
      "rosbag2_bagfile_information:\n  version: 3\n  relative_file_paths:\n"
      "    - run/split_0.mcap\n");
  EXPECT_EQ(perception::open_bag(folder.string())->format(), "mcap");
}

TEST(BagInput, ListsTopicsTypesCountsAndFrames) {
  for (const std::string name : {"scan_zstd.mcap", "scan.db3", "scan.bag", "split"}) {
    const perception::BagListing l = perception::list_bag(fixture(name));
    std::map<std::string, perception::BagListing::Topic> t;
    for (const auto& x : l.topics) t[x.name] = x;
    ASSERT_EQ(t.size(), 5u) << name;
    EXPECT_EQ(t["/points"].type, "sensor_msgs/PointCloud2");
    EXPECT_EQ(t["/points"].messages, 9u);
    EXPECT_EQ(t["/points"].frames, std::set<std::string>{"lidar"});
    EXPECT_EQ(t["/tf"].messages, 41u);
    EXPECT_EQ(l.frames, (std::vector<std::string>{"base_link", "lidar", "lidar_rear", "odom"}));
  }
}

}  // namespace
}  // namespace terrastride
