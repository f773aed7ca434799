// User-facing errors of evkit.
//
// A problem with the user's input (a bad file, a bad option) throws evkit::Error whose message names
// the file, the position (line or byte offset) and what was expected, e.g.
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

// "FILE: line N: WHAT"
[[noreturn]] void throwAtLine(const std::string& file, int64_t line, const std::string& what);
// "FILE: byte N: WHAT"
[[noreturn]] void throwAtByte(const std::string& file, int64_t byte, const std::string& what);
// "FILE: WHAT"
[[noreturn]] void throwInFile(const std::string& file, const std::string& what);

}  // namespace evkit
