#include "timed_list.h"

#include <filesystem>
#include <fstream>

#include "evkit/base/error.h"
#include "evkit/events/decimal.h"

namespace evkit::detail {

std::vector<std::pair<int64_t, std::string>> readTimedPathList(const std::string& list,
                                                               bool seconds,
                                                               bool strictly_increasing) {
  std::ifstream in(list);
  if (!in) throwInFile(list, "cannot open the list of timed images");
  const std::filesystem::path base = std::filesystem::path(list).parent_path();
  const std::string expected = seconds ? "expected 't_seconds image_path'"
                                       : "expected 't_us image_path' (t an integer in µs)";
  std::vector<std::pair<int64_t, std::string>> entries;
  std::string line;
  int64_t line_no = 0;
  while (std::getline(in, line)) {
    ++line_no;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    const size_t first = line.find_first_not_of(" \t");
    if (first == std::string::npos || line[first] == '#') continue;
    const char* p = line.data() + first;
    const char* end = line.data() + line.size();
    int64_t t = 0;
    const bool ok =
        seconds ? parseSecondsAsMicros(p, end, t) : parseInt(p, end, INT64_MIN, INT64_MAX, t);
    if (!ok || p == end || (*p != ' ' && *p != '\t')) throwAtLine(list, line_no, expected);
    while (p < end && (*p == ' ' || *p == '\t')) ++p;
    if (p == end) throwAtLine(list, line_no, "no image path after the time");
    if (!entries.empty() &&
        (t < entries.back().first || (strictly_increasing && t == entries.back().first))) {
      throwAtLine(
          list, line_no,
          strictly_increasing ? "frame times must increase" : "image timestamps go back in time");
    }
    entries.emplace_back(t, (base / std::string(p, end)).string());
  }
  return entries;
}

}  // namespace evkit::detail
