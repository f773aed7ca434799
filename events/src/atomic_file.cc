#include "evkit/events/atomic_file.h"

#include <unistd.h>

#include <atomic>
#include <filesystem>
#include <fstream>
#include <system_error>

#include "evkit/base/error.h"

namespace evkit {
namespace fs = std::filesystem;

namespace {
std::string uniqueSuffix() {
  static std::atomic<int> counter{0};
  return ".tmp-" + std::to_string(::getpid()) + "-" + std::to_string(counter++);
}
}  // namespace

AtomicPath::AtomicPath(std::string final_path)
    : final_(std::move(final_path)), temporary_(final_ + uniqueSuffix()) {}

AtomicPath::~AtomicPath() {
  if (!committed_) {
    std::error_code ignored;
    fs::remove_all(temporary_, ignored);
  }
}

void AtomicPath::commit() {
  std::error_code ec;
  if (fs::is_directory(final_, ec) && fs::is_directory(temporary_, ec)) fs::remove_all(final_, ec);
  fs::rename(temporary_, final_, ec);
  if (ec) throwInFile(final_, "cannot move the finished output into place: " + ec.message());
  committed_ = true;
}

void writeFileAtomically(const std::string& path, const std::string& bytes) {
  AtomicPath out(path);
  {
    std::ofstream file(out.temporaryPath(), std::ios::binary);
    if (!file) throwInFile(path, "cannot open for writing");
    file.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
    file.flush();
    if (!file) throwInFile(path, "write failed (disk full?)");
  }
  out.commit();
}

}  // namespace evkit
