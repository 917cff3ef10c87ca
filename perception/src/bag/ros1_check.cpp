// A careful walk of a ROS 1 bag (format 2.0) before librosbag_storage reads it (ros1_check.hpp).
// librosbag trusts the lengths in the file: it allocates a record header of whatever length the
// file claims (a huge one aborted the process), decompresses a chunk into a buffer of the size its
// header claims, and reads the records inside a chunk, at the offsets the index gives, without a
// bounds check. The walk checks what rosbag will rely on, record by record:
// - every record's header and data lie within the file, and its header fields within the header;
// - the fields rosbag reads are present with their sizes (op 1 byte, conn 4, index_pos 8, ...);
// - the bag header comes first, and its index position is the start of conn_count Connection
//   records followed by chunk_count Chunk Info records;
// - a chunk decompresses (none, bz2, lz4) to exactly the size it claims (at most
//   kMaxRos1ChunkBytes), and the records inside it are whole Message Data and Connection records;
// - each chunk's Index Data records follow it, count x 12 bytes, pointing at Message Data records
//   inside it; each Chunk Info names a chunk's start and is followed by as many Index Data
//   records as it lists connections.
#include "bag/ros1_check.hpp"

#include <bzlib.h>
#include <roslz4/lz4s.h>

#include <algorithm>
#include <cstring>
#include <fstream>
#include <map>
#include <memory>
#include <set>
#include <vector>

#include "terrastride/perception/point_cloud.hpp"

namespace terrastride::perception::bag {
namespace {

constexpr uint8_t kMessageData = 0x02, kBagHeader = 0x03, kIndexData = 0x04, kChunk = 0x05,
                  kChunkInfo = 0x06, kConnection = 0x07;
// rosbag writes chunks of ~768 kB; a bigger claim than this is corruption, not a recording.
constexpr uint64_t kMaxRos1ChunkBytes = 1ull << 30;
// Record headers hold a few fields; a connection's (its message definition) a few tens of kB.
constexpr uint64_t kMaxHeaderBytes = 1ull << 24;

using Fields = std::map<std::string, std::string>;

// "name=value" fields, each prefixed by its uint32 length (record headers, connection headers).
// Returns an empty string or what is wrong.
std::string parse_fields(const char* data, size_t size, Fields* out) {
  size_t pos = 0;
  while (pos < size) {
    if (size - pos < 4) return "a field length cut at byte " + std::to_string(pos);
    uint32_t n;
    std::memcpy(&n, data + pos, 4);
    pos += 4;
    if (n > size - pos)
      return "a field of " + std::to_string(n) + " bytes where " + std::to_string(size - pos) +
             " remain";
    const char* f = data + pos;
    const char* eq = static_cast<const char*>(std::memchr(f, '=', n));
    if (eq == nullptr) return "a field without '='";
    (*out)[std::string(f, eq)] = std::string(eq + 1, f + n);
    pos += n;
  }
  return "";
}

struct Record {
  uint64_t start = 0;
  uint8_t op = 0;
  Fields fields;
  uint64_t data_start = 0;
  uint32_t data_len = 0;
};

// A chunk's records once decompressed: where each starts and its op (Index Data offsets must
// name a Message Data record among them).
struct ChunkRecords {
  std::map<uint32_t, uint8_t> op_at;
};

class Ros1Walk {
 public:
  explicit Ros1Walk(const std::string& path) : path_(path), in_(path, std::ios::binary) {
    if (!in_) throw InputError(path + ": cannot open file");
    in_.seekg(0, std::ios::end);
    file_bytes_ = static_cast<uint64_t>(in_.tellg());
  }

  void run() {
    char magic[13] = {};
    if (file_bytes_ >= 13) read_at(0, magic, 13);
    if (std::string(magic, 13) != "#ROSBAG V2.0\n")
      throw InputError(path_ + ": not a ROS 1 bag (no '#ROSBAG V2.0' header; ROS 2 bags are "
                               ".mcap or .db3)");
    uint64_t pos = 13;
    std::vector<Record> records;
    while (pos < file_bytes_) {
      records.push_back(read_record(pos));
      const Record& r = records.back();
      if (records.size() == 1 && r.op != kBagHeader)
        fail(r.start, "the first record is not the bag header (op " + std::to_string(r.op) + ")");
      check_record(r, records.size() - 1, records);
      pos = r.data_start + r.data_len;
    }
    if (records.empty()) fail(13, "no bag header record");
    check_index(records);
  }

 private:
  [[noreturn]] void fail(uint64_t at, const std::string& what) const {
    throw InputError(path_ + ": corrupt ROS 1 bag at byte " + std::to_string(at) + ": " + what);
  }
  // A length past the end of the file: a corrupt length, or a bag cut short (by a crash or a
  // copy), which `rosbag reindex` may repair.
  [[noreturn]] void cut(uint64_t at, const std::string& what) const {
    throw InputError(path_ + ": corrupt or cut-short ROS 1 bag at byte " + std::to_string(at) +
                     ": " + what + " runs past the end of the file (" +
                     std::to_string(file_bytes_) + " bytes); if the bag was cut short, it has "
                     "lost its index: `rosbag reindex` on a copy rebuilds it from the complete "
                     "chunks");
  }

  void read_at(uint64_t pos, char* out, uint64_t n) {
    in_.clear();
    in_.seekg(static_cast<std::streamoff>(pos));
    in_.read(out, static_cast<std::streamsize>(n));
    if (!in_) throw InputError(path_ + ": read error at byte " + std::to_string(pos));
  }
  uint32_t u32_at(uint64_t pos) {
    uint32_t v;
    read_at(pos, reinterpret_cast<char*>(&v), 4);
    return v;
  }

  Record read_record(uint64_t pos) {
    Record r;
    r.start = pos;
    if (file_bytes_ - pos < 4) cut(pos, "a record's header length");
    const uint32_t header_len = u32_at(pos);
    if (header_len > file_bytes_ - pos - 4)
      cut(pos, "a record header of " + std::to_string(header_len) + " bytes");
    if (header_len > kMaxHeaderBytes)
      fail(pos, "a record header of " + std::to_string(header_len) + " bytes (more than " +
                    std::to_string(kMaxHeaderBytes) + ")");
    std::string header(header_len, '\0');
    read_at(pos + 4, header.data(), header_len);
    const std::string problem = parse_fields(header.data(), header.size(), &r.fields);
    if (!problem.empty()) fail(pos, "record header: " + problem);
    r.op = static_cast<uint8_t>(field(r, "op", 1)[0]);
    const uint64_t len_at = pos + 4 + header_len;
    if (file_bytes_ - len_at < 4) cut(pos, "a record's data length");
    r.data_len = u32_at(len_at);
    r.data_start = len_at + 4;
    if (r.data_len > file_bytes_ - r.data_start)
      cut(pos, "record data of " + std::to_string(r.data_len) + " bytes");
    return r;
  }

  const std::string& field(const Record& r, const std::string& name, size_t size) const {
    const auto it = r.fields.find(name);
    if (it == r.fields.end()) fail(r.start, "a record without its '" + name + "' field");
    if (size != 0 && it->second.size() != size)
      fail(r.start, "field '" + name + "' of " + std::to_string(it->second.size()) +
                        " bytes (expected " + std::to_string(size) + ")");
    return it->second;
  }
  template <typename T>
  T number(const Record& r, const std::string& name) const {
    T v;
    std::memcpy(&v, field(r, name, sizeof(T)).data(), sizeof(T));
    return v;
  }

  void check_record(const Record& r, size_t index, const std::vector<Record>& records) {
    switch (r.op) {
      case kBagHeader:
        if (index != 0) fail(r.start, "a second bag header");
        index_pos_ = number<uint64_t>(r, "index_pos");
        conn_count_ = number<uint32_t>(r, "conn_count");
        chunk_count_ = number<uint32_t>(r, "chunk_count");
        break;
      case kChunk:
        check_chunk(r);
        break;
      case kIndexData:
        check_index_data(r, index, records);
        break;
      case kChunkInfo:
        check_chunk_info(r);
        break;
      case kConnection:
        check_connection(r, r.data_start, r.data_len, nullptr);
        break;
      case kMessageData:
        number<uint32_t>(r, "conn");
        number<uint64_t>(r, "time");
        break;
      default:
        fail(r.start, "unknown record op " + std::to_string(r.op));
    }
  }

  void check_connection(const Record& r, uint64_t data_at, uint32_t data_len, const char* data) {
    connections_.insert(number<uint32_t>(r, "conn"));
    field(r, "topic", 0);
    std::string bytes;
    if (data == nullptr) {
      if (data_len > kMaxHeaderBytes)
        fail(r.start, "a connection header of " + std::to_string(data_len) + " bytes (more than " +
                          std::to_string(kMaxHeaderBytes) + ")");
      bytes.resize(data_len);
      read_at(data_at, bytes.data(), data_len);
      data = bytes.data();
    }
    Fields header;
    const std::string problem = parse_fields(data, data_len, &header);
    if (!problem.empty()) fail(r.start, "connection header: " + problem);
    for (const char* name : {"type", "md5sum"})
      if (!header.count(name)) fail(r.start, std::string("connection header without '") + name + "'");
  }

  void check_chunk(const Record& r) {
    const std::string compression = field(r, "compression", 0);
    const uint32_t size = number<uint32_t>(r, "size");
    if (size > kMaxRos1ChunkBytes)
      fail(r.start, "a chunk claiming " + std::to_string(size) + " bytes uncompressed");
    if (r.data_len > kMaxRos1ChunkBytes)
      fail(r.start, "a chunk of " + std::to_string(r.data_len) + " bytes");
    std::string packed(r.data_len, '\0');
    read_at(r.data_start, packed.data(), r.data_len);
    std::unique_ptr<char[]> plain;
    if (compression == "none") {
      if (size != r.data_len)
        fail(r.start, "an uncompressed chunk of " + std::to_string(r.data_len) +
                          " bytes claiming " + std::to_string(size));
      walk_chunk(r, packed.data(), size);
      return;
    }
    plain.reset(new char[std::max<uint32_t>(size, 1)]);
    unsigned int out = size;
    bool ok;
    if (compression == "bz2") {
      ok = BZ2_bzBuffToBuffDecompress(plain.get(), &out, packed.data(), r.data_len, 0, 0) == BZ_OK;
    } else if (compression == "lz4") {
      ok = roslz4_buffToBuffDecompress(packed.data(), r.data_len, plain.get(), &out) == ROSLZ4_OK;
    } else {
      fail(r.start, "chunk compression '" + compression + "' (ROS 1 bags use none, bz2 or lz4)");
    }
    if (!ok || out != size)
      fail(r.start, "a " + compression + " chunk that does not decompress to the " +
                        std::to_string(size) + " bytes its header claims");
    walk_chunk(r, plain.get(), size);
  }

  // The records inside a chunk: Message Data and Connection, whole.
  void walk_chunk(const Record& chunk, const char* data, uint32_t size) {
    ChunkRecords& inside = chunks_[chunk.start];
    size_t pos = 0;
    while (pos < size) {
      Record r;
      r.start = chunk.start;
      const auto inner = [&](const std::string& what) {
        fail(chunk.start, "inside the chunk, at its byte " + std::to_string(pos) + ": " + what);
      };
      if (size - pos < 4) inner("a record header length cut");
      uint32_t header_len;
      std::memcpy(&header_len, data + pos, 4);
      if (header_len > size - pos - 4) inner("a record header runs past the chunk's end");
      const std::string problem = parse_fields(data + pos + 4, header_len, &r.fields);
      if (!problem.empty()) inner("record header: " + problem);
      r.op = static_cast<uint8_t>(field(r, "op", 1)[0]);
      const size_t len_at = pos + 4 + header_len;
      if (size - len_at < 4) inner("a record data length cut");
      std::memcpy(&r.data_len, data + len_at, 4);
      if (r.data_len > size - len_at - 4) inner("record data runs past the chunk's end");
      if (r.op == kMessageData) {
        number<uint32_t>(r, "conn");
        number<uint64_t>(r, "time");
      } else if (r.op == kConnection) {
        check_connection(r, 0, r.data_len, data + len_at + 4);
      } else {
        inner("a record of op " + std::to_string(r.op) + " (a chunk holds messages and connections)");
      }
      inside.op_at[static_cast<uint32_t>(pos)] = r.op;
      pos = len_at + 4 + r.data_len;
    }
  }

  // Index Data follows its chunk: (time, offset) pairs, each offset a Message Data record in it.
  void check_index_data(const Record& r, size_t index, const std::vector<Record>& records) {
    if (number<uint32_t>(r, "ver") != 1) fail(r.start, "index data version is not 1");
    const uint32_t conn = number<uint32_t>(r, "conn");
    if (!connections_.count(conn))
      fail(r.start, "index data for connection " + std::to_string(conn) +
                        ", which no earlier connection record defines");
    const uint32_t count = number<uint32_t>(r, "count");
    if (static_cast<uint64_t>(count) * 12 != r.data_len)
      fail(r.start, "index data of " + std::to_string(r.data_len) + " bytes for " +
                        std::to_string(count) + " entries (12 bytes each)");
    size_t back = index;
    while (back > 0 && records[back - 1].op == kIndexData) --back;
    if (back == 0 || records[back - 1].op != kChunk)
      fail(r.start, "index data that does not follow a chunk");
    const ChunkRecords& inside = chunks_.at(records[back - 1].start);
    std::string entries(r.data_len, '\0');
    read_at(r.data_start, entries.data(), r.data_len);
    for (uint32_t k = 0; k < count; ++k) {
      uint32_t offset;
      std::memcpy(&offset, entries.data() + 12 * k + 8, 4);
      const auto it = inside.op_at.find(offset);
      if (it == inside.op_at.end() || it->second != kMessageData)
        fail(r.start, "index entry " + std::to_string(k) + " points at byte " +
                          std::to_string(offset) + " of its chunk, where no message record starts");
    }
  }

  void check_chunk_info(const Record& r) {
    if (number<uint32_t>(r, "ver") != 1) fail(r.start, "chunk info version is not 1");
    const uint64_t chunk_pos = number<uint64_t>(r, "chunk_pos");
    number<uint64_t>(r, "start_time");
    number<uint64_t>(r, "end_time");
    const uint32_t count = number<uint32_t>(r, "count");
    if (static_cast<uint64_t>(count) * 8 != r.data_len)
      fail(r.start, "chunk info of " + std::to_string(r.data_len) + " bytes for " +
                        std::to_string(count) + " connections (8 bytes each)");
    if (!chunks_.count(chunk_pos))
      fail(r.start, "chunk info naming byte " + std::to_string(chunk_pos) +
                        ", where no chunk starts");
    chunk_infos_.emplace_back(chunk_pos, count);
  }

  // The index section rosbag reads first: at index_pos, conn_count connections, then
  // chunk_count chunk infos; each chunk followed by an Index Data record per listed connection.
  void check_index(const std::vector<Record>& records) {
    if (index_pos_ == 0)
      throw InputError(path_ + ": the ROS 1 bag is unindexed (its header's index position is 0: "
                               "a recording not closed); `rosbag reindex` on a copy rebuilds it");
    size_t at = 0;
    while (at < records.size() && records[at].start != index_pos_) ++at;
    if (at == records.size())
      fail(13, "the bag header's index position " + std::to_string(index_pos_) +
                   " is not the start of a record");
    if (records.size() - at < static_cast<uint64_t>(conn_count_) + chunk_count_)
      fail(index_pos_, "the index holds fewer records than the bag header's " +
                           std::to_string(conn_count_) + " connections and " +
                           std::to_string(chunk_count_) + " chunks");
    for (uint32_t k = 0; k < conn_count_; ++k, ++at)
      if (records[at].op != kConnection)
        fail(records[at].start, "the index's connection " + std::to_string(k) + " is op " +
                                    std::to_string(records[at].op));
    for (uint32_t k = 0; k < chunk_count_; ++k, ++at)
      if (records[at].op != kChunkInfo)
        fail(records[at].start, "the index's chunk info " + std::to_string(k) + " is op " +
                                    std::to_string(records[at].op));
    std::map<uint64_t, size_t> index_of;
    for (size_t k = 0; k < records.size(); ++k) index_of[records[k].start] = k;
    for (const auto& [chunk_pos, count] : chunk_infos_) {
      const size_t c = index_of.at(chunk_pos);
      for (uint32_t k = 1; k <= count; ++k)
        if (c + k >= records.size() || records[c + k].op != kIndexData)
          fail(chunk_pos, "the chunk is followed by fewer index records than its chunk info's " +
                              std::to_string(count));
    }
  }

  std::string path_;
  std::ifstream in_;
  uint64_t file_bytes_ = 0;
  uint64_t index_pos_ = 0;
  uint32_t conn_count_ = 0, chunk_count_ = 0;
  std::set<uint32_t> connections_;
  std::map<uint64_t, ChunkRecords> chunks_;
  std::vector<std::pair<uint64_t, uint32_t>> chunk_infos_;
};

}  // namespace

void check_ros1_bag(const std::string& path) { Ros1Walk(path).run(); }

}  // namespace terrastride::perception::bag
