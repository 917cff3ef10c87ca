// MCAP writer (mcap_writer.hpp). Record layouts follow https://mcap.dev/spec: every record is
// opcode (u8), content length (u64 LE), content; strings and byte arrays carry a u32 length, maps
// and arrays a u32 byte length.
#include "export/mcap_writer.hpp"

#include <zlib.h>
#include <zstd.h>

#include <stdexcept>

#include "terrastride/perception/mcap_records.hpp"

namespace terrastride::service::mcap {
namespace {

using namespace perception::mcap;  // the format's magic and opcodes (mcap_records.hpp)

void put_u8(std::string& s, uint8_t v) { s.push_back(static_cast<char>(v)); }
template <class T>
void put_le(std::string& s, T v) {
  for (size_t i = 0; i < sizeof(T); ++i) s.push_back(static_cast<char>((v >> (8 * i)) & 0xFF));
}
void put_u16(std::string& s, uint16_t v) { put_le<uint16_t>(s, v); }
void put_u32(std::string& s, uint32_t v) { put_le<uint32_t>(s, v); }
void put_u64(std::string& s, uint64_t v) { put_le<uint64_t>(s, v); }
void put_string(std::string& s, const std::string& v) {
  put_u32(s, static_cast<uint32_t>(v.size()));
  s += v;
}
void put_record(std::string& s, uint8_t op, const std::string& content) {
  put_u8(s, op);
  put_u64(s, content.size());
  s += content;
}
uint32_t crc32_of(const std::string& s, size_t from = 0, size_t to = std::string::npos) {
  if (to == std::string::npos) to = s.size();
  uLong crc = ::crc32(0L, Z_NULL, 0);
  size_t at = from;
  while (at < to) {  // zlib takes uInt lengths
    const size_t n = std::min<size_t>(to - at, 1u << 30);
    crc = ::crc32(crc, reinterpret_cast<const Bytef*>(s.data() + at), static_cast<uInt>(n));
    at += n;
  }
  return static_cast<uint32_t>(crc);
}

}  // namespace

Writer::Writer(WriterOptions options) : options_(std::move(options)) {
  if (options_.compression != "zstd" && !options_.compression.empty())
    throw std::invalid_argument("mcap: compression '" + options_.compression +
                                "' (this writer knows zstd and none)");
  out_.append(kMagic, 8);
  std::string header;
  put_string(header, options_.profile);
  put_string(header, options_.library);
  put_record(out_, kHeader, header);
}

std::string Writer::schema_record(uint16_t id) const {
  std::string c;
  put_u16(c, id);
  put_string(c, schemas_[id - 1].first);
  put_string(c, schemas_[id - 1].second);
  put_string(c, schema_data_[id - 1]);  // u32 length + bytes
  std::string r;
  put_record(r, kSchema, c);
  return r;
}

std::string Writer::channel_record(uint16_t id) const {
  const Channel& ch = channels_[id - 1];
  std::string c;
  put_u16(c, id);
  put_u16(c, ch.schema_id);
  put_string(c, ch.topic);
  put_string(c, ch.encoding);
  std::string map;
  for (const auto& [k, v] : ch.metadata) {
    put_string(map, k);
    put_string(map, v);
  }
  put_u32(c, static_cast<uint32_t>(map.size()));
  c += map;
  std::string r;
  put_record(r, kChannel, c);
  return r;
}

uint16_t Writer::add_schema(const std::string& name, const std::string& encoding,
                            const std::string& data) {
  if (finished_ || schemas_.size() >= 65535) throw std::logic_error("mcap: cannot add a schema");
  schemas_.emplace_back(name, encoding);
  schema_data_.push_back(data);
  const auto id = static_cast<uint16_t>(schemas_.size());
  out_ += schema_record(id);  // in the data section, before any message that uses it
  return id;
}

uint16_t Writer::add_channel(uint16_t schema_id, const std::string& topic,
                             const std::string& message_encoding,
                             const std::map<std::string, std::string>& metadata) {
  if (finished_ || channels_.size() >= 65535 || schema_id > schemas_.size())
    throw std::logic_error("mcap: cannot add channel " + topic);
  channels_.push_back({schema_id, topic, message_encoding, metadata});
  const auto id = static_cast<uint16_t>(channels_.size());
  out_ += channel_record(id);
  channel_counts_[id] = 0;
  return id;
}

void Writer::add_message(uint16_t channel_id, uint64_t log_time_ns, const std::string& data) {
  if (finished_ || channel_id == 0 || channel_id > channels_.size())
    throw std::logic_error("mcap: message on an unknown channel");
  Channel& ch = channels_[channel_id - 1];
  std::string c;
  put_u16(c, channel_id);
  put_u32(c, ch.sequence++);
  put_u64(c, log_time_ns);
  put_u64(c, log_time_ns);  // publish time
  c += data;
  chunk_index_[channel_id].emplace_back(log_time_ns, chunk_.size());
  put_record(chunk_, kMessage, c);
  chunk_start_ = std::min(chunk_start_, log_time_ns);
  chunk_end_ = std::max(chunk_end_, log_time_ns);
  start_ = std::min(start_, log_time_ns);
  end_ = std::max(end_, log_time_ns);
  ++channel_counts_[channel_id];
  ++message_count_;
  if (chunk_.size() >= options_.chunk_size) close_chunk();
}

void Writer::close_chunk() {
  if (chunk_.empty()) return;
  std::string records;
  if (options_.compression == "zstd") {
    records.resize(ZSTD_compressBound(chunk_.size()));
    const size_t n = ZSTD_compress(records.data(), records.size(), chunk_.data(), chunk_.size(), 3);
    if (ZSTD_isError(n)) throw std::runtime_error(std::string("zstd: ") + ZSTD_getErrorName(n));
    records.resize(n);
  } else {
    records = chunk_;
  }
  std::string c;
  put_u64(c, chunk_start_);
  put_u64(c, chunk_end_);
  put_u64(c, chunk_.size());
  put_u32(c, crc32_of(chunk_));
  put_string(c, options_.compression);
  put_u64(c, records.size());
  c += records;
  const uint64_t chunk_offset = out_.size();
  put_record(out_, kChunk, c);
  const uint64_t chunk_length = out_.size() - chunk_offset;
  // Message indexes, one per channel with messages in the chunk, right after it.
  const uint64_t index_start = out_.size();
  std::string offsets;  // Map<u16, u64> of the chunk index
  for (const auto& [channel, entries] : chunk_index_) {
    put_u16(offsets, channel);
    put_u64(offsets, out_.size());
    std::string m;
    put_u16(m, channel);
    put_u32(m, static_cast<uint32_t>(entries.size() * 16));
    for (const auto& [t, off] : entries) {
      put_u64(m, t);
      put_u64(m, off);
    }
    put_record(out_, kMessageIndex, m);
  }
  const uint64_t index_length = out_.size() - index_start;
  std::string ci;
  put_u64(ci, chunk_start_);
  put_u64(ci, chunk_end_);
  put_u64(ci, chunk_offset);
  put_u64(ci, chunk_length);
  put_u32(ci, static_cast<uint32_t>(offsets.size()));
  ci += offsets;
  put_u64(ci, index_length);
  put_string(ci, options_.compression);
  put_u64(ci, records.size());
  put_u64(ci, chunk_.size());
  std::string rec;
  put_record(rec, kChunkIndex, ci);
  chunk_indexes_.push_back(rec);
  chunk_.clear();
  chunk_index_.clear();
  chunk_start_ = UINT64_MAX;
  chunk_end_ = 0;
}

std::string Writer::finish() {
  if (finished_) throw std::logic_error("mcap: finish() twice");
  close_chunk();
  finished_ = true;
  std::string de;
  put_u32(de, crc32_of(out_));  // CRC of everything before the data end record
  put_record(out_, kDataEnd, de);

  const uint64_t summary_start = out_.size();
  struct Group {
    uint8_t op;
    uint64_t start, length;
  };
  std::vector<Group> groups;
  const auto group = [&](uint8_t op, const std::string& records) {
    if (records.empty()) return;
    groups.push_back({op, out_.size(), records.size()});
    out_ += records;
  };
  std::string s;
  for (uint16_t id = 1; id <= schemas_.size(); ++id) s += schema_record(id);
  group(kSchema, s);
  s.clear();
  for (uint16_t id = 1; id <= channels_.size(); ++id) s += channel_record(id);
  group(kChannel, s);
  std::string st;
  put_u64(st, message_count_);
  put_u16(st, static_cast<uint16_t>(schemas_.size()));
  put_u32(st, static_cast<uint32_t>(channels_.size()));
  put_u32(st, 0);  // attachments
  put_u32(st, 0);  // metadata
  put_u32(st, static_cast<uint32_t>(chunk_indexes_.size()));
  put_u64(st, message_count_ ? start_ : 0);
  put_u64(st, message_count_ ? end_ : 0);
  std::string counts;
  for (const auto& [id, n] : channel_counts_) {
    put_u16(counts, id);
    put_u64(counts, n);
  }
  put_u32(st, static_cast<uint32_t>(counts.size()));
  st += counts;
  s.clear();
  put_record(s, kStatistics, st);
  group(kStatistics, s);
  s.clear();
  for (const auto& r : chunk_indexes_) s += r;
  group(kChunkIndex, s);

  const uint64_t summary_offset_start = out_.size();
  for (const Group& g : groups) {
    std::string so;
    put_u8(so, g.op);
    put_u64(so, g.start);
    put_u64(so, g.length);
    put_record(out_, kSummaryOffset, so);
  }
  // Footer: its CRC covers the summary section up to and including summary_offset_start.
  put_u8(out_, kFooter);
  put_u64(out_, 8 + 8 + 4);
  put_u64(out_, summary_start);
  put_u64(out_, summary_offset_start);
  put_u32(out_, crc32_of(out_, summary_start));
  out_.append(kMagic, 8);
  return std::move(out_);
}

}  // namespace terrastride::service::mcap
