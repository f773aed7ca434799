#include "evkit/events/filters.h"

#include <algorithm>
#include <array>
#include <cstdlib>

#include "evkit/base/error.h"

namespace evkit {

std::vector<uint32_t> findHotPixels(const EventSpan& events, double ratio, int64_t min_events) {
  const SensorSize s = events.sensor.known() ? events.sensor : boundingSensor(events);
  const int w = s.width, h = s.height;
  std::vector<uint32_t> counts(static_cast<size_t>(w) * static_cast<size_t>(h), 0);
  for (size_t i = 0; i < events.size(); ++i) {
    if (s.contains(events.x[i], events.y[i]))
      ++counts[static_cast<size_t>(events.y[i]) * w + events.x[i]];
  }
  std::vector<uint32_t> hot;
  std::array<uint32_t, 8> around{};
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const uint32_t c = counts[static_cast<size_t>(y) * w + x];
      if (static_cast<int64_t>(c) < min_events) continue;
      // The 8 neighbours, mirrored at the border (a corner pixel still has 8 values).
      int k = 0;
      for (int dy = -1; dy <= 1; ++dy) {
        for (int dx = -1; dx <= 1; ++dx) {
          if (dx == 0 && dy == 0) continue;
          int nx = x + dx, ny = y + dy;
          if (nx < 0 || nx >= w) nx = x - dx;
          if (ny < 0 || ny >= h) ny = y - dy;
          nx = std::clamp(nx, 0, w - 1);
          ny = std::clamp(ny, 0, h - 1);
          around[k++] = counts[static_cast<size_t>(ny) * w + nx];
        }
      }
      std::nth_element(around.begin(), around.begin() + 4, around.end());
      if (c > ratio * (around[4] + 1.0)) hot.push_back(static_cast<uint32_t>(y * w + x));
    }
  }
  return hot;
}

EventStore filterNoise(const EventSpan& events, const NoiseFilterOptions& options,
                       NoiseFilterReport* report) {
  if (!(options.hot_ratio > 0) || options.hot_min_events < 1 || options.refractory_us < 0)
    throw Error("noise filter: hot_ratio > 0, hot_min_events >= 1 and refractory_us >= 0");
  const SensorSize s = events.sensor.known() ? events.sensor : boundingSensor(events);
  const size_t pixels = static_cast<size_t>(s.width) * static_cast<size_t>(s.height);
  NoiseFilterReport local;
  NoiseFilterReport& r = report ? *report : local;
  r = {};
  std::vector<uint8_t> drop(pixels, 0);
  if (options.hot_pixels) {
    r.hot_pixels = findHotPixels(events, options.hot_ratio, options.hot_min_events);
    for (uint32_t p : r.hot_pixels) drop[p] = 1;
  }
  std::vector<int64_t> last(options.refractory_us > 0 ? pixels : 0, INT64_MIN);
  EventStore out(events.sensor);
  out.reserve(events.size());
  for (size_t i = 0; i < events.size(); ++i) {
    if (!s.contains(events.x[i], events.y[i])) continue;
    const size_t p = static_cast<size_t>(events.y[i]) * s.width + events.x[i];
    if (drop[p]) {
      ++r.hot_events;
      continue;
    }
    if (!last.empty()) {
      if (last[p] != INT64_MIN && events.t[i] - last[p] < options.refractory_us) {
        ++r.refractory_events;
        continue;
      }
      last[p] = events.t[i];
    }
    out.push_back(events.t[i], events.x[i], events.y[i], events.p[i]);
  }
  return out;
}

EventStore filterUnsupported(const EventSpan& events, int64_t window_us, int64_t* dropped) {
  if (window_us < 0) throw Error("support filter: the window must be >= 0 us");
  const SensorSize s = events.sensor.known() ? events.sensor : boundingSensor(events);
  const int w = s.width, h = s.height;
  // Each pixel's latest event time, seen forwards and then backwards in time; an event is
  // supported when a neighbour's latest (before it) or next (after it) is within the window.
  std::vector<uint8_t> supported(events.size(), 0);
  std::vector<int64_t> seen(static_cast<size_t>(w) * static_cast<size_t>(h));
  const auto visit = [&](size_t i, int64_t none) {
    const int x = events.x[i], y = events.y[i];
    if (x >= w || y >= h) return;
    const int64_t t = events.t[i];
    for (int ny = std::max(0, y - 1); ny <= std::min(h - 1, y + 1) && !supported[i]; ++ny) {
      for (int nx = std::max(0, x - 1); nx <= std::min(w - 1, x + 1); ++nx) {
        const int64_t other = seen[static_cast<size_t>(ny) * w + nx];
        if ((nx != x || ny != y) && other != none && std::abs(t - other) <= window_us) {
          supported[i] = 1;
          break;
        }
      }
    }
    seen[static_cast<size_t>(y) * w + x] = t;
  };
  const size_t n = events.size();
  std::fill(seen.begin(), seen.end(), INT64_MIN);
  for (size_t i = 0; i < n; ++i) visit(i, INT64_MIN);
  std::fill(seen.begin(), seen.end(), INT64_MAX);
  for (size_t i = n; i-- > 0;) visit(i, INT64_MAX);
  EventStore out(events.sensor);
  out.reserve(n);
  for (size_t i = 0; i < n; ++i) {
    if (supported[i]) out.push_back(events.t[i], events.x[i], events.y[i], events.p[i]);
  }
  if (dropped) *dropped = static_cast<int64_t>(n - out.size());
  return out;
}

}  // namespace evkit
