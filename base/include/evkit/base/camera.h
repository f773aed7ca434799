// The pinhole camera every module shares: intrinsics as calibration files store them (fx fy cx cy
// [k1 k2 p1 p2 [k3]], radial-tangential distortion in OpenCV's order) and the image size where it
// is known. events/ reads and writes it (calibration.h), nerf/ casts rays through it (camera.h:
// pixelDirection, projectPoint, worldRay), synth/ renders with it.
#pragma once

#include <vector>

namespace evkit {

struct PinholeCamera {
  double fx = 0, fy = 0, cx = 0, cy = 0;
  std::vector<double> distortion;  // empty, or k1 k2 p1 p2 [k3]
  int width = 0, height = 0;       // pixels; 0 where unknown (a calibration file does not say)

  PinholeCamera withSize(int w, int h) const {
    PinholeCamera c = *this;
    c.width = w;
    c.height = h;
    return c;
  }

  // The camera assumed where none is given: fx = fy = 0.9 width, the principal point at the
  // image's centre, no distortion (size left unknown, as a calibration file leaves it).
  static PinholeCamera assumed(int w, int h) {
    return PinholeCamera{0.9 * w, 0.9 * w, (w - 1) / 2.0, (h - 1) / 2.0, {}};
  }
};

}  // namespace evkit
