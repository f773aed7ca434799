// libFuzzer target for one reader (EVKIT_FUZZ_FORMAT, a format name such as "aedat4"): the input is
// written to a scratch file and read in full. A reader may reject it with evkit::Error; any other
// exception, a crash, a sanitizer report, a hang, a huge allocation, a leaked allocation
// (LeakSanitizer), a file descriptor or an HDF5 identifier still open after the reader is gone is a
// bug.
//
// Built by `cmake -DEVKIT_FUZZ=ON` with clang; run by scripts/fuzz.sh.

#include <hdf5.h>
#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>

#include "evkit/base/error.h"
#include "evkit/events/io.h"
#include "open_descriptors.h"

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
  const int descriptors_before = evkit::test::openDescriptors();
  try {
    const evkit::Recording rec = evkit::readRecording(path, evkit::parseFormat(EVKIT_FUZZ_FORMAT));
    (void)rec;
  } catch (const evkit::Error&) {
    // Rejected with a message: the expected outcome for most inputs.
  }
  const int descriptors_after = evkit::test::openDescriptors();
  if (descriptors_after != descriptors_before) {
    std::fprintf(stderr,
                 "fuzz: %d file descriptors open before reading, %d after: the reader leaked\n",
                 descriptors_before, descriptors_after);
    std::abort();
  }
  if (const ssize_t ids = H5Fget_obj_count(H5F_OBJ_ALL, H5F_OBJ_ALL); ids > 0) {
    std::fprintf(stderr, "fuzz: %zd HDF5 identifiers left open: the reader leaked\n", ids);
    std::abort();
  }
  return 0;
}
