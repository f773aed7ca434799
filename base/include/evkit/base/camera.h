// The pinhole camera every module shares: intrinsics as calibration files store them (fx fy cx cy
// [k1 k2 p1 p2 [k3]], radial-tangential distortion in OpenCV's order) and the image size where it
// is known, with its projection both ways (the lens model's one home). events/ reads and writes it
// (calibration.h), nerf/ casts rays through it (camera.h: pixelDirection, projectPoint,
// worldRay), synth/ renders with it.
#pragma once

#include <array>
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

// Distorts normalised coordinates (x, y) with k1 k2 p1 p2 k3 (OpenCV's radial-tangential model;
// missing coefficients are 0).
inline std::array<double, 2> distortNormalised(const std::vector<double>& k, double x, double y) {
  const double k1 = k.size() > 0 ? k[0] : 0, k2 = k.size() > 1 ? k[1] : 0,
               p1 = k.size() > 2 ? k[2] : 0, p2 = k.size() > 3 ? k[3] : 0,
               k3 = k.size() > 4 ? k[4] : 0;
  const double r2 = x * x + y * y;
  const double radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3));
  return {x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
          y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y};
}

// Undistorted normalised coordinates (the camera-frame direction at z = 1) of pixel (u, v): the
// inverse of the distortion by fixed-point iteration.
inline std::array<double, 2> normalisedOfPixel(const PinholeCamera& camera, double u, double v) {
  const double xd = (u - camera.cx) / camera.fx, yd = (v - camera.cy) / camera.fy;
  if (camera.distortion.empty()) return {xd, yd};
  double x = xd, y = yd;
  for (int it = 0; it < 20; ++it) {
    const std::array<double, 2> d = distortNormalised(camera.distortion, x, y);
    x = xd - (d[0] - x);
    y = yd - (d[1] - y);
  }
  return {x, y};
}

// Pixel coordinates of undistorted normalised coordinates (x, y) = (X / Z, Y / Z).
inline std::array<double, 2> pixelOfNormalised(const PinholeCamera& camera, double x, double y) {
  if (!camera.distortion.empty()) {
    const std::array<double, 2> d = distortNormalised(camera.distortion, x, y);
    x = d[0];
    y = d[1];
  }
  return {camera.fx * x + camera.cx, camera.fy * y + camera.cy};
}

}  // namespace evkit
