// Noise filters for recordings from real sensors, applied on request before deblurring
// (`evkit deblur --filter-hot-pixels`), as DV's and Metavision's users expect:
//  - hot pixels: a pixel that fires far above its neighbours (a defective pixel, or one stuck by a
//    bright source) is removed with all its events;
//  - refractory bursts: an event that follows its pixel's previous kept event by less than the
//    period is dropped (DV's RefractoryPeriodFilter), so that bursts of noise at microsecond
//    spacing do not read as large contrast changes.
// Both keep the events' order and the sensor.
//
// And for shot noise (events at random pixels and times, a few Hz per pixel on a DAVIS): the
// background-activity filter (Delbruck, "Frame-free dynamic digital vision", 2008) keeps an event
// only when one of its 8 neighbours fired within a window before or after it. A moving edge fires
// its neighbours within the time it takes to move a pixel or two; a noise event is alone.
#pragma once

#include <cstdint>
#include <vector>

#include "evkit/events/event_store.h"

namespace evkit {

struct NoiseFilterOptions {
  bool hot_pixels = true;
  // Hot: at least `hot_min_events` events, and more than `hot_ratio` times (the median count of
  // the 8 neighbours + 1).
  double hot_ratio = 10;
  int64_t hot_min_events = 20;
  // 0: no refractory filter. Edges crossing a pixel fire one event per threshold, hundreds of µs
  // apart even for 60 px of blur in 100 ms; noise bursts come microseconds apart.
  int64_t refractory_us = 50;
};

struct NoiseFilterReport {
  std::vector<uint32_t> hot_pixels;  // y * width + x
  int64_t hot_events = 0;            // events removed with the hot pixels
  int64_t refractory_events = 0;     // events dropped by the refractory filter
};

// The pixels of `events` that fire far above their neighbours (sensor-sized counts).
std::vector<uint32_t> findHotPixels(const EventSpan& events, double ratio, int64_t min_events);

// The events without hot pixels and refractory bursts; `report` (optional) says what went.
EventStore filterNoise(const EventSpan& events, const NoiseFilterOptions& options,
                       NoiseFilterReport* report = nullptr);

// The events that one of their 8 neighbouring pixels supports: a neighbour's event within
// `window_us` before or after (both sides: offline, an edge's first events are supported by
// those after them). The pixel's own events do not count. Keeps the order and the sensor;
// `dropped` (optional) receives how many went.
EventStore filterUnsupported(const EventSpan& events, int64_t window_us,
                             int64_t* dropped = nullptr);

}  // namespace evkit
