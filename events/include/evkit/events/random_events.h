// Seeded random recordings for demos, tests and benchmarks.
#pragma once

#include <cstdint>

#include "evkit/events/event_store.h"

namespace evkit {

struct RandomEventOptions {
  size_t count = 100000;
  SensorSize sensor{346, 260};
  int64_t t_start_us = 1'600'000'000'000'000;  // absolute Unix µs, as cameras write them
  double rate_hz = 1e6;                        // mean event rate (exponential gaps)
  // Fraction of events on a bar rotating about the centre (ON on its leading side, OFF behind);
  // the rest are uniform noise. 0 gives pure noise.
  double structured_fraction = 0.9;
  double rotation_hz = 2.0;
  uint64_t seed = 1;
};

// Time-sorted events inside the sensor, identical for identical options.
EventStore randomEvents(const RandomEventOptions& options);

}  // namespace evkit
