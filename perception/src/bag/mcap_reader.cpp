// MCAP (https://mcap.dev/spec), the ROS 2 default bag format since Iron. No Debian library reads
// it, so this is a careful reader of the records a bag needs: Schema, Channel, Message, and Chunks
// of them (uncompressed, zstd or lz4 frame). It streams: records are read one at a time from the
// file, a chunk is decompressed into one buffer, and nothing else is kept but the channels.
// Summary sections, indexes, attachments and metadata are skipped (the data section alone is
// enough, and a truncated file has no summary).
#include <lz4frame.h>
#include <zlib.h>
#include <zstd.h>

#include <cerrno>
#include <cstring>
#include <fstream>
#include <map>

#include "bag/bag_readers.hpp"
#include "bag/byte_cursor.hpp"
#include "terrastride/perception/mcap_records.hpp"

namespace terrastride::perception::bag {
namespace {

using namespace mcap;  // the format's magic and opcodes (mcap_records.hpp)

// A chunk bigger than this uncompressed is refused as corrupt: writers chunk at ~1-8 MB.
constexpr uint64_t kMaxChunkBytes = 1ull << 31;
// The most a codec's output can be per compressed byte: a zstd block of 128 KiB takes at least
// 4 bytes (an RLE block); an LZ4 sequence adds at most 255 bytes of match per byte. A chunk that
// claims more is corrupt, and is refused before its buffer is allocated: a 3 kB chunk claiming
// 2 GiB cost 2 GiB and a memset of it (libFuzzer: a timeout in the resize).
constexpr uint64_t kMaxZstdRatio = 32768;
constexpr uint64_t kMaxLz4Ratio = 256;

struct Schema {
  std::string name;
  std::string encoding;
};

class McapReader : public BagReader {
 public:
  explicit McapReader(const std::string& path) : BagReader(path) {
    in_.open(path, std::ios::binary);
    if (!in_) throw InputError(path + ": cannot open file: " + std::strerror(errno));
    in_.seekg(0, std::ios::end);
    const std::streamoff size = in_.tellg();
    if (size < 0) throw InputError(path + ": cannot determine the file size (not a regular file?)");
    file_bytes_ = static_cast<uint64_t>(size);
    damage_.file_bytes = file_bytes_;
    char magic[8] = {};
    in_.seekg(0);
    in_.read(magic, 8);
    if (!in_ || std::memcmp(magic, kMagic, 8) != 0)
      throw InputError(path + ": not an MCAP file (no MCAP magic at its start)");
  }

  std::string format() const override { return "mcap"; }

  std::vector<BagTopic> topics() const override {
    std::vector<BagTopic> out;
    for (const auto& [id, t] : channels_) out.push_back(t);
    return out;
  }

  void read(const std::function<bool(const BagTopic&)>& want,
            const std::function<void(const BagMessage&)>& on) override {
    want_ = want;
    on_ = on;
    in_.clear();
    uint64_t pos = 8;
    std::string content;
    bool header_seen = false;
    while (pos < file_bytes_) {
      const uint64_t record_start = pos;
      if (file_bytes_ - pos < 9) {
        truncated(record_start, "a record's opcode and length");
        return;
      }
      char head[9];
      in_.seekg(static_cast<std::streamoff>(pos));
      in_.read(head, 9);
      if (!in_) throw InputError(path_ + ": read error at byte " + std::to_string(pos));
      const uint8_t opcode = static_cast<uint8_t>(head[0]);
      uint64_t length;
      std::memcpy(&length, head + 1, 8);
      pos += 9;
      if (!header_seen && opcode != kHeader)
        throw InputError(path_ + ": MCAP file without a Header record at its start");
      header_seen = true;
      if (length > file_bytes_ - pos) {
        truncated(record_start, "a record of " + std::to_string(length) + " bytes (opcode " +
                                    std::to_string(opcode) + ")");
        return;
      }
      if (opcode == kDataEnd || opcode == kFooter) return;  // the summary follows: not needed
      if (opcode == kSchema || opcode == kChannel || opcode == kMessage || opcode == kChunk ||
          opcode == kHeader) {
        content.resize(static_cast<size_t>(length));
        in_.read(content.data(), static_cast<std::streamsize>(length));
        if (!in_) throw InputError(path_ + ": read error at byte " + std::to_string(pos));
        if (opcode == kChunk) {
          chunk(content, record_start);
        } else if (opcode != kHeader) {
          try {
            record(opcode, content, record_start);
          } catch (const Truncated& e) {
            throw InputError(path_ + ": corrupt record at byte " + std::to_string(record_start) +
                             ": " + e.what());
          }
        }
      }
      pos += length;
    }
    // No DataEnd or Footer: the writer did not finish (a recording cut by a crash).
    damage_.problems.push_back("the file ends at byte " + std::to_string(file_bytes_) +
                               " without MCAP's DataEnd/Footer (recording not closed)");
  }

 private:
  void truncated(uint64_t at, const std::string& what) {
    damage_.problems.push_back("truncated at byte " + std::to_string(at) + " of " +
                               std::to_string(file_bytes_) + ": " + what +
                               " runs past the end of the file");
    damage_.skipped_bytes += file_bytes_ - at;
  }

  // A record of the data section or of a chunk.
  void record(uint8_t opcode, std::string_view content, uint64_t where) {
    ByteCursor c(content);
    if (opcode == kSchema) {
      const uint16_t id = c.read<uint16_t>("schema id");
      Schema s;
      s.name = std::string(c.prefixed_string("schema name"));
      s.encoding = std::string(c.prefixed_string("schema encoding"));
      schemas_[id] = std::move(s);
    } else if (opcode == kChannel) {
      const uint16_t id = c.read<uint16_t>("channel id");
      const uint16_t schema_id = c.read<uint16_t>("channel schema id");
      BagTopic t;
      t.name = std::string(c.prefixed_string("channel topic"));
      t.encoding_name = std::string(c.prefixed_string("channel message encoding"));
      t.encoding = t.encoding_name == "cdr"    ? MessageEncoding::kCdr
                   : t.encoding_name == "ros1" ? MessageEncoding::kRos1
                                               : MessageEncoding::kOther;
      auto s = schemas_.find(schema_id);
      if (schema_id != 0 && s == schemas_.end())
        throw InputError(path_ + ": channel " + t.name + " (byte " + std::to_string(where) +
                         ") names schema " + std::to_string(schema_id) +
                         " that no earlier Schema record defines" + earlier_damage());
      t.type = s == schemas_.end() ? "" : normalise_type(s->second.name);
      channels_[id] = std::move(t);
    } else if (opcode == kMessage) {
      const uint16_t channel = c.read<uint16_t>("message channel id");
      c.read<uint32_t>("message sequence");
      const uint64_t log_time = c.read<uint64_t>("message log time");
      c.read<uint64_t>("message publish time");
      auto ch = channels_.find(channel);
      if (ch == channels_.end())
        throw InputError(path_ + ": message at byte " + std::to_string(where) + " on channel " +
                         std::to_string(channel) + " that no earlier Channel record defines" +
                         earlier_damage());
      if (want_ && !want_(ch->second)) return;
      BagMessage m;
      m.topic = &ch->second;
      m.log_time_ns = static_cast<int64_t>(log_time);
      m.data = c.bytes(c.remaining(), "message data");
      on_(m);
    }
  }

  void chunk(const std::string& content, uint64_t where) {
    ByteCursor c(content);
    std::string_view compression, records;
    uint64_t uncompressed_size = 0;
    uint32_t crc = 0;
    try {
      c.read<uint64_t>("chunk start time");
      c.read<uint64_t>("chunk end time");
      uncompressed_size = c.read<uint64_t>("chunk uncompressed size");
      crc = c.read<uint32_t>("chunk crc");
      compression = c.prefixed_string("chunk compression");
      records = c.bytes(c.read<uint64_t>("chunk records length"), "chunk records");
    } catch (const Truncated& e) {
      corrupt_chunk(where, content.size(), e.what());
      return;
    }
    if (uncompressed_size > kMaxChunkBytes) {
      corrupt_chunk(where, content.size(),
                    "claims " + std::to_string(uncompressed_size) + " bytes uncompressed");
      return;
    }
    // Known codecs only, before anything is allocated for the output (a chunk of compression
    // "zst\0" claiming 1.7 GB took its buffer before it was refused).
    if (!compression.empty() && compression != "zstd" && compression != "lz4")
      throw InputError(path_ + ": chunk at byte " + std::to_string(where) +
                       " uses compression '" + std::string(compression) +
                       "' (this reader knows none, zstd and lz4)");
    const uint64_t ratio = compression == "zstd" ? kMaxZstdRatio : kMaxLz4Ratio;
    if (!compression.empty() && uncompressed_size / ratio > records.size()) {
      corrupt_chunk(where, content.size(),
                    "claims " + std::to_string(uncompressed_size) + " bytes uncompressed from " +
                        std::to_string(records.size()) + " bytes of " + std::string(compression) +
                        ", more than " + std::string(compression) + " expands to");
      return;
    }
    std::string_view plain;
    if (compression.empty()) {
      plain = records;
      if (plain.size() != uncompressed_size) {
        corrupt_chunk(where, content.size(), "its size disagrees with its header");
        return;
      }
    } else {
      buffer_.resize(static_cast<size_t>(uncompressed_size));
      std::string problem;
      if (compression == "zstd") {
        const size_t n = ZSTD_decompress(buffer_.data(), buffer_.size(), records.data(),
                                         records.size());
        if (ZSTD_isError(n))
          problem = std::string("zstd: ") + ZSTD_getErrorName(n);
        else if (n != buffer_.size())
          problem = "zstd data of " + std::to_string(n) + " bytes, the header says " +
                    std::to_string(buffer_.size());
      } else {
        problem = lz4_frame(records, &buffer_);
      }
      if (!problem.empty()) {
        corrupt_chunk(where, content.size(), "decompression failed (" + problem + ")");
        return;
      }
      plain = buffer_;
    }
    if (crc != 0 &&
        static_cast<uint32_t>(crc32(0L, reinterpret_cast<const Bytef*>(plain.data()),
                                    static_cast<uInt>(plain.size()))) != crc) {
      corrupt_chunk(where, content.size(), "CRC mismatch");
      return;
    }
    ByteCursor r(plain);
    try {
      while (!r.done()) {
        const uint8_t opcode = r.read<uint8_t>("record opcode");
        const uint64_t length = r.read<uint64_t>("record length");
        const std::string_view body = r.bytes(length, "record");
        record(opcode, body, where);
      }
    } catch (const Truncated& e) {
      // The messages before the bad record were delivered.
      corrupt_chunk(where, content.size(), std::string("a record inside it is cut: ") + e.what());
    }
  }

  // A record naming a schema or channel that no earlier record defines is, after a corrupt chunk,
  // most likely the victim of that chunk (which held the definition): say so.
  std::string earlier_damage() const {
    if (!damage_.damaged()) return "";
    return " (defined, perhaps, in a chunk skipped before it: " + damage_.problems.front() + ")";
  }

  void corrupt_chunk(uint64_t where, uint64_t bytes, const std::string& why) {
    damage_.problems.push_back("corrupt chunk at byte " + std::to_string(where) + " skipped: " + why);
    damage_.skipped_bytes += bytes;
  }

  // LZ4 frame format (MCAP's "lz4"), decompressed into `out` (sized to the expected bytes).
  static std::string lz4_frame(std::string_view src, std::string* out) {
    LZ4F_dctx* ctx = nullptr;
    if (LZ4F_isError(LZ4F_createDecompressionContext(&ctx, LZ4F_VERSION)))
      return "lz4: cannot create a decompression context";
    size_t in_pos = 0, out_pos = 0;
    std::string problem;
    while (in_pos < src.size()) {
      size_t in_n = src.size() - in_pos, out_n = out->size() - out_pos;
      const size_t r = LZ4F_decompress(ctx, out->data() + out_pos, &out_n, src.data() + in_pos,
                                       &in_n, nullptr);
      if (LZ4F_isError(r)) {
        problem = std::string("lz4: ") + LZ4F_getErrorName(r);
        break;
      }
      in_pos += in_n;
      out_pos += out_n;
      if (r == 0) break;  // frame complete
      if (in_n == 0 && out_n == 0) {
        problem = "lz4: the data does not fit the size the header gives";
        break;
      }
    }
    LZ4F_freeDecompressionContext(ctx);
    if (problem.empty() && out_pos != out->size())
      problem = "lz4 data of " + std::to_string(out_pos) + " bytes, the header says " +
                std::to_string(out->size());
    return problem;
  }

  std::ifstream in_;
  uint64_t file_bytes_ = 0;
  std::map<uint16_t, Schema> schemas_;
  std::map<uint16_t, BagTopic> channels_;
  std::string buffer_;
  std::function<bool(const BagTopic&)> want_;
  std::function<void(const BagMessage&)> on_;
};

}  // namespace

std::unique_ptr<BagReader> open_mcap(const std::string& path) {
  return std::make_unique<McapReader>(path);
}

}  // namespace terrastride::perception::bag
