#include "evkit/harness/speed_error.h"

#include <gtest/gtest.h>

#include <cmath>

namespace evkit {
namespace {

constexpr int64_t kStart = 1000000, kEnd = 1100000;

// 64 x 48 pixels, f = 100: the image's border is 0.32 f from its centre.
PinholeCamera camera() { return PinholeCamera{100, 100, 31.5, 23.5, {}, 64, 48}; }

// The camera at the exposure's start, middle and end.
std::vector<StampedPose> poses(const SE3& start, const SE3& end) {
  return {{kStart, start}, {(kStart + kEnd) / 2, SE3()}, {kEnd, end}};
}

SE3 along(double x) { return SE3(Quaternion::Identity(), Vector3(x, 0, 0)); }

double motionError(const std::vector<StampedPose>& estimate, const cv::Mat& inverse_depth,
                   const std::vector<StampedPose>& truth, const cv::Mat& depth,
                   const cv::Mat& mask = cv::Mat()) {
  return exposureMotionErrorPx(estimate, inverse_depth, truth, depth, camera(), kStart, kEnd, mask);
}

// A wall at 2 m, the camera sliding 0.1 m either way of mid-exposure: every pixel moves 5 px.
TEST(SpeedError, ImageMotionErrorIsTheMeanDistanceBetweenWhereEachPixelMoves) {
  const cv::Mat depth(48, 64, CV_32F, cv::Scalar(2.0));
  const std::vector<StampedPose> truth = poses(along(-0.1), along(0.1));
  EXPECT_LT(motionError(truth, cv::Mat(48, 64, CV_32F, cv::Scalar(0.5)), truth, depth), 1e-9);
  // The method's own scale: twice the translation through half the inverse depth.
  EXPECT_LT(motionError(poses(along(-0.2), along(0.2)), cv::Mat(48, 64, CV_32F, cv::Scalar(0.25)),
                        truth, depth),
            1e-9);
  // The end 0.04 m too far: 100 * 0.04 / 2 = 2 px there, none at the start.
  EXPECT_NEAR(
      motionError(poses(along(-0.1), along(0.14)), cv::Mat(48, 64, CV_32F, 0.5), truth, depth), 1.0,
      1e-9);
  // The left half of the wall at 1 m: 100 * 0.1 * (1 - 0.5) = 5 px at both ends there.
  cv::Mat near = depth.clone(), left(48, 64, CV_8U, cv::Scalar(0));
  near.colRange(0, 32) = 1.0;
  left.colRange(0, 32) = 255;
  const cv::Mat half(48, 64, CV_32F, cv::Scalar(0.5));
  EXPECT_NEAR(motionError(truth, half, truth, near, left), 5.0, 1e-9);
  EXPECT_NEAR(motionError(truth, half, truth, near, ~left), 0.0, 1e-9);
  EXPECT_NEAR(motionError(truth, half, truth, near), 2.5, 1e-9);
  // No inverse depth, or one of another size: not measured.
  EXPECT_TRUE(std::isnan(motionError(truth, cv::Mat(), truth, depth)));
  EXPECT_TRUE(std::isnan(motionError(truth, cv::Mat(10, 10, CV_32F, 0.5), truth, depth)));
}

// The camera slides, and an estimate turns it instead with every point at infinity: the same
// image motion at the centre, 5.7 degrees of rotation error over the exposure (over 10 px at the
// border by the rotation's measure), yet the image moves within half a pixel of the truth
// everywhere, the difference only the rotation's second-order term (at most (0.32)^2 of 5 px at the
// border).
TEST(SpeedError, ARotationThatMimicsATranslationMovesTheImageAlike) {
  const cv::Mat depth(48, 64, CV_32F, cv::Scalar(2.0));
  const std::vector<StampedPose> truth = poses(along(-0.1), along(0.1));
  const double angle = std::atan(0.1 / 2);
  const auto turned = [](double a) { return SE3(expSO3(Vector3(0, a, 0)), Vector3::Zero()); };
  const std::vector<StampedPose> estimate = poses(turned(-angle), turned(angle));
  EXPECT_NEAR(exposureRotationErrorDeg(estimate, truth), 2 * angle * 180 / M_PI, 1e-9);
  EXPECT_GT(exposureRotationErrorPx(estimate, truth, camera()), 10.0);
  const double error =
      motionError(estimate, cv::Mat(48, 64, CV_32F, cv::Scalar(0.0)), truth, depth);
  EXPECT_GT(error, 0.05) << error;
  EXPECT_LT(error, 0.5);
}

}  // namespace
}  // namespace evkit
