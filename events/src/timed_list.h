// "t path" list files: RPG's images.txt (t in seconds) and the simulator's timestamps.txt (t in
// integer µs). Paths are relative to the list's folder; '#' lines and blank lines are skipped.
#pragma once

#include <cstdint>
#include <string>
#include <utility>
#include <vector>

namespace evkit::detail {

// Throws evkit::Error naming the file and line of a malformed entry or of a time that goes back
// (or, with strictly_increasing, does not advance).
std::vector<std::pair<int64_t, std::string>> readTimedPathList(const std::string& list,
                                                               bool seconds,
                                                               bool strictly_increasing);

}  // namespace evkit::detail
