#include "evkit/events/random_events.h"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <random>

namespace evkit {

EventStore randomEvents(const RandomEventOptions& o) {
  EventStore events(o.sensor);
  events.reserve(o.count);
  std::mt19937_64 rng(o.seed);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  std::exponential_distribution<double> gap(o.rate_hz * 1e-6);  // per µs
  const double cx = 0.5 * o.sensor.width, cy = 0.5 * o.sensor.height;
  const double radius = 0.45 * std::min(o.sensor.width, o.sensor.height);
  double t_offset = 0.0;  // µs since t_start, accumulated in double, then rounded: stays sorted
  for (size_t i = 0; i < o.count; ++i) {
    t_offset += gap(rng);
    const int64_t t = o.t_start_us + static_cast<int64_t>(t_offset);
    int x, y, p;
    if (unit(rng) < o.structured_fraction) {
      const double angle = 2.0 * std::numbers::pi * o.rotation_hz * t_offset * 1e-6;
      const double along = (2.0 * unit(rng) - 1.0) * radius;
      const double across = (unit(rng) - 0.5) * 4.0;  // leading side > 0
      x = static_cast<int>(std::lround(cx + along * std::cos(angle) - across * std::sin(angle)));
      y = static_cast<int>(std::lround(cy + along * std::sin(angle) + across * std::cos(angle)));
      p = (across > 0) == (along > 0) ? 1 : -1;
    } else {
      x = static_cast<int>(unit(rng) * o.sensor.width);
      y = static_cast<int>(unit(rng) * o.sensor.height);
      p = unit(rng) < 0.5 ? 1 : -1;
    }
    x = std::clamp(x, 0, o.sensor.width - 1);
    y = std::clamp(y, 0, o.sensor.height - 1);
    events.push_back(t, static_cast<uint16_t>(x), static_cast<uint16_t>(y), static_cast<int8_t>(p));
  }
  return events;
}

}  // namespace evkit
