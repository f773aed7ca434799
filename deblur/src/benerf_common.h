// Small helpers the BeNeRF files share.
#pragma once

#include <algorithm>
#include <chrono>
#include <opencv2/core.hpp>

#include "evkit/base/camera.h"
#include "evkit/deblur/metrics.h"
#include "evkit/events/log_intensity.h"
#include "evkit/spline/lie.h"

namespace evkit {
struct Observation;
}

namespace evkit::benerf_detail {

// How many events each pixel saw over the exposure (float64, the frame's size; events outside it
// are not counted). In pixel_grid_start.cc.
cv::Mat exposureEventCounts(const Observation& obs);

// Where the camera at one time sees a mid-exposure point, and how that moves with the time's
// motion and the point's inverse depth: the registration's Gauss-Newton terms. The camera's
// rotation R (Rt its transpose) is stepped on the right, R exp(delta), its translation p by dp;
// the point seen is X = R^T (b - rho p) (b its bearing, rho its inverse depth; 0: at infinity).
// In benerf_motion.cc.
struct SeenPoint {
  Eigen::Vector2d at;                     // the pixel
  Eigen::Matrix<double, 2, 6> by_motion;  // by (delta, dp)
  Eigen::Vector2d by_inverse_depth;       // by rho
};
SeenPoint seenPoint(const PinholeCamera& camera, const Vector3& bearing, double rho,
                    const Matrix3& Rt, const Vector3& p);

inline double secondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

inline cv::Mat toFloat(const cv::Mat& image) {
  cv::Mat f;
  image.convertTo(f, CV_32F);
  return f;
}

// The log mapping of an image's grey level (float32), as the event model sees it.
inline cv::Mat logGrey(const cv::Mat& image, const LogMapping& log) {
  const cv::Mat grey = toGrey(image);
  cv::Mat L(grey.size(), CV_32F);
  for (int y = 0; y < grey.rows; ++y) {
    for (int x = 0; x < grey.cols; ++x)
      L.at<float>(y, x) = log.toLog(std::max(grey.at<float>(y, x), 0.0f));
  }
  return L;
}

}  // namespace evkit::benerf_detail
