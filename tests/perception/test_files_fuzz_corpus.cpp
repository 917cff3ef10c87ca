// The file readers' fuzz target (tests/fuzz/fuzz_files.cpp) on every seed of
// tests/fuzz/corpus_files (the hostile OctoMaps that crashed `terrastride map` among them) and on
// the committed OctoMap fixture, each also with bytes flipped and cut at 16 places: nothing may
// crash, trap, hang or throw anything but an InputError (the target catches only those). Here,
// unlike in the fuzz build, PCD and PLY inputs that pass the checks go on into PCL.
#include <gtest/gtest.h>

#include <filesystem>

#include "support/fuzz_replay.hpp"

namespace {

TEST(FileFuzzCorpus, Replay) {
  const std::filesystem::path root(TERRASTRIDE_SOURCE_DIR);
  const int n = terrastride::test_support::replay_fuzz_corpus(
      root / "tests/fuzz/corpus_files", {root / "tests/fixtures/octomap/pallet_10.bt"});
  EXPECT_GE(n, 16);
}

}  // namespace
