// Small helpers the BeNeRF files share.
#pragma once

#include <chrono>
#include <opencv2/core.hpp>

namespace evkit::benerf_detail {

inline double secondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

inline cv::Mat toFloat(const cv::Mat& image) {
  cv::Mat f;
  image.convertTo(f, CV_32F);
  return f;
}

}  // namespace evkit::benerf_detail
