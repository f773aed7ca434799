// Image quality: PSNR and SSIM against a reference (OpenCV's quality module), and the
// no-reference BRISQUE score (lower is better) with the LIVE model that Debian's opencv-data ships.
#pragma once

#include <opencv2/core.hpp>
#include <string>

namespace evkit {

// Images float32 in [0,1] (any channel count; SSIM is averaged over channels). PSNR with peak 1.
// The grey image of a grey or BGR colour image: 0.299 R + 0.587 G + 0.114 B (as the simulator).
cv::Mat toGrey(const cv::Mat& image);

double psnr(const cv::Mat& image, const cv::Mat& reference);
double ssim(const cv::Mat& image, const cv::Mat& reference);
// Throws evkit::Error when the model files are missing (see brisqueModelDir).
double brisque(const cv::Mat& image);
// Folder of brisque_model_live.yml / brisque_range_live.yml: $EVKIT_BRISQUE_DIR, else
// /usr/share/opencv4/quality.
std::string brisqueModelDir();

}  // namespace evkit
