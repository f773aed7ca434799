// Helpers shared by the test suites: scratch folders, running the evkit binary, fixtures.
#pragma once

#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>
#include <string>

namespace evkit::test {

namespace fs = std::filesystem;

// Whether the tests run under AddressSanitizer (the sanitizer build).
#if defined(__SANITIZE_ADDRESS__)
inline constexpr bool kSanitized = true;
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
inline constexpr bool kSanitized = true;
#else
inline constexpr bool kSanitized = false;
#endif
#else
inline constexpr bool kSanitized = false;
#endif

// Whether this run is the sanitizer pass, in which the long accuracy tests skip: the sanitizer
// build, or EVKIT_TEST_AS_SANITIZED=1 in any build (scripts/sanitizer_coverage.sh runs the pass so
// to measure which lines only the skipped tests reach).
inline bool sanitizerPass() {
  static const bool pass = kSanitized || std::getenv("EVKIT_TEST_AS_SANITIZED") != nullptr;
  return pass;
}

// Why an accuracy test skips in the sanitizer pass: it trains for hundreds of steps (a minute or
// two there on 2 cores), and the pass's shorter tests reach its code (scripts/sanitizer_coverage.sh
// lists the lines they do not). Its numbers are checked in the Release pass.
inline constexpr const char* kReachedByShorterTests =
    "an accuracy run whose code shorter tests reach under the sanitizers";

// A fresh folder removed at the end of the test.
class ScratchDir {
 public:
  ScratchDir() {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    std::string name = info ? std::string(info->test_suite_name()) + "_" + info->name() : "evkit";
    for (char& c : name) {
      if (c == '/') c = '_';
    }
    path_ = fs::temp_directory_path() / ("evkit_test_" + name + "_" + std::to_string(::getpid()));
    fs::remove_all(path_);
    fs::create_directories(path_);
  }
  ~ScratchDir() { fs::remove_all(path_); }
  std::string operator/(const std::string& name) const { return (path_ / name).string(); }
  const fs::path& path() const { return path_; }

 private:
  fs::path path_;
};

inline void writeText(const std::string& path, const std::string& text) {
  std::ofstream(path, std::ios::binary) << text;
}

inline std::string readText(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

struct RunResult {
  int exit_code = -1;
  std::string out;
  std::string err;
};

// Runs the evkit binary with `args` (a shell-quoted string), capturing stdout and stderr.
inline RunResult runEvkit(const std::string& args, const ScratchDir& dir) {
  const std::string out_path = dir / "stdout.log";
  const std::string err_path = dir / "stderr.log";
  const std::string command =
      std::string(EVKIT_BINARY) + " " + args + " >" + out_path + " 2>" + err_path + " </dev/null";
  const int status = std::system(command.c_str());
  RunResult r;
  r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
  r.out = readText(out_path);
  r.err = readText(err_path);
  return r;
}

// Path of a real recording in ../shared/fixtures/real, or "" when the folder is absent.
inline std::string fixture(const std::string& name) {
  const fs::path p = fs::path(EVKIT_SOURCE_DIR) / ".." / "shared" / "fixtures" / "real" / name;
  return fs::exists(p) ? fs::canonical(p).string() : std::string();
}

// Another program that keeps one core busy for the life of this object: a child process that
// spins, killed and reaped at the end (and ending itself after `seconds` should the test die
// first). pid() is -1 where fork failed.
class SpinningProcess {
 public:
  explicit SpinningProcess(unsigned seconds = 60) : pid_(fork()) {
    if (pid_ != 0) return;
    alarm(seconds);
    volatile uint64_t spins = 0;
    for (;;) spins = spins + 1;
  }
  ~SpinningProcess() {
    if (pid_ <= 0) return;
    kill(pid_, SIGKILL);
    waitpid(pid_, nullptr, 0);
  }
  SpinningProcess(const SpinningProcess&) = delete;
  SpinningProcess& operator=(const SpinningProcess&) = delete;
  pid_t pid() const { return pid_; }

 private:
  pid_t pid_;
};

// Files under `dir` whose name contains ".tmp-" (leftovers of an interrupted write).
inline int countTemporaries(const fs::path& dir) {
  int n = 0;
  for (const auto& e : fs::recursive_directory_iterator(dir)) {
    if (e.path().filename().string().find(".tmp-") != std::string::npos) ++n;
  }
  return n;
}

}  // namespace evkit::test
