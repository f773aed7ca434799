// libFuzzer target for one reader (EVKIT_FUZZ_FORMAT, a format name such as "aedat4"): the input is
// written to a scratch file and read in full. A reader may reject it with evkit::Error; any other
// exception, a crash, a sanitizer report, a hang or a huge allocation is a bug.
//
// Built by `cmake -DEVKIT_FUZZ=ON` with clang; run by scripts/fuzz.sh.

#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <string>

#include "evkit/events/error.h"
#include "evkit/events/io.h"

namespace {

const std::string& scratchPath() {
  static const std::string path = [] {
    const char* dir = std::getenv("EVKIT_FUZZ_DIR");
    const std::filesystem::path base = dir ? dir : std::filesystem::temp_directory_path();
    return (base / ("evkit-fuzz-" + std::to_string(::getpid()) + EVKIT_FUZZ_EXTENSION)).string();
  }();
  return path;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string& path = scratchPath();
  std::FILE* f = std::fopen(path.c_str(), "wb");
  if (!f) return 0;
  std::fwrite(data, 1, size, f);
  std::fclose(f);
  try {
    const evkit::Recording rec = evkit::readRecording(path, evkit::parseFormat(EVKIT_FUZZ_FORMAT));
    (void)rec;
  } catch (const evkit::Error&) {
    // Rejected with a message: the expected outcome for most inputs.
  }
  return 0;
}
