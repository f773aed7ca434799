// Small helpers the BeNeRF files share.
#pragma once

#include <chrono>

#include <opencv2/core.hpp>

#include "evkit/events/calibration.h"
#include "evkit/nerf/camera.h"

namespace evkit::benerf_detail {

inline double secondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

inline cv::Mat toFloat(const cv::Mat& image) {
  cv::Mat f;
  image.convertTo(f, CV_32F);
  return f;
}

inline nerf::PinholeCamera pinhole(const Calibration& c, int width, int height) {
  nerf::PinholeCamera camera;
  camera.width = width;
  camera.height = height;
  camera.fx = c.fx;
  camera.fy = c.fy;
  camera.cx = c.cx;
  camera.cy = c.cy;
  camera.distortion = c.distortion;
  return camera;
}

}  // namespace evkit::benerf_detail
