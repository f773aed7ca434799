// Small helpers the BeNeRF files share.
#pragma once

#include <algorithm>
#include <chrono>
#include <opencv2/core.hpp>

#include "evkit/deblur/metrics.h"
#include "evkit/events/log_intensity.h"

namespace evkit {
struct Observation;
}

namespace evkit::benerf_detail {

// How many events each pixel saw over the exposure (float64, the frame's size; events outside it
// are not counted). In pixel_grid_start.cc.
cv::Mat exposureEventCounts(const Observation& obs);

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
