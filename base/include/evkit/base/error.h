// User-facing errors of evkit.
//
// A problem with the user's input (a bad file, a bad option) throws evkit::Error whose message
// names the file, the position (line or byte offset) and what was expected, e.g.
//   "events.txt: line 12: expected 4 fields 't x y p', found 3"
// The CLI prints the message as one line on stderr and exits non-zero. Internal invariants are
// asserts, never Errors.
#pragma once

#include <cstdint>
#include <stdexcept>
#include <string>

namespace evkit {

class Error : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// Header-only, so that modules that do not link evkit_events (spline/) report errors the same way.

// "FILE: line N: WHAT"
[[noreturn]] inline void throwAtLine(const std::string& file, int64_t line,
                                     const std::string& what) {
  throw Error(file + ": line " + std::to_string(line) + ": " + what);
}
// "FILE: byte N: WHAT"
[[noreturn]] inline void throwAtByte(const std::string& file, int64_t byte,
                                     const std::string& what) {
  throw Error(file + ": byte " + std::to_string(byte) + ": " + what);
}
// "FILE: WHAT"
[[noreturn]] inline void throwInFile(const std::string& file, const std::string& what) {
  throw Error(file + ": " + what);
}

}  // namespace evkit
