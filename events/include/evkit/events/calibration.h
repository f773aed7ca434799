// Pinhole intrinsics as calibration files store them (RPG calib.txt, the observation folder's
// calib.txt): fx fy cx cy [k1 k2 p1 p2 [k3]] (radial-tangential distortion, OpenCV's order).
#pragma once

#include <string>
#include <vector>

namespace evkit {

struct Calibration {
  double fx = 0, fy = 0, cx = 0, cy = 0;
  std::vector<double> distortion;  // empty, or k1 k2 p1 p2 [k3]
};

// Reads one line "fx fy cx cy [k1 k2 p1 p2 [k3]]"; throws evkit::Error naming the file and line.
Calibration readCalibration(const std::string& path);
void writeCalibration(const std::string& path, const Calibration& calib);

}  // namespace evkit
