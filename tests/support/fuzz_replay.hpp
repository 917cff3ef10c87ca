// A fuzz target replayed in the regular suite: each input as it is, then with one byte flipped and
// cut short at 16 places spread over it. The target must neither crash nor trap on any of them.
#pragma once

#include <gtest/gtest.h>

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size);

namespace terrastride::test_support {

inline std::string file_bytes(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

inline void fuzz_one(const std::string& bytes) {
  LLVMFuzzerTestOneInput(reinterpret_cast<const std::uint8_t*>(bytes.data()), bytes.size());
}

// `bytes` and its flipped and truncated variants through the target.
inline void fuzz_with_mutations(const std::string& bytes) {
  fuzz_one(bytes);
  for (std::size_t i = 0; i < bytes.size(); i += 1 + bytes.size() / 16) {
    std::string m = bytes;
    m[i] = static_cast<char>(m[i] ^ 0x5a);
    fuzz_one(m);
    m.resize(i);
    fuzz_one(m);
  }
}

// Every file of `corpus` (and the `extra` files), with mutations; the number of inputs.
inline int replay_fuzz_corpus(const std::filesystem::path& corpus,
                              const std::vector<std::filesystem::path>& extra = {}) {
  std::vector<std::filesystem::path> inputs;
  for (const auto& e : std::filesystem::directory_iterator(corpus)) inputs.push_back(e.path());
  inputs.insert(inputs.end(), extra.begin(), extra.end());
  for (const auto& path : inputs) {
    SCOPED_TRACE(path.string());
    fuzz_with_mutations(file_bytes(path));
  }
  return static_cast<int>(inputs.size());
}

}  // namespace terrastride::test_support
