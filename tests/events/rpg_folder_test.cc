#include <gtest/gtest.h>

#include "evkit/base/error.h"
#include "evkit/events/image_io.h"
#include "evkit/events/io.h"
#include "test_util.h"

namespace evkit {
namespace {

using test::ScratchDir;
using test::writeText;

TEST(RpgFolder, ReadsEventsImagesAndCalibration) {
  ScratchDir dir;
  writeText(dir / "events.txt", "0.001 1 2 1\n0.002 3 4 0\n0.010 5 0 1\n0.020 2 2 0\n");
  test::fs::create_directories(dir / "images");
  for (int i = 0; i < 2; ++i) {
    cv::Mat img(5, 6, CV_32F, cv::Scalar(0.25 * (i + 1)));
    writeImageFile(dir / ("images/frame_0000000" + std::to_string(i) + ".png"), img, 8);
  }
  writeText(dir / "images.txt",
            "0.0015 images/frame_00000000.png\n0.015 images/frame_00000001.png\n");
  writeText(dir / "calib.txt", "199.1 198.7 132.2 110.8 -0.36 0.15 0.001 -0.0002 0.0\n");

  EXPECT_EQ(detectFormat(dir.path().string()), Format::kRpgFolder);
  const Recording rec = readRecording(dir.path().string());
  EXPECT_EQ(rec.info.layout, "rpg-folder");
  EXPECT_EQ(rec.events.t, (std::vector<int64_t>{1000, 2000, 10000, 20000}));
  ASSERT_EQ(rec.frames.size(), 2u);
  EXPECT_EQ(rec.frames[0].exposure_start_us, 1500);
  EXPECT_EQ(rec.frames[1].exposure_end_us, 15000);
  EXPECT_NEAR(rec.frames[1].image.at<float>(4, 5), 0.5f, 1.0f / 255);
  ASSERT_TRUE(rec.info.calibration.has_value());
  EXPECT_DOUBLE_EQ(rec.info.calibration->fx, 199.1);
  EXPECT_DOUBLE_EQ(rec.info.calibration->cy, 110.8);
  ASSERT_EQ(rec.info.calibration->distortion.size(), 5u);
  EXPECT_DOUBLE_EQ(rec.info.calibration->distortion[0], -0.36);
}

TEST(RpgFolder, BadImageListAndCalibrationAreReported) {
  ScratchDir dir;
  writeText(dir / "events.txt", "0.001 1 2 1\n");
  writeText(dir / "images.txt", "0.5 images/missing.png\n");
  try {
    readRecording(dir.path().string());
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("missing.png: no such image file"), std::string::npos)
        << e.what();
  }
  writeText(dir / "images.txt", "zero images/a.png\n");
  EXPECT_THROW(readRecording(dir.path().string()), Error);
  writeText(dir / "images.txt", "");
  writeText(dir / "calib.txt", "199.1 198.7 132.2\n");
  try {
    readRecording(dir.path().string());
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("calib.txt: line 1: expected 4, 8 or 9 numbers"),
              std::string::npos)
        << e.what();
  }
}

TEST(Calibration, RoundTrip) {
  ScratchDir dir;
  const Calibration c{320.5, 321.25, 173.0, 130.5, {0.1, -0.01, 0.001, 0.0002}};
  writeCalibration(dir / "calib.txt", c);
  const Calibration back = readCalibration(dir / "calib.txt");
  EXPECT_EQ(back.fx, c.fx);
  EXPECT_EQ(back.cy, c.cy);
  EXPECT_EQ(back.distortion, c.distortion);
}

}  // namespace
}  // namespace evkit
