#include "evkit/deblur/settings.h"

#include <cstdio>

namespace evkit {

double settingNumber(const std::string& method, const std::string& key, const std::string& value) {
  try {
    size_t used = 0;
    const double v = std::stod(value, &used);
    if (used == value.size() && std::isfinite(v)) return v;
  } catch (const std::exception&) {
  }
  throw Error(method + ": setting " + key + "=" + value + " is not a number");
}

std::string shortNumber(double v) {
  char text[32];
  std::snprintf(text, sizeof(text), "%.6g", v);
  return text;
}

std::string SettingRange::describe() const {
  const bool low = std::isfinite(min), high = std::isfinite(max);
  if (low && high) {
    return std::string("in ") + (min_open ? "(" : "[") + shortNumber(min) + ", " +
           shortNumber(max) + (max_open ? ")" : "]");
  }
  if (low) return (min_open ? "> " : ">= ") + shortNumber(min);
  if (high) return (max_open ? "< " : "<= ") + shortNumber(max);
  return "finite";
}

}  // namespace evkit
