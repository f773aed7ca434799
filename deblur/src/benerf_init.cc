// BeNeRF's start: the blur length and the thresholds measured through EDI, the number of virtual
// views, and the camera's rotation over the exposure from the events alone.

#include <algorithm>
#include <cmath>
#include <numbers>
#include <opencv2/imgproc.hpp>

#include "benerf_common.h"
#include "evkit/deblur/benerf.h"
#include "evkit/deblur/edi.h"
#include "evkit/deblur/metrics.h"

namespace evkit {

double measureBlurLength(const Observation& obs) { return measureBlur(obs, obs.contrast).blur_px; }

BlurMeasurement measureBlur(const Observation& obs, const std::optional<Contrast>& contrast,
                            const LogMapping& log) {
  EdiOptions edi_options;
  edi_options.use_observation_contrast = false;
  edi_options.contrast = contrast;
  EdiDeblurrer edi{edi_options};
  DeblurRequest request;
  request.times_us = {obs.blurry.midExposure()};
  const DeblurResult r = edi.run(obs, request);
  BlurMeasurement m;
  m.c_on = r.parameters.at("contrast_on");
  m.c_off = r.parameters.at("contrast_off");
  m.searched = r.parameters.at("contrast_searched") != 0;
  const double margin = 0.01 * (edi_options.search_max - edi_options.search_min);
  m.inside = m.searched && m.c_on > edi_options.search_min + margin &&
             m.c_on < edi_options.search_max - margin;
  const cv::Mat L = benerf_detail::logGrey(r.frames.front().image, log);  // frames are float32
  double gradient = 0;
  for (int y = 1; y + 1 < L.rows; ++y) {
    for (int x = 1; x + 1 < L.cols; ++x) {
      const double gx = 0.5 * (L.at<float>(y, x + 1) - L.at<float>(y, x - 1)),
                   gy = 0.5 * (L.at<float>(y + 1, x) - L.at<float>(y - 1, x));
      gradient += std::hypot(gx, gy);
    }
  }
  const EventSpan ev =
      obs.events.sliceTime(obs.blurry.exposure_start_us, obs.blurry.exposure_end_us + 1);
  double variation = 0;
  for (size_t i = 0; i < ev.size(); ++i) variation += ev.p[i] > 0 ? m.c_on : m.c_off;
  m.blur_px = gradient > 0 ? variation / (2.0 / std::numbers::pi * gradient) : 0.0;
  return m;
}

int virtualViewsFor(double blur_px) {
  if (!std::isfinite(blur_px)) return 19;
  return std::clamp(static_cast<int>(std::ceil(blur_px / 2.0)) + 1, 5, 19);
}

namespace {

// The image of warped events for contrast maximisation: events as bearings (z = 1) and normalised
// times about mid-exposure, voted bilinearly at their warped pixel.
class WarpedEventImage {
 public:
  WarpedEventImage(const Observation& obs, const nerf::PinholeCamera& camera, size_t max_events)
      : camera_(camera) {
    const EventSpan ev =
        obs.events.sliceTime(obs.blurry.exposure_start_us, obs.blurry.exposure_end_us + 1);
    const double t_mid =
        0.5 * static_cast<double>(obs.blurry.exposure_start_us + obs.blurry.exposure_end_us);
    const double length = std::max<double>(
        1, static_cast<double>(obs.blurry.exposure_end_us - obs.blurry.exposure_start_us));
    const size_t stride = std::max<size_t>(1, ev.size() / std::max<size_t>(1, max_events));
    for (size_t i = 0; i < ev.size(); i += stride) {
      if (ev.x[i] >= camera.width || ev.y[i] >= camera.height) continue;
      bearings_.push_back(nerf::pixelDirection(camera, ev.x[i], ev.y[i]));
      tau_.push_back((static_cast<double>(ev.t[i]) - t_mid) / length);
    }
  }
  size_t size() const { return tau_.size(); }

  // Variance of the image of the events warped by exp(omega tau) (first order: b + tau omega x b),
  // smoothed by a Gaussian of sigma pixels.
  double contrast(const Vector3& omega, double sigma) {
    image_.create(camera_.height, camera_.width, CV_32F);
    image_.setTo(0);
    const int W = camera_.width, H = camera_.height;
    for (size_t i = 0; i < tau_.size(); ++i) {
      const Vector3& b = bearings_[i];
      const Vector3 d = b + tau_[i] * omega.cross(b);
      if (d.z() <= 0) continue;
      const double u = camera_.fx * d.x() / d.z() + camera_.cx,
                   v = camera_.fy * d.y() / d.z() + camera_.cy;
      if (!(u >= 0 && v >= 0 && u < W - 1 && v < H - 1)) continue;  // also NaN
      const int x0 = static_cast<int>(u), y0 = static_cast<int>(v);
      const float fx = static_cast<float>(u - x0), fy = static_cast<float>(v - y0);
      float* r0 = image_.ptr<float>(y0) + x0;
      float* r1 = image_.ptr<float>(y0 + 1) + x0;
      r0[0] += (1 - fx) * (1 - fy);
      r0[1] += fx * (1 - fy);
      r1[0] += (1 - fx) * fy;
      r1[1] += fx * fy;
    }
    cv::GaussianBlur(image_, image_, cv::Size(0, 0), sigma);
    cv::Scalar mean, deviation;
    cv::meanStdDev(image_, mean, deviation);
    return deviation[0] * deviation[0];
  }

 private:
  nerf::PinholeCamera camera_;
  std::vector<Vector3> bearings_;
  std::vector<double> tau_;
  cv::Mat image_;
};

}  // namespace

Vector3 rotationFromEvents(const Observation& obs, const nerf::PinholeCamera& camera,
                           double blur_px) {
  WarpedEventImage iwe(obs, camera, 200000);
  Vector3 omega = Vector3::Zero();
  if (iwe.size() < 100 || !(camera.fx > 0)) return omega;
  // Steps per axis: about the optical axis, the rotation that moves the image's edge as far as a
  // tilt moves its centre.
  const double radius = 0.5 * std::max(camera.width, camera.height);
  const Vector3 unit(1 / camera.fx, 1 / camera.fy, 1 / radius);
  const double first_px = std::clamp(std::isfinite(blur_px) ? blur_px : 0.0, 2.0, 0.25 * radius);
  // Start: the best of no rotation and tilts of the measured blur length in 8 directions (the
  // contrast has a single wide peak once near it), then a pattern search that halves its step,
  // first on a smoother image (a wider basin), then a sharper one.
  double best = iwe.contrast(omega, 3.0);
  for (int k = 0; k < 8; ++k) {
    const double a = k * std::numbers::pi / 4;
    const Vector3 candidate(first_px * std::cos(a) * unit.x(), first_px * std::sin(a) * unit.y(),
                            0);
    const double c = iwe.contrast(candidate, 3.0);
    if (c > best) best = c, omega = candidate;
  }
  for (const double sigma : {3.0, 1.0}) {
    best = iwe.contrast(omega, sigma);
    for (double step_px = 0.5 * first_px; step_px >= 0.05; step_px *= 0.5) {
      for (int round = 0, moved = 1; moved && round < 64; ++round) {
        moved = 0;
        for (int axis = 0; axis < 3; ++axis) {
          for (const double sign : {1.0, -1.0}) {
            Vector3 candidate = omega;
            candidate[axis] += sign * step_px * unit[axis];
            const double c = iwe.contrast(candidate, sigma);
            if (c > best) best = c, omega = candidate, moved = 1;
          }
        }
      }
    }
  }
  return omega;
}

}  // namespace evkit
