#include "evkit/events/accumulate.h"

#include <gtest/gtest.h>

#include <cmath>
#include <tuple>

#include "evkit/base/error.h"
#include "evkit/events/npy.h"
#include "evkit/events/random_events.h"
#include "evkit/events/slicer.h"
#include "test_util.h"

namespace evkit {
namespace {

constexpr float kTol = 1e-6f;

// 3x2 sensor: (0,0) gets ON, ON, OFF; (2,1) gets OFF; (1,0) gets ON.
EventStore handStore() {
  EventStore s(SensorSize{3, 2});
  s.push_back(100, 0, 0, 1);
  s.push_back(200, 0, 0, 1);
  s.push_back(300, 2, 1, -1);
  s.push_back(400, 0, 0, -1);
  s.push_back(500, 1, 0, 1);
  return s;
}

TEST(Accumulate, SignedFrameWithAndWithoutContrast) {
  const cv::Mat f = accumulateSigned(handStore().view());
  ASSERT_EQ(f.rows, 2);
  ASSERT_EQ(f.cols, 3);
  EXPECT_FLOAT_EQ(f.at<float>(0, 0), 1.0f);
  EXPECT_FLOAT_EQ(f.at<float>(0, 1), 1.0f);
  EXPECT_FLOAT_EQ(f.at<float>(1, 2), -1.0f);
  EXPECT_FLOAT_EQ(f.at<float>(1, 0), 0.0f);
  const cv::Mat c = accumulateSigned(handStore().view(), 0.2f, 0.3f);
  EXPECT_NEAR(c.at<float>(0, 0), 0.2f + 0.2f - 0.3f, kTol);
  EXPECT_NEAR(c.at<float>(1, 2), -0.3f, kTol);
}

TEST(Accumulate, CountsPerPolarity) {
  const PolarityCounts c = accumulateCounts(handStore().view());
  EXPECT_FLOAT_EQ(c.on.at<float>(0, 0), 2.0f);
  EXPECT_FLOAT_EQ(c.off.at<float>(0, 0), 1.0f);
  EXPECT_FLOAT_EQ(c.off.at<float>(1, 2), 1.0f);
  EXPECT_FLOAT_EQ(cv::sum(c.on)[0] + cv::sum(c.off)[0], 5.0f);
}

TEST(Accumulate, NormalizedHasUnitNormAndEmptyWindowGivesZeros) {
  const cv::Mat n = accumulateNormalized(handStore().view());
  // Signed values 1, 1, -1 -> norm sqrt(3).
  EXPECT_NEAR(n.at<float>(0, 0), 1.0f / std::sqrt(3.0f), kTol);
  EXPECT_NEAR(cv::norm(n), 1.0, 1e-6);
  const EventStore s = handStore();
  const cv::Mat empty = accumulateNormalized(s.sliceTime(1000, 2000));
  EXPECT_EQ(cv::countNonZero(empty), 0);
  EXPECT_TRUE(cv::checkRange(empty));
  // Events that cancel everywhere: norm 0, zeros, no NaN.
  const cv::Mat cancel = accumulateNormalized(s.view().subspan(0, 0));
  EXPECT_TRUE(cv::checkRange(cancel));
  EventStore zero(SensorSize{2, 2});
  zero.push_back(1, 1, 1, 1);
  zero.push_back(2, 1, 1, -1);
  const cv::Mat z = accumulateNormalized(zero.view());
  EXPECT_TRUE(cv::checkRange(z));
  EXPECT_EQ(cv::countNonZero(z), 0);
}

TEST(Accumulate, TimeSurfaceDecaysFromTheLatestEvent) {
  const TimeSurface ts = timeSurface(handStore().view(), 500, 100.0);
  EXPECT_NEAR(ts.on.at<float>(0, 0), std::exp(-(500.0 - 200.0) / 100.0), kTol);
  EXPECT_NEAR(ts.off.at<float>(0, 0), std::exp(-(500.0 - 400.0) / 100.0), kTol);
  EXPECT_NEAR(ts.on.at<float>(0, 1), 1.0f, kTol);
  EXPECT_FLOAT_EQ(ts.on.at<float>(1, 1), 0.0f);
  // Events after t_ref are ignored.
  const TimeSurface early = timeSurface(handStore().view(), 250, 100.0);
  EXPECT_FLOAT_EQ(early.off.at<float>(1, 2), 0.0f);
  EXPECT_NEAR(early.on.at<float>(0, 0), std::exp(-0.5), kTol);
}

TEST(Accumulate, VoxelGridSplitsEventsBilinearlyBetweenBins) {
  EventStore s(SensorSize{2, 1});
  s.push_back(0, 0, 0, 1);     // t* = 0 -> bin 0
  s.push_back(250, 1, 0, -1);  // t* = 0.75 (B = 4, t1 = 1000) -> 0.25 in bin 0, 0.75 in bin 1
  s.push_back(1000, 1, 0, 1);  // t* = 3 -> bin 3
  const std::vector<cv::Mat> v = voxelGrid(s.view(), 4, 0, 1000);
  ASSERT_EQ(v.size(), 4u);
  EXPECT_NEAR(v[0].at<float>(0, 0), 1.0f, kTol);
  EXPECT_NEAR(v[0].at<float>(0, 1), -0.25f, kTol);
  EXPECT_NEAR(v[1].at<float>(0, 1), -0.75f, kTol);
  EXPECT_NEAR(v[3].at<float>(0, 1), 1.0f, kTol);
  EXPECT_NEAR(v[2].at<float>(0, 1), 0.0f, kTol);
  // Each event's weights sum to its polarity: the bins sum to the signed frame.
  RandomEventOptions o;
  o.count = 20000;
  const EventStore r = randomEvents(o);
  const std::vector<cv::Mat> g = voxelGrid(r.view(), 7, r.t.front(), r.t.back());
  cv::Mat total = cv::Mat::zeros(g[0].size(), CV_32F);
  for (const cv::Mat& b : g) total += b;
  EXPECT_LT(cv::norm(total - accumulateSigned(r.view()), cv::NORM_INF), 1e-3);
  // A zero-length window puts everything in bin 0.
  const std::vector<cv::Mat> flat = voxelGrid(s.view(), 3, 0, 0);
  EXPECT_NEAR(flat[0].at<float>(0, 1), 0.0f, kTol);  // -1 + 1
  EXPECT_NEAR(cv::norm(flat[1]) + cv::norm(flat[2]), 0.0, 1e-9);
}

TEST(Accumulate, WindowsByTimeAndByCountCoverEveryEventOnce) {
  RandomEventOptions o;
  o.count = 10000;
  const EventStore r = randomEvents(o);
  const auto by_time = windowsByTime(r.view(), 1000);
  size_t covered = 0, prev_end = 0;
  for (size_t k = 0; k < by_time.size(); ++k) {
    const auto [b, e] = by_time[k];
    EXPECT_EQ(b, prev_end);
    for (size_t i = b; i < e; ++i) {
      EXPECT_GE(r.t[i], r.t.front() + 1000 * static_cast<int64_t>(k));
      EXPECT_LT(r.t[i], r.t.front() + 1000 * static_cast<int64_t>(k + 1));
    }
    covered += e - b;
    prev_end = e;
  }
  EXPECT_EQ(covered, r.size());
  const auto by_count = windowsByCount(r.view(), 3000);
  ASSERT_EQ(by_count.size(), 4u);
  EXPECT_EQ(by_count[3], (std::pair<size_t, size_t>{9000, 10000}));
}

TEST(Accumulate, PolarityRenderingIsRedOnBlueOffWhiteEmpty) {
  const cv::Mat png = renderPolarity(accumulateSigned(handStore().view()), 1.0f);
  ASSERT_EQ(png.type(), CV_8UC3);
  EXPECT_EQ(png.at<cv::Vec3b>(0, 1), cv::Vec3b(0, 0, 255));      // ON: red (BGR)
  EXPECT_EQ(png.at<cv::Vec3b>(1, 2), cv::Vec3b(255, 0, 0));      // OFF: blue
  EXPECT_EQ(png.at<cv::Vec3b>(1, 0), cv::Vec3b(255, 255, 255));  // no events: white
  const cv::Mat cm = renderColormap(timeSurface(handStore().view(), 500, 100.0).on);
  EXPECT_EQ(cm.type(), CV_8UC3);
}

TEST(Npy, RoundTripAndHeaderAlignment) {
  test::ScratchDir dir;
  const std::vector<float> data = {1.5f, -2.0f, 3.25f, 0.0f, 7.0f, 8.0f};
  writeNpy(dir / "a.npy", data.data(), {2, 3});
  const std::string bytes = test::readText(dir / "a.npy");
  EXPECT_EQ(bytes.substr(0, 6), "\x93NUMPY");
  EXPECT_EQ((bytes.size() - data.size() * 4) % 64, 0u);  // data starts 64-byte aligned
  const NpyArray back = readNpy(dir / "a.npy");
  EXPECT_EQ(back.shape, (std::vector<size_t>{2, 3}));
  EXPECT_EQ(back.data, data);
}

// A header's shape must be decimal counts whose product is the data's: a shape whose product wraps
// to the data's size (2^62 + 1 rows of 4) would have read as a huge array over 16 bytes.
TEST(Npy, ShapesAreCountsTheDataHolds) {
  test::ScratchDir dir;
  const auto npy = [&](const std::string& shape, size_t floats) {
    std::string dict = "{'descr': '<f4', 'fortran_order': False, 'shape': " + shape + ", }";
    dict.resize(118, ' ');
    dict += '\n';
    std::string bytes = std::string("\x93NUMPY\x01\x00", 8) + char(dict.size()) + '\0' + dict;
    bytes += std::string(floats * sizeof(float), '\0');
    test::writeText(dir / "s.npy", bytes);
    return dir / "s.npy";
  };
  EXPECT_EQ(readNpy(npy("(4,)", 4)).shape, (std::vector<size_t>{4}));
  EXPECT_EQ(readNpy(npy("(1, 2, 2)", 4)).shape, (std::vector<size_t>{1, 2, 2}));
  for (const char* shape : {"(4611686018427387905, 4)", "(-4,)", "(0x4,)", "(4, 'a')"}) {
    try {
      readNpy(npy(shape, 4));
      ADD_FAILURE() << shape << " was read";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find("is not a count that the file's data can hold"),
                std::string::npos)
          << e.what();
    }
  }
}

}  // namespace
}  // namespace evkit

namespace evkit {
namespace {

// Windows of a slicer fed in chunks of `chunk` events: (index, t_begin, t_end, events).
std::vector<std::tuple<size_t, int64_t, int64_t, size_t>> slice(EventSlicer slicer,
                                                                const EventStore& ev, size_t chunk,
                                                                size_t max_windows = 1000) {
  std::vector<std::tuple<size_t, int64_t, int64_t, size_t>> out;
  const auto keep = [&](const EventSlicer::Window& w) {
    out.emplace_back(w.index, w.t_begin, w.t_end, w.events.size());
    return out.size() < max_windows;
  };
  for (size_t b = 0; b < ev.size(); b += chunk) {
    if (!slicer.accept(ev.view().subspan(b, std::min(ev.size(), b + chunk)), keep)) break;
  }
  slicer.finish(keep);
  return out;
}

EventStore tenEvents() {
  EventStore ev(SensorSize{4, 4});
  for (int64_t t : {100, 105, 120, 121, 139, 140, 141, 180, 199, 260}) ev.push_back(t, 1, 1, 1);
  return ev;
}

TEST(EventSlicer, ByTimeGivesTheSameWindowsWhateverTheChunks) {
  const EventStore ev = tenEvents();
  using W = std::tuple<size_t, int64_t, int64_t, size_t>;
  // 20 µs windows from the first event; the empty 200..220..260 windows inside the stream appear.
  const std::vector<W> expected = {{0, 100, 120, 2}, {1, 120, 140, 3}, {2, 140, 160, 2},
                                   {3, 160, 180, 0}, {4, 180, 200, 2}, {5, 200, 220, 0},
                                   {6, 220, 240, 0}, {7, 240, 260, 0}, {8, 260, 280, 1}};
  for (size_t chunk : {1, 3, 10})
    EXPECT_EQ(slice(EventSlicer::byTime(20, ev.sensor()), ev, chunk), expected) << chunk;
}

TEST(EventSlicer, ByCountOriginEndAndStop) {
  const EventStore ev = tenEvents();
  using W = std::tuple<size_t, int64_t, int64_t, size_t>;
  EXPECT_EQ(slice(EventSlicer::byCount(4, ev.sensor()), ev, 3),
            (std::vector<W>{{0, 100, 122, 4}, {1, 139, 181, 4}, {2, 199, 261, 2}}));
  EventSlicer windowed = EventSlicer::byTime(50, ev.sensor());
  windowed.setOrigin(110);
  windowed.setEnd(190);
  EXPECT_EQ(slice(std::move(windowed), ev, 2),
            (std::vector<W>{{0, 110, 160, 5}, {1, 160, 210, 1}}));
  EXPECT_EQ(slice(EventSlicer::byTime(20, ev.sensor()), ev, 10, 2).size(),
            2u);  // the callback stops it
  EXPECT_THROW(EventSlicer::byCount(0, ev.sensor()), Error);
}

}  // namespace
}  // namespace evkit
