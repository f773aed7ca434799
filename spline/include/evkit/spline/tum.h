// Trajectories as text in the TUM RGB-D format: one pose per line, "t tx ty tz qx qy qz qw", t in
// seconds (read and written exactly to the µs), T_world_cam, '#' comment lines.
#pragma once

#include <string>
#include <vector>

#include "evkit/spline/fit.h"

namespace evkit {

// Throws evkit::Error naming the file and line of the first malformed line (wrong field count, not
// a number, a quaternion far from unit norm, time going back).
std::vector<StampedPose> readTum(const std::string& path);
// Written to a temporary name, then renamed.
void writeTum(const std::string& path, const std::vector<StampedPose>& poses);
// Samples a trajectory at the given times.
std::vector<StampedPose> sampleTrajectory(const Trajectory& trajectory,
                                          const std::vector<int64_t>& times_us);

}  // namespace evkit
