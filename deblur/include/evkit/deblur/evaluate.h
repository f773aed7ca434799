// A method run on an observation and judged against its ground truth: the frames it produced,
// PSNR/SSIM at mid-exposure and over every ground-truth time, BRISQUE, and the files a user keeps
// (sharp frames, a latent video, the trajectory, a JSON summary). `evkit deblur`, `evkit compare`
// and the speed-against-error harness all go through here.
#pragma once

#include <cmath>
#include <memory>
#include <string>
#include <vector>

#include "evkit/deblur/deblurrer.h"

namespace evkit {

// A method made from its name and settings, once (makeDeblurrer checks them).
struct Method {
  std::string name;
  MethodSettings settings;
  std::shared_ptr<Deblurrer> deblurrer;
};
Method makeMethod(const std::string& name, const MethodSettings& settings = {});

struct MethodReport {
  std::string method;
  DeblurResult result;
  double wall_s = 0;
  // Against the ground-truth frame at mid-exposure (NaN without one); BRISQUE of the mid frame.
  double psnr_mid = std::nan(""), ssim_mid = std::nan(""), brisque_mid = std::nan("");
  double psnr_mean = std::nan(""), ssim_mean = std::nan("");  // over every gt time
  cv::Mat mid;                                                // the frame at mid-exposure
};

// The request with the ground truth's times inside the exposure (so that metrics exist) and the
// middle added.
DeblurRequest completeRequest(const Observation& obs, DeblurRequest request);

// Runs the method (request.progress is passed on) and measures it against obs.gt_frames.
MethodReport evaluateMethod(const Observation& obs, const Method& method,
                            const DeblurRequest& request);

// Writes <t_us>.png (linear, the input's bit depth), latent.avi (sRGB-encoded for viewing),
// trajectory.txt (TUM), disparity.npy/.png and summary.json into `dir`, which appears complete
// or not at all.
void writeMethodOutputs(const std::string& dir, const Observation& obs, const Method& method,
                        const MethodReport& report);

std::string frameName(int64_t t_us);

// One image: each report's mid frame labelled with its method (and PSNR), then the ground truth at
// mid-exposure when there is one; 8-bit, linear values as the frames hold them.
void writeSideBySide(const std::string& path, const Observation& obs,
                     const std::vector<MethodReport>& reports);

}  // namespace evkit
