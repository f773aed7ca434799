#include "evkit/deblur/metrics.h"

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <opencv2/imgproc.hpp>
#include <opencv2/quality.hpp>

#include "evkit/base/error.h"
#include "evkit/events/image_io.h"

namespace evkit {

namespace {
void checkPair(const cv::Mat& a, const cv::Mat& b) {
  if (a.size() != b.size() || a.channels() != b.channels()) {
    throw Error("images differ in size or channels (" + std::to_string(a.cols) + "x" +
                std::to_string(a.rows) + "x" + std::to_string(a.channels()) + " vs " +
                std::to_string(b.cols) + "x" + std::to_string(b.rows) + "x" +
                std::to_string(b.channels()) + ")");
  }
}
}  // namespace

cv::Mat toGrey(const cv::Mat& image) {
  if (image.channels() == 1) return image;
  cv::Mat grey;
  cv::cvtColor(image, grey, cv::COLOR_BGR2GRAY);
  return grey;
}

double psnr(const cv::Mat& image, const cv::Mat& reference) {
  checkPair(image, reference);
  // OpenCV's QualityPSNR on [0,1] data with peak 1 (the mean over channels of per-channel MSE).
  cv::Mat a, b;
  image.convertTo(a, CV_64F);
  reference.convertTo(b, CV_64F);
  const cv::Scalar per_channel = cv::quality::QualityPSNR::compute(b, a, cv::noArray(), 1.0);
  // Combine through the mean MSE, not the mean of per-channel PSNRs.
  double mse = 0;
  for (int c = 0; c < image.channels(); ++c) mse += std::pow(10.0, -per_channel[c] / 10.0);
  mse /= image.channels();
  return mse > 0 ? -10.0 * std::log10(mse) : std::numeric_limits<double>::infinity();
}

double ssim(const cv::Mat& image, const cv::Mat& reference) {
  checkPair(image, reference);
  // OpenCV's SSIM constants assume a 0..255 range.
  cv::Mat a, b;
  image.convertTo(a, CV_32F, 255.0);
  reference.convertTo(b, CV_32F, 255.0);
  const cv::Scalar s = cv::quality::QualitySSIM::compute(b, a, cv::noArray());
  double sum = 0;
  for (int c = 0; c < image.channels(); ++c) sum += s[c];
  return sum / image.channels();
}

std::string brisqueModelDir() {
  const char* env = std::getenv("EVKIT_BRISQUE_DIR");
  return env ? env : "/usr/share/opencv4/quality";
}

double brisque(const cv::Mat& image) {
  const std::string dir = brisqueModelDir();
  const std::string model = dir + "/brisque_model_live.yml",
                    range = dir + "/brisque_range_live.yml";
  if (!std::filesystem::exists(model) || !std::filesystem::exists(range)) {
    throwInFile(model,
                "BRISQUE model files not found (Debian: opencv-data; or set EVKIT_BRISQUE_DIR)");
  }
  const cv::Mat u8 = quantize(image, 8);
  return cv::quality::QualityBRISQUE::compute(u8, model, range)[0];
}

}  // namespace evkit
