// Cuts a stream of events into windows, by time (fixed length from an origin) or by count, as
// dv-processing's EventStreamSlicer does, in bounded memory: feed the chunks of a reader in time
// order with accept(); each complete window goes to the callback with its bounds; finish() hands
// over what is left (the last partial window). Only events in [origin, end) are kept.
//
//   EventSlicer slicer = EventSlicer::byTime(10'000, sensor);        // 10 ms windows
//   while (reader->next(chunk, 1 << 20)) slicer.accept(chunk.events.view(), use);
//   slicer.finish(use);
#pragma once

#include <cstdint>
#include <functional>
#include <optional>

#include "evkit/events/event_store.h"

namespace evkit {

class EventSlicer {
 public:
  struct Window {
    size_t index = 0;
    int64_t t_begin = 0, t_end = 0;  // [t_begin, t_end): by time the window's bounds, by count its
                                     // first event's time and its last one's plus 1 µs
    EventSpan events;                // valid during the callback
  };
  // Returns false to stop: no further window is handed over.
  using Callback = std::function<bool(const Window&)>;

  // Windows of `length_us`, the first starting at the origin (the first event's time unless set).
  static EventSlicer byTime(int64_t length_us, SensorSize sensor);
  // Windows of `count` events.
  static EventSlicer byCount(size_t count, SensorSize sensor);

  // Before the first accept(): where windows start and where events stop counting.
  void setOrigin(int64_t t_us) { origin_ = t_us; }
  void setEnd(int64_t t_us) { end_ = t_us; }

  // Returns false once the callback has stopped the slicer.
  bool accept(const EventSpan& events, const Callback& callback);
  void finish(const Callback& callback);

  size_t windows() const { return windows_; }
  bool stopped() const { return stopped_; }

 private:
  EventSlicer(int64_t length_us, size_t count, SensorSize sensor)
      : length_(length_us), count_(count), pending_(sensor) {}
  void emit(size_t end_index, int64_t t0, int64_t t1, const Callback& callback);
  void slice(bool final, const Callback& callback);

  int64_t length_ = 0;  // > 0: by time
  size_t count_ = 0;    // > 0: by count
  std::optional<int64_t> origin_, end_;
  EventStore pending_;
  size_t offset_ = 0;  // the first event of pending_ not yet in a window
  int64_t window_begin_ = 0;
  bool started_ = false, stopped_ = false;
  size_t windows_ = 0;
};

}  // namespace evkit
