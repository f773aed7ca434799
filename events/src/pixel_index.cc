#include "evkit/events/pixel_index.h"

namespace evkit {

PixelEventIndex::PixelEventIndex(const EventSpan& events, int width, int height)
    : width_(width), height_(height) {
  const size_t pixels = static_cast<size_t>(width) * static_cast<size_t>(height);
  const auto inside = [&](size_t e) { return events.x[e] < width && events.y[e] < height; };
  const auto pixel = [&](size_t e) {
    return static_cast<size_t>(events.y[e]) * static_cast<size_t>(width) + events.x[e];
  };
  first_.assign(pixels + 1, 0);
  for (size_t e = 0; e < events.size(); ++e) {
    if (inside(e)) ++first_[pixel(e) + 1];
  }
  for (size_t p = 0; p < pixels; ++p) first_[p + 1] += first_[p];
  t_.resize(first_[pixels]);
  p_.resize(first_[pixels]);
  std::vector<uint32_t> fill(first_.begin(), first_.end() - 1);
  for (size_t e = 0; e < events.size(); ++e) {
    if (!inside(e)) continue;
    const uint32_t at = fill[pixel(e)]++;
    t_[at] = events.t[e];
    p_[at] = events.p[e];
  }
}

}  // namespace evkit
