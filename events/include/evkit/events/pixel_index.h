// Events grouped by pixel: a counting sort that keeps each pixel's events in time order, so that a
// per-pixel model (EDI's double integral, BeNeRF's accumulated events) walks one pixel's history
// without searching. Events outside the width x height sensor are left out.
//
//   PixelEventIndex index(events, width, height);
//   for (uint32_t e = index.begin(p); e < index.end(p); ++e) use(index.t()[e],
//   index.polarity()[e]);
#pragma once

#include <cstdint>
#include <vector>

#include "evkit/events/event_store.h"

namespace evkit {

class PixelEventIndex {
 public:
  PixelEventIndex() = default;
  PixelEventIndex(const EventSpan& events, int width, int height);

  // Pixel p = y * width + x: its events are [begin(p), end(p)) of t() and polarity().
  uint32_t begin(size_t pixel) const { return first_[pixel]; }
  uint32_t end(size_t pixel) const { return first_[pixel + 1]; }
  uint32_t count(size_t pixel) const { return end(pixel) - begin(pixel); }
  const std::vector<int64_t>& t() const { return t_; }
  const std::vector<int8_t>& polarity() const { return p_; }
  size_t size() const { return t_.size(); }  // events inside the sensor
  int width() const { return width_; }
  int height() const { return height_; }

 private:
  int width_ = 0, height_ = 0;
  std::vector<uint32_t> first_;  // pixels + 1 offsets
  std::vector<int64_t> t_;
  std::vector<int8_t> p_;
};

}  // namespace evkit
