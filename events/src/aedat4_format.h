// What the AEDAT 4.0 reader and writer share (DV's file format).
#pragma once

#include <cstddef>

namespace evkit::detail {

inline constexpr char kAedat4Magic[] = "#!AER-DAT4.0\r\n";
inline constexpr size_t kAedat4MagicBytes = 14;

}  // namespace evkit::detail
