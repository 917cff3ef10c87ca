// `report --batch --resume` trusts a committed report only when its files match the digests
// (size, CRC-32) recorded at its commit: a report truncated or altered since is said so and
// reported again, to the very bytes of an undamaged run.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>

#include "perception/test_util.hpp"
#include "support/run_command.hpp"
#include "terrastride/terrain/scenes.hpp"
#include "terrastride/terrain/terrain_map.hpp"

namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using terrastride::perception::test::ScratchDir;
using terrastride::test_support::CommandResult;
using terrastride::test_support::run_terrastride;
using terrastride::test_support::shell_quote;

std::string slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

void write_map_dir(const fs::path& dir, const std::string& scene_name) {
  const auto scene = terrastride::terrain::make_scene(scene_name);
  const auto map = terrastride::terrain::TerrainMap::from_scene(*scene, 0.02, {0.02, 0.05});
  fs::create_directories(dir / "layers");
  json meta = terrastride::terrain::write_terrain_layers(*map, dir.string());
  std::ofstream(dir / "terrain.json") << meta.dump(1);
}

TEST(ReportBatchDigest, DamagedCommittedReportsAreRedoneAndSaidSo) {
  ScratchDir dir;
  const fs::path scans = dir.path() / "scans";
  write_map_dir(scans / "a", "flat");
  write_map_dir(scans / "b", "stairs");
  const fs::path out = dir.path() / "out";
  const std::string args =
      "report --batch " + shell_quote(scans.string()) + " --out " + shell_quote(out.string());
  CommandResult r = run_terrastride(args);
  ASSERT_EQ(r.code, 0) << r.all();
  const json summary = json::parse(slurp(out / "a" / "summary.json"));
  ASSERT_TRUE(summary["digests"].contains("a.html")) << summary.dump();
  EXPECT_FALSE(json::parse(slurp(out / "index.json"))["reports"][0].contains("digests"));
  const std::string html = slurp(out / "a" / "a.html"), report = slurp(out / "a" / "a.json");
  const std::string b_html = slurp(out / "b" / "b.html");

  // Undamaged: both skipped.
  r = run_terrastride(args + " --resume");
  ASSERT_EQ(r.code, 0) << r.all();
  EXPECT_NE(r.err.find("a (reported: skipped)"), std::string::npos) << r.err;
  EXPECT_EQ(r.err.find("damaged"), std::string::npos) << r.err;

  // a.html cut in half, b.json with a byte changed (same size): both redone, both named.
  std::ofstream(out / "a" / "a.html", std::ios::binary) << html.substr(0, html.size() / 2);
  std::string b_json = slurp(out / "b" / "b.json");
  b_json[b_json.size() / 2] ^= 1;
  std::ofstream(out / "b" / "b.json", std::ios::binary) << b_json;
  r = run_terrastride(args + " --resume");
  ASSERT_EQ(r.code, 0) << r.all();
  EXPECT_NE(r.err.find("a: its committed report is damaged (a.html is"), std::string::npos)
      << r.err;
  EXPECT_NE(r.err.find("b: its committed report is damaged (b.json is"), std::string::npos)
      << r.err;
  EXPECT_EQ(r.err.find("(reported: skipped)"), std::string::npos) << r.err;
  EXPECT_EQ(slurp(out / "a" / "a.html"), html);
  EXPECT_EQ(slurp(out / "a" / "a.json"), report);
  EXPECT_EQ(slurp(out / "b" / "b.html"), b_html);

  // A deleted report file, and a summary that is no longer JSON.
  fs::remove(out / "a" / "a.json");
  std::ofstream(out / "b" / "summary.json") << "{\"scan\": \"b\", trunc";
  r = run_terrastride(args + " --resume");
  ASSERT_EQ(r.code, 0) << r.all();
  EXPECT_NE(r.err.find("a.json is missing"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("summary.json is unreadable"), std::string::npos) << r.err;
  EXPECT_EQ(slurp(out / "a" / "a.json"), report);
  EXPECT_TRUE(json::parse(slurp(out / "b" / "summary.json")).contains("digests"));
}

}  // namespace
