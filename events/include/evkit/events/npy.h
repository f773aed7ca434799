// NumPy .npy files (format version 1.0), so that float results load with numpy.load().
#pragma once

#include <opencv2/core.hpp>
#include <string>
#include <vector>

namespace evkit {

// Writes C-order float32 data of the given shape, atomically.
void writeNpy(const std::string& path, const float* data, const std::vector<size_t>& shape);
// Writes a stack of equally sized single-channel float images as (N, H, W).
void writeNpy(const std::string& path, const std::vector<cv::Mat>& planes);

struct NpyArray {
  std::vector<size_t> shape;
  std::vector<float> data;
};
// Reads a little-endian float32 C-order .npy file; throws evkit::Error otherwise.
NpyArray readNpy(const std::string& path);

}  // namespace evkit
