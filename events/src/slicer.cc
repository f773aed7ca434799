#include "evkit/events/slicer.h"

#include <limits>

#include "evkit/base/error.h"

namespace evkit {

EventSlicer EventSlicer::byTime(int64_t length_us, SensorSize sensor) {
  if (length_us <= 0) throw Error("event slicer: the window length must be positive");
  return EventSlicer(length_us, 0, sensor);
}

EventSlicer EventSlicer::byCount(size_t count, SensorSize sensor) {
  if (count == 0) throw Error("event slicer: the window must hold at least one event");
  return EventSlicer(0, count, sensor);
}

bool EventSlicer::accept(const EventSpan& events, const Callback& callback) {
  if (stopped_) return false;
  if (!started_ && !events.empty()) {
    window_begin_ = origin_.value_or(events.t.front());
    origin_ = window_begin_;
    started_ = true;
  }
  if (!started_) return true;
  pending_.append(events.sliceTime(*origin_, end_.value_or(std::numeric_limits<int64_t>::max())));
  slice(false, callback);
  // Drop what the windows have consumed once it is most of the buffer.
  if (offset_ > (size_t{1} << 22) && offset_ > pending_.size() / 2) {
    EventStore rest(pending_.sensor());
    rest.append(pending_.view().subspan(offset_, pending_.size()));
    pending_ = std::move(rest);
    offset_ = 0;
  }
  return !stopped_;
}

void EventSlicer::finish(const Callback& callback) {
  if (!stopped_ && started_) slice(true, callback);
}

void EventSlicer::emit(size_t end_index, int64_t t0, int64_t t1, const Callback& callback) {
  const Window w{windows_++, t0, t1, pending_.view().subspan(offset_, end_index)};
  offset_ = end_index;
  if (!callback(w)) stopped_ = true;
}

void EventSlicer::slice(bool final, const Callback& callback) {
  const size_t available = pending_.size();
  if (count_ > 0) {
    while (!stopped_ && available - offset_ >= count_) {
      emit(offset_ + count_, pending_.t[offset_], pending_.t[offset_ + count_ - 1] + 1, callback);
    }
    if (final && !stopped_ && available > offset_)
      emit(available, pending_.t[offset_], pending_.t[available - 1] + 1, callback);
    return;
  }
  const int64_t stop = end_.value_or(std::numeric_limits<int64_t>::max());
  while (!stopped_ && window_begin_ < stop) {
    const int64_t window_end = window_begin_ > std::numeric_limits<int64_t>::max() - length_
                                   ? std::numeric_limits<int64_t>::max()
                                   : window_begin_ + length_;
    // A window is complete once an event at or after its end has arrived (or the stream ended).
    const bool complete = available > offset_ && pending_.t[available - 1] >= window_end;
    if (!complete && !final) break;
    if (final && offset_ >= available) break;
    const size_t end_index =
        offset_ + pending_.view().subspan(offset_, available).lowerBound(window_end);
    const int64_t begin = window_begin_;
    window_begin_ = window_end;
    emit(end_index, begin, window_end, callback);
  }
}

}  // namespace evkit
