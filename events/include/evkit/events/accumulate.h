// Event representations: images built from a window of events.
//
// All take an EventSpan (slice it first with sliceTime or the window helpers below) and return
// float32 images of the sensor size (rows = height). Events outside the sensor are ignored.
#pragma once

#include <cstdint>
#include <opencv2/core.hpp>
#include <utility>
#include <vector>

#include "evkit/events/event_store.h"

namespace evkit {

// Σ p·C per pixel, with C = c_on for ON and c_off for OFF events (both 1: the signed count).
cv::Mat accumulateSigned(const EventSpan& events, float c_on = 1.0f, float c_off = 1.0f);

struct PolarityCounts {
  cv::Mat on;   // number of ON events per pixel
  cv::Mat off;  // number of OFF events per pixel
};
PolarityCounts accumulateCounts(const EventSpan& events);

// BeNeRF's event image: the signed count divided by its L2 norm over the whole image. An empty
// window (or one whose events cancel everywhere) gives zeros, never NaN.
cv::Mat accumulateNormalized(const EventSpan& events);

// Exponentially decaying time surface per polarity: exp(-(t_ref - t_last(x, y)) / tau) where
// t_last is the pixel's latest event at or before t_ref; 0 where the pixel has no event.
struct TimeSurface {
  cv::Mat on;
  cv::Mat off;
};
TimeSurface timeSurface(const EventSpan& events, int64_t t_ref_us, double tau_us);

// Voxel grid with B temporal bins over [t0, t1], as in E2VID (Rebecq et al., TPAMI 2019): an event
// at time t sits at t* = (B - 1)(t - t0)/(t1 - t0) and adds p·max(0, 1 - |b - t*|) to bin b, i.e.
// it is split bilinearly between the two nearest bins; the first event time maps to bin 0 and t1 to
// bin B - 1. With t1 == t0 every event falls in bin 0.
std::vector<cv::Mat> voxelGrid(const EventSpan& events, int bins, int64_t t0_us, int64_t t1_us);

// Windows as index ranges [begin, end) into `events`.
// Consecutive windows of `duration_us` starting at the first event.
std::vector<std::pair<size_t, size_t>> windowsByTime(const EventSpan& events, int64_t duration_us);
// Consecutive windows of `count` events (the last may hold fewer).
std::vector<std::pair<size_t, size_t>> windowsByCount(const EventSpan& events, size_t count);

// Renderings for people (8-bit BGR).
// ON events red, OFF events blue, on white; colour saturates at `saturation` events per pixel.
cv::Mat renderPolarity(const cv::Mat& signed_frame, float saturation = 0);  // 0: from the data
cv::Mat renderPolarity(const PolarityCounts& counts, float saturation = 0);
// A non-negative float image through the viridis colour map, scaled from its minimum to maximum.
// (Signed data such as voxel bins read better with renderPolarity.)
cv::Mat renderColormap(const cv::Mat& values);

}  // namespace evkit
