// Image files, linear (no gamma curve), keeping the bit depth (DESIGN.md §2).
#pragma once

#include <memory>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "evkit/events/frame.h"

namespace evkit {

// Reads an 8- or 16-bit grey or colour image (alpha dropped) as float32 in [0,1]; sets bit_depth.
// Exposure fields are left at zero. Throws evkit::Error when the file is missing or not an image.
Frame readImageFile(const std::string& path);

// Writes a float image in [0,1] (values outside are clamped, NaN written as 0) as an 8- or 16-bit
// PNG/TIFF/... chosen by the extension, atomically.
void writeImageFile(const std::string& path, const cv::Mat& image, int bit_depth = 8);

// Converts a float [0,1] image to CV_8U/CV_16U with rounding and clamping (NaN -> 0).
cv::Mat quantize(const cv::Mat& image, int bit_depth);
// A linear [0,1] image encoded with the sRGB curve in 8 bits: a copy for viewing (videos), never
// instead of the linear files.
cv::Mat encodeSrgb8(const cv::Mat& linear);

// A folder of frames: one PNG per frame (linear, the frame's bit depth) and frames.csv
// ("index,exposure_start_us,exposure_end_us,file"). Used beside text files, which cannot hold
// frames, and by `evkit frames`. Frames are written as they come; the folder appears under its
// name only at close().
class FrameFolderWriter {
 public:
  explicit FrameFolderWriter(const std::string& dir);
  ~FrameFolderWriter();
  FrameFolderWriter(const FrameFolderWriter&) = delete;
  FrameFolderWriter& operator=(const FrameFolderWriter&) = delete;
  void add(const Frame& frame);
  size_t count() const { return count_; }
  void close();

 private:
  struct State;
  std::unique_ptr<State> state_;
  size_t count_ = 0;
};
void writeFrameFolder(const std::string& dir, const std::vector<Frame>& frames);
std::vector<Frame> readFrameFolder(const std::string& dir);

}  // namespace evkit
