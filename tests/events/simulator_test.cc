#include "evkit/events/simulator.h"

#include <gtest/gtest.h>
#include <omp.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <opencv2/videoio.hpp>
#include <random>

#include "evkit/base/error.h"
#include "evkit/events/frame_source.h"
#include "evkit/events/image_io.h"
#include "test_util.h"

namespace evkit {
namespace {

constexpr int64_t kEpoch = 1605537493000000;  // absolute Unix µs

// A frame whose log intensity (shared mapping) is `L` everywhere... per pixel via a function.
cv::Mat frameFromLog(int w, int h, const std::function<double(int, int)>& L,
                     const LogMapping& m = {}) {
  cv::Mat img(h, w, CV_32F);
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) img.at<float>(y, x) = m.fromLog(static_cast<float>(L(x, y)));
  }
  return img;
}

// Smooth random video: each pixel's log intensity follows a sum of sines with random phases.
std::vector<cv::Mat> randomVideo(int w, int h, int frames, uint64_t seed, double amplitude = 1.5) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0, 2 * M_PI);
  std::vector<double> phase(static_cast<size_t>(w * h)), freq(static_cast<size_t>(w * h));
  for (size_t i = 0; i < phase.size(); ++i) {
    phase[i] = u(rng);
    freq[i] = 0.05 + 0.1 * u(rng) / (2 * M_PI);
  }
  std::vector<cv::Mat> video;
  for (int f = 0; f < frames; ++f) {
    video.push_back(frameFromLog(w, h, [&](int x, int y) {
      const size_t i = static_cast<size_t>(y * w + x);
      return -1.5 + amplitude * std::sin(phase[i] + freq[i] * f);
    }));
  }
  return video;
}

EventStore run(const std::vector<cv::Mat>& video, const SimulatorOptions& o, int64_t t0, int64_t dt,
               EventSimulator* keep = nullptr) {
  const SensorSize size{video[0].cols, video[0].rows};
  EventSimulator local(size, o);
  EventSimulator& sim = keep ? *keep : local;
  EventStore out(size);
  for (size_t f = 0; f < video.size(); ++f)
    sim.addFrame(video[f], t0 + static_cast<int64_t>(f) * dt, out);
  return out;
}

TEST(Simulator, ExactRampGivesTheExpectedEventsAtTheExpectedTimes) {
  SimulatorOptions o;
  o.contrast_pos = o.contrast_neg = 0.2;
  // One pixel's log intensity rises by 1.1 over 1100 µs: crossings at 0.2, 0.4, ... 1.0, i.e. at
  // 200, 400, ..., 1000 µs, whether in one frame interval or in eleven.
  for (int frames : {2, 12}) {
    std::vector<cv::Mat> video;
    for (int f = 0; f < frames; ++f) {
      const double level = -2.0 + 1.1 * f / (frames - 1);
      video.push_back(frameFromLog(1, 1, [&](int, int) { return level; }));
    }
    const EventStore ev = run(video, o, kEpoch, 1100 / (frames - 1), nullptr);
    ASSERT_EQ(ev.size(), 5u) << frames << " frames";
    for (size_t k = 0; k < 5; ++k) {
      EXPECT_EQ(ev.t[k], kEpoch + 200 * static_cast<int64_t>(k + 1))
          << frames << " frames, event " << k;
      EXPECT_EQ(ev.p[k], 1);
    }
  }
  // Falling: OFF events.
  std::vector<cv::Mat> down = {frameFromLog(1, 1, [](int, int) { return -1.0; }),
                               frameFromLog(1, 1, [](int, int) { return -1.45; })};
  const EventStore off = run(down, o, 0, 450, nullptr);
  EXPECT_EQ(off.p, (std::vector<int8_t>{-1, -1}));
  EXPECT_EQ(off.t, (std::vector<int64_t>{200, 400}));
}

TEST(Simulator, StillVideoGivesNoEvents) {
  const cv::Mat still = frameFromLog(32, 24, [](int x, int y) { return -3.0 + 0.05 * (x + y); });
  SimulatorOptions o;
  o.sigma = 0.05;
  const EventStore ev = run(std::vector<cv::Mat>(20, still), o, kEpoch, 1000, nullptr);
  EXPECT_EQ(ev.size(), 0u);
}

TEST(Simulator, EsimInvariantHoldsForEveryPixelAfterEveryFrame) {
  const std::vector<cv::Mat> video = randomVideo(40, 30, 60, 3);
  SimulatorOptions o;
  o.contrast_pos = 0.25;
  o.contrast_neg = 0.2;
  EventSimulator sim(SensorSize{40, 30}, o);
  std::vector<double> sum(40 * 30, 0.0);
  std::vector<float> L0;
  EventStore ev(SensorSize{40, 30});
  for (size_t f = 0; f < video.size(); ++f) {
    ev.clear();
    sim.addFrame(video[f], kEpoch + static_cast<int64_t>(f) * 5000, ev);
    if (f == 0) L0 = sim.logIntensity();
    validate(ev.view(), "simulated");
    for (size_t e = 0; e < ev.size(); ++e) {
      sum[static_cast<size_t>(ev.y[e] * 40 + ev.x[e])] +=
          ev.p[e] > 0 ? o.contrast_pos : -o.contrast_neg;
    }
    const std::vector<float>& L = sim.logIntensity();
    for (size_t i = 0; i < sum.size(); ++i) {
      const double residual = L0[i] + sum[i] - L[i];
      ASSERT_LE(std::abs(residual), std::max(o.contrast_pos, o.contrast_neg) + 1e-5)
          << "pixel " << i << " frame " << f;
    }
  }
}

TEST(Simulator, ThresholdMismatchLeavesNoPixelSilent) {
  // Every pixel swings by about 3 C: with sigma = 0.05 each one must still fire (the stepping form
  // of the original ESIM falls silent for pixels whose threshold changed).
  const std::vector<cv::Mat> video = randomVideo(24, 16, 80, 5, 0.3);
  SimulatorOptions o;
  o.sigma = 0.05;
  const EventStore ev = run(video, o, 0, 1000, nullptr);
  std::vector<int> per_pixel(24 * 16, 0);
  for (size_t e = 0; e < ev.size(); ++e) ++per_pixel[static_cast<size_t>(ev.y[e] * 24 + ev.x[e])];
  EXPECT_EQ(std::count(per_pixel.begin(), per_pixel.end(), 0), 0);
}

TEST(Simulator, RefractoryPeriodDropsExactlyTheEventsTooCloseToTheLastOne) {
  // Log intensity rising steeply: several events per 100 µs frame interval.
  std::vector<cv::Mat> video;
  for (int f = 0; f <= 50; ++f)
    video.push_back(frameFromLog(2, 1, [&](int x, int) { return -3.0 + (0.33 + 0.1 * x) * f; }));
  SimulatorOptions o;
  const EventStore free = run(video, o, 0, 100, nullptr);
  // The refractory rule applied to the free events: the reference moves for every crossing, so
  // only emission changes.
  std::map<int, int64_t> last;
  std::vector<int64_t> expected_t;
  for (size_t e = 0; e < free.size(); ++e) {
    if (!last.count(free.x[e]) || free.t[e] - last[free.x[e]] >= 250) {
      last[free.x[e]] = free.t[e];
      expected_t.push_back(free.t[e]);
    }
  }
  o.refractory_us = 250;
  EventSimulator sim(SensorSize{2, 1}, o);
  const EventStore ev = run(video, o, 0, 100, &sim);
  EXPECT_EQ(ev.t, expected_t);
  EXPECT_LT(ev.size(), free.size() / 2);
  EXPECT_EQ(sim.stats().refractory_dropped, static_cast<int64_t>(free.size() - ev.size()));
}

TEST(Simulator, ShotNoiseAndLeakRatesMatchInExpectation) {
  const cv::Mat still = frameFromLog(64, 48, [](int, int) { return -1.0; });
  const std::vector<cv::Mat> video(101, still);  // 1 s at 100 fps
  const double pixels = 64 * 48;
  SimulatorOptions shot;
  shot.shot_noise_rate_hz = 5.0;
  const EventStore s = run(video, shot, kEpoch, 10000, nullptr);
  EXPECT_NEAR(static_cast<double>(s.size()), 5.0 * pixels, 4 * std::sqrt(5.0 * pixels));
  EXPECT_NEAR(static_cast<double>(s.countOn()) / static_cast<double>(s.size()), 0.5, 0.02);
  EXPECT_NO_THROW(validate(s.view(), "shot noise"));
  SimulatorOptions leak;
  leak.leak_rate_hz = 2.0;
  const EventStore l = run(video, leak, kEpoch, 10000, nullptr);
  EXPECT_NEAR(static_cast<double>(l.size()), 2.0 * pixels, 0.03 * 2.0 * pixels);
  EXPECT_EQ(l.countOn(), static_cast<int64_t>(l.size()));  // leak events are ON
}

TEST(Simulator, DeterministicWhateverTheThreadCount) {
  const std::vector<cv::Mat> video = randomVideo(50, 37, 30, 9);
  SimulatorOptions o;
  o.sigma = 0.03;
  o.shot_noise_rate_hz = 1.0;
  o.refractory_us = 50;
  const int threads = omp_get_max_threads();
  omp_set_num_threads(1);
  const EventStore one = run(video, o, kEpoch, 2000, nullptr);
  omp_set_num_threads(std::max(2, threads));
  const EventStore many = run(video, o, kEpoch, 2000, nullptr);
  omp_set_num_threads(threads);
  ASSERT_GT(one.size(), 1000u);
  EXPECT_TRUE(one.t == many.t && one.x == many.x && one.y == many.y && one.p == many.p);
  o.seed = 2;
  EXPECT_NE(run(video, o, kEpoch, 2000, nullptr).x, one.x);
}

TEST(Simulator, ColourConversionAndBayerMosaic) {
  cv::Mat bgr(2, 2, CV_32FC3, cv::Scalar(0.2, 0.5, 0.8));  // B, G, R
  const cv::Mat grey = toSensorIntensity(bgr);
  EXPECT_NEAR(grey.at<float>(0, 0), 0.114f * 0.2f + 0.587f * 0.5f + 0.299f * 0.8f, 1e-6);
  const cv::Mat bayer = toSensorIntensity(bgr, true);
  EXPECT_FLOAT_EQ(bayer.at<float>(0, 0), 0.8f);  // R
  EXPECT_FLOAT_EQ(bayer.at<float>(0, 1), 0.5f);  // G
  EXPECT_FLOAT_EQ(bayer.at<float>(1, 0), 0.5f);  // G
  EXPECT_FLOAT_EQ(bayer.at<float>(1, 1), 0.2f);  // B
  EXPECT_NEAR(srgbToLinear(cv::Mat(1, 1, CV_32F, cv::Scalar(0.5))).at<float>(0, 0), 0.214041, 1e-5);
}

TEST(BlurAccumulator, MeanOfLinearlyInterpolatedFramesOverTheExposure) {
  // Intensity ramps 0 -> 1 over [0, 1000] µs in 4 frames; exposure [100, 700]: mean 0.4.
  BlurAccumulator blur({{100, 700}, {0, 1000}, {500, 500}});
  std::vector<std::pair<BlurAccumulator::Exposure, cv::Mat>> done;
  for (int f = 0; f <= 4; ++f) {
    for (auto& d : blur.addFrame(cv::Mat(1, 1, CV_32F, cv::Scalar(f / 4.0)), 250 * f))
      done.push_back(d);
  }
  ASSERT_EQ(done.size(), 3u);
  std::map<int64_t, float> mean;
  for (auto& [e, img] : done) mean[e.start_us * 10000 + e.end_us] = img.at<float>(0, 0);
  EXPECT_NEAR(mean[100 * 10000 + 700], 0.4f, 1e-6);
  EXPECT_NEAR(mean[0 * 10000 + 1000], 0.5f, 1e-6);
  EXPECT_NEAR(mean[500 * 10000 + 500], 0.5f, 1e-6);
}

TEST(FrameSequence, ImageFolderWithTimestampsAndClearErrors) {
  test::ScratchDir dir;
  for (int i = 0; i < 3; ++i)
    writeImageFile(dir / ("f" + std::to_string(i) + ".png"),
                   cv::Mat(4, 5, CV_32F, cv::Scalar(0.1 * i + 0.1)), 16);
  test::writeText(dir / "timestamps.txt",
                  "1605537493000000 f0.png\n1605537493001000 f1.png\n1605537493002500 f2.png\n");
  auto seq = openFrameSequence(dir.path().string());
  EXPECT_EQ(seq->sensor(), (SensorSize{5, 4}));
  EXPECT_EQ(seq->timeOf(2), 1605537493002500);
  Frame f;
  int64_t t;
  int n = 0;
  while (seq->next(f, t)) ++n;
  EXPECT_EQ(n, 3);
  EXPECT_EQ(t, 1605537493002500);
  test::writeText(dir / "timestamps.txt", "0 f0.png\n1000 f1.png\n2000 missing.png\n");
  seq = openFrameSequence(dir.path().string());
  seq->next(f, t);
  seq->next(f, t);
  try {
    seq->next(f, t);
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("missing.png: no such image file"), std::string::npos)
        << e.what();
  }
  test::writeText(dir / "timestamps.txt", "0 f0.png\n0 f1.png\n");
  EXPECT_THROW(openFrameSequence(dir.path().string()), Error);
  test::writeText(dir / "timestamps.txt", "0.5 f0.png\n");
  EXPECT_THROW(openFrameSequence(dir.path().string()), Error);
}

TEST(FrameSequence, VideoFileTimestampsFromTheFrameRate) {
  test::ScratchDir dir;
  const std::string path = dir / "bar.avi";
  {
    cv::VideoWriter writer(path, cv::VideoWriter::fourcc('M', 'J', 'P', 'G'), 100.0,
                           cv::Size(32, 16), true);
    ASSERT_TRUE(writer.isOpened());
    for (int f = 0; f < 10; ++f) {
      cv::Mat img(16, 32, CV_8UC3, cv::Scalar(20, 20, 20));
      img(cv::Rect(2 + 2 * f, 0, 6, 16)).setTo(cv::Scalar(220, 220, 220));
      writer.write(img);
    }
  }
  SequenceOptions o;
  o.start_us = kEpoch;
  auto seq = openFrameSequence(path, o);
  EXPECT_EQ(seq->sensor(), (SensorSize{32, 16}));
  EXPECT_EQ(seq->timeOf(3), kEpoch + 30000);
  DriverOptions d;
  size_t events = 0;
  const SimulatorStats stats =
      simulateSequence(*seq, d, [&](const EventStore& e, const std::vector<Frame>&) {
        EXPECT_NO_THROW(validate(e.view(), "video"));
        if (!e.empty()) {
          EXPECT_GE(e.t.front(), kEpoch);
        }
        events += e.size();
      });
  EXPECT_EQ(stats.frames, 10);
  EXPECT_GT(events, 200u);
  EXPECT_THROW(openFrameSequence(dir / "none.mp4"), Error);
}

TEST(LogMapping, LinLogIsContinuousAndInvertible) {
  LogMapping m;
  m.lin_log = true;
  const float thr = static_cast<float>(LogMapping::kLinLogThreshold);
  EXPECT_NEAR(m.toLog(thr * 0.99999f), m.toLog(thr), 1e-4);
  EXPECT_NEAR(m.toLog(0.5f), std::log(0.5f), 1e-7);
  for (float i : {0.0f, 0.01f, 0.05f, 0.3f, 1.0f}) EXPECT_NEAR(m.fromLog(m.toLog(i)), i, 1e-6) << i;
  const LogMapping plain;
  EXPECT_NEAR(plain.toLog(0.0f), std::log(1e-3f), 1e-7);
  EXPECT_NEAR(plain.fromLog(plain.toLog(0.25f)), 0.25f, 1e-6);
}

// A bright bar sweeping across a dark field at a programmable speed.
class SweepingBar final : public RenderSource {
 public:
  SensorSize sensor() const override { return {64, 16}; }
  cv::Mat render(int64_t t_us) override {
    cv::Mat img(16, 64, CV_32F);
    const double centre = 8.0 + 48.0 * static_cast<double>(t_us) / 100000.0;
    for (int y = 0; y < 16; ++y) {
      for (int x = 0; x < 64; ++x)
        img.at<float>(y, x) =
            static_cast<float>(0.05 + 0.9 * std::exp(-0.5 * std::pow((x - centre) / 2.0, 2)));
    }
    return img;
  }
};

TEST(Simulator, AdaptiveSamplingNeverSkipsMoreThanAFractionOfC) {
  SweepingBar bar;
  DriverOptions options;
  size_t events = 0;
  const SimulatorStats adaptive = simulateAdaptive(
      bar, 0, 100000, options, {}, [&](const EventStore& e, const std::vector<Frame>&) {
        EXPECT_NO_THROW(validate(e.view(), "adaptive"));
        events += e.size();
      });
  EXPECT_EQ(adaptive.max_fraction_over_c, 0.0);  // no pixel moved by C between samples
  EXPECT_GT(events, 1000u);
  // The same scene at 10 fixed frames is badly under-sampled, and the stats say so.
  EventSimulator coarse(bar.sensor(), options.simulator);
  EventStore out(bar.sensor());
  for (int f = 0; f <= 10; ++f) coarse.addFrame(bar.render(10000 * f), 10000 * f, out);
  EXPECT_GT(coarse.stats().max_fraction_over_c, 0.05);
  EXPECT_GT(coarse.stats().undersampled_intervals, 5);
}

// The bar, and the times it was rendered at.
class RecordedBar final : public RenderSource {
 public:
  SensorSize sensor() const override { return bar_.sensor(); }
  cv::Mat render(int64_t t_us) override {
    times.push_back(t_us);
    return bar_.render(t_us);
  }
  std::vector<int64_t> times;

 private:
  SweepingBar bar_;
};

TEST(Simulator, AdaptiveSamplingRendersTheRequiredInstants) {
  RecordedBar bar;
  AdaptiveOptions uniform;
  uniform.lambda = 1e30;  // never rejects: fixed steps of 700 us
  uniform.min_step_us = uniform.max_step_us = 700;
  uniform.sample_at = {2500, 5000, 9999};
  simulateAdaptive(bar, 0, 10000, DriverOptions{}, uniform,
                   [](const EventStore&, const std::vector<Frame>&) {});
  for (int64_t t : uniform.sample_at)
    EXPECT_EQ(std::count(bar.times.begin(), bar.times.end(), t), 1) << t;
  EXPECT_EQ(bar.times.front(), 0);
  EXPECT_EQ(bar.times.back(), 10000);
  for (size_t k = 1; k < bar.times.size(); ++k) {
    EXPECT_GT(bar.times[k], bar.times[k - 1]);
    EXPECT_LE(bar.times[k] - bar.times[k - 1], 700);
  }
  // Between the instants the steps stay on the grid they set out on: 0, 700, ..., 2100, 2500,
  // 3200, ...
  EXPECT_EQ(bar.times[4], 2500);
  EXPECT_EQ(bar.times[5], 3200);
}

}  // namespace
}  // namespace evkit
