// A writer of MCAP files (https://mcap.dev/spec, version 0), in memory: header, schemas, channels,
// messages in chunks (zstd or uncompressed) each followed by its message indexes, the data end
// record with the data section's CRC, and a summary section (schemas, channels, statistics, chunk
// indexes, summary offsets) with its CRC in the footer. No Debian package writes MCAP; the files
// are checked in tests by the independent reader of @mcap/core (tests/service/mcap_check.js).
#pragma once

#include <cstdint>
#include <map>
#include <string>
#include <vector>

namespace terrastride::service::mcap {

struct WriterOptions {
  std::string profile;            // header profile ("" for none; Foxglove uses none for JSON)
  std::string library = "terrastride";
  std::string compression = "zstd";  // "zstd" or "" (uncompressed chunks)
  size_t chunk_size = 1 << 20;        // uncompressed bytes after which a chunk is closed
};

class Writer {
 public:
  explicit Writer(WriterOptions options = {});
  // Returns the schema id (ids start at 1; 0 means "no schema" in MCAP).
  uint16_t add_schema(const std::string& name, const std::string& encoding,
                      const std::string& data);
  uint16_t add_channel(uint16_t schema_id, const std::string& topic,
                       const std::string& message_encoding,
                       const std::map<std::string, std::string>& metadata = {});
  // log_time and publish_time in nanoseconds. Messages may come in any time order.
  void add_message(uint16_t channel_id, uint64_t log_time_ns, const std::string& data);
  // Closes the last chunk, writes the summary and footer; returns the whole file.
  std::string finish();

  size_t message_count() const { return message_count_; }
  size_t chunk_count() const { return chunk_indexes_.size(); }

 private:
  struct Channel {
    uint16_t schema_id;
    std::string topic, encoding;
    std::map<std::string, std::string> metadata;
    uint32_t sequence = 0;
  };
  void close_chunk();
  std::string schema_record(uint16_t id) const;
  std::string channel_record(uint16_t id) const;

  WriterOptions options_;
  std::string out_;
  std::vector<std::pair<std::string, std::string>> schemas_;  // (name, encoding) by id - 1
  std::vector<std::string> schema_data_;
  std::vector<Channel> channels_;                             // by id - 1
  // The open chunk: its records, per channel the (log time, offset in the records) of its
  // messages, and its time range.
  std::string chunk_;
  std::map<uint16_t, std::vector<std::pair<uint64_t, uint64_t>>> chunk_index_;
  uint64_t chunk_start_ = UINT64_MAX, chunk_end_ = 0;
  std::vector<std::string> chunk_indexes_;  // chunk index records for the summary
  std::map<uint16_t, uint64_t> channel_counts_;
  size_t message_count_ = 0;
  uint64_t start_ = UINT64_MAX, end_ = 0;
  bool finished_ = false;
};

}  // namespace terrastride::service::mcap
