// OctoMap files as input. OctoMap's readers do the parsing; this file checks the header first
// (their own failures are a message on stderr and a false or null return), names the tree type,
// and turns occupied voxels into the support points a height grid is built from.
#include "terrastride/perception/octomap_input.hpp"

#include <octomap/ColorOcTree.h>
#include <octomap/OcTreeStamped.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <sstream>
#include <unordered_map>
#include <vector>

#include "cloud_io_internal.hpp"

namespace terrastride::perception {
namespace {

using detail::lower_extension;

std::string read_file(const std::string& path) {
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) throw InputError(path + ": file not found");
  if (std::filesystem::is_directory(path, ec))
    throw InputError(path + ": is a directory, not an OctoMap file");
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError(path + ": cannot open file: " + std::strerror(errno));
  std::ostringstream data;
  data << in.rdbuf();
  if (!in && !in.eof()) throw InputError(path + ": read error");
  return data.str();
}

// The header's lines up to "data" (both formats: first line, '#' comments, then "key value"
// lines). Returns the keys' values; throws when the first line is not `first_line`.
struct Header {
  std::string id;
  double res = 0;
  bool has_res = false;
  uint64_t size = 0;  // the number of nodes the writer counted
  bool has_size = false;
  size_t data_offset = 0;  // where the body begins
};

Header parse_header(const std::string& path, const std::string& bytes,
                    const std::string& first_line, const std::string& format) {
  Header h;
  size_t pos = bytes.find('\n');
  const std::string line0 = bytes.substr(0, pos == std::string::npos ? 0 : pos);
  if (line0.rfind(first_line, 0) != 0)
    throw InputError(path + ": not an OctoMap " + format + " file (the first line is not '" +
                     first_line + "')");
  size_t p = pos + 1;
  while (p < bytes.size()) {
    const size_t e = bytes.find('\n', p);
    if (e == std::string::npos) break;
    std::string line = bytes.substr(p, e - p);
    p = e + 1;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.empty() || line[0] == '#') continue;
    std::istringstream ls(line);
    std::string key;
    ls >> key;
    if (key == "id") {
      ls >> h.id;
    } else if (key == "res") {
      h.has_res = static_cast<bool>(ls >> h.res);
    } else if (key == "size") {
      std::string count;
      ls >> count;
      h.has_size = !count.empty() && count.size() <= 19 &&
                   std::all_of(count.begin(), count.end(), [](char c) { return c >= '0' && c <= '9'; });
      if (h.has_size) h.size = std::stoull(count);
    } else if (key == "data") {
      h.data_offset = p;
      return h;
    }
  }
  throw InputError(path + ": OctoMap header without a 'data' line (truncated or not an OctoMap)");
}

bool is_occupancy_type(const std::string& id) {
  return id == "OcTree" || id == "ColorOcTree" || id == "OcTreeStamped";
}

void check_type(const std::string& path, const std::string& id) {
  if (id.empty()) throw InputError(path + ": OctoMap header without a tree type ('id' line)");
  if (!is_occupancy_type(id))
    throw InputError(path + ": an OctoMap of type " + id +
                     ", not an occupancy tree (terrastride reads OcTree, ColorOcTree and "
                     "OcTreeStamped)");
}

void check_resolution(const std::string& path, const Header& h) {
  if (!h.has_res || !std::isfinite(h.res) || h.res < 0.001 || h.res > 10)
    throw InputError(path + ": OctoMap resolution " +
                     (h.has_res ? std::to_string(h.res) : "missing") +
                     " is not within [0.001, 10] m");
}

// OctoMap's readers trust the body: they recurse for as long as the node bits say "children
// follow" (past the tree's 16 levels, and past the end of the data, where a failed read leaves
// the last byte's bits in place: a body of 0xFF bytes recurses until the stack overflows), and
// never check a read. So the body is walked here first, in OctoMap's own layout, and handed to
// OctoMap only when it is exactly one well-formed tree of the size the header gives.
constexpr unsigned kTreeDepth = 16;        // OctoMap's fixed depth: the leaves lie at depth 16
constexpr uint64_t kMaxNodes = 1ull << 25;  // ~1 GB of OcTree nodes

class BodyWalk {
 public:
  BodyWalk(const std::string& path, const std::string& bytes, size_t begin)
      : path_(path), bytes_(bytes), pos_(begin) {}

  // .bt: a node is two bytes of child flags, two bits per child (bit 2i and 2i+1 of byte i/4):
  // 00 no child, 10 a free leaf, 01 an occupied leaf, 11 an inner node, whose own flags follow
  // (depth first, after all eight flags of this node).
  void binary_node(unsigned depth) {
    need(2, depth);
    const auto b0 = static_cast<uint8_t>(bytes_[pos_]), b1 = static_cast<uint8_t>(bytes_[pos_ + 1]);
    const size_t at = pos_;
    pos_ += 2;
    bool inner[8] = {};
    for (unsigned i = 0; i < 8; ++i) {
      const unsigned bits = ((i < 4 ? b0 : b1) >> (2 * (i % 4))) & 3u;
      if (bits == 0) continue;
      add_node();
      inner[i] = bits == 3;
      if (inner[i] && depth + 1 >= kTreeDepth) deeper_than_the_tree(at, depth + 1);
    }
    for (unsigned i = 0; i < 8; ++i)
      if (inner[i]) binary_node(depth + 1);
  }

  // .ot: a node is its data (`data_bytes`: the occupancy's float, a colour's three bytes), then
  // one byte with a bit per existing child, whose nodes follow depth first.
  void full_node(unsigned depth, size_t data_bytes) {
    need(data_bytes + 1, depth);
    float value;
    std::memcpy(&value, bytes_.data() + pos_, sizeof value);
    if (!std::isfinite(value))
      throw InputError(path_ + ": corrupt OctoMap data at byte " + std::to_string(pos_) +
                       ": a node's occupancy is not a finite number");
    const size_t at = pos_ + data_bytes;
    const auto children = static_cast<uint8_t>(bytes_[at]);
    pos_ = at + 1;
    if (children != 0 && depth >= kTreeDepth) deeper_than_the_tree(at, depth + 1);
    for (unsigned i = 0; i < 8; ++i)
      if (children & (1u << i)) {
        add_node();
        full_node(depth + 1, data_bytes);
      }
  }

  // After the root: the body must end where the tree does, with as many nodes as the header says.
  void finish(const Header& h) const {
    if (pos_ != bytes_.size())
      throw InputError(path_ + ": corrupt OctoMap: " + std::to_string(bytes_.size() - pos_) +
                       " bytes after the end of the tree (at byte " + std::to_string(pos_) +
                       " of " + std::to_string(bytes_.size()) + ")");
    if (h.size != nodes_)
      throw InputError(path_ + ": corrupt OctoMap: the header says " + std::to_string(h.size) +
                       " nodes, the data holds " + std::to_string(nodes_));
  }

 private:
  void need(size_t n, unsigned depth) const {
    if (n > bytes_.size() - pos_)
      throw InputError(path_ + ": the OctoMap data is truncated: a node at depth " +
                       std::to_string(depth) + " needs " + std::to_string(n) + " bytes at byte " +
                       std::to_string(pos_) + ", the file ends at byte " +
                       std::to_string(bytes_.size()) + " (" + std::to_string(nodes_) +
                       " nodes read)");
  }
  void add_node() {
    if (++nodes_ > kMaxNodes)
      throw InputError(path_ + ": the OctoMap holds more than " + std::to_string(kMaxNodes) +
                       " nodes (about 1 GB in memory): refused");
  }
  [[noreturn]] void deeper_than_the_tree(size_t at, unsigned depth) const {
    throw InputError(path_ + ": corrupt OctoMap data at byte " + std::to_string(at) +
                     ": a node at depth " + std::to_string(depth) + " has children, but OctoMap "
                     "trees are " + std::to_string(kTreeDepth) + " levels deep");
  }

  const std::string& path_;
  const std::string& bytes_;
  size_t pos_;
  uint64_t nodes_ = 1;  // the root
};

// The checked body as a stream for OctoMap's node readers. The file readers (readBinary,
// AbstractOcTree::read) are not used: they parse the header again, by other rules than
// parse_header's, and announce every read on std::cerr ("Reading binary octree type OcTree"),
// which the commands keep for their own messages and the server's threads share.
std::istringstream checked_body(const Header& h, const std::string& bytes) {
  return std::istringstream(bytes.substr(h.data_offset), std::ios::in | std::ios::binary);
}

// A full (.ot) body read into a tree of the file's type.
template <typename Tree>
std::unique_ptr<Tree> read_full_body(const std::string& path, const Header& h,
                                     const std::string& bytes) {
  auto tree = std::make_unique<Tree>(h.res);
  std::istringstream in = checked_body(h, bytes);
  tree->readData(in);
  if (in.bad() || tree->size() != h.size)
    throw InputError(path + ": the OctoMap data is truncated or corrupt");
  return tree;
}

// The node data bytes of a full (.ot) file's tree type (OcTreeDataNode::readData and
// ColorOcTreeNode::readData: the float log-odds, and a colour's r, g, b).
size_t full_node_data_bytes(const std::string& id) {
  return id == "ColorOcTree" ? sizeof(float) + 3 : sizeof(float);
}

void check_header(const std::string& path, const Header& h) {
  check_type(path, h.id);
  check_resolution(path, h);
  if (!h.has_size)
    throw InputError(path + ": OctoMap header without a node count ('size' line)");
  if (h.size == 0) throw InputError(path + ": the OctoMap is empty (no nodes)");
}

// An occupancy tree of another node type as an OcTree, through OctoMap's binary stream (the
// occupancy bits every .bt holds, pruned structure included): what octomap.bt keeps anyway.
template <typename Tree>
std::unique_ptr<octomap::OcTree> as_octree(const Tree& from) {
  std::stringstream bits(std::ios::in | std::ios::out | std::ios::binary);
  from.writeBinaryData(bits);
  auto to = std::make_unique<octomap::OcTree>(from.getResolution());
  to->readBinaryData(bits);
  return to;
}

// ---- octree_support_cloud's columns and runs -----------------------------------------------

// A vertical run of occupied voxels (z keys bottom..top) and what it is.
struct SupportRun {
  enum Kind : uint8_t { kSupport, kOverhang, kUnseenTop };
  uint16_t bottom = 0, top = 0;
  Kind kind = kSupport;
};

struct SupportColumn {
  uint16_t kx = 0, ky = 0;
  std::vector<SupportRun> runs;  // bottom to top
};

// The occupied voxels as columns of runs, in key order (so the cloud, and what is built from it,
// does not depend on hashing).
std::vector<SupportColumn> occupied_columns(const octomap::OcTree& tree, const std::string& source,
                                            size_t max_voxels, OctreeSupportStats* st) {
  const unsigned max_depth = tree.getTreeDepth();
  // Columns keyed by (kx, ky); each holds the z keys of its occupied voxels.
  std::unordered_map<uint32_t, std::vector<uint16_t>> columns;
  for (auto it = tree.begin_leafs(), end = tree.end_leafs(); it != end; ++it) {
    if (!tree.isNodeOccupied(*it)) {
      st->free_leaves += 1;
      continue;
    }
    const unsigned depth = it.getDepth();
    const octomap::OcTreeKey center = it.getKey();
    // A leaf at depth d spans 2^(max_depth - d) voxels per axis; its key is that of its centre,
    // so its voxels are the keys [c - half, c + half).
    const unsigned span = 1u << (max_depth - depth);
    const unsigned half = span / 2;
    const size_t n = static_cast<size_t>(span) * span * span;
    st->occupied_voxels += n;
    if (st->occupied_voxels > max_voxels)
      throw InputError(source + ": more than " + std::to_string(max_voxels) +
                       " occupied voxels once coarse leaves are expanded");
    for (unsigned dx = 0; dx < span; ++dx)
      for (unsigned dy = 0; dy < span; ++dy) {
        const uint32_t kx = center[0] - half + dx, ky = center[1] - half + dy;
        auto& col = columns[(kx << 16) | (ky & 0xffffu)];
        for (unsigned dz = 0; dz < span; ++dz)
          col.push_back(static_cast<uint16_t>(center[2] - half + dz));
      }
  }
  if (columns.empty())
    throw InputError(source + ": the OctoMap has no occupied voxel (nothing to build a map from)");
  st->columns = columns.size();
  std::vector<std::pair<uint32_t, std::vector<uint16_t>>> ordered(
      std::make_move_iterator(columns.begin()), std::make_move_iterator(columns.end()));
  columns.clear();
  std::sort(ordered.begin(), ordered.end(),
            [](const auto& a, const auto& b) { return a.first < b.first; });
  std::vector<SupportColumn> out(ordered.size());
  for (size_t c = 0; c < ordered.size(); ++c) {
    auto& zs = ordered[c].second;
    std::sort(zs.begin(), zs.end());
    zs.erase(std::unique(zs.begin(), zs.end()), zs.end());
    out[c].kx = static_cast<uint16_t>(ordered[c].first >> 16);
    out[c].ky = static_cast<uint16_t>(ordered[c].first & 0xffffu);
    for (size_t r = 0; r < zs.size();) {
      size_t top = r;
      while (top + 1 < zs.size() && zs[top + 1] == zs[top] + 1) ++top;
      out[c].runs.push_back({zs[r], zs[top], SupportRun::kSupport});
      r = top + 1;
    }
    st->runs += out[c].runs.size();
  }
  return out;
}

// A run is an overhang when the sensor saw enough beneath it: known-free voxels (search() answers
// for coarse free leaves too) between it and the run below adding up to `need` voxels, or, with a
// run below, any free voxel and `need` voxels of room (a table top whose underside was seen in
// part); the lowest run of a column needs `need` free voxels within kMaxFreeScan beneath it (a
// floor never has any: rays reach it from above). So is a run with some free space seen beneath
// and none seen above it (seen from beneath only), and every run above an overhang (a ceiling over
// a duct, a lamp over a table). Less room beneath (a pallet deck) is support; so is a run nothing
// was seen beneath (a floor, a table top never seen from below).
constexpr double kMaxFreeScan = 5.0;  // m

void classify_runs(const octomap::OcTree& tree, unsigned need, unsigned lowest_key,
                   SupportColumn& c, OctreeSupportStats* st) {
  const unsigned scan = static_cast<unsigned>(std::ceil(kMaxFreeScan / tree.getResolution()));
  bool above_overhang = false;
  for (size_t r = 0; r < c.runs.size(); ++r) {
    SupportRun& run = c.runs[r];
    // Nothing lies below the tree's lowest key (a floor at the bottom of the map scans nothing).
    const unsigned below =
        r > 0 ? c.runs[r - 1].top + 1u
              : std::max<unsigned>(lowest_key, run.bottom > scan ? run.bottom - scan : 0u);
    const unsigned room = run.bottom - below;
    unsigned free = 0;
    bool right_beneath = false;
    for (unsigned z = run.bottom; free < need && z > below; --z) {
      const octomap::OcTreeNode* node =
          tree.search(octomap::OcTreeKey(c.kx, c.ky, static_cast<uint16_t>(z - 1)));
      if (node == nullptr || tree.isNodeOccupied(node)) continue;
      right_beneath |= z == run.bottom;
      ++free;
    }
    st->seen_beneath += right_beneath;
    // Less free space seen beneath than an overhang's, and none seen above the run's top: it was
    // seen from beneath only (a ceiling lit by rays grazing under it); a surface stood on is seen
    // from above.
    bool only_from_beneath = false;
    if (free < need && !above_overhang) {
      const unsigned above = r + 1 < c.runs.size() ? c.runs[r + 1].bottom : 0xffffu;
      only_from_beneath = true;
      for (unsigned z = run.top + 1u; only_from_beneath && z < above && z <= run.top + need; ++z) {
        const octomap::OcTreeNode* node =
            tree.search(octomap::OcTreeKey(c.kx, c.ky, static_cast<uint16_t>(z)));
        only_from_beneath = node == nullptr || tree.isNodeOccupied(node);
      }
    }
    if (above_overhang || free >= need || (free > 0 && only_from_beneath) ||
        (r > 0 && free > 0 && room >= need)) {
      run.kind = SupportRun::kOverhang;
      above_overhang = true;
    } else {
      // Seen neither from above nor from beneath (the edge of a ceiling lit from the side), in a
      // tree that knows free space (built from rays): its top is no surface the sensor saw, and
      // the column gives no point for it. A tree without free leaves says nothing either way.
      run.kind = only_from_beneath && st->free_leaves > 0 ? SupportRun::kUnseenTop
                                                           : SupportRun::kSupport;
    }
  }
}

}  // namespace

bool is_octomap_file(const std::string& path) {
  const std::string ext = lower_extension(path);
  return ext == ".bt" || ext == ".ot";
}

std::unique_ptr<octomap::OcTree> read_octomap_file(const std::string& path) {
  const std::string ext = lower_extension(path);
  if (ext != ".bt" && ext != ".ot")
    throw InputError(path + ": not an OctoMap file name (expected .bt or .ot)");
  return read_octomap_bytes(path, read_file(path), ext == ".bt");
}

std::unique_ptr<octomap::OcTree> read_octomap_bytes(const std::string& path,
                                                    const std::string& bytes, bool binary) {
  if (bytes.empty()) throw InputError(path + ": file is empty");
  std::unique_ptr<octomap::OcTree> tree;
  if (binary) {
    const Header h = parse_header(path, bytes, "# Octomap OcTree binary file", "binary (.bt)");
    check_header(path, h);
    BodyWalk walk(path, bytes, h.data_offset);
    walk.binary_node(0);
    walk.finish(h);
    // The bit stream does not depend on the tree type: read it as an OcTree.
    std::istringstream in = checked_body(h, bytes);
    tree = std::make_unique<octomap::OcTree>(h.res);
    tree->readBinaryData(in);
    if (in.bad() || tree->size() != h.size)
      throw InputError(path + ": the OctoMap binary data is truncated or corrupt");
  } else {
    const Header h = parse_header(path, bytes, "# Octomap OcTree file", "(.ot)");
    check_header(path, h);
    BodyWalk walk(path, bytes, h.data_offset);
    walk.full_node(0, full_node_data_bytes(h.id));
    walk.finish(h);
    if (h.id == "ColorOcTree")
      tree = as_octree(*read_full_body<octomap::ColorOcTree>(path, h, bytes));
    else if (h.id == "OcTreeStamped")
      tree = as_octree(*read_full_body<octomap::OcTreeStamped>(path, h, bytes));
    else
      tree = read_full_body<octomap::OcTree>(path, h, bytes);
  }
  if (tree->size() == 0) throw InputError(path + ": the OctoMap is empty (no nodes)");
  return tree;
}

PointCloud octree_support_cloud(const octomap::OcTree& tree, const std::string& source,
                                OctreeSupportStats* stats, size_t max_voxels,
                                double overhang_free_height) {
  if (!(overhang_free_height > 0) || !std::isfinite(overhang_free_height))
    throw InputError(source + ": the overhang free height must be a positive number of metres");
  OctreeSupportStats st;
  std::vector<SupportColumn> columns = occupied_columns(tree, source, max_voxels, &st);
  const double res = tree.getResolution();
  // The overhang free height in whole voxels.
  const unsigned need =
      static_cast<unsigned>(std::max(1.0, std::ceil(overhang_free_height / res - 1e-9)));
  double x0, y0, z0;
  tree.getMetricMin(x0, y0, z0);
  const unsigned lowest_key = tree.coordToKey(z0 + 0.5 * res);
  for (SupportColumn& c : columns) classify_runs(tree, need, lowest_key, c, &st);
  PointCloud cloud;
  cloud.source = source;
  for (const SupportColumn& c : columns) {
    bool support = false, overhang = false;
    for (const SupportRun& run : c.runs) {
      if (run.kind == SupportRun::kOverhang) {
        ++st.overhangs;
        overhang = true;
        const octomap::point3d p = tree.keyToCoord(octomap::OcTreeKey(c.kx, c.ky, run.bottom));
        cloud.overhangs.emplace_back(p.x(), p.y(), static_cast<float>(p.z() - 0.5 * res));
      } else if (run.kind == SupportRun::kUnseenTop) {
        ++st.unseen_tops;
      } else {
        support = true;
        const octomap::point3d p = tree.keyToCoord(octomap::OcTreeKey(c.kx, c.ky, run.top));
        cloud.points.emplace_back(p.x(), p.y(), p.z());
      }
    }
    st.overhang_only_columns += overhang && !support;
  }
  if (cloud.points.empty())
    throw InputError(source + ": every run of occupied voxels of the OctoMap was seen from "
                              "beneath (overhangs only, no support surface)");
  if (stats) *stats = st;
  return cloud;
}

}  // namespace terrastride::perception
