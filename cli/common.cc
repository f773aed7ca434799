#include "common.h"

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <iostream>

#include "evkit/base/error.h"
#include "evkit/events/decimal.h"

namespace evkit::cli {

bool parseArgs(const Args& args, const std::string& usage, const po::options_description& visible,
               const po::positional_options_description& positional, po::variables_map& vm) {
  po::options_description all;
  all.add(visible);
  all.add_options()("help,h", "show this help");
  try {
    po::store(po::command_line_parser(args).options(all).positional(positional).run(), vm);
    if (vm.count("help")) {
      std::cout << usage << "\n\n" << visible << std::endl;
      return false;
    }
    po::notify(vm);
  } catch (const po::error& e) {
    throw UsageError(e.what());
  }
  return true;
}

int64_t parseDuration(const std::string& text, const std::string& option) {
  const TimeValue v = parseTimeValue(text, option);
  if (v.relative || v.us <= 0)
    throw UsageError("--" + option + ": expected a positive duration, got '" + text + "'");
  return v.us;
}

TimeValue parseTimeValue(const std::string& text, const std::string& option) {
  TimeValue value;
  std::string body = text;
  if (!body.empty() && body[0] == '+') {
    value.relative = true;
    body.erase(0, 1);
  }
  int64_t scale_down = 1;  // the number is in seconds; divide µs by this to get the unit
  std::string number = body;
  if (body.size() > 2 && body.compare(body.size() - 2, 2, "us") == 0) {
    number = body.substr(0, body.size() - 2);
    scale_down = 1000000;
  } else if (body.size() > 2 && body.compare(body.size() - 2, 2, "ms") == 0) {
    number = body.substr(0, body.size() - 2);
    scale_down = 1000;
  } else if (body.size() > 1 && body.back() == 's') {
    number = body.substr(0, body.size() - 1);
  } else {
    scale_down = 1000000;  // bare numbers are µs
  }
  const char* p = number.data();
  const char* end = p + number.size();
  int64_t micros_if_seconds = 0;
  bool ok = false;
  if (scale_down == 1) {
    ok = parseSecondsAsMicros(p, end, micros_if_seconds) && p == end;
    value.us = micros_if_seconds;
  } else {
    // Parse as seconds then shift: "1.5ms" = 0.0015 s. Append the exponent textually for exactness.
    const std::string scaled = number + (scale_down == 1000 ? "e-3" : "e-6");
    const char* q = scaled.data();
    const char* qend = q + scaled.size();
    ok = number.find_first_of("eE") == std::string::npos &&
         parseSecondsAsMicros(q, qend, value.us) && q == qend;
  }
  if (!ok || number.empty()) {
    throw UsageError("--" + option + ": cannot read the time '" + text +
                     "' (expected e.g. 1605537493718345, 250us, 10ms, 1.5s, or +10ms)");
  }
  return value;
}

std::pair<double, double> parseNumberPair(const std::string& text, const std::string& option) {
  try {
    size_t used = 0;
    const double a = std::stod(text, &used);
    if (used == text.size()) return {a, a};
    if (text[used] != ',') throw std::invalid_argument(text);
    size_t used_b = 0;
    const std::string rest = text.substr(used + 1);
    const double b = std::stod(rest, &used_b);
    if (used_b != rest.size()) throw std::invalid_argument(text);
    return {a, b};
  } catch (const std::exception&) {
    throw UsageError("--" + option + ": expected a number or two separated by a comma, got '" +
                     text + "'");
  }
}

std::optional<Format> optionalFormat(const po::variables_map& vm, const std::string& key) {
  if (!vm.count(key)) return std::nullopt;
  try {
    return parseFormat(vm[key].as<std::string>());
  } catch (const Error& e) {
    throw UsageError("--" + key + ": " + e.what());
  }
}

std::string formatSeconds(int64_t us) {
  char buf[40];
  char* end = formatMicrosAsSeconds(us, buf);
  return std::string(buf, end) + " s";
}

std::string withThousands(int64_t n) {
  std::string digits = std::to_string(n < 0 ? -n : n);
  std::string out;
  for (size_t i = 0; i < digits.size(); ++i) {
    if (i > 0 && (digits.size() - i) % 3 == 0) out += ',';
    out += digits[i];
  }
  return n < 0 ? "-" + out : out;
}

Progress::Progress(std::string label, std::optional<int64_t> total)
    : label_(std::move(label)),
      total_(total),
      start_(std::chrono::steady_clock::now()),
      last_draw_(start_),
      enabled_(::isatty(STDERR_FILENO) == 1) {}

Progress::~Progress() { finish(); }

void Progress::update(int64_t done, const std::string& status) {
  status_ = status;
  update(done);
}

void Progress::update(int64_t done) {
  if (!enabled_) return;
  const auto now = std::chrono::steady_clock::now();
  const double elapsed = std::chrono::duration<double>(now - start_).count();
  if (elapsed < 2.0 || now - last_draw_ < std::chrono::milliseconds(200)) return;
  last_draw_ = now;
  drawn_ = true;
  if (total_ && *total_ > 0) {
    const double fraction = std::min(1.0, static_cast<double>(done) / static_cast<double>(*total_));
    const int width = 30;
    const int filled = static_cast<int>(fraction * width);
    const double eta = fraction > 0 ? elapsed * (1.0 - fraction) / fraction : 0.0;
    std::fprintf(stderr, "\r%s [%s%s] %3.0f%%  %s%s%s  %.0fs left   ", label_.c_str(),
                 std::string(static_cast<size_t>(filled), '#').c_str(),
                 std::string(static_cast<size_t>(width - filled), ' ').c_str(), 100.0 * fraction,
                 withThousands(done).c_str(), status_.empty() ? "" : "  ", status_.c_str(), eta);
  } else {
    std::fprintf(stderr, "\r%s %s  %.0fs   ", label_.c_str(), withThousands(done).c_str(), elapsed);
  }
  std::fflush(stderr);
}

void Progress::finish() {
  if (drawn_) {
    std::fprintf(stderr, "\r\033[K");
    std::fflush(stderr);
    drawn_ = false;
  }
}

std::vector<std::string> splitList(const std::string& list) {
  std::vector<std::string> out;
  for (size_t start = 0; start <= list.size();) {
    const size_t comma = std::min(list.find(',', start), list.size());
    if (comma > start) out.push_back(list.substr(start, comma - start));
    start = comma + 1;
  }
  return out;
}

std::pair<int, int> parseImageSize(const std::string& text, const std::string& option, int min_side,
                                   int max_side) {
  int w = 0, h = 0;
  if (std::sscanf(text.c_str(), "%dx%d", &w, &h) != 2 || w < min_side || h < min_side ||
      w > max_side || h > max_side) {
    throw UsageError("--" + option + ": expected WxH, e.g. 346x260");
  }
  return {w, h};
}

}  // namespace evkit::cli
