// An owned C stream: closed when it goes out of scope, so a constructor or an early return that
// throws after opening a file cannot leak its descriptor.
#pragma once

#include <cstdio>
#include <memory>
#include <string>

namespace evkit::detail {

struct FileCloser {
  void operator()(std::FILE* f) const { std::fclose(f); }
};
using UniqueFile = std::unique_ptr<std::FILE, FileCloser>;

// Opens `path` with fopen's `mode`; empty when it cannot be opened (errno says why).
inline UniqueFile openFile(const std::string& path, const char* mode) {
  return UniqueFile(std::fopen(path.c_str(), mode));
}

// Closes the stream now and reports whether everything buffered reached the file.
inline bool closeFile(UniqueFile& file) { return std::fclose(file.release()) == 0; }

}  // namespace evkit::detail
