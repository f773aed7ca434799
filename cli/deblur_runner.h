// Running a deblurring method on an observation and writing what it produced: the sharp frames,
// a latent video, the trajectory, and a JSON summary with timings and metrics against gt/.
#pragma once

#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "evkit/deblur/deblurrer.h"

namespace evkit::cli {

struct MethodReport {
  std::string method;
  DeblurResult result;
  double wall_s = 0;
  // Against the ground-truth frame at mid-exposure (NaN without one); BRISQUE of the mid frame.
  double psnr_mid = std::nan(""), ssim_mid = std::nan(""), brisque_mid = std::nan("");
  double psnr_mean = std::nan(""), ssim_mean = std::nan("");  // over every gt time
  cv::Mat mid;                                                // the frame at mid-exposure
};

// Adds the ground truth's times to the request (so that metrics exist) and the middle.
DeblurRequest completeRequest(const Observation& obs, DeblurRequest request);

// A method made from its name and settings, once: a bad name or setting is a UsageError here,
// before anything runs.
struct Method {
  std::string name;
  MethodSettings settings;
  std::shared_ptr<Deblurrer> deblurrer;
};
Method makeMethod(const std::string& name, const MethodSettings& settings);

// Runs the method and, when out_dir is not empty, writes <t_us>.png (linear, the input's bit
// depth), latent.avi (sRGB-encoded for viewing), trajectory.txt (TUM) and summary.json into it.
MethodReport runMethod(const Observation& obs, const Method& method, const DeblurRequest& request,
                       const std::string& out_dir);

std::string frameName(int64_t t_us);

// One image: each report's mid frame labelled with its method (and PSNR), then the ground truth at
// mid-exposure when there is one; 8-bit, linear values as the frames hold them.
// An 8-bit image (as cv::imwrite takes it) that appears complete or not at all.
void writeImageAtomically(const std::string& path, const cv::Mat& image);

void writeSideBySide(const std::string& path, const Observation& obs,
                     const std::vector<MethodReport>& reports);

}  // namespace evkit::cli
