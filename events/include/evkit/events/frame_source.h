// Where simulated events come from: recorded frame sequences (an image folder with timestamps, a
// video file) and programmatic sources that render any requested time. Plus the drivers that feed
// them to the EventSimulator and the BlurAccumulator.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "evkit/events/event_store.h"
#include "evkit/events/frame.h"
#include "evkit/events/simulator.h"

namespace evkit {

// Frames in time order. Images are float32 linear [0,1], grey or colour (BGR).
class FrameSequence {
 public:
  virtual ~FrameSequence() = default;
  // The next frame; false at the end. Throws evkit::Error for a missing or unreadable frame.
  virtual bool next(Frame& frame, int64_t& t_us) = 0;
  // Time of frame i (known in advance: the timestamps file, or the video's frame rate).
  virtual int64_t timeOf(size_t i) const = 0;
  // Number of frames (for a video, the container's count, which may be approximate).
  virtual size_t sizeHint() const = 0;
  virtual SensorSize sensor() const = 0;
};

struct SequenceOptions {
  // Image folders: "timestamps.txt" holds "t_us path" lines; RPG's "images.txt" holds seconds.
  // Video: timestamps t0 + i / fps, fps from the file unless given.
  double fps = 0;
  int64_t start_us = 0;  // time of the first video frame
  bool srgb = false;  // decode sRGB-encoded input to linear (rendered PNGs and videos usually are)
};

// A folder (with timestamps.txt or images.txt), a timestamps file, or a video file (by extension:
// .mp4 .avi .mkv .mov .webm .mpg).
std::unique_ptr<FrameSequence> openFrameSequence(const std::string& path,
                                                 const SequenceOptions& options = {});

// Decodes sRGB (IEC 61966-2-1) to linear, elementwise.
cv::Mat srgbToLinear(const cv::Mat& image);

// A scene that renders its linear intensity at any time (for adaptive sampling).
class RenderSource {
 public:
  virtual ~RenderSource() = default;
  virtual SensorSize sensor() const = 0;
  virtual cv::Mat render(int64_t t_us) = 0;  // float32 linear, grey or colour
};

struct DriverOptions {
  SimulatorOptions simulator;
  bool bayer_rggb = false;
  // Blurry frames: explicit exposures, and/or one every `exposure_every` frames spanning
  // round(duty * exposure_every) frame intervals.
  std::vector<BlurAccumulator::Exposure> exposures;
  int exposure_every = 0;
  double duty = 0.5;
};

// Receives events (sorted, in time order across calls) and finished blurry frames.
using SimulationSink =
    std::function<void(const EventStore& events, const std::vector<Frame>& blurry)>;

SimulatorStats simulateSequence(FrameSequence& sequence, const DriverOptions& options,
                                const SimulationSink& sink);

struct AdaptiveOptions {
  // ESIM's rule: steps such that no pixel's log intensity changes by more than lambda C between
  // samples; a sample that overshoots is rejected and the step halved.
  double lambda = 0.5;
  int64_t min_step_us = 10;
  int64_t max_step_us = 10000;
  // Times that must be samples, sorted: a step that would pass one ends on it. The events
  // interpolate log intensity linearly between samples, so at a sample they agree with a frame
  // rendered at that time, and anywhere else they may lag it by up to a step (an edge that
  // crosses a pixel between two samples fires across the whole step).
  std::vector<int64_t> sample_at;
};

SimulatorStats simulateAdaptive(RenderSource& source, int64_t t_begin_us, int64_t t_end_us,
                                const DriverOptions& options, const AdaptiveOptions& adaptive,
                                const SimulationSink& sink);

}  // namespace evkit
