// One interface for every deblurring method: input an Observation, request the timestamps wanted,
// get one sharp image per timestamp (float32 linear [0,1], the blurry frame's channels), the
// camera trajectory where the method estimates one, and timings. Methods are made by name.
#pragma once

#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "evkit/deblur/observation.h"
#include "evkit/deblur/settings.h"

namespace evkit {

struct DeblurRequest {
  std::vector<int64_t> times_us;  // inside the exposure
  // Called now and then by iterative methods: iteration done, iterations planned, current loss.
  std::function<void(int, int, double)> progress = {};
};

struct DeblurResult {
  std::vector<Frame> frames;  // one per requested time (exposure_start_us = exposure_end_us = time)
  std::optional<std::vector<StampedPose>> trajectory;
  std::map<std::string, double> timings_s;    // named phases, plus "total"
  std::map<std::string, double> parameters;   // what the method chose or used (e.g. "contrast")
  std::vector<std::pair<int, double>> curve;  // training curve (iteration, loss), when there is one
  std::vector<std::pair<int, double>> curve_psnr;  // (iteration, PSNR of the mid frame against gt/)
  cv::Mat disparity;  // float32 at mid-exposure, where the method models depth (1 / depth,
                      // arbitrary scale)
  // What the method did, in a line of words: the model it chose, the thresholds and the camera it
  // used, and why it left a model out (BeNeRF's; EDI's thresholds). Empty where nothing was chosen.
  std::string account;
};

// A `contrast=C[,C_off]` setting as (C_on, C_off), both positive; throws evkit::Error otherwise.
Contrast contrastSetting(const std::string& method, const std::string& value);

// The thresholds a method works with, decided in one place: its setting, else the observation's
// contrast.txt (when use_observation), else none, and the method estimates them (EDI by its
// sharpness search, BeNeRF through EDI's).
std::optional<Contrast> resolveContrast(const std::optional<Contrast>& setting,
                                        const Observation& obs, bool use_observation = true);

class Deblurrer {
 public:
  virtual ~Deblurrer() = default;
  virtual std::string name() const = 0;
  virtual DeblurResult run(const Observation& obs, const DeblurRequest& request) = 0;
};

// The methods (deblur/src/methods.cc): blurry, edi, benerf.
std::vector<std::string> deblurrerNames();
// Each setting of a method with its type, default and help, one per line.
std::string deblurrerHelp(const std::string& name);
// Throws evkit::Error for an unknown name or setting.
std::unique_ptr<Deblurrer> makeDeblurrer(const std::string& name,
                                         const MethodSettings& settings = {});

// Default request: n evenly spaced times over the exposure (start and end included) plus the
// middle.
DeblurRequest defaultRequest(const Observation& obs, int n = 5);

}  // namespace evkit
