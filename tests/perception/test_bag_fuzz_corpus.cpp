// The readers' fuzz target (tests/fuzz/fuzz_bag.cpp) on every seed of tests/fuzz/corpus_bag (the
// inputs fuzzing found crashes or hangs with stay there) and on the bag fixtures, each also with
// bytes flipped and cut at 16 places: nothing may crash, trap, hang or throw anything but an
// InputError (the target catches only those).
#include <gtest/gtest.h>

#include <cstdint>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size);

namespace {

void run(const std::string& bytes) {
  LLVMFuzzerTestOneInput(reinterpret_cast<const std::uint8_t*>(bytes.data()), bytes.size());
}

TEST(BagFuzzCorpus, Replay) {
  const std::filesystem::path root(TERRASTRIDE_SOURCE_DIR);
  std::vector<std::filesystem::path> inputs;
  for (const auto& e : std::filesystem::directory_iterator(root / "tests/fuzz/corpus_bag"))
    inputs.push_back(e.path());
  for (const char* f : {"scan_zstd.mcap", "scan_lz4.mcap", "scan.db3", "scan.bag"})
    inputs.push_back(root / "tests/fixtures/bags" / f);
  int n = 0;
  for (const auto& path : inputs) {
    SCOPED_TRACE(path.string());
    std::ifstream in(path, std::ios::binary);
    std::stringstream ss;
    ss << in.rdbuf();
    const std::string bytes = ss.str();
    run(bytes);
    for (std::size_t i = 0; i < bytes.size(); i += 1 + bytes.size() / 16) {
      std::string m = bytes;
      m[i] = static_cast<char>(m[i] ^ 0x5a);
      run(m);
      m.resize(i);
      run(m);
    }
    ++n;
  }
  EXPECT_GE(n, 24);
}

}  // namespace
