// The pixel grid's geometry, shared by its problem (pixel_grid.cc) and its views
// (pixel_grid_views.cc): a canvas position's bilinear stencil, and where a view's pixel lands on
// the mid-exposure image through the registered inverse depth.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <opencv2/core.hpp>

#include "evkit/deblur/pixel_grid.h"
#include "evkit/nerf/volume_render.h"

namespace evkit::pixel_grid_detail {

// A canvas position as its bilinear stencil's top-left cell and offsets, clamped inside the canvas.
using Taps = CanvasTaps;

inline Taps tapsAt(double u, double v, int width, int height) {
  const double cu = std::clamp(u, 0.0, width - 1.001), cv = std::clamp(v, 0.0, height - 1.001);
  const int x0 = static_cast<int>(cu), y0 = static_cast<int>(cv);
  return {y0 * width + x0, static_cast<float>(cu - x0), static_cast<float>(cv - y0)};
}

// The channels of a canvas x (row-major, C channels interleaved, `width` cells a row) at a
// position, and the adjoint: d added to the position's four cells.
inline void sample(const double* x, int width, int C, const Taps& t, double* out) {
  const double* a = x + static_cast<size_t>(t.index) * C;
  const double* b = a + static_cast<size_t>(width) * C;
  const double w00 = (1 - t.ay) * (1 - t.ax), w01 = (1 - t.ay) * t.ax, w10 = t.ay * (1 - t.ax),
               w11 = t.ay * t.ax;
  for (int c = 0; c < C; ++c) out[c] = w00 * a[c] + w01 * a[C + c] + w10 * b[c] + w11 * b[C + c];
}

inline void sampleBackward(double* g, int width, int C, const Taps& t, const double* d) {
  double* a = g + static_cast<size_t>(t.index) * C;
  double* b = a + static_cast<size_t>(width) * C;
  const double w00 = (1 - t.ay) * (1 - t.ax), w01 = (1 - t.ay) * t.ax, w10 = t.ay * (1 - t.ax),
               w11 = t.ay * t.ax;
  for (int c = 0; c < C; ++c) {
    a[c] += w00 * d[c];
    a[C + c] += w01 * d[c];
    b[c] += w10 * d[c];
    b[C + c] += w11 * d[c];
  }
}

// The nearest of 0..size-1 to a coordinate (0 for NaN): std::lround's pixel, without its call.
inline int nearestIndex(double u, int size) {
  if (!(u > 0)) return 0;
  return u >= size - 1 ? size - 1 : static_cast<int>(u + 0.5);
}

// The inverse depth of the mid frame's pixel nearest (u, v) (0 without a map).
inline double inverseDepthAt(const PinholeCamera& camera, const cv::Mat& inverse_depth, double u,
                             double v) {
  if (inverse_depth.empty()) return 0.0;
  return inverse_depth.at<float>(nearestIndex(v, camera.height), nearestIndex(u, camera.width));
}

// Where pixel (x, y), ray direction R d in the mid-exposure camera (d its own), first lands in the
// camera at the pose (R, t): its point at the mid frame's inverse depth there. The nearest pixel
// to that landing gives the depth the sample is taken through (reproject).
inline Eigen::Vector2d firstLanding(const PinholeCamera& camera, const cv::Mat& inverse_depth,
                                    int x, int y, const Vector3& Rd, const Vector3& t) {
  return nerf::projectPoint(camera, Rd + inverseDepthAt(camera, inverse_depth, x, y) * t);
}

// Where that pixel is seen by the camera at (R, t): once more at the inverse depth where the first
// landing lies (the view and the mid frame see nearly the same point); rho_used: that depth.
inline Eigen::Vector2d reproject(const PinholeCamera& camera, const cv::Mat& inverse_depth, int x,
                                 int y, const Vector3& Rd, const Vector3& t, double* rho_used) {
  const Eigen::Vector2d q = firstLanding(camera, inverse_depth, x, y, Rd, t);
  const double rho = inverseDepthAt(camera, inverse_depth, q.x(), q.y());
  if (rho_used) *rho_used = rho;
  return nerf::projectPoint(camera, Rd + rho * t);
}

// How far (px) a view's sample moves on the mid image per unit of the inverse depth it is taken
// through, to first order (the pinhole's derivative along the epipolar line, dq / drho = f / z
// (t_xy - X_xy / z t_z) at X = Rd + rho t); -1 behind the camera.
// move: the derivative itself, where given.
inline double moveRate(const PinholeCamera& camera, const Vector3& Rd, const Vector3& t, double rho,
                       Eigen::Vector2d* move = nullptr) {
  const Vector3 X = Rd + rho * t;
  if (!(X.z() > 0)) return -1;
  const double iz = 1 / X.z();
  const double mx = camera.fx * iz * (t.x() - X.x() * iz * t.z()),
               my = camera.fy * iz * (t.y() - X.y() * iz * t.z());
  if (move) *move = {mx, my};
  return std::sqrt(mx * mx + my * my);
}

// How far (px) the inverse depth where a view's sample landed (reproject's q) would move it once
// more, from which the sample is taken as seen across a depth edge (PixelGridProblem::across_):
// half a pixel, the cells' own resolution (measured at 0.25 and 1 px too, on four natural scenes
// with occlusions, within 0.1 dB of it).
inline constexpr double kDepthEdgePx = 0.5;

// The widest parallax between the layers (px) over which a view's pixel looks for a nearer or a
// farther surface than its lookups found.
inline constexpr int kMostParallax = 48;

// Whether the view's sample at q, taken through inverse depth rho_used, is seen across a depth
// edge: the mid frame's inverse depth at q moves it more than kDepthEdgePx. The view then looks
// past an occluding edge at what the mid frame does not hold (a background that the near surface
// hides at mid-exposure), or at a surface whose depth the two lookups did not settle.
inline bool acrossDepthEdge(const PinholeCamera& camera, const cv::Mat& inverse_depth,
                            const Vector3& Rd, const Vector3& t, const Eigen::Vector2d& q,
                            double rho_used) {
  const double rho = inverseDepthAt(camera, inverse_depth, q.x(), q.y());
  if (rho == rho_used) return false;
  // The move to first order (moveRate), before the projection: under a quarter of kDepthEdgePx (a
  // margin for the lens's distortion and the curve) it is not across. On a smooth depth (a plane's)
  // neighbouring pixels' depths differ a little everywhere, and projecting every sample cost the
  // whole run 10%.
  const double rate = moveRate(camera, Rd, t, rho_used);
  if (rate >= 0 && std::abs(rho - rho_used) * rate < 0.25 * kDepthEdgePx) return false;
  return (nerf::projectPoint(camera, Rd + rho * t) - q).norm() > kDepthEdgePx;
}

}  // namespace evkit::pixel_grid_detail

namespace evkit {

// Inline: returned from a call, the stencil's three fields went back through the stack and stalled
// the store into taps_ (8% of a frame with a layer behind).
inline CanvasTaps PixelGridProblem::tapsOf(const Eigen::Vector2d& q, bool behind) const {
  if (!behind)
    return pixel_grid_detail::tapsAt(cellCoordinate(q.x()), cellCoordinate(q.y()), canvas_w_,
                                     canvas_h_);
  CanvasTaps t = pixel_grid_detail::tapsAt(q.x() + margin_, q.y() + margin_, behind_w_, behind_h_);
  t.index = -t.index - 1;
  return t;
}

// viewSample's first part: the two lookups and the depth-edge test (inline: the grid's taps on a
// scene without depth edges take this alone, 5% of a frame against the call).
inline PixelGridProblem::ViewSample PixelGridProblem::lookups(int x, int y, const Vector3& Rd,
                                                              const Vector3& t) const {
  ViewSample s;
  s.q = pixel_grid_detail::reproject(camera_, inverse_depth_, x, y, Rd, t, &s.rho);
  s.across = pixel_grid_detail::acrossDepthEdge(camera_, inverse_depth_, Rd, t, s.q, s.rho);
  return s;
}

}  // namespace evkit
