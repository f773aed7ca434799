#include "evkit/events/frame_source.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>

#include "evkit/base/error.h"
#include "evkit/events/image_io.h"
#include "timed_list.h"

namespace evkit {
namespace fs = std::filesystem;

namespace {

bool isVideo(const std::string& path) {
  std::string ext = fs::path(path).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return std::tolower(c); });
  for (const char* v : {".mp4", ".avi", ".mkv", ".mov", ".webm", ".mpg", ".mpeg", ".m4v"}) {
    if (ext == v) return true;
  }
  return false;
}

class ImageSequence final : public FrameSequence {
 public:
  ImageSequence(const std::string& list, bool seconds, bool srgb) : srgb_(srgb) {
    for (auto& [t, path] : detail::readTimedPathList(list, seconds, true)) {
      times_.push_back(t);
      paths_.push_back(std::move(path));
    }
    if (times_.size() < 2) throwInFile(list, "fewer than two frames: nothing to simulate");
    const Frame first = readImageFile(paths_[0]);
    sensor_ = SensorSize{first.image.cols, first.image.rows};
  }

  bool next(Frame& frame, int64_t& t_us) override {
    if (next_ == paths_.size()) return false;
    frame = readImageFile(paths_[next_]);
    if (frame.image.cols != sensor_.width || frame.image.rows != sensor_.height) {
      throwInFile(paths_[next_], "image size differs from the first frame's");
    }
    if (srgb_) frame.image = srgbToLinear(frame.image);
    t_us = times_[next_++];
    frame.exposure_start_us = frame.exposure_end_us = t_us;
    return true;
  }
  int64_t timeOf(size_t i) const override {
    return times_[std::min(i, times_.size() - 1)] + (i >= times_.size() ? 1 : 0);
  }
  size_t sizeHint() const override { return times_.size(); }
  SensorSize sensor() const override { return sensor_; }

 private:
  bool srgb_;
  std::vector<int64_t> times_;
  std::vector<std::string> paths_;
  size_t next_ = 0;
  SensorSize sensor_;
};

class VideoSequence final : public FrameSequence {
 public:
  VideoSequence(const std::string& path, const SequenceOptions& options)
      : path_(path), options_(options) {
    if (!fs::is_regular_file(path)) throwInFile(path, "no such video file");
    if (!capture_.open(path))
      throwInFile(path, "cannot open the video (unsupported codec or container?)");
    fps_ = options.fps > 0 ? options.fps : capture_.get(cv::CAP_PROP_FPS);
    if (!(fps_ > 0) || !std::isfinite(fps_))
      throwInFile(path, "the video states no frame rate; pass --fps");
    count_ = static_cast<size_t>(std::max(0.0, capture_.get(cv::CAP_PROP_FRAME_COUNT)));
    sensor_ = SensorSize{static_cast<int>(capture_.get(cv::CAP_PROP_FRAME_WIDTH)),
                         static_cast<int>(capture_.get(cv::CAP_PROP_FRAME_HEIGHT))};
  }

  bool next(Frame& frame, int64_t& t_us) override {
    cv::Mat raw;
    if (!capture_.read(raw) || raw.empty()) return false;
    frame.bit_depth = raw.depth() == CV_16U ? 16 : 8;
    raw.convertTo(frame.image, CV_32F, raw.depth() == CV_16U ? 1.0 / 65535 : 1.0 / 255);
    if (options_.srgb) frame.image = srgbToLinear(frame.image);
    t_us = timeOf(index_++);
    frame.exposure_start_us = frame.exposure_end_us = t_us;
    return true;
  }
  int64_t timeOf(size_t i) const override {
    return options_.start_us + std::llround(static_cast<double>(i) * 1e6 / fps_);
  }
  size_t sizeHint() const override { return count_; }
  SensorSize sensor() const override { return sensor_; }

 private:
  std::string path_;
  SequenceOptions options_;
  cv::VideoCapture capture_;
  double fps_ = 0;
  size_t count_ = 0, index_ = 0;
  SensorSize sensor_;
};

// Exposures of the "every N frames, duty d" schedule, from the frame times.
void addScheduledExposures(const FrameSequence& seq, const DriverOptions& options,
                           std::vector<BlurAccumulator::Exposure>& exposures) {
  if (options.exposure_every <= 0) return;
  const size_t span =
      static_cast<size_t>(std::max(1L, std::lround(options.duty * options.exposure_every)));
  for (size_t k = 0; k + span < seq.sizeHint(); k += static_cast<size_t>(options.exposure_every)) {
    exposures.push_back({seq.timeOf(k), seq.timeOf(k + span)});
  }
}

}  // namespace

cv::Mat srgbToLinear(const cv::Mat& image) {
  cv::Mat out;
  image.convertTo(out, CV_32F);
  if (!out.isContinuous()) out = out.clone();
  float* p = out.ptr<float>();
  const size_t n = out.total() * static_cast<size_t>(out.channels());
  for (size_t i = 0; i < n; ++i) {
    const float c = p[i];
    p[i] = c <= 0.04045f ? c / 12.92f : std::pow((c + 0.055f) / 1.055f, 2.4f);
  }
  return out;
}

std::unique_ptr<FrameSequence> openFrameSequence(const std::string& path,
                                                 const SequenceOptions& options) {
  std::error_code ec;
  if (fs::is_directory(path, ec)) {
    for (const auto& [name, seconds] :
         {std::pair<const char*, bool>{"timestamps.txt", false}, {"images.txt", true}}) {
      const fs::path list = fs::path(path) / name;
      if (fs::exists(list))
        return std::make_unique<ImageSequence>(list.string(), seconds, options.srgb);
    }
    throwInFile(
        path,
        "a folder without timestamps.txt ('t_us path' lines) or images.txt ('t_seconds path')");
  }
  if (isVideo(path)) return std::make_unique<VideoSequence>(path, options);
  if (!fs::exists(path, ec)) throwInFile(path, "no such file or folder");
  const bool seconds = fs::path(path).filename() == "images.txt";
  return std::make_unique<ImageSequence>(path, seconds, options.srgb);
}

SimulatorStats simulateSequence(FrameSequence& sequence, const DriverOptions& options,
                                const SimulationSink& sink) {
  EventSimulator sim(sequence.sensor(), options.simulator);
  std::vector<BlurAccumulator::Exposure> exposures = options.exposures;
  addScheduledExposures(sequence, options, exposures);
  BlurAccumulator blur(exposures);
  Frame frame;
  int64_t t = 0;
  EventStore events(sequence.sensor());
  std::vector<Frame> blurry;
  int bit_depth = 8;
  while (sequence.next(frame, t)) {
    bit_depth = frame.bit_depth;
    events.clear();
    blurry.clear();
    sim.addFrame(toSensorIntensity(frame.image, options.bayer_rggb), t, events);
    for (auto& [e, image] : blur.addFrame(frame.image, t)) {
      Frame b;
      b.image = image;
      b.exposure_start_us = e.start_us;
      b.exposure_end_us = e.end_us;
      b.bit_depth = bit_depth;
      blurry.push_back(std::move(b));
    }
    sink(events, blurry);
  }
  return sim.stats();
}

SimulatorStats simulateAdaptive(RenderSource& source, int64_t t_begin_us, int64_t t_end_us,
                                const DriverOptions& options, const AdaptiveOptions& adaptive,
                                const SimulationSink& sink) {
  EventSimulator sim(source.sensor(), options.simulator);
  BlurAccumulator blur(options.exposures);
  const double c_min = std::min(options.simulator.contrast_pos, options.simulator.contrast_neg);
  const double limit = adaptive.lambda * c_min;
  EventStore events(source.sensor());
  std::vector<Frame> blurry;
  const auto feed = [&](const cv::Mat& image, int64_t t) {
    events.clear();
    blurry.clear();
    sim.addFrame(toSensorIntensity(image, options.bayer_rggb), t, events);
    for (auto& [e, img] : blur.addFrame(image, t)) {
      Frame b;
      b.image = img;
      b.exposure_start_us = e.start_us;
      b.exposure_end_us = e.end_us;
      b.bit_depth = 16;
      blurry.push_back(std::move(b));
    }
    sink(events, blurry);
  };
  cv::Mat current = source.render(t_begin_us);
  feed(current, t_begin_us);
  cv::Mat log_current;
  const auto toLogImage = [&](const cv::Mat& img) {
    cv::Mat grey = toSensorIntensity(img, options.bayer_rggb), out(grey.size(), CV_32F);
    for (int y = 0; y < grey.rows; ++y) {
      for (int x = 0; x < grey.cols; ++x)
        out.at<float>(y, x) = options.simulator.log.toLog(std::max(grey.at<float>(y, x), 0.0f));
    }
    return out;
  };
  log_current = toLogImage(current);
  int64_t t = t_begin_us;
  int64_t step = adaptive.max_step_us;
  while (t < t_end_us) {
    step = std::clamp<int64_t>(step, adaptive.min_step_us,
                               std::max<int64_t>(adaptive.min_step_us, t_end_us - t));
    int64_t t_next = std::min(t + step, t_end_us);
    const auto required = std::upper_bound(adaptive.sample_at.begin(), adaptive.sample_at.end(), t);
    if (required != adaptive.sample_at.end()) t_next = std::min(t_next, *required);
    const cv::Mat candidate = source.render(t_next);
    const cv::Mat log_candidate = toLogImage(candidate);
    double max_change;
    cv::minMaxLoc(cv::abs(log_candidate - log_current), nullptr, &max_change);
    if (max_change > limit && step > adaptive.min_step_us) {
      step = std::max(adaptive.min_step_us, step / 2);  // overshoot: refine
      continue;
    }
    feed(candidate, t_next);
    log_current = log_candidate;
    // Next step from the observed rate, at most doubling.
    const double rate = max_change / static_cast<double>(t_next - t);
    t = t_next;
    // In double until clamped: limit / rate overflows int64 when the scene barely changes.
    const double ideal = rate > 0 ? limit / rate : static_cast<double>(adaptive.max_step_us);
    step = static_cast<int64_t>(std::clamp(std::min(ideal, 2.0 * static_cast<double>(step)),
                                           static_cast<double>(adaptive.min_step_us),
                                           static_cast<double>(adaptive.max_step_us)));
  }
  return sim.stats();
}

}  // namespace evkit
