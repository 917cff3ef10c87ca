// NPY format (https://numpy.org/doc/stable/reference/generated/numpy.lib.format.html): magic
// "\x93NUMPY", version, header length (u16 for v1, u32 for v2/v3), then a Python dict literal
// {'descr': '<f4', 'fortran_order': False, 'shape': (N, 3), } padded with spaces and '\n', then
// data.
#include "terrastride/perception/npy.hpp"

#include <cassert>
#include <cctype>
#include <cstring>
#include <fstream>
#include <limits>
#include <sstream>

#include "terrastride/perception/atomic_output.hpp"
#include "terrastride/perception/point_cloud.hpp"

namespace terrastride::perception {
namespace {

constexpr char kMagic[] = "\x93NUMPY";
constexpr size_t kMagicLen = 6;

// A tiny parser for the header dict: only the literal forms numpy writes (quoted strings,
// True/False, tuples of non-negative integers) are accepted, anything else is a format error.
class HeaderParser {
 public:
  HeaderParser(const std::string& text, const std::string& file) : s_(text), file_(file) {}

  void parse(std::string& descr, bool& fortran, std::vector<size_t>& shape) {
    bool have_descr = false, have_fortran = false, have_shape = false;
    expect('{');
    while (true) {
      skip_ws();
      if (peek() == '}') break;
      const std::string key = parse_string();
      expect(':');
      if (key == "descr") {
        skip_ws();
        if (peek() == '[') {
          // Fields are named in a list of tuples, e.g. [('x', '<f4'), ('y', '<f4'), ...].
          throw InputError(file_ +
                           ": NPY array has a structured dtype (named fields); only plain "
                           "numeric arrays are supported: save a float array of shape "
                           "(N, 3), e.g. np.stack([a['x'], a['y'], a['z']], axis=1)");
        }
        descr = parse_string();
        have_descr = true;
      } else if (key == "fortran_order") {
        fortran = parse_bool();
        have_fortran = true;
      } else if (key == "shape") {
        shape = parse_tuple();
        have_shape = true;
      } else {
        fail("unexpected key '" + key + "'");
      }
      skip_ws();
      if (peek() == ',') {
        ++i_;
        continue;
      }
      skip_ws();
      if (peek() != '}') fail("expected ',' or '}'");
    }
    if (!have_descr || !have_fortran || !have_shape) {
      fail("header lacks one of 'descr', 'fortran_order', 'shape'");
    }
  }

 private:
  [[noreturn]] void fail(const std::string& what) const {
    throw InputError(file_ + ": malformed NPY header (" + what + ")");
  }
  void skip_ws() {
    while (i_ < s_.size() && std::isspace(static_cast<unsigned char>(s_[i_]))) ++i_;
  }
  char peek() const { return i_ < s_.size() ? s_[i_] : '\0'; }
  void expect(char c) {
    skip_ws();
    if (peek() != c) fail(std::string("expected '") + c + "'");
    ++i_;
  }
  std::string parse_string() {
    skip_ws();
    const char q = peek();
    if (q != '\'' && q != '"') fail("expected a quoted string");
    const size_t end = s_.find(q, i_ + 1);
    if (end == std::string::npos) fail("unterminated string");
    std::string out = s_.substr(i_ + 1, end - i_ - 1);
    i_ = end + 1;
    return out;
  }
  bool parse_bool() {
    skip_ws();
    if (s_.compare(i_, 4, "True") == 0) {
      i_ += 4;
      return true;
    }
    if (s_.compare(i_, 5, "False") == 0) {
      i_ += 5;
      return false;
    }
    fail("expected True or False");
  }
  std::vector<size_t> parse_tuple() {
    expect('(');
    std::vector<size_t> out;
    while (true) {
      skip_ws();
      if (peek() == ')') {
        ++i_;
        return out;
      }
      if (!std::isdigit(static_cast<unsigned char>(peek()))) fail("expected a dimension");
      size_t v = 0;
      while (std::isdigit(static_cast<unsigned char>(peek()))) {
        const size_t d = static_cast<size_t>(s_[i_++] - '0');
        if (v > (std::numeric_limits<size_t>::max() - d) / 10) fail("dimension too large");
        v = v * 10 + d;
      }
      out.push_back(v);
      skip_ws();
      if (peek() == ',')
        ++i_;
      else if (peek() != ')')
        fail("expected ',' or ')' in shape");
    }
  }

  const std::string& s_;
  const std::string& file_;
  size_t i_ = 0;
};

size_t item_size_of(const std::string& descr) {
  if (descr == "<f4" || descr == "<i4") return 4;
  if (descr == "<f8" || descr == "<i8") return 8;
  if (descr == "|u1" || descr == "<u1" || descr == "u1" || descr == "|b1") return 1;
  return 0;
}

template <typename T>
void write_npy_impl(const std::string& path, const T* data, size_t rows, size_t cols,
                    const char* descr) {
  if (data == nullptr && rows * cols > 0) throw InputError(path + ": no data to write");
  std::ostringstream dict;
  dict << "{'descr': '" << descr << "', 'fortran_order': False, 'shape': (" << rows << ", " << cols
       << "), }";
  std::string header = dict.str();
  // Pad so that magic + version + length + header is a multiple of 64, ending with '\n' (NEP 1).
  const size_t fixed = kMagicLen + 2 + 2;
  const size_t total = ((fixed + header.size() + 1 + 63) / 64) * 64;
  header.append(total - fixed - header.size() - 1, ' ');
  header.push_back('\n');
  std::string bytes;
  const size_t payload = rows * cols * sizeof(T);
  bytes.reserve(total + payload);
  bytes.append(kMagic, kMagicLen);
  bytes.push_back('\x01');
  bytes.push_back('\x00');
  const uint16_t len = static_cast<uint16_t>(header.size());
  bytes.push_back(static_cast<char>(len & 0xff));
  bytes.push_back(static_cast<char>(len >> 8));
  bytes += header;
  // Host is little endian (x86-64/aarch64), matching the '<' descr written above.
  bytes.append(reinterpret_cast<const char*>(data), payload);
  write_file_atomically(path, bytes);
}

}  // namespace

void write_npy(const std::string& path, const float* data, size_t rows, size_t cols) {
  write_npy_impl(path, data, rows, cols, "<f4");
}
void write_npy(const std::string& path, const double* data, size_t rows, size_t cols) {
  write_npy_impl(path, data, rows, cols, "<f8");
}
void write_npy(const std::string& path, const uint8_t* data, size_t rows, size_t cols) {
  write_npy_impl(path, data, rows, cols, "|u1");
}

double NpyArray::at(size_t r, size_t c) const {
  const size_t index = r * cols() + c;
  assert(index * item_size < bytes.size());
  const char* p = bytes.data() + index * item_size;
  if (dtype == "<f4") {
    float v;
    std::memcpy(&v, p, 4);
    return v;
  }
  if (dtype == "<f8") {
    double v;
    std::memcpy(&v, p, 8);
    return v;
  }
  if (dtype == "<i4") {
    int32_t v;
    std::memcpy(&v, p, 4);
    return v;
  }
  if (dtype == "<i8") {
    int64_t v;
    std::memcpy(&v, p, 8);
    return static_cast<double>(v);
  }
  return static_cast<unsigned char>(*p);
}

NpyArray read_npy(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError(path + ": cannot open file: " + std::strerror(errno));
  char prefix[kMagicLen + 2];
  in.read(prefix, sizeof(prefix));
  if (in.gcount() == 0) throw InputError(path + ": file is empty");
  if (in.gcount() != static_cast<std::streamsize>(sizeof(prefix)) ||
      std::memcmp(prefix, kMagic, kMagicLen) != 0) {
    throw InputError(path + ": not an NPY file (missing the \\x93NUMPY magic)");
  }
  const int major = static_cast<unsigned char>(prefix[kMagicLen]);
  size_t header_len = 0;
  if (major == 1) {
    unsigned char l[2];
    in.read(reinterpret_cast<char*>(l), 2);
    header_len = l[0] | (static_cast<size_t>(l[1]) << 8);
  } else if (major == 2 || major == 3) {
    unsigned char l[4];
    in.read(reinterpret_cast<char*>(l), 4);
    header_len = l[0] | (static_cast<size_t>(l[1]) << 8) | (static_cast<size_t>(l[2]) << 16) |
                 (static_cast<size_t>(l[3]) << 24);
  } else {
    throw InputError(path + ": unsupported NPY format version " + std::to_string(major));
  }
  if (!in || header_len > (1u << 20))
    throw InputError(path + ": truncated or oversized NPY header");
  std::string header(header_len, '\0');
  in.read(header.data(), static_cast<std::streamsize>(header_len));
  if (!in) throw InputError(path + ": truncated NPY header");

  NpyArray a;
  bool fortran = false;
  HeaderParser(header, path).parse(a.dtype, fortran, a.shape);
  a.item_size = item_size_of(a.dtype);
  if (a.item_size == 0) {
    throw InputError(path + ": unsupported NPY dtype '" + a.dtype +
                     "' (expected little-endian <f4, <f8, <i4, <i8 or |u1)");
  }
  if (a.shape.empty() || a.shape.size() > 2) {
    throw InputError(path + ": NPY array has " + std::to_string(a.shape.size()) +
                     " dimensions; expected a 1-D or 2-D array");
  }
  size_t count = 1;
  for (size_t d : a.shape) {
    if (d != 0 && count > std::numeric_limits<size_t>::max() / d / a.item_size) {
      throw InputError(path + ": NPY shape is absurdly large");
    }
    count *= d;
  }
  const size_t payload = count * a.item_size;
  // Check the size against the file before allocating, so a lying header cannot exhaust memory.
  const std::streamoff here = in.tellg();
  in.seekg(0, std::ios::end);
  const std::streamoff end = in.tellg();
  in.seekg(here);
  if (end - here < static_cast<std::streamoff>(payload)) {
    throw InputError(path + ": NPY data is truncated (header promises " + std::to_string(payload) +
                     " bytes, file has " + std::to_string(end - here) + ")");
  }
  // np.save writes exactly the array; more bytes mean a wrong shape in the header or several
  // arrays saved into one file, and reading only the first part would silently lose data.
  if (end - here > static_cast<std::streamoff>(payload)) {
    const auto extra = static_cast<uint64_t>(end - here) - payload;
    throw InputError(path + ": NPY file has " + std::to_string(extra) +
                     " bytes after the data of its header's shape (" + std::to_string(payload) +
                     " bytes): wrong shape in the header, or more than one array in the file");
  }
  a.bytes.resize(payload);
  in.read(a.bytes.data(), static_cast<std::streamsize>(payload));
  if (!in) throw InputError(path + ": cannot read NPY data");
  // numpy writes a transposed array (a.T) in Fortran order: column after column. Reordered here
  // so that every reader sees rows; a 1-D array is the same either way.
  if (fortran && a.shape.size() == 2 && a.shape[0] > 1 && a.shape[1] > 1) {
    const size_t rows = a.shape[0], cols = a.shape[1], item = a.item_size;
    std::vector<char> c_order(payload);
    for (size_t c = 0; c < cols; ++c) {
      for (size_t r = 0; r < rows; ++r) {
        std::memcpy(&c_order[(r * cols + c) * item], &a.bytes[(c * rows + r) * item], item);
      }
    }
    a.bytes.swap(c_order);
  }
  return a;
}

}  // namespace terrastride::perception
