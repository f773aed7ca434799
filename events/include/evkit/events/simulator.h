// An ESIM-like event simulator (Rebecq, Gehrig, Scaramuzza, "ESIM: an Open Event Camera Simulator",
// CoRL 2018), with the noise of v2e (Hu, Liu, Delbruck, CVPRW 2021).
//
// Model, per pixel: log intensity L = LogMapping(I) varies linearly in time between consecutive
// frames. The pixel keeps a reference level; at the end of every frame interval it has crossed
// n = floor(|L - ref| / C) levels (C = C+ upwards, C- downwards), each an event at the time the
// linear ramp reached ref ± k C (its own interpolated µs timestamp), and ref moves by n C. Counting
// from the reference, rather than stepping one level inside (L0, L1] as the original ESIM code
// does, keeps every pixel alive when the thresholds vary per pixel. Invariant (sigma = 0, no
// leak): |L_0 + sum p C - L| < C for every pixel after every frame.
//  - mismatch: per-pixel C+ and C- drawn once from N(C, sigma^2) (seeded, clamped at 0.01);
//  - refractory period: a crossing within refractory_us of the pixel's last event is not emitted
//    (the reference still moves, so the pixel does not burst afterwards);
//  - leak: the reference sinks by leak_rate_hz * C+ per second, so a still pixel emits ON events at
//    leak_rate_hz on average (per-pixel phase random);
//  - shot noise: extra events of random polarity, a Poisson process of shot_noise_rate_hz per
//    pixel, that do not touch the reference.
// Output is sorted by time (a stable counting sort on the µs offsets within each interval) and is
// identical for a seed whatever the number of threads.
#pragma once

#include <cstdint>
#include <opencv2/core.hpp>
#include <vector>

#include "evkit/events/event_store.h"
#include "evkit/events/log_intensity.h"

namespace evkit {

struct SimulatorOptions {
  double contrast_pos = 0.2;  // C+, log units
  double contrast_neg = 0.2;  // C-
  double sigma = 0.0;         // per-pixel threshold mismatch (std. dev., log units)
  int64_t refractory_us = 0;
  double shot_noise_rate_hz = 0.0;  // per pixel
  double leak_rate_hz = 0.0;        // per pixel
  LogMapping log;
  uint64_t seed = 1;
  // A frame interval in which more than this fraction of pixels changes by more than C (so that
  // linear interpolation may miss events) counts as under-sampled.
  double undersampling_fraction = 0.01;
};

struct SimulatorStats {
  int64_t frames = 0;
  int64_t events = 0;
  int64_t noise_events = 0;
  int64_t refractory_dropped = 0;
  double max_fraction_over_c = 0;  // worst interval: fraction of pixels with |dL| > C
  int64_t undersampled_intervals = 0;
};

class EventSimulator {
 public:
  EventSimulator(SensorSize sensor, const SimulatorOptions& options);

  // Feeds the next frame (float32 grey, linear [0,1], sensor size) at time t_us (after the previous
  // one). The first frame sets the reference levels; later ones append the events of
  // (t_previous, t_us] to `out`, sorted.
  void addFrame(const cv::Mat& grey, int64_t t_us, EventStore& out);

  // Fraction of pixels whose log intensity changed by more than C in the last interval.
  double lastFractionOverC() const { return last_fraction_over_c_; }
  const SimulatorStats& stats() const { return stats_; }
  // Per-pixel state, for tests and diagnostics.
  const std::vector<float>& reference() const { return ref_; }
  const std::vector<float>& logIntensity() const { return log_prev_; }
  const std::vector<float>& thresholdsPos() const { return c_pos_; }
  const std::vector<float>& thresholdsNeg() const { return c_neg_; }
  bool initialized() const { return initialized_; }

 private:
  SensorSize sensor_;
  SimulatorOptions options_;
  bool initialized_ = false;
  int64_t t_prev_ = 0;
  std::vector<float> log_prev_, ref_, c_pos_, c_neg_;
  std::vector<int64_t> last_event_;
  std::vector<float> log_next_;
  std::vector<uint32_t> counts_;  // events per pixel in the current interval
  // Unsorted events of the current interval, then counting-sorted by time.
  std::vector<uint32_t> offsets_, pixel_of_;
  std::vector<int8_t> pol_;
  std::vector<uint32_t> bucket_, order_;
  std::vector<uint64_t> start_;
  double last_fraction_over_c_ = 0;
  SimulatorStats stats_;
};

// Linear intensity of a colour frame for a monochrome sensor: 0.299 R + 0.587 G + 0.114 B (ITU-R
// BT.601 weights, applied to linear values; BGR in memory). With bayer_rggb, each pixel instead
// sees the one channel of its colour filter (an RGGB mosaic, as colour DAVIS sensors).
cv::Mat toSensorIntensity(const cv::Mat& image, bool bayer_rggb = false);

// Blurry frames: the time-weighted mean of the linearly interpolated linear frames over each
// exposure [start, end], accumulated as frames arrive (any channel count).
class BlurAccumulator {
 public:
  struct Exposure {
    int64_t start_us, end_us;
  };
  explicit BlurAccumulator(std::vector<Exposure> exposures);
  // Feeds the next frame; returns the exposures that this frame completed, as finished frames.
  std::vector<std::pair<Exposure, cv::Mat>> addFrame(const cv::Mat& linear, int64_t t_us);
  size_t pending() const;

 private:
  std::vector<Exposure> exposures_;
  std::vector<cv::Mat> sums_;
  size_t next_done_ = 0;
  bool have_prev_ = false;
  int64_t t_prev_ = 0;
  cv::Mat prev_;
};

}  // namespace evkit
