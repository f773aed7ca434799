#include "evkit/events/event_store.h"

#include <gtest/gtest.h>

#include "evkit/base/error.h"
#include "evkit/events/pixel_index.h"
#include "evkit/events/random_events.h"

namespace evkit {
namespace {

EventStore smallStore() {
  EventStore s(SensorSize{4, 3});
  s.push_back(10, 0, 0, 1);
  s.push_back(20, 1, 0, -1);
  s.push_back(20, 2, 1, 1);
  s.push_back(35, 3, 2, -1);
  return s;
}

TEST(EventStore, SliceTimeIsHalfOpenAndUsesEqualTimesCorrectly) {
  const EventStore s = smallStore();
  EXPECT_EQ(s.sliceTime(0, 10).size(), 0u);
  EXPECT_EQ(s.sliceTime(10, 20).size(), 1u);
  EXPECT_EQ(s.sliceTime(10, 21).size(), 3u);
  const EventSpan mid = s.sliceTime(20, 36);
  ASSERT_EQ(mid.size(), 3u);
  EXPECT_EQ(mid.t[0], 20);
  EXPECT_EQ(mid.x[0], 1);
  EXPECT_EQ(s.sliceTime(36, 100).size(), 0u);
  EXPECT_EQ(s.sliceTime(30, 20).size(), 0u);  // reversed window: empty, no crash
}

TEST(EventStore, SliceKeepsAbsoluteUnixMicroseconds) {
  RandomEventOptions o;
  o.count = 10000;
  o.t_start_us = 1605537493718345;
  const EventStore s = randomEvents(o);
  const int64_t a = s.t[1234], b = s.t[5678];
  const EventSpan w = s.sliceTime(a, b);
  EXPECT_EQ(w.t.front(), a);
  EXPECT_LT(w.t.back(), b);
  EXPECT_EQ(w.size(), s.view().lowerBound(b) - s.view().lowerBound(a));
}

TEST(EventStore, MergeIsSortedAndStable) {
  EventStore a(SensorSize{4, 4}), b(SensorSize{8, 2});
  a.push_back(1, 0, 0, 1);
  a.push_back(5, 1, 1, 1);
  b.push_back(1, 7, 1, -1);
  b.push_back(3, 6, 0, -1);
  b.push_back(9, 5, 1, 1);
  const EventStore m = merge(a.view(), b.view());
  EXPECT_EQ(m.t, (std::vector<int64_t>{1, 1, 3, 5, 9}));
  EXPECT_EQ(m.x, (std::vector<uint16_t>{0, 7, 6, 1, 5}));  // on equal t, `a` first
  EXPECT_EQ(m.sensor(), (SensorSize{8, 4}));
  EXPECT_EQ(merge(a.view(), EventStore().view()).t, a.t);
}

TEST(EventStore, ValidateNamesTheFirstOffender) {
  EXPECT_NO_THROW(validate(smallStore().view(), "mem"));
  EventStore outside = smallStore();
  outside.x[2] = 4;
  try {
    validate(outside.view(), "mem");
    FAIL();
  } catch (const Error& e) {
    EXPECT_STREQ(e.what(), "mem: event 2: (x, y) = (4, 1) lies outside the 4x3 sensor");
  }
  EventStore backwards = smallStore();
  backwards.t[3] = 19;
  EXPECT_THROW(validate(backwards.view(), "mem"), Error);
  try {
    validate(backwards.view(), "mem", 100);
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("event 103: timestamp 19 us goes back in time"),
              std::string::npos)
        << e.what();
  }
  EventStore polarity = smallStore();
  polarity.p[0] = 0;
  EXPECT_THROW(validate(polarity.view(), "mem"), Error);
  // Continuity with the previous part of a stream.
  EXPECT_THROW(validate(smallStore().view(), "mem", 0, 11), Error);
}

TEST(EventStore, BoundingSensorAndCounts) {
  const EventStore s = smallStore();
  EXPECT_EQ(boundingSensor(s.view()), (SensorSize{4, 3}));
  EXPECT_EQ(boundingSensor(EventStore().view()), (SensorSize{}));
  EXPECT_EQ(s.countOn(), 2);
}

TEST(RandomEvents, DeterministicSortedAndInsideTheSensor) {
  RandomEventOptions o;
  o.count = 50000;
  const EventStore a = randomEvents(o), b = randomEvents(o);
  EXPECT_EQ(a.t, b.t);
  EXPECT_EQ(a.x, b.x);
  EXPECT_NO_THROW(validate(a.view(), "random"));
  o.seed = 2;
  EXPECT_NE(randomEvents(o).x, a.x);
}

}  // namespace
}  // namespace evkit

namespace evkit {
namespace {

TEST(PixelEventIndex, GroupsByPixelInTimeOrderAndDropsOutsiders) {
  EventStore ev(SensorSize{3, 2});
  // (t, x, y, p): pixel 1 = (1, 0) gets three events, pixel 5 = (2, 1) one; (3, 0) is outside.
  const int64_t t[] = {10, 11, 12, 13, 14, 15};
  const uint16_t x[] = {1, 2, 1, 3, 1, 0};
  const uint16_t y[] = {0, 1, 0, 0, 0, 2};
  const int8_t p[] = {1, -1, -1, 1, 1, 1};
  for (int i = 0; i < 6; ++i) ev.push_back(t[i], x[i], y[i], p[i]);
  const PixelEventIndex index(ev.view(), 3, 2);
  EXPECT_EQ(index.size(), 4u);
  EXPECT_EQ(index.count(0), 0u);
  ASSERT_EQ(index.count(1), 3u);
  EXPECT_EQ(index.t()[index.begin(1)], 10);
  EXPECT_EQ(index.t()[index.begin(1) + 1], 12);
  EXPECT_EQ(index.polarity()[index.begin(1) + 1], -1);
  EXPECT_EQ(index.t()[index.end(1) - 1], 14);
  ASSERT_EQ(index.count(5), 1u);
  EXPECT_EQ(index.t()[index.begin(5)], 11);
  EXPECT_EQ(index.end(5), index.size());
}

}  // namespace
}  // namespace evkit
