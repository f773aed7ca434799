// Running a deblurring method from the command line: the method made once (a bad name or setting
// is a usage error), a progress line on the terminal while it trains, then its outputs written.
// The work itself is evkit/deblur/evaluate.h's.
#pragma once

#include <functional>
#include <optional>
#include <string>

#include "common.h"
#include "evkit/deblur/evaluate.h"

namespace evkit::cli {

// evkit::makeMethod, with a bad name or setting thrown as a UsageError.
Method makeMethod(const std::string& name, const MethodSettings& settings);

// A terminal progress line for a method's training, fed through DeblurRequest::progress.
class TrainingProgress {
 public:
  explicit TrainingProgress(std::string label) : label_(std::move(label)) {}
  std::function<void(int, int, double)> callback();
  void finish() {
    if (progress_) progress_->finish();
  }

 private:
  std::string label_;
  std::optional<Progress> progress_;
};

// Runs the method with a progress line and, when out_dir is not empty, writes its outputs there
// (evkit::writeMethodOutputs).
MethodReport runMethod(const Observation& obs, const Method& method, const DeblurRequest& request,
                       const std::string& out_dir);

}  // namespace evkit::cli
