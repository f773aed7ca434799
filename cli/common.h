// Shared pieces of the evkit subcommands: option parsing, time values, progress, exit codes.
#pragma once

#include <boost/program_options.hpp>
#include <chrono>
#include <cstdint>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "evkit/base/text.h"
#include "evkit/events/io.h"

namespace evkit::cli {

namespace po = boost::program_options;

// Exit codes (documented in the README and in `evkit --help`).
constexpr int kExitOk = 0;
constexpr int kExitInputError = 1;  // bad or unreadable input, failed output
constexpr int kExitUsage = 2;       // bad command line
constexpr int kExitInternal = 3;    // a bug: please report

// A mistake on the command line: exit code 2.
class UsageError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

using Args = std::vector<std::string>;

// Parses `args` against `visible` (+ positional names). Prints help and returns false on --help.
bool parseArgs(const Args& args, const std::string& usage, const po::options_description& visible,
               const po::positional_options_description& positional, po::variables_map& vm);

// Durations: "250us", "10ms", "1.5s", or a bare integer in µs. Exact (no floating point).
int64_t parseDuration(const std::string& text, const std::string& option);
// Instants: an absolute time in µs ("1605537493718345", or with a unit "1605537493.7s"), or
// relative to the first event with a leading '+' ("+10ms"). Returns the value and whether it is
// relative.
struct TimeValue {
  int64_t us = 0;
  bool relative = false;
};
TimeValue parseTimeValue(const std::string& text, const std::string& option);

// "C" or "C_on,C_off" (the second defaults to the first); throws UsageError naming the option.
std::pair<double, double> parseNumberPair(const std::string& text, const std::string& option);

std::optional<Format> optionalFormat(const po::variables_map& vm, const std::string& key);

// "a,b,,c" -> {"a", "b", "c"}.
std::vector<std::string> splitList(const std::string& list);
// "346x260" -> {346, 260}, each side in [min_side, max_side]; throws UsageError naming the option.
std::pair<int, int> parseImageSize(const std::string& text, const std::string& option, int min_side,
                                   int max_side);

// "1605537493.718345 s" and "1,234,567".
std::string formatSeconds(int64_t us);
std::string withThousands(int64_t n);

// A progress line on stderr, shown only when stderr is a terminal and the work has run > 2 s.
class Progress {
 public:
  explicit Progress(std::string label, std::optional<int64_t> total = std::nullopt);
  ~Progress();
  void update(int64_t done);
  // With a short status after the count (e.g. the current loss).
  void update(int64_t done, const std::string& status);
  void finish();

 private:
  std::string label_;
  std::optional<int64_t> total_;
  std::chrono::steady_clock::time_point start_, last_draw_;
  bool enabled_;
  bool drawn_ = false;
  std::string status_;
};

int runInfo(const Args& args);
int runConvert(const Args& args);
int runAccumulate(const Args& args);
int runDemo(const Args& args);
int runFrames(const Args& args);
int runSimulate(const Args& args);
int runSynth(const Args& args);
int runDeblur(const Args& args);
int runVideo(const Args& args);
int runCompare(const Args& args);
int runMetrics(const Args& args);
int runBench(const Args& args);

// Building blocks the demo reuses.
void printInfo(const std::string& path, std::optional<Format> format);
int64_t convertFile(const std::string& in, std::optional<Format> in_format, const std::string& out,
                    std::optional<Format> out_format, const WriterOptions& options,
                    std::optional<TimeValue> start, std::optional<TimeValue> end);

}  // namespace evkit::cli
