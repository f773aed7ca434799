#include "evkit/events/image_io.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>

#include "evkit/base/error.h"
#include "evkit/events/atomic_file.h"
#include "evkit/events/decimal.h"

namespace evkit {
namespace fs = std::filesystem;

Frame readImageFile(const std::string& path) {
  if (!fs::is_regular_file(path)) throwInFile(path, "no such image file");
  cv::Mat raw = cv::imread(path, cv::IMREAD_UNCHANGED);
  if (raw.empty()) throwInFile(path, "not a readable image (expected PNG, TIFF, JPEG, ...)");
  if (raw.channels() == 4) cv::cvtColor(raw, raw, cv::COLOR_BGRA2BGR);
  if (raw.channels() == 2) cv::extractChannel(raw, raw, 0);
  Frame frame;
  switch (raw.depth()) {
    case CV_8U:
      raw.convertTo(frame.image, CV_32F, 1.0 / 255.0);
      frame.bit_depth = 8;
      break;
    case CV_16U:
      raw.convertTo(frame.image, CV_32F, 1.0 / 65535.0);
      frame.bit_depth = 16;
      break;
    case CV_32F:
      frame.image = raw;
      frame.bit_depth = 16;
      break;
    default:
      throwInFile(path, "unsupported pixel type (expected 8- or 16-bit)");
  }
  return frame;
}

cv::Mat encodeSrgb8(const cv::Mat& linear) {
  cv::Mat out;
  linear.convertTo(out, CV_32F);
  out = out.clone();
  float* p = out.ptr<float>();
  for (size_t i = 0; i < out.total() * static_cast<size_t>(out.channels()); ++i) {
    const float c = std::clamp(p[i], 0.0f, 1.0f);
    p[i] = c <= 0.0031308f ? 12.92f * c : 1.055f * std::pow(c, 1.0f / 2.4f) - 0.055f;
  }
  return quantize(out, 8);
}

cv::Mat quantize(const cv::Mat& image, int bit_depth) {
  const double scale = bit_depth == 16 ? 65535.0 : 255.0;
  cv::Mat clean;
  image.convertTo(clean, CV_32F);
  cv::patchNaNs(clean, 0.0);
  cv::Mat out;
  clean.convertTo(out, bit_depth == 16 ? CV_16U : CV_8U, scale);  // saturating, rounds to nearest
  return out;
}

void writeImageFile(const std::string& path, const cv::Mat& image, int bit_depth) {
  AtomicPath out(path);
  const std::string ext = fs::path(path).extension().string();
  // OpenCV picks the codec from the name, so the temporary keeps the extension at its end.
  const std::string tmp = out.temporaryPath() + ext;
  bool ok = false;
  try {
    ok = cv::imwrite(tmp, image.depth() == CV_32F ? quantize(image, bit_depth) : image);
  } catch (const cv::Exception& e) {
    std::error_code ignored;
    fs::remove(tmp, ignored);
    throwInFile(path, std::string("cannot write image: ") + e.what());
  }
  if (!ok) throwInFile(path, "cannot write image (unknown extension or unwritable folder?)");
  fs::rename(tmp, out.temporaryPath());
  out.commit();
}

struct FrameFolderWriter::State {
  explicit State(const std::string& dir) : out(dir) {}
  AtomicPath out;
  std::ostringstream csv;
};

FrameFolderWriter::FrameFolderWriter(const std::string& dir)
    : state_(std::make_unique<State>(dir)) {
  std::error_code ec;
  fs::create_directories(state_->out.temporaryPath(), ec);
  if (ec) throwInFile(dir, "cannot create folder: " + ec.message());
  state_->csv << "index,exposure_start_us,exposure_end_us,file\n";
}

FrameFolderWriter::~FrameFolderWriter() = default;

void FrameFolderWriter::add(const Frame& frame) {
  char name[32];
  std::snprintf(name, sizeof(name), "%06zu.png", count_);
  if (!cv::imwrite(state_->out.temporaryPath() + "/" + name,
                   quantize(frame.image, frame.bit_depth))) {
    throwInFile(state_->out.finalPath(), std::string("cannot write ") + name);
  }
  state_->csv << count_ << ',' << frame.exposure_start_us << ',' << frame.exposure_end_us << ','
              << name << '\n';
  ++count_;
}

void FrameFolderWriter::close() {
  std::ofstream csv(state_->out.temporaryPath() + "/frames.csv");
  csv << state_->csv.str();
  csv.close();
  if (!csv) throwInFile(state_->out.finalPath(), "cannot write frames.csv");
  state_->out.commit();
}

void writeFrameFolder(const std::string& dir, const std::vector<Frame>& frames) {
  FrameFolderWriter writer(dir);
  for (const Frame& f : frames) writer.add(f);
  writer.close();
}

std::vector<Frame> readFrameFolder(const std::string& dir) {
  const std::string csv_path = dir + "/frames.csv";
  std::ifstream csv(csv_path);
  if (!csv) throwInFile(csv_path, "cannot open");
  std::vector<Frame> frames;
  std::string line;
  int64_t line_no = 0;
  while (std::getline(csv, line)) {
    ++line_no;
    if (line_no == 1 || line.empty()) continue;
    if (line.back() == '\r') line.pop_back();
    std::vector<std::string> fields;
    std::stringstream ss(line);
    for (std::string field; std::getline(ss, field, ',');) fields.push_back(field);
    int64_t index = 0, start = 0, end = 0;
    const char* p0 = fields.size() == 4 ? fields[0].c_str() : nullptr;
    const char* p1 = fields.size() == 4 ? fields[1].c_str() : nullptr;
    const char* p2 = fields.size() == 4 ? fields[2].c_str() : nullptr;
    if (!p0 || !parseInt(p0, p0 + fields[0].size(), 0, INT64_MAX, index) ||
        !parseInt(p1, p1 + fields[1].size(), INT64_MIN, INT64_MAX, start) ||
        !parseInt(p2, p2 + fields[2].size(), INT64_MIN, INT64_MAX, end) || end < start) {
      throwAtLine(csv_path, line_no,
                  "expected 'index,exposure_start_us,exposure_end_us,file' with start <= end");
    }
    Frame frame = readImageFile(dir + "/" + fields[3]);
    frame.exposure_start_us = start;
    frame.exposure_end_us = end;
    frames.push_back(std::move(frame));
  }
  return frames;
}

}  // namespace evkit
