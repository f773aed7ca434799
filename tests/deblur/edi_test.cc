#include "evkit/deblur/edi.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <opencv2/imgproc.hpp>

#include "evkit/base/error.h"
#include "evkit/deblur/metrics.h"
#include "evkit/deblur/observation.h"
#include "evkit/events/io.h"
#include "evkit/events/npy.h"
#include "evkit/synth/generator.h"
#include "test_util.h"

namespace evkit {
namespace {

using test::ScratchDir;

// A small planes observation with noiseless events and known C = 0.2 (generated once).
const Observation& planes() {
  static const Observation obs = [] {
    ScratchDir dir;
    synth::SynthOptions o;
    o.width = 120;
    o.height = 90;
    o.exposure_us = 50000;
    o.shake.blur_px = 14;
    o.shake.seed = 4;
    synth::writeObservation(synth::makePreset("planes", {}), o, dir / "obs");
    return loadObservation(dir / "obs");
  }();
  return obs;
}

Frame gtAt(const Observation& obs, int64_t t) {
  for (const Frame& f : obs.gt_frames) {
    if (f.exposure_start_us == t) return f;
  }
  throw Error("no ground truth at " + std::to_string(t));
}

TEST(Edi, MiddleFrameBeatsTheBlurryInputBySixDecibels) {
  const Observation& obs = planes();
  ASSERT_TRUE(obs.contrast.has_value());
  const int64_t mid = obs.blurry.exposure_start_us +
                      (obs.blurry.exposure_end_us - obs.blurry.exposure_start_us) / 2;
  auto edi = makeDeblurrer("edi");
  const DeblurResult r = edi->run(obs, DeblurRequest{{mid}});
  ASSERT_EQ(r.frames.size(), 1u);
  const Frame gt = gtAt(obs, mid);
  const double gain = psnr(r.frames[0].image, gt.image) - psnr(obs.blurry.image, gt.image);
  EXPECT_GE(gain, 6.0) << "EDI " << psnr(r.frames[0].image, gt.image) << " dB, blurry "
                       << psnr(obs.blurry.image, gt.image);
  EXPECT_GT(ssim(r.frames[0].image, gt.image), ssim(obs.blurry.image, gt.image));
  EXPECT_EQ(r.parameters.at("contrast_searched"), 0.0);
  EXPECT_EQ(r.account, "thresholds given, 0.200 / 0.200");
}

TEST(Edi, ContrastSearchRecoversTheSimulatorThresholdWithinTwentyPercent) {
  const Observation& obs = planes();
  auto edi = makeDeblurrer("edi", {{"search", "1"}});
  const DeblurResult r = edi->run(obs, DeblurRequest{{obs.blurry.exposure_start_us}});
  EXPECT_EQ(r.parameters.at("contrast_searched"), 1.0);
  EXPECT_NEAR(r.parameters.at("contrast_on"), 0.2, 0.2 * 0.2);
  EXPECT_NE(r.account.find(" by the sharpness search"), std::string::npos) << r.account;
}

// Two grey pixels (0.5) exposed over [0, 1000] µs, without events yet.
Observation twoGreyPixels() {
  Observation obs;
  obs.blurry.image = cv::Mat(1, 2, CV_32F, cv::Scalar(0.5));
  obs.blurry.exposure_start_us = 0;
  obs.blurry.exposure_end_us = 1000;
  obs.events.setSensor(SensorSize{2, 1});
  return obs;
}

// One pixel, hand-computed: exposure [0, 1000], ON events at 200 and 600, C = 0.5.
// Levels: 0 on [0,200), 1 on [200,600), 2 on [600,1000]. (1/T) int exp(c E) = 0.2 + 0.4 e^0.5 + 0.4
// e^1.
TEST(Edi, ExactSumOverTheStepFunctionOfOnePixel) {
  Observation obs = twoGreyPixels();
  obs.events.push_back(200, 0, 0, 1);
  obs.events.push_back(600, 0, 0, 1);
  auto edi = makeDeblurrer("edi", {{"contrast", "0.5"}});
  const DeblurResult r = edi->run(obs, DeblurRequest{{0, 400, 1000}});
  const double s = 0.2 + 0.4 * std::exp(0.5) + 0.4 * std::exp(1.0);
  EXPECT_NEAR(r.frames[0].image.at<float>(0, 0), 0.5 / s, 1e-6);
  EXPECT_NEAR(r.frames[1].image.at<float>(0, 0), 0.5 * std::exp(0.5) / s, 1e-6);
  EXPECT_NEAR(r.frames[2].image.at<float>(0, 0), std::min(1.0, 0.5 * std::exp(1.0) / s), 1e-6);
  // The pixel without events returns the blurry value, at every time.
  for (const Frame& f : r.frames) EXPECT_EQ(f.image.at<float>(0, 1), 0.5f);
}

// The same pixel with the levels straight between events: 0.5 at the first event, 1 at the second,
// half a threshold before the first and after the second, reached at half their interval (400 µs)
// outside them, 0.25 at 0 and 1.25 from 800 on. A second pixel's ON at 200 and OFF at 600 turned
// unseen in between: its level holds at 0.5 until 600, with 0.25 before and -0.25 after.
TEST(Edi, LinearLevelsIntegrateTheStraightPiecesBetweenEvents) {
  Observation obs = twoGreyPixels();
  obs.events.push_back(200, 0, 0, 1);
  obs.events.push_back(200, 1, 0, 1);
  obs.events.push_back(600, 0, 0, 1);
  obs.events.push_back(600, 1, 0, -1);
  auto edi = makeDeblurrer("edi", {{"contrast", "0.5"}, {"levels", "linear"}});
  const DeblurResult r = edi->run(obs, DeblurRequest{{0, 400, 1000}});
  // (1/T) integral of exp(l) over pieces straight from a to b: duration (e^b - e^a) / (b - a).
  const auto piece = [](double duration, double a, double b) {
    return duration * (std::exp(b) - std::exp(a)) / (b - a);
  };
  const double run = (piece(200, 0.25, 0.5) + piece(400, 0.5, 1.0) + piece(200, 1.0, 1.25) +
                      200 * std::exp(1.25)) /
                     1000;
  EXPECT_NEAR(r.frames[0].image.at<float>(0, 0), 0.5 * std::exp(0.25) / run, 1e-6);
  EXPECT_NEAR(r.frames[1].image.at<float>(0, 0), 0.5 * std::exp(0.75) / run, 1e-6);
  EXPECT_NEAR(r.frames[2].image.at<float>(0, 0), 0.5 * std::exp(1.25) / run, 1e-6);
  const double turn = (200 * std::exp(0.25) + 400 * std::exp(0.5) + 400 * std::exp(-0.25)) / 1000;
  EXPECT_NEAR(r.frames[1].image.at<float>(0, 1), 0.5 * std::exp(0.5) / turn, 1e-6);
  EXPECT_NEAR(r.frames[2].image.at<float>(0, 1), 0.5 * std::exp(-0.25) / turn, 1e-6);
}

// Mid-exposure, where each pixel's level is between events rather than at a step's foot, the
// straight levels re-make the sharp frame better than the steps on a simulated shake.
TEST(Edi, LinearLevelsSharpenTheMiddleFrame) {
  const Observation& obs = planes();
  const int64_t mid = obs.blurry.midExposure();
  const Frame gt = gtAt(obs, mid);
  const double steps =
      psnr(makeDeblurrer("edi")->run(obs, DeblurRequest{{mid}}).frames[0].image, gt.image);
  const double linear = psnr(
      makeDeblurrer("edi", {{"levels", "linear"}})->run(obs, DeblurRequest{{mid}}).frames[0].image,
      gt.image);
  EXPECT_GT(linear, steps + 0.3) << "steps " << steps << " dB, linear " << linear;
}

TEST(Edi, SaturatedAndBlackPixelsKeepTheBlurryValueAndColourSharesTheGain) {
  Observation obs;
  obs.blurry.image = cv::Mat(1, 3, CV_32FC3);
  obs.blurry.image.at<cv::Vec3f>(0, 0) = cv::Vec3f(1.0f, 1.0f, 1.0f);    // saturated
  obs.blurry.image.at<cv::Vec3f>(0, 1) = cv::Vec3f(0.0f, 0.001f, 0.0f);  // black
  obs.blurry.image.at<cv::Vec3f>(0, 2) = cv::Vec3f(0.2f, 0.4f, 0.1f);    // ordinary
  obs.blurry.exposure_start_us = 0;
  obs.blurry.exposure_end_us = 1000;
  obs.events.setSensor(SensorSize{3, 1});
  for (int x = 0; x < 3; ++x) obs.events.push_back(500 + x, static_cast<uint16_t>(x), 0, -1);
  auto edi = makeDeblurrer("edi", {{"contrast", "0.3"}});
  const DeblurResult r = edi->run(obs, DeblurRequest{{0}});
  const cv::Mat& l = r.frames[0].image;
  EXPECT_TRUE(cv::checkRange(l));
  EXPECT_EQ(l.at<cv::Vec3f>(0, 0), cv::Vec3f(1.0f, 1.0f, 1.0f));
  EXPECT_EQ(l.at<cv::Vec3f>(0, 1), cv::Vec3f(0.0f, 0.001f, 0.0f));
  const cv::Vec3f v = l.at<cv::Vec3f>(0, 2);
  EXPECT_NEAR(v[1] / v[0], 2.0, 1e-5);
  EXPECT_NEAR(v[2] / v[0], 0.5, 1e-5);
  EXPECT_GT(v[0], 0.2f);  // before an OFF event the pixel was brighter
}

TEST(Edi, RecordingPathExtractsTheFramesEventsAndWritesTheFolder) {
  ScratchDir dir;
  Recording rec;
  rec.events.setSensor(SensorSize{8, 6});
  for (int64_t t = 0; t < 100000; t += 1000)
    rec.events.push_back(1605537493000000 + t, static_cast<uint16_t>(t / 1000 % 8), 2, 1);
  for (int i = 0; i < 3; ++i) {
    Frame f;
    f.image = cv::Mat(6, 8, CV_32F, cv::Scalar(0.25 * (i + 1)));
    f.exposure_start_us = 1605537493000000 + 30000 * i + 5000;
    f.exposure_end_us = f.exposure_start_us + 20000;
    f.bit_depth = 16;
    rec.frames.push_back(f);
  }
  writeRecording(dir / "rec.aedat4", rec);
  const Observation obs = observationFromRecording(dir / "rec.aedat4", 1, 2000);
  EXPECT_EQ(obs.blurry.exposure_start_us, 1605537493035000);
  EXPECT_EQ(obs.blurry.exposure_end_us, 1605537493055000);
  EXPECT_NEAR(obs.blurry.image.at<float>(0, 0), 0.5f, 1e-4);
  // Events in [35000 - 2000, 55000 + 2000]: 33000 .. 57000 every 1000 -> 25 events.
  EXPECT_EQ(obs.events.size(), 25u);
  EXPECT_EQ(obs.events.t.front(), 1605537493033000);
  EXPECT_EQ(obs.events.t.back(), 1605537493057000);
  saveObservation(obs, dir / "obs");
  const Observation back = loadObservation(dir / "obs");
  EXPECT_EQ(back.events.t, obs.events.t);
  EXPECT_EQ(back.blurry.exposure_end_us, obs.blurry.exposure_end_us);
  EXPECT_TRUE(back.gt_depth.empty());
  EXPECT_THROW(observationFromRecording(dir / "rec.aedat4", 3), Error);

  // The ground truth's depth: one plane at the frame's size, else an error naming the file.
  std::filesystem::create_directories(dir / "obs/gt");
  std::vector<float> depth(6 * 8, 2.5f);
  writeNpy(dir / "obs/gt/depth.npy", depth.data(), {6, 8});
  EXPECT_EQ(cv::countNonZero(loadObservation(dir / "obs").gt_depth == 2.5f), 6 * 8);
  writeNpy(dir / "obs/gt/depth.npy", depth.data(), {8, 6});
  try {
    loadObservation(dir / "obs");
    ADD_FAILURE() << "a depth map of another size was read";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("depth.npy"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("6 x 8"), std::string::npos) << e.what();
  }
}

TEST(Metrics, PsnrSsimAndBrisque) {
  cv::Mat a(40, 50, CV_32F);
  cv::randu(a, 0.2, 0.8);
  const cv::Mat b = a + 0.1;
  EXPECT_NEAR(psnr(b, a), 20.0, 1e-4);  // MSE 0.01
  EXPECT_TRUE(std::isinf(psnr(a, a)));
  EXPECT_NEAR(ssim(a, a), 1.0, 1e-9);
  EXPECT_LT(ssim(b, a), 1.0);
  EXPECT_TRUE(std::isfinite(brisque(a)));
  EXPECT_THROW(psnr(a, cv::Mat(10, 10, CV_32F)), Error);
}

TEST(Deblurrer, RegistryAndSettingsAreChecked) {
  EXPECT_EQ(deblurrerNames(), (std::vector<std::string>{"blurry", "edi", "benerf"}));
  EXPECT_THROW(makeDeblurrer("magic"), Error);
  EXPECT_THROW(makeDeblurrer("benerf", {{"budget", "slow"}}), Error);
  EXPECT_THROW(makeDeblurrer("benerf", {{"budget", "-5"}}), Error);
  EXPECT_THROW(makeDeblurrer("benerf", {{"field", "voxels"}}), Error);
  EXPECT_THROW(makeDeblurrer("benerf", {{"iterations", "2.5"}}), Error);
  EXPECT_THROW(makeDeblurrer("benerf", {{"alpha", "0"}}), Error);
  EXPECT_NO_THROW(
      makeDeblurrer("benerf", {{"budget", "90"}, {"preset", "real"}, {"trajectory", "split"}}));
  EXPECT_THROW(makeDeblurrer("edi", {{"contrasts", "0.2"}}), Error);
  EXPECT_THROW(makeDeblurrer("edi", {{"contrast", "-1"}}), Error);
  const Observation& obs = planes();
  const DeblurRequest r = defaultRequest(obs, 4);
  EXPECT_EQ(r.times_us.front(), obs.blurry.exposure_start_us);
  EXPECT_EQ(r.times_us.back(), obs.blurry.exposure_end_us);
  EXPECT_EQ(r.times_us.size(), 5u);  // 4 evenly spaced + the middle
  const DeblurResult blurry = makeDeblurrer("blurry")->run(obs, r);
  EXPECT_EQ(cv::norm(blurry.frames[2].image - obs.blurry.image, cv::NORM_INF), 0.0);
}

}  // namespace
}  // namespace evkit
