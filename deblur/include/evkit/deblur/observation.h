// The input of every deblurring method: one blurry frame, its exposure, the events, the camera
// (the observation folder of DESIGN.md §6), and the ground truth when there is some.
#pragma once

#include <cmath>
#include <optional>
#include <string>
#include <vector>

#include "evkit/events/calibration.h"
#include "evkit/events/event_store.h"
#include "evkit/events/frame.h"
#include "evkit/spline/fit.h"

namespace evkit {

// The camera's contrast thresholds, in log intensity: an ON event per rise of `on`, an OFF event
// per fall of `off`.
struct Contrast {
  double on = 0, off = 0;
};

struct Observation {
  Frame blurry;  // image + exposure_start_us / exposure_end_us + bit depth
  EventStore events;
  Calibration camera;
  // No calibration was given (no calib.txt, a recording without one): camera is
  // Calibration::assumed, which a method may refine from the data.
  bool camera_assumed = false;
  std::optional<Contrast> contrast;  // when known (contrast.txt)
  // Ground truth (synthetic data): sharp frames (their exposure_start_us is their time) and poses.
  std::vector<Frame> gt_frames;
  std::vector<StampedPose> gt_poses;
  double gt_blur_px = std::nan("");  // the longest image path of a point (gt/info.txt's blur_px)
  // Each pixel's depth (z, scene units) at mid-exposure, CV_32F at the frame's size (gt/depth.npy;
  // empty when absent). Not finite or not positive: nothing there (the background at infinity).
  cv::Mat gt_depth;
  std::string source;  // where it came from, for reports
};

// Reads an observation folder: blurry.png, exposure.txt, events.{h5,txt,aedat4,...}, optional
// calib.txt (else the camera is assumed), optional contrast.txt and gt/. Throws evkit::Error naming
// the missing or bad file.
Observation loadObservation(const std::string& dir);

// Writes one (for `evkit deblur --recording ... --extract DIR`), atomically.
void saveObservation(const Observation& obs, const std::string& dir);

// Frame `index` of a recording with frames, with the events of its exposure widened by margin_us
// on both sides. Camera: the recording's calibration, else fx = fy = 0.9 width at the centre.
Observation observationFromRecording(const std::string& path, size_t index, int64_t margin_us = 0);

}  // namespace evkit
