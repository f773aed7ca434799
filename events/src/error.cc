#include "evkit/events/error.h"

namespace evkit {

void throwAtLine(const std::string& file, int64_t line, const std::string& what) {
  throw Error(file + ": line " + std::to_string(line) + ": " + what);
}

void throwAtByte(const std::string& file, int64_t byte, const std::string& what) {
  throw Error(file + ": byte " + std::to_string(byte) + ": " + what);
}

void throwInFile(const std::string& file, const std::string& what) { throw Error(file + ": " + what); }

}  // namespace evkit
