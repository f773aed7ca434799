#include "deblur_runner.h"

#include <cstdio>

#include "evkit/base/error.h"

namespace evkit::cli {

Method makeMethod(const std::string& name, const MethodSettings& settings) {
  try {
    return evkit::makeMethod(name, settings);
  } catch (const Error& e) {
    throw UsageError(e.what());
  }
}

std::function<void(int, int, double)> TrainingProgress::callback() {
  return [this](int done, int total, double loss) {
    if (!progress_) progress_.emplace(label_, total);
    char status[48];
    std::snprintf(status, sizeof(status), "loss %.3g", loss);
    progress_->update(done, status);
  };
}

MethodReport runMethod(const Observation& obs, const Method& method, const DeblurRequest& request,
                       const std::string& out_dir) {
  TrainingProgress progress(method.name + " training");
  DeblurRequest with_progress = request;
  with_progress.progress = progress.callback();
  MethodReport report = evaluateMethod(obs, method, with_progress);
  progress.finish();
  if (!out_dir.empty()) writeMethodOutputs(out_dir, obs, method, report);
  return report;
}

}  // namespace evkit::cli
