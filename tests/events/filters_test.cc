#include "evkit/events/filters.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <random>

namespace evkit {
namespace {

// Sparse background events (about 3 per pixel over 100 ms) on a 40 x 30 sensor.
EventStore background(uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_int_distribution<int> x(0, 39), y(0, 29), t(0, 99'999), p(0, 1);
  std::vector<std::array<int64_t, 4>> rows;
  for (int i = 0; i < 3600; ++i) rows.push_back({t(rng), x(rng), y(rng), p(rng) ? 1 : -1});
  std::sort(rows.begin(), rows.end());
  EventStore s(SensorSize{40, 30});
  for (const auto& r : rows)
    s.push_back(r[0], static_cast<uint16_t>(r[1]), static_cast<uint16_t>(r[2]),
                static_cast<int8_t>(r[3]));
  return s;
}

EventStore sorted(EventStore s) {
  std::vector<size_t> order(s.size());
  for (size_t i = 0; i < order.size(); ++i) order[i] = i;
  std::stable_sort(order.begin(), order.end(), [&](size_t a, size_t b) { return s.t[a] < s.t[b]; });
  EventStore out(s.sensor());
  for (size_t i : order) out.push_back(s.t[i], s.x[i], s.y[i], s.p[i]);
  return out;
}

TEST(NoiseFilter, FindsTheHotPixelsAndNothingElse) {
  EventStore s = background(3);
  for (int k = 0; k < 300; ++k) s.push_back(k * 300 + 7, 12, 5, 1);    // hot: 1 kHz... 3 kHz
  for (int k = 0; k < 200; ++k) s.push_back(k * 400 + 11, 0, 29, -1);  // hot, in a corner
  s = sorted(s);
  NoiseFilterOptions o;
  o.refractory_us = 0;
  NoiseFilterReport report;
  const EventStore out = filterNoise(s.view(), o, &report);
  ASSERT_EQ(report.hot_pixels.size(), 2u);
  EXPECT_EQ(report.hot_pixels[0], 5u * 40 + 12);
  EXPECT_EQ(report.hot_pixels[1], 29u * 40 + 0);
  // Every event of the two pixels went (the background's too), nothing else did.
  int64_t at_hot = 0;
  for (size_t i = 0; i < s.size(); ++i)
    at_hot += (s.x[i] == 12 && s.y[i] == 5) || (s.x[i] == 0 && s.y[i] == 29);
  EXPECT_EQ(report.hot_events, at_hot);
  EXPECT_EQ(out.size() + static_cast<size_t>(at_hot), s.size());
  EXPECT_TRUE(std::is_sorted(out.t.begin(), out.t.end()));
  EXPECT_EQ(out.sensor(), s.sensor());
}

TEST(NoiseFilter, BackgroundAloneHasNoHotPixel) {
  const EventStore s = background(5);
  EXPECT_TRUE(findHotPixels(s.view(), 10, 20).empty());
}

TEST(NoiseFilter, RefractoryDropsBurstsButKeepsAnEdgesEvents) {
  EventStore s(SensorSize{8, 8});
  for (int k = 0; k < 6; ++k) s.push_back(1000 + 3 * k, 2, 2, 1);     // a burst, 3 µs apart
  for (int k = 0; k < 5; ++k) s.push_back(5000 + 340 * k, 4, 4, -1);  // an edge, 340 µs apart
  s = sorted(s);
  NoiseFilterOptions o;
  o.hot_pixels = false;
  o.refractory_us = 50;
  NoiseFilterReport report;
  const EventStore out = filterNoise(s.view(), o, &report);
  EXPECT_EQ(report.refractory_events, 5);
  ASSERT_EQ(out.size(), 6u);
  EXPECT_EQ(out.t[0], 1000);
  for (size_t i = 1; i < out.size(); ++i) EXPECT_EQ(out.x[i], 4);
}

TEST(SupportFilter, KeepsAMovingEdgeAndDropsShotNoise) {
  // A vertical edge crossing a 40 x 30 sensor at one column per ms (each pixel fires two events,
  // jittered by up to 200 us), and 120 noise events at random pixels and times over 100 ms.
  std::mt19937_64 rng(7);
  std::uniform_int_distribution<int> jitter(0, 200), x(0, 39), y(0, 29), t(0, 99'999);
  std::vector<std::array<int64_t, 5>> rows;  // t, x, y, p, noise
  for (int c = 0; c < 40; ++c) {
    for (int r = 0; r < 30; ++r) {
      for (int k = 0; k < 2; ++k) rows.push_back({2000 * c + 300 * k + jitter(rng), c, r, 1, 0});
    }
  }
  for (int i = 0; i < 120; ++i) rows.push_back({t(rng), x(rng), y(rng), -1, 1});
  std::sort(rows.begin(), rows.end());
  EventStore s(SensorSize{40, 30});
  for (const auto& r : rows)
    s.push_back(r[0], static_cast<uint16_t>(r[1]), static_cast<uint16_t>(r[2]),
                static_cast<int8_t>(r[3]));
  int64_t dropped = 0;
  const EventStore out = filterUnsupported(s.view(), 1000, &dropped);
  // The noise events are the negative ones: every edge event stays, nearly all the noise goes
  // (a noise event next to the edge as it passes, about 1 in 20, is kept).
  const int64_t kept_edge = std::count(out.p.begin(), out.p.end(), 1);
  const int64_t kept_noise = std::count(out.p.begin(), out.p.end(), -1);
  EXPECT_EQ(kept_edge, 40 * 30 * 2);
  EXPECT_LE(kept_noise, 18);
  EXPECT_EQ(dropped, static_cast<int64_t>(s.size() - out.size()));
  EXPECT_TRUE(std::is_sorted(out.t.begin(), out.t.end()));
  EXPECT_EQ(out.sensor(), s.sensor());
  // A lone event has no support, whatever the window; an empty stream stays empty.
  EventStore lone(SensorSize{8, 8});
  lone.push_back(10, 3, 3, 1);
  lone.push_back(20, 3, 3, 1);  // its own pixel does not count
  EXPECT_EQ(filterUnsupported(lone.view(), 1'000'000).size(), 0u);
  EXPECT_EQ(filterUnsupported(EventStore(SensorSize{8, 8}).view(), 10).size(), 0u);
  EXPECT_THROW(filterUnsupported(lone.view(), -1), Error);
}

TEST(NoiseFilter, RefusesBadOptions) {
  const EventStore s = background(1);
  NoiseFilterOptions o;
  o.refractory_us = -1;
  EXPECT_THROW(filterNoise(s.view(), o), Error);
}

}  // namespace
}  // namespace evkit
