#include "evkit/deblur/evaluate.h"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>
#include <sstream>

#include "evkit/base/text.h"
#include "evkit/deblur/metrics.h"
#include "evkit/events/atomic_file.h"
#include "evkit/events/image_io.h"
#include "evkit/events/npy.h"
#include "evkit/spline/tum.h"

namespace evkit {

namespace fs = std::filesystem;

namespace {

cv::Mat labelled(const cv::Mat& linear, const std::string& label) {
  cv::Mat img = quantize(linear, 8);
  if (img.channels() == 1) cv::cvtColor(img, img, cv::COLOR_GRAY2BGR);
  cv::Mat out(img.rows + 22, img.cols, CV_8UC3, cv::Scalar(255, 255, 255));
  img.copyTo(out(cv::Rect(0, 22, img.cols, img.rows)));
  cv::putText(out, label, cv::Point(4, 16), cv::FONT_HERSHEY_SIMPLEX, 0.5, cv::Scalar(0, 0, 0), 1,
              cv::LINE_AA);
  return out;
}

}  // namespace

void writeSideBySide(const std::string& path, const Observation& obs,
                     const std::vector<MethodReport>& reports) {
  std::vector<cv::Mat> tiles;
  for (const MethodReport& r : reports) {
    std::string label = r.method;
    if (std::isfinite(r.psnr_mid)) {
      char db[32];
      std::snprintf(db, sizeof(db), " %.2f dB", r.psnr_mid);
      label += db;
    }
    if (!r.mid.empty()) tiles.push_back(labelled(r.mid, label));
  }
  const int64_t mid = obs.blurry.exposure_start_us +
                      (obs.blurry.exposure_end_us - obs.blurry.exposure_start_us) / 2;
  for (const Frame& g : obs.gt_frames) {
    if (g.exposure_start_us == mid) tiles.push_back(labelled(g.image, "ground truth"));
  }
  if (tiles.empty()) return;
  cv::Mat side;
  cv::hconcat(tiles, side);
  writeImageFile(path, side);
}

std::string frameName(int64_t t_us) { return std::to_string(t_us) + ".png"; }

DeblurRequest completeRequest(const Observation& obs, DeblurRequest request) {
  for (const Frame& g : obs.gt_frames) {
    if (g.exposure_start_us >= obs.blurry.exposure_start_us &&
        g.exposure_start_us <= obs.blurry.exposure_end_us) {
      request.times_us.push_back(g.exposure_start_us);
    }
  }
  request.times_us.push_back(obs.blurry.exposure_start_us +
                             (obs.blurry.exposure_end_us - obs.blurry.exposure_start_us) / 2);
  std::sort(request.times_us.begin(), request.times_us.end());
  request.times_us.erase(std::unique(request.times_us.begin(), request.times_us.end()),
                         request.times_us.end());
  return request;
}

Method makeMethod(const std::string& name, const MethodSettings& settings) {
  return {name, settings, makeDeblurrer(name, settings)};
}

MethodReport evaluateMethod(const Observation& obs, const Method& method,
                            const DeblurRequest& request) {
  MethodReport report;
  report.method = method.name;
  const auto start = std::chrono::steady_clock::now();
  report.result = method.deblurrer->run(obs, request);
  report.wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  const int64_t mid = obs.blurry.exposure_start_us +
                      (obs.blurry.exposure_end_us - obs.blurry.exposure_start_us) / 2;
  double psnr_sum = 0, ssim_sum = 0;
  int count = 0;
  for (const Frame& f : report.result.frames) {
    if (f.exposure_start_us == mid) report.mid = f.image;
    for (const Frame& g : obs.gt_frames) {
      if (g.exposure_start_us != f.exposure_start_us || g.image.size() != f.image.size() ||
          g.image.channels() != f.image.channels())
        continue;
      const double p = psnr(f.image, g.image), s = ssim(f.image, g.image);
      psnr_sum += p;
      ssim_sum += s;
      ++count;
      if (f.exposure_start_us == mid) {
        report.psnr_mid = p;
        report.ssim_mid = s;
      }
    }
  }
  if (count > 0) {
    report.psnr_mean = psnr_sum / count;
    report.ssim_mean = ssim_sum / count;
  }
  if (report.mid.empty() && !report.result.frames.empty())
    report.mid = report.result.frames[report.result.frames.size() / 2].image;
  if (!report.mid.empty()) report.brisque_mid = brisque(report.mid);
  return report;
}

void writeMethodOutputs(const std::string& dir, const Observation& obs, const Method& method,
                        const MethodReport& report) {
  AtomicPath out(dir);
  const std::string tmp = out.temporaryPath();
  fs::create_directories(tmp);
  for (const Frame& f : report.result.frames)
    writeImageFile(tmp + "/" + frameName(f.exposure_start_us), f.image, obs.blurry.bit_depth);
  if (report.result.frames.size() > 1) {
    const cv::Mat& first = report.result.frames.front().image;
    cv::VideoWriter video(tmp + "/latent.avi", cv::VideoWriter::fourcc('M', 'J', 'P', 'G'), 10.0,
                          first.size(), first.channels() == 3);
    if (video.isOpened()) {
      for (const Frame& f : report.result.frames) video.write(encodeSrgb8(f.image));
    }
  }
  if (report.result.trajectory) writeTum(tmp + "/trajectory.txt", *report.result.trajectory);
  if (!report.result.disparity.empty()) {
    // disparity.npy: float32 (1 / depth, the method's arbitrary scale); disparity.png: 16-bit,
    // scaled to the 99th percentile for viewing.
    const cv::Mat& d = report.result.disparity;
    writeNpy(tmp + "/disparity.npy", {d});
    std::vector<float> values(d.begin<float>(), d.end<float>());
    std::nth_element(values.begin(),
                     values.begin() + static_cast<std::ptrdiff_t>(values.size() * 99 / 100),
                     values.end());
    const float top = values[values.size() * 99 / 100];
    writeImageFile(tmp + "/disparity.png", top > 0 ? cv::Mat(d / top) : d, 16);
  }
  std::ostringstream j;
  j << "{\n  \"method\": " << jsonString(method.name)
    << ",\n  \"observation\": " << jsonString(obs.source) << ",\n  \"settings\": {";
  bool first = true;
  for (const auto& [k, v] : method.settings)
    j << (first ? "" : ", ") << jsonString(k) << ": " << jsonString(v), first = false;
  j << "},\n  \"account\": " << jsonString(report.result.account) << ",\n  \"parameters\": {";
  first = true;
  for (const auto& [k, v] : report.result.parameters)
    j << (first ? "" : ", ") << jsonString(k) << ": " << jsonNumber(v), first = false;
  j << "},\n  \"wall_time_s\": " << jsonNumber(report.wall_s) << ",\n  \"timings_s\": {";
  first = true;
  for (const auto& [k, v] : report.result.timings_s)
    j << (first ? "" : ", ") << jsonString(k) << ": " << jsonNumber(v), first = false;
  j << "},\n  \"frames\": [";
  first = true;
  for (const Frame& f : report.result.frames)
    j << (first ? "" : ", ") << f.exposure_start_us, first = false;
  j << "],\n  \"metrics\": {\"psnr_mid\": " << jsonNumber(report.psnr_mid)
    << ", \"ssim_mid\": " << jsonNumber(report.ssim_mid)
    << ", \"psnr_mean\": " << jsonNumber(report.psnr_mean)
    << ", \"ssim_mean\": " << jsonNumber(report.ssim_mean)
    << ", \"brisque_mid\": " << jsonNumber(report.brisque_mid) << "},\n  \"training_curve\": [";
  first = true;
  for (const auto& [it, loss] : report.result.curve)
    j << (first ? "" : ", ") << "[" << it << ", " << jsonNumber(loss) << "]", first = false;
  j << "],\n  \"training_psnr\": [";
  first = true;
  for (const auto& [it, p] : report.result.curve_psnr)
    j << (first ? "" : ", ") << "[" << it << ", " << jsonNumber(p) << "]", first = false;
  j << "]\n}\n";
  std::ofstream(tmp + "/summary.json") << j.str();
  out.commit();
}

}  // namespace evkit
