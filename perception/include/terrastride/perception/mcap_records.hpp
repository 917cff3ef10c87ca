// The MCAP container's magic and record opcodes (https://mcap.dev/spec), shared by the bag
// reader (perception/src/bag/mcap_reader.cpp) and `terrastride export`'s writer
// (service/src/export/mcap_writer.cpp), so the two cannot disagree on the format.
#pragma once

#include <cstdint>

namespace terrastride::perception::mcap {

// The 8 bytes that open and close every MCAP file.
inline constexpr char kMagic[8] = {'\x89', 'M', 'C', 'A', 'P', '0', '\r', '\n'};

// Record opcodes: every record is opcode (u8), content length (u64 LE), content.
enum Opcode : uint8_t {
  kHeader = 0x01,
  kFooter = 0x02,
  kSchema = 0x03,
  kChannel = 0x04,
  kMessage = 0x05,
  kChunk = 0x06,
  kMessageIndex = 0x07,
  kChunkIndex = 0x08,
  kStatistics = 0x0B,
  kSummaryOffset = 0x0E,
  kDataEnd = 0x0F,
};

}  // namespace terrastride::perception::mcap
