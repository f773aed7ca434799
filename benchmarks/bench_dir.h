// Where benchmarks leave their generated files: $EVKIT_BENCH_DIR, else <tmp>/evkit-bench (created),
// so that the Python reference scripts can read the very same files in the same hour.
#pragma once

#include <cstdlib>
#include <filesystem>
#include <string>

namespace evkit {

inline std::string benchPath(const std::string& name) {
  const char* env = std::getenv("EVKIT_BENCH_DIR");
  const std::filesystem::path dir =
      env ? std::filesystem::path(env) : std::filesystem::temp_directory_path() / "evkit-bench";
  std::filesystem::create_directories(dir);
  return (dir / name).string();
}

}  // namespace evkit
