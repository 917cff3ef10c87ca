// The readers' fuzz target (tests/fuzz/fuzz_bag.cpp) on every seed of tests/fuzz/corpus_bag (the
// inputs fuzzing found crashes or hangs with stay there) and on the bag fixtures, each also with
// bytes flipped and cut at 16 places: nothing may crash, trap, hang or throw anything but an
// InputError (the target catches only those).
#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include "support/fuzz_replay.hpp"
#include "terrastride/perception/bag.hpp"


namespace {

TEST(BagFuzzCorpus, Replay) {
  const std::filesystem::path root(TERRASTRIDE_SOURCE_DIR);
  std::vector<std::filesystem::path> fixtures;
  for (const char* f : {"scan_zstd.mcap", "scan_lz4.mcap", "scan.db3", "scan.bag"})
    fixtures.push_back(root / "tests/fixtures/bags" / f);
  EXPECT_GE(terrastride::test_support::replay_fuzz_corpus(root / "tests/fuzz/corpus_bag", fixtures),
            24);
}

// A chunk's uncompressed size is checked against what its codec can expand its bytes to before
// the buffer is allocated: the 3 kB input fuzzing found, a zstd chunk claiming 2 GiB, took 2 GiB
// and a memset of it (a libFuzzer timeout). The seeds tiny_zstd.mcap and tiny_lz4.mcap with their
// first chunk's uncompressed size raised: that chunk is skipped as corrupt, named, unallocated.
TEST(McapChunk, ClaimingMoreThanItsCodecExpandsToIsSkippedAsCorrupt) {
  namespace fs = std::filesystem;
  const fs::path root(TERRASTRIDE_SOURCE_DIR);
  const fs::path dir = fs::temp_directory_path() / ("ts_mcap_claims_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  for (const std::string codec : {"zstd", "lz4"}) {
    std::ifstream in(root / "tests/fuzz/corpus_bag" / ("tiny_" + codec + ".mcap"), std::ios::binary);
    std::stringstream ss;
    ss << in.rdbuf();
    std::string bytes = ss.str();
    // Records after the 8-byte magic: opcode (1), length (8), body; a Chunk (0x06) body starts
    // with its start and end times and then its uncompressed size.
    std::size_t pos = 8, chunk = 0;
    while (pos + 9 <= bytes.size() && !chunk) {
      std::uint64_t length;
      std::memcpy(&length, bytes.data() + pos + 1, 8);
      if (bytes[pos] == 0x06) chunk = pos;
      pos += 9 + length;
    }
    ASSERT_GT(chunk, 0u) << codec;
    const std::uint64_t claimed = std::uint64_t{1} << 31;
    std::memcpy(&bytes[chunk + 9 + 16], &claimed, 8);
    const fs::path path = dir / ("claims_" + codec + ".mcap");
    std::ofstream(path, std::ios::binary) << bytes;
    // The chunk held the channel's definition, so its message after it is refused, naming the
    // skipped chunk.
    const auto reader = terrastride::perception::open_bag(path.string());
    std::string problem;
    try {
      reader->read([](const auto&) { return true; }, [](const auto&) {});
    } catch (const terrastride::perception::InputError& e) {
      problem = e.what();
    }
    ASSERT_TRUE(reader->damage().damaged()) << codec;
    EXPECT_NE(problem.find(reader->damage().problems.front()), std::string::npos) << problem;
    EXPECT_NE(problem.find("corrupt chunk at byte " + std::to_string(chunk) +
                           " skipped: claims 2147483648 bytes uncompressed from"),
              std::string::npos)
        << problem;
    EXPECT_NE(problem.find("more than " + codec + " expands to"), std::string::npos) << problem;
  }
  fs::remove_all(dir);
}

}  // namespace
