// Buffered sequential reading of binary files with byte offsets for error messages. Lengths read
// from a file are untrusted: callers check them against remaining() before allocating.
#pragma once

#include <cstdint>
#include <cstdio>
#include <string>
#include <vector>

#include "unique_file.h"

namespace evkit::detail {

class BinaryFile {
 public:
  explicit BinaryFile(std::string path);
  BinaryFile(const BinaryFile&) = delete;
  BinaryFile& operator=(const BinaryFile&) = delete;

  const std::string& path() const { return path_; }
  int64_t size() const { return size_; }
  int64_t offset() const { return offset_; }
  int64_t remaining() const { return size_ - offset_; }

  // Reads up to n bytes; returns how many were read (fewer only at the end of the file).
  size_t read(void* out, size_t n);
  // Reads exactly n bytes or throws "FILE: byte OFFSET: truncated: expected <what>".
  void readExact(void* out, size_t n, const char* what);
  void seek(int64_t offset);
  // Reads a header line (without "\\n" or "\\r\\n"); false at the end of the file. A line that the
  // end of the file cuts off, or one longer than max_length, is an error: the header is truncated,
  // or this is not a text header.
  bool readLine(std::string& line, size_t max_length = 1 << 20);
  // Looks at the next byte without consuming it; -1 at the end.
  int peek();

  [[noreturn]] void fail(const std::string& what) const;  // at the current offset
  [[noreturn]] void failAt(int64_t offset, const std::string& what) const;

 private:
  std::string path_;
  UniqueFile file_;
  int64_t size_ = 0;
  int64_t offset_ = 0;
};

// Little- and big-endian loads from bytes.
inline uint16_t loadLe16(const uint8_t* p) { return static_cast<uint16_t>(p[0] | (p[1] << 8)); }
inline uint32_t loadLe32(const uint8_t* p) {
  return uint32_t{p[0]} | (uint32_t{p[1]} << 8) | (uint32_t{p[2]} << 16) | (uint32_t{p[3]} << 24);
}
inline uint32_t loadBe32(const uint8_t* p) {
  return (uint32_t{p[0]} << 24) | (uint32_t{p[1]} << 16) | (uint32_t{p[2]} << 8) | uint32_t{p[3]};
}
inline uint64_t loadLe64(const uint8_t* p) {
  return uint64_t{loadLe32(p)} | (uint64_t{loadLe32(p + 4)} << 32);
}

// Sensor size of a camera named in a header ("DAVIS240C", "Davis346red", "DVXplorer", ...);
// unknown (0x0) when the name is not recognised.
struct SensorSizeGuess {
  int width = 0;
  int height = 0;
};
SensorSizeGuess sensorSizeForCamera(const std::string& name);

}  // namespace evkit::detail
