// Bounds-checked little-endian reading of a byte range (bag records and serialised messages).
// Reading past the end throws Truncated; the callers turn it into an InputError that names the file
// and the record.
#pragma once

#include <cstdint>
#include <cstring>
#include <stdexcept>
#include <string>
#include <string_view>

namespace terrastride::perception::bag {

struct Truncated : std::runtime_error {
  using std::runtime_error::runtime_error;
};

class ByteCursor {
 public:
  ByteCursor(const char* data, size_t size) : data_(data), size_(size) {}
  explicit ByteCursor(std::string_view s) : data_(s.data()), size_(s.size()) {}

  size_t pos() const { return pos_; }
  size_t remaining() const { return size_ - pos_; }
  bool done() const { return pos_ >= size_; }

  template <typename T>
  T read(const char* what) {
    need(sizeof(T), what);
    T v;
    std::memcpy(&v, data_ + pos_, sizeof(T));  // the machine is little endian (checked at build)
    pos_ += sizeof(T);
    return v;
  }
  std::string_view bytes(uint64_t n, const char* what) {
    need(n, what);
    std::string_view v(data_ + pos_, static_cast<size_t>(n));
    pos_ += static_cast<size_t>(n);
    return v;
  }
  void skip(uint64_t n, const char* what) { bytes(n, what); }
  // MCAP's string: uint32 length, bytes.
  std::string_view prefixed_string(const char* what) { return bytes(read<uint32_t>(what), what); }

 private:
  void need(uint64_t n, const char* what) {
    if (n > remaining())
      throw Truncated(std::string(what) + ": needs " + std::to_string(n) + " bytes, " +
                      std::to_string(remaining()) + " left");
  }
  const char* data_;
  size_t size_;
  size_t pos_ = 0;
};

static_assert(__BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__, "the bag readers assume a little-endian host");

}  // namespace terrastride::perception::bag
