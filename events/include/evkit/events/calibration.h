// Calibration files (RPG calib.txt, the observation folder's calib.txt): one line
// fx fy cx cy [k1 k2 p1 p2 [k3]] (radial-tangential distortion, OpenCV's order), read into the
// shared camera type (its size left unknown).
#pragma once

#include <string>

#include "evkit/base/camera.h"

namespace evkit {

using Calibration = PinholeCamera;

// Reads one line "fx fy cx cy [k1 k2 p1 p2 [k3]]"; throws evkit::Error naming the file and line.
Calibration readCalibration(const std::string& path);
void writeCalibration(const std::string& path, const Calibration& calib);

}  // namespace evkit
