// Events in memory: a structure of arrays with the sensor size.
//
// Conventions (DESIGN.md §2):
//  - t is int64 microseconds as the camera wrote it; many files hold absolute Unix time (~1.6e15),
//    so never put t in a float or round-trip it through double seconds. Subtract in int64, then
//    convert the difference.
//  - x to the right, y down, origin top-left, 0-based.
//  - p is +1 (ON, brighter) or -1 (OFF).
//  - Events are sorted by t (non-decreasing). Readers that meet out-of-order timestamps report it.
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

namespace evkit {

struct SensorSize {
  int width = 0;
  int height = 0;

  bool known() const { return width > 0 && height > 0; }
  bool contains(int x, int y) const { return x >= 0 && y >= 0 && x < width && y < height; }
  bool operator==(const SensorSize&) const = default;
};

// A read-only view of a contiguous run of events (no ownership).
struct EventSpan {
  std::span<const int64_t> t;
  std::span<const uint16_t> x;
  std::span<const uint16_t> y;
  std::span<const int8_t> p;
  SensorSize sensor;

  size_t size() const { return t.size(); }
  bool empty() const { return t.empty(); }
  EventSpan subspan(size_t begin, size_t end) const;
  // Events with t in [t_begin, t_end), found by binary search.
  EventSpan sliceTime(int64_t t_begin, int64_t t_end) const;
  // Index of the first event with t >= t_query.
  size_t lowerBound(int64_t t_query) const;
};

class EventStore {
 public:
  EventStore() = default;
  explicit EventStore(SensorSize sensor) : sensor_(sensor) {}

  SensorSize sensor() const { return sensor_; }
  void setSensor(SensorSize sensor) { sensor_ = sensor; }

  size_t size() const { return t.size(); }
  bool empty() const { return t.empty(); }
  void reserve(size_t n);
  void clear();
  void push_back(int64_t t_us, uint16_t x_px, uint16_t y_px, int8_t polarity) {
    t.push_back(t_us);
    x.push_back(x_px);
    y.push_back(y_px);
    p.push_back(polarity);
  }
  void append(const EventSpan& events);

  EventSpan view() const { return EventSpan{t, x, y, p, sensor_}; }
  EventSpan sliceTime(int64_t t_begin, int64_t t_end) const {
    return view().sliceTime(t_begin, t_end);
  }

  int64_t countOn() const;

  // The four columns; kept public so that readers and kernels can fill and scan them directly.
  std::vector<int64_t> t;
  std::vector<uint16_t> x;
  std::vector<uint16_t> y;
  std::vector<int8_t> p;

 private:
  SensorSize sensor_;
};

// Merges two time-sorted event sets into one time-sorted set (stable: on equal t, `a` comes first).
// The sensor is the larger of the two in each dimension.
EventStore merge(const EventSpan& a, const EventSpan& b);

// Throws evkit::Error naming `source` and the index of the first event that lies outside the sensor
// (when the sensor is known), has a polarity other than ±1, or goes back in time. For a part of a
// longer stream, `first_index` numbers the events in the message and `previous_t` is the time of
// the event before the part.
void validate(const EventSpan& events, const std::string& source, size_t first_index = 0,
              int64_t previous_t = INT64_MIN);

// The smallest sensor that contains every event (max x + 1, max y + 1).
SensorSize boundingSensor(const EventSpan& events);

}  // namespace evkit
