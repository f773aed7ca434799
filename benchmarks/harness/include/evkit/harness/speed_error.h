// Speed against error: deblurring methods at several budgets on observation folders with ground
// truth, one row of figures per (scene, method, budget), written as results.csv, results.md and a
// speed-against-error plot. Used by `evkit bench` and `evkit demo`; errors are evkit::Error.
#pragma once

#include <cmath>
#include <cstdint>
#include <functional>
#include <map>
#include <string>
#include <vector>

#include "evkit/deblur/evaluate.h"

namespace evkit {

// One method at one budget.
struct BenchRun {
  std::string method;  // label: blurry, edi, benerf, benerf-mlp
  std::string budget;  // "-" for methods without one, else e.g. "500 it", "fast", "60 s"
  Method deblurrer;    // made once (benerf-mlp runs benerf with field=mlp)
};

// The runs for `methods` (blurry, edi, benerf, benerf-mlp): BeNeRF once per entry of `budgets`,
// the MLP once per entry of `mlp_budgets`. A budget is N (iterations of the fast budget), a name
// (fast, balanced, quality) or a duration in seconds ("60s"). `extra` holds METHOD.KEY settings
// added to every run of that method. Throws evkit::Error on an unknown method, setting or budget.
std::vector<BenchRun> benchRuns(const std::vector<std::string>& methods,
                                const std::vector<std::string>& budgets,
                                const std::vector<std::string>& mlp_budgets,
                                const std::map<std::string, MethodSettings>& extra);

struct BenchRow {
  std::string group, scene, what, method, budget;
  std::string status = "ok";  // or "failed: <message>"
  double wall_s = std::nan("");
  double psnr = std::nan(""), ssim = std::nan(""), brisque = std::nan("");  // of the mid frame
  double psnr_mean = std::nan("");           // over every ground-truth time
  double rotation_error_deg = std::nan("");  // of the exposure's rotation, R(start)^T R(end)
  double rotation_truth_deg = std::nan("");
  double rotation_estimated_deg = std::nan("");  // the method's own exposure rotation
  // The rotation error as image motion: the largest displacement (px) of the image's corners and
  // edge midpoints under the error rotation (the trajectory's error at the image border).
  double rotation_error_px = std::nan("");
  // The image motion's error (px, exposureMotionErrorPx): what the data can tell apart, where the
  // rotation's split from the translation may not be.
  double motion_error_px = std::nan("");
  double blur_truth_px = std::nan(""), blur_estimated_px = std::nan("");  // gt/info.txt; method
  double iterations = std::nan("");
  int64_t nonfinite = 0;  // NaN or Inf values in the output frames

  bool ok() const { return status == "ok"; }
  std::string key() const { return scene + "|" + method + "|" + budget; }
};

// Runs one method on one observation, writing its outputs into out_dir (empty: none). Failures
// become a row with status "failed: ..."; the report is returned through `report` when given;
// `progress` is passed to the method (DeblurRequest::progress).
BenchRow runBench(const Observation& obs, const std::string& group, const std::string& scene,
                  const std::string& what, const BenchRun& run, const std::string& out_dir,
                  MethodReport* report = nullptr,
                  const std::function<void(int, int, double)>& progress = {});

// The angle (degrees) of R_a(start)^T R_a(end) against the same for b.
double exposureRotationErrorDeg(const std::vector<StampedPose>& a,
                                const std::vector<StampedPose>& b);
double exposureRotationDeg(const std::vector<StampedPose>& poses);
// The largest image displacement (px) of the border points (corners, edge midpoints) of `camera`
// under the rotation between a's and b's exposure rotations.
double exposureRotationErrorPx(const std::vector<StampedPose>& a, const std::vector<StampedPose>& b,
                               const PinholeCamera& camera);

// The image motion's error (px): the mean over the pixels of the distance between where the
// estimate and the truth move each pixel from mid-exposure to the exposure's start and to its end
// (the mean of the two ends). Each pixel moves through its depth at mid-exposure: the truth's depth
// map (z; not finite or not positive: at infinity) and the estimate's inverse depth map (the
// method's own scale, that of its translation; 0: at infinity). A rotation and a translation
// through the scene's depths can move the image alike, so the rotation's error alone may be large
// where this one is small; this is the error a deblurring pays for. Poses between stamps are
// interpolated; `mask` (CV_8U, optional) picks the pixels counted. NaN where either is missing.
double exposureMotionErrorPx(const std::vector<StampedPose>& estimate, const cv::Mat& inverse_depth,
                             const std::vector<StampedPose>& truth, const cv::Mat& depth,
                             const PinholeCamera& camera, int64_t start_us, int64_t end_us,
                             const cv::Mat& mask = cv::Mat());

// results.csv (every row), results.md (the mean per method and budget, per scene, hard cases with
// their numerical health) and speed_vs_error.png, each written atomically into `dir`.
void writeBenchResults(const std::string& dir, const std::vector<BenchRow>& rows,
                       const std::string& title);
// Reads a results.csv written before (to keep finished runs); missing file: empty.
std::vector<BenchRow> readBenchCsv(const std::string& path);

// The speed-against-error plot: mean PSNR against log wall time, one curve per method through its
// budgets (points labelled by budget). Rows of the "standard" group when there are some, else all.
void drawSpeedError(const std::vector<BenchRow>& rows, const std::string& title,
                    const std::string& png_path);

}  // namespace evkit
