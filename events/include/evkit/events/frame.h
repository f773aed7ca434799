// Intensity frames (APS frames, rendered frames, blurry frames) with their exposure interval.
#pragma once

#include <cstdint>
#include <opencv2/core.hpp>
#include <vector>

namespace evkit {

struct Frame {
  // The level from which a channel was clipped by the sensor: its exposure's mean reached the top,
  // so the value says only that the mean was at least this. EDI masks such pixels and the pixel
  // grid's blur term charges only a re-blur below it (EdiOptions, PixelGridOptions::saturated).
  static constexpr double kClipped = 0.99;

  // float32, linear, [0,1]; CV_32FC1 (grey) or CV_32FC3 (colour in OpenCV's BGR order).
  cv::Mat image;
  int64_t exposure_start_us = 0;
  int64_t exposure_end_us = 0;
  // Bit depth of the source (8 or 16); writers keep it so that 16-bit in gives 16-bit out.
  int bit_depth = 8;

  int64_t midExposure() const {
    return exposure_start_us + (exposure_end_us - exposure_start_us) / 2;
  }
};

}  // namespace evkit
