// PCD and PLY reading through PCL's io module. The only translation unit with PCL io headers.
#include <algorithm>
#include <cerrno>
#include <charconv>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <sstream>
#include <string_view>
#include <vector>

#include "cloud_io_internal.hpp"
#include "terrastride/perception/point_cloud.hpp"

#ifdef TERRASTRIDE_HAVE_PCL
#include <pcl/PCLPointCloud2.h>
#include <pcl/console/print.h>
#include <pcl/io/pcd_io.h>
#include <pcl/io/ply_io.h>
#endif

namespace terrastride::perception::detail {
namespace {

std::string first_bytes(const std::string& path, size_t n) {
  std::ifstream in(path, std::ios::binary);
  std::string s(n, '\0');
  in.read(s.data(), static_cast<std::streamsize>(n));
  s.resize(static_cast<size_t>(in.gcount()));
  return s;
}

// PCL's readers print their own diagnostics and, for some garbage, get far before failing; a
// cheap look at the first bytes gives a clearer "this is not a PCD/PLY file" message up front.
void check_pcd_signature(const std::string& path) {
  std::string head = first_bytes(path, 4096);
  size_t pos = 0;
  while (pos < head.size()) {
    size_t eol = head.find('\n', pos);
    if (eol == std::string::npos) eol = head.size();
    std::string line = head.substr(pos, eol - pos);
    pos = eol + 1;
    const size_t start = line.find_first_not_of(" \t\r");
    if (start == std::string::npos || line[start] == '#') continue;
    static const char* const kKeys[] = {"VERSION", "FIELDS", "SIZE",   "TYPE",      "COUNT",
                                        "WIDTH",   "HEIGHT", "POINTS", "VIEWPOINT", "DATA"};
    for (const char* key : kKeys) {
      if (line.compare(start, std::strlen(key), key) == 0) return;
    }
    break;
  }
  throw InputError(path + ": not a PCD file (no PCD header: expected VERSION/FIELDS lines)");
}

// ---- Header and body checks, before PCL sees the file ----
//
// PCL's readers trust the header. They allocate what it promises (even in readHeader), so a lying
// count in a corrupt or hostile file would make them allocate gigabytes; they stop after the
// promised count, dropping further points without a word; and in ASCII bodies PCD reads an
// unparsable value as 0 and skips lines with the wrong number of values, PLY reads it as NaN.
// These checks compare the header with the body and name the first disagreement (line, field),
// so that PCL only ever reads a file whose body is what its header says.

[[noreturn]] void too_short(const std::string& path, double points, uintmax_t file_size) {
  throw InputError(path + ": header promises " + std::to_string(static_cast<uint64_t>(points)) +
                   " points but the file has only " + std::to_string(file_size) +
                   " bytes (truncated or corrupt)");
}

// A binary body longer than the header says: either more points than declared or a corrupt
// header. Zero bytes are tolerated: old PCL versions padded binary PCDs with zeros (the real
// grid_map sample has 3873 of them), and a few stray bytes (a final newline) are not a point.
void check_binary_tail(const std::string& path, std::ifstream& in, std::streamoff data_end,
                       uintmax_t file_size, double points, double record) {
  const double extra = static_cast<double>(file_size) - static_cast<double>(data_end);
  if (record <= 0 || extra < record) return;
  in.clear();
  in.seekg(data_end);
  char buf[1 << 16];
  bool nonzero = false;
  while (!nonzero && in) {
    in.read(buf, sizeof(buf));
    nonzero = std::any_of(buf, buf + in.gcount(), [](char c) { return c != 0; });
  }
  if (!nonzero) return;
  throw InputError(path + ": header says " + std::to_string(static_cast<uint64_t>(points)) +
                   " points but the file holds " + std::to_string(static_cast<uint64_t>(extra)) +
                   " more bytes of data after them (room for " +
                   std::to_string(static_cast<uint64_t>(extra / record)) +
                   " more points): the point count in the header is wrong or the file is corrupt");
}

std::vector<std::string> split_words(const std::string& line) {
  std::istringstream in(line);
  std::vector<std::string> words;
  for (std::string w; in >> w;) words.push_back(w);
  return words;
}

// Splits a body line at PCL's separators (space, tab, CR: CRLF files are fine). Any other byte,
// a comma included, is part of a token, which then is not a number.
void split_tokens(const std::string& line, std::vector<std::string_view>& out) {
  out.clear();
  const auto blank = [](char c) { return c == ' ' || c == '\t' || c == '\r'; };
  size_t i = 0;
  while (i < line.size()) {
    while (i < line.size() && blank(line[i])) ++i;
    const size_t start = i;
    while (i < line.size() && !blank(line[i])) ++i;
    if (i > start) out.emplace_back(line.data() + start, i - start);
  }
}

// Whether the whole token is a decimal number (nan/inf included, which PCL reads as such). PCL
// turns anything else into 0 or NaN ("abc"), or into its numeric prefix ("1.5abc"). Integer fields
// are held to the same rule only: a "255.0" in a colour field is sloppy but harmless, as PCL
// reads coordinates only from float fields.
bool is_number(std::string_view t) {
  if (t.size() > 1 && t[0] == '+' && t[1] != '-') t.remove_prefix(1);  // from_chars takes no '+'
  const char* const end = t.data() + t.size();
  double v;
  const auto r = std::from_chars(t.data(), end, v);
  if (r.ec == std::errc::result_out_of_range) {
    // Beyond a double's range (PCL reads it as infinite or 0); `ptr` is not reliable here.
    return t.find_first_not_of("0123456789.eE+-") == std::string_view::npos;
  }
  return r.ec == std::errc() && r.ptr == end;
}

std::string quoted(std::string_view token) {
  return "'" + std::string(token.substr(0, 40)) + (token.size() > 40 ? "...'" : "'");
}

std::string line_prefix(const std::string& path, size_t line_no) {
  return path + ": line " + std::to_string(line_no) + ": ";
}

// Every number in a PCD or PLY header is a count or a byte size: plain decimal digits (PCL reads
// "1e3" or "0x10" as 1 or 0), at most 2^53 (exact in a double, so no later arithmetic or
// conversion to a 64-bit integer can overflow; a real file is far below that).
double to_count(const std::string& path, const std::string& text) {
  uint64_t v = 0;
  const char* const end = text.data() + text.size();
  const auto r = std::from_chars(text.data(), end, v);
  if (r.ec != std::errc() || r.ptr != end || v > (uint64_t{1} << 53)) {
    throw InputError(path + ": bad number " + detail::quoted(text) +
                     " in header: counts and sizes are whole decimal numbers from 0 to 2^53");
  }
  return static_cast<double>(v);
}

uintmax_t file_size_of(const std::string& path) {
  std::error_code ec;
  const uintmax_t size = std::filesystem::file_size(path, ec);
  if (ec) throw InputError(path + ": cannot determine the file size: " + ec.message());
  return size;
}

// Where the body starts: the stream position after the header's last line, or the end of the file
// when the header's last line has no newline (getline then sets eof and tellg fails).
std::streamoff body_offset(std::ifstream& in, uintmax_t file_size) {
  const std::streamoff pos = in.tellg();
  return pos < 0 ? static_cast<std::streamoff>(file_size) : pos;
}

struct PcdHeader {
  std::vector<std::string> fields, types;
  std::vector<double> sizes, counts;
  double points = -1, width = -1, height = -1;
  bool has_data = false;
  std::string data;  // ascii, binary or binary_compressed
  size_t lines = 0;  // header lines, DATA included: body line k (1-based) is file line lines + k
};

PcdHeader parse_pcd_header(const std::string& path, std::ifstream& in) {
  PcdHeader h;
  std::string line;
  while (!h.has_data && h.lines < 1000 && std::getline(in, line)) {
    ++h.lines;
    const auto w = split_words(line);
    if (w.empty() || w[0][0] == '#') continue;
    if (w[0] == "FIELDS") {
      h.fields.assign(w.begin() + 1, w.end());
    } else if (w[0] == "TYPE") {
      h.types.assign(w.begin() + 1, w.end());
    } else if (w[0] == "SIZE" || w[0] == "COUNT") {
      auto& v = w[0] == "SIZE" ? h.sizes : h.counts;
      v.clear();
      for (size_t i = 1; i < w.size(); ++i) v.push_back(to_count(path, w[i]));
    } else if (w[0] == "POINTS" && w.size() > 1) {
      h.points = to_count(path, w[1]);
    } else if (w[0] == "WIDTH" && w.size() > 1) {
      h.width = to_count(path, w[1]);
    } else if (w[0] == "HEIGHT" && w.size() > 1) {
      h.height = to_count(path, w[1]);
    } else if (w[0] == "DATA") {
      h.has_data = true;
      h.data = w.size() > 1 ? w[1] : "";
    }
  }
  return h;
}

// Every body line (blank ones aside, which PCL skips) must hold one number per value the header
// declares, and there must be exactly as many such lines as points.
void check_pcd_ascii_body(const std::string& path, const PcdHeader& h, double points,
                          std::ifstream& in) {
  std::vector<std::string> names;  // one per value on a line: "x", or "normal[2]" for COUNT 3
  for (size_t i = 0; i < h.fields.size(); ++i) {
    const size_t count = i < h.counts.size() ? static_cast<size_t>(h.counts[i]) : 1;
    for (size_t j = 0; j < count && names.size() < 100000; ++j) {
      names.push_back(count == 1 ? h.fields[i] : h.fields[i] + "[" + std::to_string(j) + "]");
    }
  }
  std::string field_list;
  for (size_t i = 0; i < names.size() && i < 12; ++i) field_list += (i ? " " : "") + names[i];
  if (names.size() > 12) field_list += " ...";
  const auto n = static_cast<uint64_t>(points);
  uint64_t found = 0, extra = 0;
  size_t line_no = h.lines, last_point_line = h.lines, first_extra_line = 0;
  std::string line;
  std::vector<std::string_view> tok;
  while (std::getline(in, line)) {
    ++line_no;
    split_tokens(line, tok);
    if (tok.empty()) continue;
    if (found == n) {
      if (extra++ == 0) first_extra_line = line_no;
      continue;
    }
    if (tok.size() != names.size()) {
      throw InputError(line_prefix(path, line_no) + "expected " + std::to_string(names.size()) +
                       " values (" + field_list + "), found " + std::to_string(tok.size()) +
                       (in.eof() ? " (the file ends in this line: truncated?)" : ""));
    }
    for (size_t k = 0; k < tok.size(); ++k) {
      if (!is_number(tok[k])) {
        throw InputError(line_prefix(path, line_no) + "field '" + names[k] +
                         "': " + quoted(tok[k]) + " is not a number");
      }
    }
    ++found;
    last_point_line = line_no;
  }
  if (extra > 0) {
    throw InputError(path + ": header says " + std::to_string(n) + " points but the data has " +
                     std::to_string(extra) + " more line(s) of values after them, from line " +
                     std::to_string(first_extra_line) +
                     ": the POINTS/WIDTH in the header is wrong or the file is corrupt");
  }
  if (found < n) {
    throw InputError(path + ": header says " + std::to_string(n) + " points, data ends after " +
                     std::to_string(found) + " (line " + std::to_string(last_point_line) +
                     "): truncated file or wrong POINTS/WIDTH");
  }
}

// Whether a header comment (before DATA) is kSensorFrameMarker.
[[maybe_unused]] bool header_has_marker(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::string line;
  for (int n = 0; n < 1000 && std::getline(in, line); ++n) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line == kSensorFrameMarker) return true;
    if (line.compare(0, 4, "DATA") == 0) return false;
  }
  return false;
}

void check_pcd(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError(path + ": cannot open file: " + std::strerror(errno));
  const PcdHeader h = parse_pcd_header(path, in);
  const auto header_error = [&](const std::string& what) {
    throw InputError(path + ": bad PCD header: " + what);
  };
  if (!h.has_data) header_error("no DATA line (truncated header?)");
  if (h.data != "ascii" && h.data != "binary" && h.data != "binary_compressed") {
    header_error("DATA '" + h.data + "' is not ascii, binary or binary_compressed");
  }
  if (h.fields.empty()) header_error("no FIELDS line");
  const auto same_length = [&](const char* key, size_t size) {
    if (size != h.fields.size()) {
      header_error(std::to_string(h.fields.size()) + " FIELDS but " + std::to_string(size) + " " +
                   key + " entries");
    }
  };
  same_length("SIZE", h.sizes.size());
  same_length("TYPE", h.types.size());
  if (!h.counts.empty()) same_length("COUNT", h.counts.size());
  // As PCL: POINTS is required, HEIGHT defaults to 1, and a header without WIDTH is a single row.
  if (h.points < 0) header_error("no POINTS line");
  if (h.points == 0) throw InputError(path + ": contains no points (POINTS 0)");
  if (h.width < 0 && h.height >= 0) header_error("HEIGHT without WIDTH");
  const double height = h.height < 0 ? 1 : h.height;
  if (h.width >= 0 && h.width * height != h.points) {
    header_error("WIDTH " + std::to_string(static_cast<uint64_t>(h.width)) + " x HEIGHT " +
                 std::to_string(static_cast<uint64_t>(height)) + " is not POINTS " +
                 std::to_string(static_cast<uint64_t>(h.points)));
  }
  const double n = h.points;

  const uintmax_t file_size = file_size_of(path);
  const std::streamoff body_start = body_offset(in, file_size);
  const double body = static_cast<double>(file_size) - static_cast<double>(body_start);
  if (h.data == "ascii") {
    check_pcd_ascii_body(path, h, n, in);
    return;
  }
  double step = 0;
  for (size_t i = 0; i < h.sizes.size(); ++i) {
    step += h.sizes[i] * (i < h.counts.size() ? h.counts[i] : 1);
  }
  if (h.data == "binary") {
    if (n * step > body) too_short(path, n, file_size);
    check_binary_tail(path, in, body_start + static_cast<std::streamoff>(n * step), file_size, n,
                      step);
    return;
  }
  // binary_compressed: u32 compressed size, u32 uncompressed size, then LZF data. LZF does not
  // compress better than about 1:90, which bounds what a lying header can make PCL allocate.
  if (n * step / 100.0 - 1e6 > body) too_short(path, n, file_size);
  unsigned char sizes[8];
  if (body < 8 || !in.read(reinterpret_cast<char*>(sizes), 8)) {
    throw InputError(path + ": compressed PCD data is truncated (no block sizes after the header)");
  }
  const auto u32 = [&](int at) {
    return static_cast<uint32_t>(sizes[at]) | static_cast<uint32_t>(sizes[at + 1]) << 8 |
           static_cast<uint32_t>(sizes[at + 2]) << 16 | static_cast<uint32_t>(sizes[at + 3]) << 24;
  };
  const uint32_t compressed = u32(0), uncompressed = u32(4);
  if (8.0 + compressed > body) {
    throw InputError(path + ": compressed PCD data is truncated (block of " +
                     std::to_string(compressed) + " bytes, " +
                     std::to_string(static_cast<uint64_t>(body) - 8) + " present)");
  }
  // PCL resizes its buffer to the stored size when the two disagree: points would go missing
  // or be dropped silently.
  if (step > 0 && static_cast<double>(uncompressed) != n * step) {
    throw InputError(path + ": header says " + std::to_string(static_cast<uint64_t>(n)) +
                     " points (" + std::to_string(static_cast<uint64_t>(n * step)) +
                     " bytes) but the compressed data unpacks to " + std::to_string(uncompressed) +
                     " bytes (" + std::to_string(static_cast<uint64_t>(uncompressed / step)) +
                     " points): corrupt file or wrong POINTS");
  }
}

size_t ply_type_size(const std::string& t) {
  if (t == "char" || t == "uchar" || t == "int8" || t == "uint8") return 1;
  if (t == "short" || t == "ushort" || t == "int16" || t == "uint16") return 2;
  if (t == "int" || t == "uint" || t == "float" || t == "int32" || t == "uint32" ||
      t == "float32") {
    return 4;
  }
  if (t == "double" || t == "float64") return 8;
  return 1;
}

struct PlyProperty {
  bool list = false;
  std::string count_type, type, name;
};
struct PlyElement {
  std::string name;
  double count = 0;
  std::vector<PlyProperty> props;
};
struct PlyHeader {
  std::string format;
  std::vector<PlyElement> elements;
  bool ended = false;
  size_t lines = 0;  // header lines, end_header included
};

PlyHeader parse_ply_header(const std::string& path, std::ifstream& in) {
  PlyHeader h;
  std::string line;
  while (h.lines < 10000 && std::getline(in, line)) {
    ++h.lines;
    const auto w = split_words(line);
    if (w.empty()) continue;
    if (w[0] == "format" && w.size() > 1) {
      h.format = w[1];
    } else if (w[0] == "element" && w.size() > 2) {
      h.elements.push_back({w[1], to_count(path, w[2]), {}});
    } else if (w[0] == "property" && w.size() > 2 && !h.elements.empty()) {
      PlyProperty p;
      if (w[1] == "list" && w.size() > 4) {
        p = {true, w[2], w[3], w[4]};
      } else {
        p = {false, "", w[1], w[2]};
      }
      h.elements.back().props.push_back(p);
    } else if (w[0] == "end_header") {
      h.ended = true;
      break;
    }
  }
  return h;
}

// "point 5 of 100" for vertices, "'face' 5 of 100" for other elements (1-based).
std::string ply_item(const PlyElement& e, uint64_t i) {
  const std::string what = e.name == "vertex" ? "point" : "'" + e.name + "'";
  return what + " " + std::to_string(i + 1) + " of " +
         std::to_string(static_cast<uint64_t>(e.count));
}

std::string ply_count(const PlyElement& e) {
  const std::string n = std::to_string(static_cast<uint64_t>(e.count));
  return e.name == "vertex" ? n + " points" : n + " '" + e.name + "' elements";
}

// PCL reads an ASCII PLY body one line per element, in header order.
void check_ply_ascii_body(const std::string& path, const PlyHeader& h, std::ifstream& in) {
  std::string line;
  std::vector<std::string_view> tok;
  size_t line_no = h.lines;
  for (const PlyElement& e : h.elements) {
    const auto count = static_cast<uint64_t>(e.count);
    for (uint64_t i = 0; i < count; ++i) {
      if (!std::getline(in, line)) {
        throw InputError(path + ": header says " + ply_count(e) + ", data ends after " +
                         std::to_string(i) + " (at line " + std::to_string(line_no) +
                         "): truncated file or wrong element count");
      }
      ++line_no;
      split_tokens(line, tok);
      size_t k = 0;         // next token
      size_t expected = 0;  // values this line must hold
      bool exact = true;    // false when the line ends before a list's length
      const auto where = [&] { return line_prefix(path, line_no) + ply_item(e, i); };
      for (const PlyProperty& p : e.props) {
        if (k >= tok.size()) {
          ++expected;
          exact = exact && !p.list;
          continue;
        }
        if (!p.list) {
          if (!is_number(tok[k])) {
            throw InputError(where() + ", property '" + p.name + "': " + quoted(tok[k]) +
                             " is not a number");
          }
          ++k;
          ++expected;
          continue;
        }
        // A list: its length, then that many values. The length steers the parse, so it must be
        // a non-negative integer.
        int64_t items = -1;
        const auto r = std::from_chars(tok[k].data(), tok[k].data() + tok[k].size(), items);
        if (r.ec != std::errc() || r.ptr != tok[k].data() + tok[k].size() || items < 0) {
          throw InputError(where() + ", list '" + p.name + "': length " + quoted(tok[k]) +
                           " is not a non-negative integer");
        }
        ++k;
        // Capped so that absurd lengths cannot overflow the sum; the line is refused either way.
        expected += 1 + static_cast<size_t>(std::min<int64_t>(items, int64_t{1} << 40));
        for (; k < tok.size() && k < expected; ++k) {
          if (!is_number(tok[k])) {
            throw InputError(where() + ", list '" + p.name + "': " + quoted(tok[k]) +
                             " is not a number");
          }
        }
        k = expected;
      }
      if (tok.size() != expected) {
        throw InputError(
            where() + ": expected " + (exact ? "" : "at least ") + std::to_string(expected) +
            " values, found " + std::to_string(tok.size()) +
            (in.eof() && tok.size() < expected ? " (the file ends in this line: truncated?)" : ""));
      }
    }
  }
  // Blank lines may follow; more values mean more elements than the header declares.
  size_t extra = 0, first_extra_line = 0;
  while (std::getline(in, line)) {
    ++line_no;
    split_tokens(line, tok);
    if (!tok.empty() && extra++ == 0) first_extra_line = line_no;
  }
  if (extra > 0) {
    const std::string declared =
        h.elements.size() == 1 && h.elements[0].name == "vertex"
            ? ply_count(h.elements[0])
            : "elements up to line " + std::to_string(first_extra_line - 1);
    throw InputError(path + ": header says " + declared + " but the data has " +
                     std::to_string(extra) + " more line(s) of values after them, from line " +
                     std::to_string(first_extra_line) +
                     ": the element count in the header is wrong or the file is corrupt");
  }
}

void check_ply(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError(path + ": cannot open file: " + std::strerror(errno));
  const PlyHeader h = parse_ply_header(path, in);
  if (!h.ended) throw InputError(path + ": bad PLY header: no end_header line");
  if (h.format == "ascii") {
    check_ply_ascii_body(path, h, in);
    return;
  }
  if (h.format != "binary_little_endian" && h.format != "binary_big_endian") {
    throw InputError(path + ": bad PLY header: format '" + h.format +
                     "' is not ascii, binary_little_endian or binary_big_endian");
  }
  double need = 0, points = 0, vertex_record = 0;
  bool has_list = false;
  for (const PlyElement& e : h.elements) {
    double record = 0;  // a list counts only its length here, so `need` is a lower bound
    for (const PlyProperty& p : e.props) {
      record += static_cast<double>(ply_type_size(p.list ? p.count_type : p.type));
      has_list = has_list || p.list;
    }
    need += e.count * record;
    if (e.name == "vertex") {
      points = e.count;
      vertex_record = record;
    }
  }
  const uintmax_t file_size = file_size_of(path);
  const std::streamoff body_start = body_offset(in, file_size);
  if (need > static_cast<double>(file_size) - static_cast<double>(body_start)) {
    too_short(path, points, file_size);
  }
  // Lists (faces) make the exact body size unknown without walking it.
  if (!has_list) {
    check_binary_tail(path, in, body_start + static_cast<std::streamoff>(need), file_size, points,
                      vertex_record);
  }
}

void check_ply_signature(const std::string& path) {
  const std::string head = first_bytes(path, 4);
  if (head.compare(0, 3, "ply") != 0 || (head.size() > 3 && head[3] != '\n' && head[3] != '\r')) {
    throw InputError(path + ": not a PLY file (does not start with 'ply')");
  }
}

#ifdef TERRASTRIDE_HAVE_PCL

// PCL reports parse problems on its console; we turn them into one InputError instead. The
// level is set once per process and never restored: toggling a global around each read would race
// when several threads (the socket service) read clouds at once, and PCL is used only here.
void silence_pcl() {
  static std::once_flag once;
  std::call_once(once, [] { pcl::console::setVerbosityLevel(pcl::console::L_ALWAYS); });
}

// Pulls x, y, z (float32 or float64 fields) out of a PCLPointCloud2 blob, whatever other fields
// (normals, intensity, padding) it carries.
RawCloud extract_xyz(const std::string& path, const pcl::PCLPointCloud2& blob) {
  int offset[3] = {-1, -1, -1};
  uint8_t type[3] = {0, 0, 0};
  const char* names[3] = {"x", "y", "z"};
  for (const auto& f : blob.fields) {
    for (int k = 0; k < 3; ++k) {
      if (f.name == names[k]) {
        offset[k] = static_cast<int>(f.offset);
        type[k] = f.datatype;
      }
    }
  }
  for (int k = 0; k < 3; ++k) {
    if (offset[k] < 0) throw InputError(path + ": has no '" + names[k] + "' field");
    if (type[k] != pcl::PCLPointField::FLOAT32 && type[k] != pcl::PCLPointField::FLOAT64) {
      throw InputError(path + ": field '" + names[k] + "' is not float32/float64");
    }
    const size_t size = type[k] == pcl::PCLPointField::FLOAT32 ? 4 : 8;
    if (static_cast<size_t>(offset[k]) + size > blob.point_step) {
      throw InputError(path + ": field '" + names[k] + "' lies outside the point record");
    }
  }
  const size_t n = static_cast<size_t>(blob.width) * blob.height;
  if (blob.data.size() < n * blob.point_step) throw InputError(path + ": point data is truncated");
  RawCloud raw;
  raw.points.resize(n);
  const uint8_t* base = blob.data.data();
  for (size_t i = 0; i < n; ++i) {
    const uint8_t* rec = base + i * blob.point_step;
    for (int k = 0; k < 3; ++k) {
      if (type[k] == pcl::PCLPointField::FLOAT32) {
        float v;
        std::memcpy(&v, rec + offset[k], 4);
        raw.points[i][k] = v;
      } else {
        double v;
        std::memcpy(&v, rec + offset[k], 8);
        raw.points[i][k] = static_cast<float>(v);
      }
    }
  }
  return raw;
}

// "Identity-zero" is PCL's default viewpoint, i.e. no sensor pose recorded in the file. The
// values are checked by the caller (cloud_io.cpp), which names the file.
void set_viewpoint(RawCloud& raw, const Eigen::Vector4f& origin,
                   const Eigen::Quaternionf& orientation) {
  const bool zero = origin.head<3>().isZero(0.0f);
  const bool identity = orientation.w() == 1.0f && orientation.vec().isZero(0.0f);
  raw.has_viewpoint = !(zero && identity);
  raw.viewpoint_position = origin.head<3>().cast<double>();
  raw.viewpoint_wxyz =
      Eigen::Vector4d(orientation.w(), orientation.x(), orientation.y(), orientation.z());
}

#endif

}  // namespace

namespace {

#ifdef TERRASTRIDE_HAVE_PCL
// PCD and PLY differ only in PCL's reader class; both share pcl::FileReader::read.
RawCloud read_with_pcl_reader(pcl::FileReader& reader, const std::string& path,
                              const std::string& format) {
  silence_pcl();
  pcl::PCLPointCloud2 blob;
  Eigen::Vector4f origin = Eigen::Vector4f::Zero();
  Eigen::Quaternionf orientation = Eigen::Quaternionf::Identity();
  int version = 0;
  int rc;
  try {
    rc = reader.read(path, blob, origin, orientation, version);
  } catch (const std::exception& e) {
    throw InputError(path + ": unreadable " + format + " file: " + e.what());
  }
  if (rc < 0)
    throw InputError(path + ": unreadable or corrupt " + format + " file (PCL reader failed)");
  RawCloud raw = extract_xyz(path, blob);
  set_viewpoint(raw, origin, orientation);
  return raw;
}
#endif

}  // namespace

RawCloud read_pcd_with_pcl(const std::string& path) {
  check_pcd_signature(path);
  check_pcd(path);
#ifdef TERRASTRIDE_HAVE_PCL
  pcl::PCDReader reader;
  RawCloud raw = read_with_pcl_reader(reader, path, "PCD");
  raw.sensor_frame_marked = header_has_marker(path);
  return raw;
#else
  throw InputError(path + ": PCD reading needs PCL (built with TERRASTRIDE_WITH_PCL=OFF)");
#endif
}

RawCloud read_ply_with_pcl(const std::string& path) {
  check_ply_signature(path);
  check_ply(path);
#ifdef TERRASTRIDE_HAVE_PCL
  pcl::PLYReader reader;
  return read_with_pcl_reader(reader, path, "PLY");
#else
  throw InputError(path + ": PLY reading needs PCL (built with TERRASTRIDE_WITH_PCL=OFF)");
#endif
}

}  // namespace terrastride::perception::detail
