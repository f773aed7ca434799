#include "evkit/deblur/benerf.h"

#include <omp.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <numbers>
#include <sstream>

#include <opencv2/imgproc.hpp>

#include "evkit/deblur/edi.h"
#include "evkit/deblur/metrics.h"
#include "evkit/base/error.h"
#include "evkit/nerf/adam.h"
#include "evkit/nerf/train.h"

namespace evkit {

namespace {

double secondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

cv::Mat toFloat(const cv::Mat& image) {
  cv::Mat f;
  image.convertTo(f, CV_32F);
  return f;
}

nerf::PinholeCamera pinhole(const Calibration& c, int width, int height) {
  nerf::PinholeCamera camera;
  camera.width = width;
  camera.height = height;
  camera.fx = c.fx;
  camera.fy = c.fy;
  camera.cx = c.cx;
  camera.cy = c.cy;
  camera.distortion = c.distortion;
  return camera;
}

std::vector<SE3> initialKnots(int count, double spread, uint64_t seed) {
  std::mt19937_64 rng(seed ^ 0x6b6e6f7473ULL);
  std::uniform_real_distribution<double> u(-spread, spread);
  std::vector<SE3> knots;
  for (int k = 0; k < count; ++k) {
    Vector6 xi;
    for (int i = 0; i < 6; ++i) xi[i] = u(rng);
    knots.push_back(expSE3(xi));
  }
  return knots;
}

// The hash grid's level scale so that the finest level has `finest` cells across [0, 1].
nerf::HashFieldConfig adaptedHash(nerf::HashFieldConfig c, int finest) {
  if (c.grid.levels > 1 && finest > c.grid.base_resolution) {
    c.grid.per_level_scale = std::pow(static_cast<double>(finest) / c.grid.base_resolution, 1.0 / (c.grid.levels - 1));
  }
  return c;
}

// The samples of one ray in the field's precision: NDC positions into columns [col, col + S) of
// `positions`, interval lengths (t_{j+1} - t_j) |d| (t_S = 1), stratified t from the jitter.
template <typename T>
void sampleRayInto(const nerf::NdcRay& ray, int S, const float* jitter, double depth_scale,
                   Eigen::Matrix<T, Eigen::Dynamic, Eigen::Dynamic>& positions, Eigen::Index col, T* t, T* delta) {
  const double length = ray.direction.norm();
  for (int j = 0; j < S; ++j) t[j] = (static_cast<T>(j) + static_cast<T>(jitter[j])) / static_cast<T>(S);
  for (int j = 0; j < S; ++j) {
    delta[j] = ((j + 1 < S ? t[j + 1] : T(1)) - t[j]) * static_cast<T>(length);
    const double tj = static_cast<double>(t[j]);
    positions(0, col + j) = static_cast<T>(ray.origin.x() + tj * ray.direction.x());
    positions(1, col + j) = static_cast<T>(ray.origin.y() + tj * ray.direction.y());
    positions(2, col + j) = static_cast<T>(depth_scale * (ray.origin.z() + tj * ray.direction.z()));
  }
}

}  // namespace

BenerfOptions benerfBudget(const std::string& name) {
  BenerfOptions o;
  if (name == "fast") {
    o.iterations = 1000;
    o.blur_rays = 2048;
    o.event_rays = 2048;
    o.samples = 8;
    o.hash.grid.levels = 8;
    o.hash.grid.log2_table = 15;
  } else if (name == "balanced") {  // twice fast's steps and table (32 samples, 1,024 + 2 x 1,024 rays until session 8)
    o.iterations = 2000;
    o.blur_rays = 2048;
    o.event_rays = 2048;
    o.samples = 8;
    o.hash.grid.levels = 8;
    o.hash.grid.log2_table = 16;
  } else if (name == "quality") {  // twice balanced's steps and table (6,000 iterations, 48 samples, 12 levels until session 9)
    o.iterations = 4000;
    o.blur_rays = 2048;
    o.event_rays = 2048;
    o.samples = 8;
    o.hash.grid.levels = 8;
    o.hash.grid.log2_table = 17;
  } else {
    throw Error("benerf: unknown budget '" + name + "' (known: fast, balanced, quality, or seconds)");
  }
  return o;
}

double measureBlurLength(const Observation& obs) { return measureBlur(obs, obs.contrast).blur_px; }

BlurMeasurement measureBlur(const Observation& obs, const std::optional<std::pair<double, double>>& contrast) {
  EdiOptions edi_options;
  edi_options.use_observation_contrast = false;
  if (contrast) {
    edi_options.contrast_on = contrast->first;
    edi_options.contrast_off = contrast->second;
  }
  EdiDeblurrer edi{edi_options};
  DeblurRequest request;
  request.times_us = {obs.blurry.midExposure()};
  const DeblurResult r = edi.run(obs, request);
  BlurMeasurement m;
  m.c_on = r.parameters.at("contrast_on");
  m.c_off = r.parameters.at("contrast_off");
  m.searched = r.parameters.at("contrast_searched") != 0;
  const double margin = 0.01 * (edi_options.search_max - edi_options.search_min);
  m.inside = m.searched && m.c_on > edi_options.search_min + margin && m.c_on < edi_options.search_max - margin;
  const cv::Mat grey = toGrey(r.frames.front().image);  // frames are float32
  const LogMapping log;
  cv::Mat L(grey.size(), CV_32F);
  for (int y = 0; y < grey.rows; ++y) {
    for (int x = 0; x < grey.cols; ++x) L.at<float>(y, x) = log.toLog(std::max(grey.at<float>(y, x), 0.0f));
  }
  double gradient = 0;
  for (int y = 1; y + 1 < L.rows; ++y) {
    for (int x = 1; x + 1 < L.cols; ++x) {
      const double gx = 0.5 * (L.at<float>(y, x + 1) - L.at<float>(y, x - 1)), gy = 0.5 * (L.at<float>(y + 1, x) - L.at<float>(y - 1, x));
      gradient += std::hypot(gx, gy);
    }
  }
  const EventSpan ev = obs.events.sliceTime(obs.blurry.exposure_start_us, obs.blurry.exposure_end_us + 1);
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
  WarpedEventImage(const Observation& obs, const nerf::PinholeCamera& camera, size_t max_events) : camera_(camera) {
    const EventSpan ev = obs.events.sliceTime(obs.blurry.exposure_start_us, obs.blurry.exposure_end_us + 1);
    const double t_mid = 0.5 * static_cast<double>(obs.blurry.exposure_start_us + obs.blurry.exposure_end_us);
    const double length = std::max<double>(1, static_cast<double>(obs.blurry.exposure_end_us - obs.blurry.exposure_start_us));
    const size_t stride = std::max<size_t>(1, ev.size() / std::max<size_t>(1, max_events));
    for (size_t i = 0; i < ev.size(); i += stride) {
      if (ev.x[i] >= camera.width || ev.y[i] >= camera.height) continue;
      bearings_.push_back(camera.direction(ev.x[i], ev.y[i]));
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
      const double u = camera_.fx * d.x() / d.z() + camera_.cx, v = camera_.fy * d.y() / d.z() + camera_.cy;
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

Vector3 rotationFromEvents(const Observation& obs, const nerf::PinholeCamera& camera, double blur_px) {
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
    const Vector3 candidate(first_px * std::cos(a) * unit.x(), first_px * std::sin(a) * unit.y(), 0);
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

// ---------------------------------------------------------------------------------------------
// The problem

template <typename T>
BenerfProblem<T>::BenerfProblem(const Observation& obs, const BenerfOptions& options, int virtual_views)
    : options_(options),
      camera_(pinhole(obs.camera, obs.blurry.image.cols, obs.blurry.image.rows)),
      channels_(obs.blurry.image.channels()),
      views_(virtual_views),
      blurry_(toFloat(obs.blurry.image)),
      trajectory_(options.trajectory, obs.blurry.exposure_start_us, obs.blurry.exposure_end_us,
                  initialKnots(std::max(options.knots, Trajectory::minimumKnots(options.trajectory)), options.knot_init, options.seed)) {
  if (channels_ != 1 && channels_ != 3) throw Error("benerf: the blurry frame must be grey or colour, not " + std::to_string(channels_) + " channels");
  if (views_ < 1) throw Error("benerf: need at least one virtual view");
  if (options.field == "hash") {
    const int finest = options.finest_resolution > 0 ? options.finest_resolution : std::max(camera_.width, camera_.height);
    field_ = nerf::makeHashField<T>(adaptedHash(options.hash, finest), channels_, options.seed);
  } else if (options.field == "mlp") {
    field_ = nerf::makeMlpField<T>(options.mlp, channels_, options.seed);
  } else {
    throw Error("benerf: unknown field '" + options.field + "' (known: hash, mlp)");
  }
  if (const auto& thresholds = options.contrast ? options.contrast : obs.contrast) {
    c_on_ = thresholds->first;
    c_off_ = thresholds->second;
    known_contrast_ = true;
  }
  normalised_ = !known_contrast_ || options.event_form == BenerfOptions::EventForm::kNormalised;
  // The presets are the paper's β at its 1,024 event pixels per step. The normalised term is a mean
  // over the batch of the squared differences of two unit vectors, so it shrinks as 1 / pixels:
  // its β grows with them to keep the same weight (the direct term is a plain mean and does not).
  beta_ = options.beta >= 0 ? options.beta : (normalised_ ? 2.0 * std::max(1, options.event_rays) / 1024.0 : 0.1);
  // The blur term is in linear intensity and the event term in log intensity, so their balance
  // shifts with the frame's brightness m as m^2: below options.dim_frame the blur term is weighed as
  // if the frame were that bright.
  const cv::Scalar mean = cv::mean(blurry_);
  double brightness = 0;
  for (int c = 0; c < channels_; ++c) brightness += mean[c] / channels_;
  blur_weight_ = brightness < options.dim_frame ? std::pow(options.dim_frame / std::max(brightness, 1e-3), 2) : 1.0;
  // Events of the exposure grouped by pixel (a counting sort keeps each pixel's time order).
  const EventSpan ev = obs.events.sliceTime(obs.blurry.exposure_start_us, obs.blurry.exposure_end_us + 1);
  const int W = camera_.width, H = camera_.height;
  event_first_.assign(static_cast<size_t>(W) * H + 1, 0);
  size_t kept = 0;
  for (size_t i = 0; i < ev.size(); ++i) {
    if (ev.x[i] < W && ev.y[i] < H) {
      ++event_first_[static_cast<size_t>(ev.y[i]) * W + ev.x[i] + 1];
      ++kept;
    }
  }
  for (size_t p = 1; p < event_first_.size(); ++p) event_first_[p] += event_first_[p - 1];
  event_t_.resize(kept);
  event_level_.resize(kept);
  std::vector<uint32_t> fill(event_first_.begin(), event_first_.end() - 1);
  std::vector<double> level(static_cast<size_t>(W) * H, 0.0);
  for (size_t i = 0; i < ev.size(); ++i) {
    if (ev.x[i] >= W || ev.y[i] >= H) continue;
    const size_t p = static_cast<size_t>(ev.y[i]) * W + ev.x[i];
    level[p] += ev.p[i] > 0 ? (known_contrast_ ? c_on_ : 1.0) : -(known_contrast_ ? c_off_ : 1.0);
    event_t_[fill[p]] = ev.t[i];
    event_level_[fill[p]] = level[p];
    ++fill[p];
  }
}

template <typename T>
double BenerfProblem<T>::accumulatedEvents(int pixel, int64_t t_begin, int64_t t_end) const {
  const auto first = event_t_.begin() + event_first_[static_cast<size_t>(pixel)];
  const auto last = event_t_.begin() + event_first_[static_cast<size_t>(pixel) + 1];
  // The level after the last event before t (0 before the first).
  const auto levelAt = [&](int64_t t) {
    const auto it = std::lower_bound(first, last, t);
    return it == first ? 0.0 : event_level_[static_cast<size_t>(it - event_t_.begin()) - 1];
  };
  return levelAt(t_end) - levelAt(t_begin);
}

template <typename T>
typename BenerfProblem<T>::Batch BenerfProblem<T>::sampleBatch(std::mt19937_64& rng) const {
  Batch b;
  const int pixels = camera_.width * camera_.height;
  std::uniform_int_distribution<int> pixel(0, pixels - 1);
  const int blur_pixels = std::max(1, options_.blur_rays / views_);
  for (int i = 0; i < blur_pixels; ++i) b.blur_pixels.push_back(pixel(rng));
  for (int i = 0; i < options_.event_rays; ++i) b.event_pixels.push_back(pixel(rng));
  const int64_t t0 = trajectory_.beginUs(), t1 = trajectory_.endUs();
  const int64_t length = std::max<int64_t>(1, static_cast<int64_t>(std::llround(options_.alpha * static_cast<double>(t1 - t0))));
  std::uniform_int_distribution<int64_t> begin(t0, std::max(t0, t1 - length));
  const int windows = std::min(std::max(1, options_.windows), options_.event_rays);  // none without event pixels
  for (int w = 0; w < windows; ++w) {
    b.window_begin.push_back(begin(rng));
    b.window_end.push_back(std::min(t1, b.window_begin.back() + length));
  }
  const size_t rays = b.blur_pixels.size() * static_cast<size_t>(views_) + 2 * b.event_pixels.size();
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  b.jitter.resize(rays * static_cast<size_t>(options_.samples));
  for (float& j : b.jitter) j = u(rng);
  return b;
}

template <typename T>
typename BenerfProblem<T>::Loss BenerfProblem<T>::evaluate(const Batch& batch, Eigen::VectorXd* knot_gradient) {
  using Matrix = typename nerf::RadianceField<T>::Matrix;
  const int C = channels_, S = options_.samples, V = views_;
  const int W = camera_.width;
  const int Pb = static_cast<int>(batch.blur_pixels.size()), Pe = static_cast<int>(batch.event_pixels.size());
  const int R = Pb * V + 2 * Pe;
  // Poses: the V virtual views, then the ends of each event window; event pixel i has window
  // i mod windows.
  const int windows = static_cast<int>(batch.window_begin.size());
  std::vector<double> s(static_cast<size_t>(V + 2 * windows));
  for (int k = 0; k < V; ++k) s[static_cast<size_t>(k)] = viewTime(k);
  for (int w = 0; w < windows; ++w) {
    s[static_cast<size_t>(V + 2 * w)] = trajectory_.normalizedTime(batch.window_begin[static_cast<size_t>(w)]);
    s[static_cast<size_t>(V + 2 * w + 1)] = trajectory_.normalizedTime(batch.window_end[static_cast<size_t>(w)]);
  }
  std::vector<SE3> poses(s.size());
  std::vector<KnotJacobians> jacobians(s.size());
  for (size_t k = 0; k < s.size(); ++k) poses[k] = trajectory_.evaluate(s[k], knot_gradient ? &jacobians[k] : nullptr);
  // Ray r: pixel and pose index.
  const auto rayPixel = [&](int r) {
    if (r < Pb * V) return batch.blur_pixels[static_cast<size_t>(r / V)];
    return batch.event_pixels[static_cast<size_t>((r - Pb * V) / 2)];
  };
  const auto rayPose = [&](int r) { return r < Pb * V ? r % V : V + 2 * (((r - Pb * V) / 2) % windows) + (r - Pb * V) % 2; };

  Matrix positions(3, static_cast<Eigen::Index>(R) * S);
  std::vector<T> ts(static_cast<size_t>(R) * S), delta(static_cast<size_t>(R) * S);
  std::vector<Eigen::Vector3d> directions(static_cast<size_t>(R));  // NDC d of each ray
#pragma omp parallel for schedule(static)
  for (int r = 0; r < R; ++r) {
    const int p = rayPixel(r);
    const nerf::NdcRay ray = nerf::toNdc(nerf::worldRay(camera_, poses[static_cast<size_t>(rayPose(r))], p % W, p / W), camera_, options_.near);
    directions[static_cast<size_t>(r)] = ray.direction;
    const size_t o = static_cast<size_t>(r) * S;
    sampleRayInto<T>(ray, S, &batch.jitter[o], options_.depth_scale, positions, static_cast<Eigen::Index>(o), &ts[o], &delta[o]);
  }
  if (knot_gradient) field_->zeroGradients();
  const Matrix out = field_->forward(positions);

  // Render every ray.
  const nerf::RenderSettings settings{};
  std::vector<nerf::RayRender<T>> renders(static_cast<size_t>(R));
  std::vector<T> sigma(static_cast<size_t>(R) * S), colours(static_cast<size_t>(R) * S * C);
#pragma omp parallel for schedule(static)
  for (int r = 0; r < R; ++r) {
    for (int j = 0; j < S; ++j) {
      const Eigen::Index col = static_cast<Eigen::Index>(r) * S + j;
      sigma[static_cast<size_t>(col)] = out(0, col);
      for (int c = 0; c < C; ++c) colours[static_cast<size_t>(col) * C + c] = out(1 + c, col);
    }
    const size_t o = static_cast<size_t>(r) * S;
    renders[static_cast<size_t>(r)] = nerf::renderRay(&sigma[o], &colours[o * C], &delta[o], static_cast<const T*>(nullptr), static_cast<size_t>(S), C, settings);
  }

  Loss loss;
  std::vector<T> d_colour(static_cast<size_t>(R) * 3, T(0));  // dL/d(rendered colour) per ray
  // Blur term: the mean of the V renders against the blurry pixel (or each render against its
  // view's target).
  for (int i = 0; i < Pb; ++i) {
    const int p = batch.blur_pixels[static_cast<size_t>(i)];
    if (!view_targets_.empty()) {
      for (int k = 0; k < V; ++k) {
        const float* b = view_targets_[static_cast<size_t>(k)].ptr<float>(p / W) + (p % W) * C;
        for (int c = 0; c < C; ++c) {
          const T e = renders[static_cast<size_t>(i * V + k)].colour[c] - static_cast<T>(b[c]);
          loss.blur += static_cast<double>(e * e) / (Pb * C * V);
          d_colour[static_cast<size_t>(i * V + k) * 3 + c] = static_cast<T>(2 * blur_weight_) * e / static_cast<T>(Pb * C * V);
        }
      }
      continue;
    }
    const float* b = blurry_.ptr<float>(p / W) + (p % W) * C;
    for (int c = 0; c < C; ++c) {
      T mean = 0;
      for (int k = 0; k < V; ++k) mean += renders[static_cast<size_t>(i * V + k)].colour[c];
      mean /= T(V);
      const T e = mean - static_cast<T>(b[c]);
      loss.blur += static_cast<double>(e * e) / (Pb * C);
      const T g = static_cast<T>(2 * blur_weight_) * e / static_cast<T>(Pb * C * V);
      for (int k = 0; k < V; ++k) d_colour[static_cast<size_t>(i * V + k) * 3 + c] = g;
    }
  }
  // Event term: accumulated events against the change of the log grey renders.
  if (Pe > 0) {
    std::vector<T> grey_a(static_cast<size_t>(Pe)), grey_b(static_cast<size_t>(Pe)), change(static_cast<size_t>(Pe));
    std::vector<double> target(static_cast<size_t>(Pe));
    double target_norm2 = 0;
    T change_norm2 = 0;
    for (int i = 0; i < Pe; ++i) {
      const size_t ra = static_cast<size_t>(Pb * V + 2 * i);
      grey_a[static_cast<size_t>(i)] = nerf::greyOf(renders[ra].colour, C);
      grey_b[static_cast<size_t>(i)] = nerf::greyOf(renders[ra + 1].colour, C);
      change[static_cast<size_t>(i)] = options_.log.logOf(grey_b[static_cast<size_t>(i)]) - options_.log.logOf(grey_a[static_cast<size_t>(i)]);
      target[static_cast<size_t>(i)] = accumulatedEvents(batch.event_pixels[static_cast<size_t>(i)], batch.window_begin[static_cast<size_t>(i % windows)],
                                                  batch.window_end[static_cast<size_t>(i % windows)]);
      target_norm2 += target[static_cast<size_t>(i)] * target[static_cast<size_t>(i)];
      change_norm2 += change[static_cast<size_t>(i)] * change[static_cast<size_t>(i)];
    }
    std::vector<T> d_change(static_cast<size_t>(Pe));
    // Normalised comparison unless the thresholds are known and normalisation is off; a window
    // without events compares directly with zero change.
    const bool normalise = target_norm2 > 0 && normalised_;
    if (normalise) {
      const T tiny = T(1e-6);
      const T norm = std::sqrt(change_norm2 + tiny * tiny);
      const double target_norm = std::sqrt(target_norm2);
      T dot = 0;
      std::vector<T> g(static_cast<size_t>(Pe));
      for (int i = 0; i < Pe; ++i) {
        const T e = change[static_cast<size_t>(i)] / norm - static_cast<T>(target[static_cast<size_t>(i)] / target_norm);
        loss.event += static_cast<double>(e * e) / Pe;
        g[static_cast<size_t>(i)] = T(2) * e / static_cast<T>(Pe);
        dot += change[static_cast<size_t>(i)] * g[static_cast<size_t>(i)];
      }
      for (int i = 0; i < Pe; ++i) {
        d_change[static_cast<size_t>(i)] = g[static_cast<size_t>(i)] / norm - change[static_cast<size_t>(i)] * dot / (norm * norm * norm);
      }
    } else {
      for (int i = 0; i < Pe; ++i) {
        const T e = change[static_cast<size_t>(i)] - static_cast<T>(target[static_cast<size_t>(i)]);
        loss.event += static_cast<double>(e * e) / Pe;
        d_change[static_cast<size_t>(i)] = T(2) * e / static_cast<T>(Pe);
      }
    }
    const T beta = static_cast<T>(beta_);
    for (int i = 0; i < Pe; ++i) {
      const size_t ra = static_cast<size_t>(Pb * V + 2 * i);
      const T d = beta * d_change[static_cast<size_t>(i)];
      nerf::greyBackward(-d * options_.log.logSlope(grey_a[static_cast<size_t>(i)]), C, &d_colour[ra * 3]);
      nerf::greyBackward(d * options_.log.logSlope(grey_b[static_cast<size_t>(i)]), C, &d_colour[(ra + 1) * 3]);
    }
  }
  loss.total = blur_weight_ * loss.blur + beta_ * loss.event;
  if (!knot_gradient) return loss;

  // Back through the renderer and the field.
  Matrix d_out(1 + C, static_cast<Eigen::Index>(R) * S);
  // dL/d|d| per ray: the interval lengths scale with the NDC direction's length, tau_j = sigma_j
  // (t_{j+1} - t_j) |d|, so dL/d|d| = sum_j dL/dsigma_j sigma_j / |d|.
  std::vector<double> d_length(static_cast<size_t>(R), 0.0);
#pragma omp parallel for schedule(static)
  for (int r = 0; r < R; ++r) {
    const size_t o = static_cast<size_t>(r) * S;
    std::vector<T> d_sigma(static_cast<size_t>(S)), d_colours(static_cast<size_t>(S) * C);
    nerf::renderRayBackward(&sigma[o], &colours[o * C], &delta[o], static_cast<size_t>(S), C, settings, renders[static_cast<size_t>(r)],
                            &d_colour[static_cast<size_t>(r) * 3], d_sigma.data(), d_colours.data());
    double dl = 0;
    for (int j = 0; j < S; ++j) dl += static_cast<double>(d_sigma[static_cast<size_t>(j)] * sigma[o + static_cast<size_t>(j)]);
    d_length[static_cast<size_t>(r)] = dl / directions[static_cast<size_t>(r)].norm();
    for (int j = 0; j < S; ++j) {
      d_out(0, static_cast<Eigen::Index>(o) + j) = d_sigma[static_cast<size_t>(j)];
      for (int c = 0; c < C; ++c) d_out(1 + c, static_cast<Eigen::Index>(o) + j) = d_colours[static_cast<size_t>(j) * C + c];
    }
  }
  const Matrix d_positions = field_->backward(d_out);

  // Sample positions -> poses: p(t) is affine in t for a fixed pixel, so is its pose Jacobian:
  // sum_j J(t_j)^T g_j = J(0)^T sum_j (1 - t_j) g_j + J(1)^T sum_j t_j g_j; and d = p(1) - p(0), so
  // the length term adds (J(1) - J(0))^T (d / |d|) dL/d|d|.
  const int threads = omp_get_max_threads();
  std::vector<std::vector<Vector6>> pose_gradient(static_cast<size_t>(threads), std::vector<Vector6>(poses.size(), Vector6::Zero()));
#pragma omp parallel for schedule(static)
  for (int r = 0; r < R; ++r) {
    Eigen::Vector3d g0 = Eigen::Vector3d::Zero(), g1 = Eigen::Vector3d::Zero();
    for (int j = 0; j < S; ++j) {
      Eigen::Vector3d g = d_positions.col(static_cast<Eigen::Index>(r) * S + j).template cast<double>();
      g.z() *= options_.depth_scale;  // the field saw depth_scale * z
      const double t = static_cast<double>(ts[static_cast<size_t>(r) * S + static_cast<size_t>(j)]);
      g0 += (1 - t) * g;
      g1 += t * g;
    }
    const Eigen::Vector3d& d = directions[static_cast<size_t>(r)];
    const Eigen::Vector3d g_length = d / d.norm() * d_length[static_cast<size_t>(r)];
    g0 -= g_length;
    g1 += g_length;
    if (g0.isZero(0) && g1.isZero(0)) continue;
    const int p = rayPixel(r), k = rayPose(r);
    const SE3& pose = poses[static_cast<size_t>(k)];
    pose_gradient[static_cast<size_t>(omp_get_thread_num())][static_cast<size_t>(k)] +=
        nerf::ndcPointPoseJacobian(camera_, pose, p % W, p / W, 0.0, options_.near).transpose() * g0 +
        nerf::ndcPointPoseJacobian(camera_, pose, p % W, p / W, 1.0, options_.near).transpose() * g1;
  }
  knot_gradient->setZero(6 * static_cast<Eigen::Index>(trajectory_.knots().size()));
  for (size_t k = 0; k < poses.size(); ++k) {
    Vector6 g = Vector6::Zero();
    for (const auto& per_thread : pose_gradient) g += per_thread[k];
    const KnotJacobians& J = jacobians[k];
    for (int i = 0; i < J.count; ++i) knot_gradient->segment<6>(6 * (J.first_knot + i)) += J.d_pose_d_knot[static_cast<size_t>(i)].transpose() * g;
  }
  return loss;
}

template <typename T>
void BenerfProblem<T>::setViewTargets(std::vector<cv::Mat> targets) {
  if (!targets.empty() && static_cast<int>(targets.size()) != views_) throw Error("benerf: one view target per virtual view");
  for (const cv::Mat& t : targets) {
    if (t.type() != CV_MAKETYPE(CV_32F, channels_) || t.size() != blurry_.size()) throw Error("benerf: a view target must be float32 like the blurry frame");
  }
  view_targets_ = std::move(targets);
}

template <typename T>
cv::Mat BenerfProblem<T>::render(int64_t t_us, cv::Mat* disparity) {
  return renderRows(t_us, disparity, camera_.height);
}

template <typename T>
double BenerfProblem<T>::renderSeconds() {
  const int rows = std::min(camera_.height, rowsPerRenderBatch());
  const auto start = std::chrono::steady_clock::now();
  renderRows(trajectory_.beginUs(), nullptr, rows);  // any pose costs the same
  return secondsSince(start) * camera_.height / rows;
}

template <typename T>
int BenerfProblem<T>::rowsPerRenderBatch() const {
  return std::max(1, 8192 / std::max(1, camera_.width));
}

template <typename T>
cv::Mat BenerfProblem<T>::renderRows(int64_t t_us, cv::Mat* disparity, int H) {
  using Matrix = typename nerf::RadianceField<T>::Matrix;
  const int C = channels_, S = options_.samples, W = camera_.width;
  const SE3 pose = trajectory_.poseAt(t_us);
  cv::Mat image(H, W, CV_MAKETYPE(CV_32F, C));
  if (disparity) disparity->create(H, W, CV_32F);
  const std::vector<float> centres(static_cast<size_t>(S), 0.5f);
  const nerf::RenderSettings settings{};
  const int rows_per_batch = rowsPerRenderBatch();
  for (int y0 = 0; y0 < H; y0 += rows_per_batch) {
    const int rows = std::min(rows_per_batch, H - y0), R = rows * W;
    Matrix positions(3, static_cast<Eigen::Index>(R) * S);
    std::vector<T> ts(static_cast<size_t>(R) * S), delta(static_cast<size_t>(R) * S);
#pragma omp parallel for schedule(static)
    for (int r = 0; r < R; ++r) {
      const nerf::NdcRay ray = nerf::toNdc(nerf::worldRay(camera_, pose, r % W, y0 + r / W), camera_, options_.near);
      const size_t o = static_cast<size_t>(r) * S;
      sampleRayInto<T>(ray, S, centres.data(), options_.depth_scale, positions, static_cast<Eigen::Index>(o), &ts[o], &delta[o]);
    }
    // The field in chunks: the MLP keeps every layer's activations, which for a whole batch of
    // rows would be gigabytes.
    Matrix out(1 + C, positions.cols());
    constexpr Eigen::Index kFieldChunk = 16384;
    for (Eigen::Index c0 = 0; c0 < positions.cols(); c0 += kFieldChunk) {
      const Eigen::Index count = std::min(kFieldChunk, positions.cols() - c0);
      out.middleCols(c0, count) = field_->forward(positions.middleCols(c0, count));
    }
#pragma omp parallel for schedule(static)
    for (int r = 0; r < R; ++r) {
      std::vector<T> sigma(static_cast<size_t>(S)), colours(static_cast<size_t>(S) * C);
      for (int j = 0; j < S; ++j) {
        const Eigen::Index col = static_cast<Eigen::Index>(r) * S + j;
        sigma[static_cast<size_t>(j)] = out(0, col);
        for (int c = 0; c < C; ++c) colours[static_cast<size_t>(j) * C + c] = out(1 + c, col);
      }
      const size_t o = static_cast<size_t>(r) * S;
      const nerf::RayRender<T> f = nerf::renderRay(sigma.data(), colours.data(), &delta[o], &ts[o], static_cast<size_t>(S), C, settings);
      const int y = y0 + r / W, x = r % W;
      for (int c = 0; c < C; ++c) image.ptr<float>(y)[x * C + c] = static_cast<float>(f.colour[c]);
      if (disparity) {
        // Expected NDC parameter, the background at t = 1 (infinity); NDC z = 2t - 1 = 1 - 2 near / z.
        const double t_mean = static_cast<double>(f.depth) + (1.0 - static_cast<double>(f.opacity));
        disparity->at<float>(y, x) = static_cast<float>(std::max(0.0, 1.0 - t_mean) / options_.near);
      }
    }
  }
  return image;
}

template class BenerfProblem<float>;
template class BenerfProblem<double>;

// ---------------------------------------------------------------------------------------------
// Training

namespace {

constexpr char kCheckpointMagic[8] = {'E', 'V', 'K', 'B', 'N', 'R', 'F', '1'};

struct Checkpoint {
  int iteration = 0;
  int iterations = 0;
  int views = 0;
};

void writeCheckpoint(const std::string& path, const Checkpoint& c, nerf::RadianceField<float>& field, const Trajectory& trajectory,
                     const nerf::Adam<float>& field_adam, const nerf::Adam<double>& knot_adam, const std::mt19937_64& rng) {
  const std::string tmp = path + ".partial";
  {
    std::ofstream out(tmp, std::ios::binary);
    if (!out) throw Error(path + ": cannot write the checkpoint");
    out.write(kCheckpointMagic, sizeof(kCheckpointMagic));
    out.write(reinterpret_cast<const char*>(&c), sizeof(c));
    for (const nerf::ParameterBlock<float>& b : field.parameters()) {
      const uint64_t n = b.size;
      out.write(reinterpret_cast<const char*>(&n), sizeof(n));
      out.write(reinterpret_cast<const char*>(b.values), static_cast<std::streamsize>(b.size * sizeof(float)));
    }
    for (const SE3& k : trajectory.knots()) {
      const double v[7] = {k.rotation().w(), k.rotation().x(), k.rotation().y(), k.rotation().z(), k.translation().x(), k.translation().y(), k.translation().z()};
      out.write(reinterpret_cast<const char*>(v), sizeof(v));
    }
    field_adam.save(out);
    knot_adam.save(out);
    std::ostringstream state;
    state << rng;
    const std::string text = state.str();
    const uint64_t n = text.size();
    out.write(reinterpret_cast<const char*>(&n), sizeof(n));
    out.write(text.data(), static_cast<std::streamsize>(n));
    if (!out) throw Error(path + ": cannot write the checkpoint");
  }
  std::filesystem::rename(tmp, path);
}

Checkpoint readCheckpoint(const std::string& path, nerf::RadianceField<float>& field, Trajectory& trajectory, nerf::Adam<float>& field_adam,
                          nerf::Adam<double>& knot_adam, std::mt19937_64& rng) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error(path + ": cannot open the checkpoint");
  char magic[8];
  in.read(magic, sizeof(magic));
  if (!in || !std::equal(magic, magic + 8, kCheckpointMagic)) throw Error(path + ": not an evkit BeNeRF checkpoint");
  Checkpoint c;
  in.read(reinterpret_cast<char*>(&c), sizeof(c));
  for (const nerf::ParameterBlock<float>& b : field.parameters()) {
    uint64_t n = 0;
    in.read(reinterpret_cast<char*>(&n), sizeof(n));
    if (!in || n != b.size) throw Error(path + ": the checkpoint's field does not match these settings (byte " + std::to_string(static_cast<long long>(in.tellg())) + ")");
    in.read(reinterpret_cast<char*>(b.values), static_cast<std::streamsize>(b.size * sizeof(float)));
  }
  for (SE3& k : trajectory.knots()) {
    double v[7];
    in.read(reinterpret_cast<char*>(v), sizeof(v));
    k = SE3(Quaternion(v[0], v[1], v[2], v[3]), Vector3(v[4], v[5], v[6]));
  }
  field_adam.restore(in);
  knot_adam.restore(in);
  uint64_t n = 0;
  in.read(reinterpret_cast<char*>(&n), sizeof(n));
  if (!in || n > 100000) throw Error(path + ": truncated checkpoint");
  std::string text(n, '\0');
  in.read(text.data(), static_cast<std::streamsize>(n));
  if (!in) throw Error(path + ": truncated checkpoint");
  std::istringstream state(text);
  state >> rng;
  return c;
}

// The ground-truth frame nearest to mid-exposure, when there is one at the camera's size.
const Frame* midGroundTruth(const Observation& obs) {
  const Frame* best = nullptr;
  const int64_t mid = obs.blurry.midExposure();
  for (const Frame& g : obs.gt_frames) {
    if (g.image.size() != obs.blurry.image.size() || g.image.channels() != obs.blurry.image.channels()) continue;
    if (!best || std::llabs(g.exposure_start_us - mid) < std::llabs(best->exposure_start_us - mid)) best = &g;
  }
  return best;
}

}  // namespace

DeblurResult BenerfDeblurrer::run(const Observation& obs, const DeblurRequest& request) {
  const auto start = std::chrono::steady_clock::now();
  DeblurResult result;
  BenerfOptions o = options_;
  const int saved_threads = omp_get_max_threads();
  if (o.threads > 0) omp_set_num_threads(o.threads);
  struct RestoreThreads {
    int n;
    ~RestoreThreads() { omp_set_num_threads(n); }
  } restore_threads{saved_threads};

  int views = o.virtual_views;
  double blur_px = 0;
  if (!o.contrast) o.contrast = obs.contrast;
  const bool estimate = !o.contrast && o.estimate_contrast && o.event_form == BenerfOptions::EventForm::kAuto;
  if (views <= 0 || o.init == BenerfOptions::Init::kEvents || estimate) {
    const BlurMeasurement m = measureBlur(obs, o.contrast);
    blur_px = m.blur_px;
    result.parameters["blur_px_measured"] = blur_px;
    if (estimate && m.inside) {
      o.contrast = std::make_pair(m.c_on, m.c_off);
      result.parameters["contrast_estimated"] = m.c_on;
    }
  }
  if (views <= 0) views = virtualViewsFor(blur_px);
  BenerfProblem<float> problem(obs, o, views);
  if (o.init == BenerfOptions::Init::kEvents) {
    // The knots fitted to a constant rotation through identity at mid-exposure, each then moved by
    // its random jitter.
    const Vector3 omega = rotationFromEvents(obs, problem.camera(), blur_px);
    Trajectory& trajectory = problem.trajectory();
    std::vector<StampedPose> poses;
    for (int k = 0; k <= 20; ++k) {
      const double s = k / 20.0;
      const int64_t t = trajectory.beginUs() + std::llround(s * static_cast<double>(trajectory.endUs() - trajectory.beginUs()));
      poses.push_back({t, SE3(expSO3((s - 0.5) * omega), Vector3::Zero())});
    }
    const Trajectory fitted = fitTrajectory(trajectory.kind(), static_cast<int>(trajectory.knots().size()), trajectory.beginUs(), trajectory.endUs(), poses);
    for (size_t k = 0; k < trajectory.knots().size(); ++k) trajectory.knots()[k] = fitted.knots()[k] * trajectory.knots()[k];
    result.parameters["initial_rotation_deg"] = omega.norm() * 180 / std::numbers::pi;
  }
  nerf::AdamOptions field_adam_options;
  field_adam_options.learning_rate = o.field_lr;
  nerf::Adam<float> field_adam(problem.field().parameters(), field_adam_options);
  const size_t knot_values = 6 * problem.trajectory().knots().size();
  Eigen::VectorXd knot_step = Eigen::VectorXd::Zero(static_cast<Eigen::Index>(knot_values)), knot_gradient = knot_step;
  nerf::AdamOptions knot_adam_options;
  knot_adam_options.learning_rate = o.knot_lr;
  knot_adam_options.epsilon = 1e-12;
  nerf::Adam<double> knot_adam({nerf::ParameterBlock<double>{knot_step.data(), knot_gradient.data(), knot_values, nullptr, 1}}, knot_adam_options);
  std::mt19937_64 rng(o.seed);

  int iterations = o.iterations;
  int first = 0;
  if (!o.resume.empty()) {
    const Checkpoint c = readCheckpoint(o.resume, problem.field(), problem.trajectory(), field_adam, knot_adam, rng);
    if (c.views != views) throw Error(o.resume + ": the checkpoint used " + std::to_string(c.views) + " virtual views, these settings " + std::to_string(views));
    first = c.iteration;
    iterations = std::max(iterations, c.iterations);
  }
  // One learning-rate schedule over the prefit's steps and the training's.
  const auto setSchedule = [&](int total) {
    field_adam.options().decay_rate = knot_adam.options().decay_rate = o.lr_final;
    field_adam.options().decay_steps = knot_adam.options().decay_steps = std::max(1, o.prefit + total);
  };
  setSchedule(iterations);
  // One step of both optimisers; a non-finite loss or gradient is a loud error naming the step.
  const auto trainStep = [&](const BenerfProblem<float>::Batch& batch, const char* step_name, int step) {
    const auto loss = problem.evaluate(batch, &knot_gradient);
    if (!std::isfinite(loss.total) || !knot_gradient.allFinite()) {
      throw Error("benerf: the loss or its gradient became " + std::string(std::isfinite(loss.total) ? "non-finite" : "NaN/Inf") + " at " +
                  step_name + " " + std::to_string(step) + " (blur term " + std::to_string(loss.blur) + ", event term " + std::to_string(loss.event) + ")");
    }
    field_adam.step();
    knot_step.setZero();
    knot_adam.step();
    problem.trajectory().applyKnotSteps(knot_step);
    return loss;
  };
  if (o.prefit > 0 && o.resume.empty()) {
    // The field and knots fitted to EDI's latent frames at the views' times (every band open, no
    // event term), with the training's optimisers, so that their moments carry over.
    const auto prefit_start = std::chrono::steady_clock::now();
    const Trajectory& trajectory = problem.trajectory();
    DeblurRequest edi_request;
    for (int k = 0; k < views; ++k) {
      edi_request.times_us.push_back(trajectory.beginUs() + std::llround(problem.viewTime(k) * static_cast<double>(trajectory.endUs() - trajectory.beginUs())));
    }
    std::vector<cv::Mat> targets;
    for (const Frame& f : EdiDeblurrer{EdiOptions{}}.run(obs, edi_request).frames) targets.push_back(toFloat(f.image));
    problem.setViewTargets(std::move(targets));
    std::mt19937_64 prefit_rng(o.seed + 1);
    for (int it = 0; it < o.prefit; ++it) {
      auto batch = problem.sampleBatch(prefit_rng);
      batch.event_pixels.clear();
      batch.window_begin.clear();
      batch.window_end.clear();
      const auto loss = trainStep(batch, "prefit iteration", it);
      if (it + 1 == o.prefit) result.parameters["prefit_final_term"] = loss.blur;
    }
    problem.setViewTargets({});
    result.timings_s["prefit"] = secondsSince(prefit_start);
  }
  result.timings_s["setup"] = secondsSince(start);

  const Frame* gt = midGroundTruth(obs);
  int psnr_every = gt ? std::max(1, iterations / 10) : 0;
  // The final renders: the requested frames, and the mid-exposure frame for the disparity unless
  // it is one of them.
  const int64_t mid = obs.blurry.midExposure();
  const bool mid_requested = std::find(request.times_us.begin(), request.times_us.end(), mid) != request.times_us.end();
  const int final_renders = static_cast<int>(request.times_us.size()) + (mid_requested ? 0 : 1);
  const auto train_start = std::chrono::steady_clock::now();
  double curve_seconds = 0;  // spent on the training-PSNR renders
  double loss_sum = 0, blur_sum = 0, event_sum = 0, last_blur = 0, last_event = 0;
  int loss_count = 0;
  const int bands = problem.field().bands();
  for (int it = first; it < iterations; ++it) {
    if (o.coarse_to_fine > 0) {
      const double opened = std::clamp(static_cast<double>(it) / (o.coarse_to_fine * iterations), 0.0, 1.0);
      problem.field().setBandLimit(1 + (bands - 2) * opened);
    }
    const auto loss = trainStep(problem.sampleBatch(rng), "iteration", it);
    loss_sum += loss.total;
    blur_sum += loss.blur;
    event_sum += loss.event;
    ++loss_count;
    const int done = it + 1;
    if (done % o.curve_every == 0 || done == iterations) {
      result.curve.emplace_back(done, loss_sum / loss_count);
      if (request.progress) request.progress(done, iterations, loss_sum / loss_count);
      last_blur = blur_sum / loss_count;
      last_event = event_sum / loss_count;
      loss_sum = blur_sum = event_sum = 0;
      loss_count = 0;
    }
    if (psnr_every > 0 && (done % psnr_every == 0 || done == iterations)) {
      const auto curve_start = std::chrono::steady_clock::now();
      result.curve_psnr.emplace_back(done, psnr(problem.render(mid), gt->image));
      curve_seconds += secondsSince(curve_start);
    }
    // A wall-time budget: after a few iterations, the count that fits with the renders still to
    // come (the schedule follows); the training-PSNR curve gets at most a quarter of what is left.
    if (o.budget_seconds > 0 && done == first + 20) {
      const double per_iteration = (secondsSince(train_start) - curve_seconds) / 20;
      const double render_seconds = problem.renderSeconds();
      double left = o.budget_seconds * 0.95 - secondsSince(start) - final_renders * render_seconds;
      int curve_renders = gt ? std::min(10, static_cast<int>(0.25 * std::max(0.0, left) / render_seconds)) : 0;
      left -= curve_renders * render_seconds;
      iterations = std::max(done + 1, static_cast<int>(left / per_iteration) + done);
      setSchedule(iterations);
      psnr_every = curve_renders > 0 ? std::max(1, iterations / curve_renders) : 0;
    }
    const bool stop = o.stop_after > 0 && done >= o.stop_after;
    if (!o.checkpoint.empty() && (done % o.checkpoint_every == 0 || done == iterations || stop)) {
      writeCheckpoint(o.checkpoint, Checkpoint{done, iterations, views}, problem.field(), problem.trajectory(), field_adam, knot_adam, rng);
    }
    if (stop) break;
  }
  result.timings_s["train"] = secondsSince(train_start);
  problem.field().setBandLimit(bands);

  const auto render_start = std::chrono::steady_clock::now();
  for (int64_t t : request.times_us) {
    Frame f;
    f.image = problem.render(t, t == mid ? &result.disparity : nullptr);
    f.exposure_start_us = f.exposure_end_us = t;
    f.bit_depth = obs.blurry.bit_depth;
    result.frames.push_back(std::move(f));
  }
  if (!mid_requested) problem.render(mid, &result.disparity);
  result.timings_s["render"] = secondsSince(render_start);
  std::vector<StampedPose> trajectory;
  const int64_t t0 = obs.blurry.exposure_start_us, t1 = obs.blurry.exposure_end_us;
  for (int k = 0; k <= 100; ++k) {
    const int64_t t = t0 + (t1 - t0) * k / 100;
    trajectory.push_back({t, problem.trajectory().poseAt(t)});
  }
  result.trajectory = std::move(trajectory);
  size_t parameters = 0;
  for (const auto& b : problem.field().parameters()) parameters += b.size;
  result.parameters["iterations"] = iterations;
  result.parameters["virtual_views"] = views;
  result.parameters["field_parameters"] = static_cast<double>(parameters);
  result.parameters["events"] = static_cast<double>(problem.eventsInExposure());
  result.parameters["samples_per_ray"] = o.samples;
  result.parameters["beta"] = problem.beta();
  result.parameters["blur_weight"] = problem.blurWeight();
  result.parameters["events_normalised"] = problem.normalisedEvents() ? 1.0 : 0.0;
  result.parameters["rays_per_step"] = std::max(1, o.blur_rays / views) * views + 2 * o.event_rays;
  if (!result.curve.empty()) {
    result.parameters["final_loss"] = result.curve.back().second;
    // The two terms over the last curve interval: how well the model explains the blurry frame
    // (as a PSNR of the re-blurred renders against it) and the events.
    result.parameters["final_blur_term"] = last_blur;
    result.parameters["final_event_term"] = last_event;
    if (last_blur > 0) result.parameters["blur_fit_psnr"] = -10 * std::log10(last_blur);
  }
  result.timings_s["total"] = secondsSince(start);
  return result;
}

// ---------------------------------------------------------------------------------------------
// Settings

namespace {

double number(const std::string& key, const std::string& value) { return settingNumber("benerf", key, value); }

int settingInt(const std::string& key, const std::string& value, int min) {
  const double v = number(key, value);
  if (v != std::floor(v) || v < min || v > 1e9) throw Error("benerf: setting " + key + "=" + value + " must be an integer >= " + std::to_string(min));
  return static_cast<int>(v);
}

}  // namespace

std::unique_ptr<Deblurrer> makeBenerf(const MethodSettings& settings) {
  BenerfOptions o = benerfBudget("balanced");
  if (const auto b = settings.find("budget"); b != settings.end()) {
    const std::string& v = b->second;
    if (!v.empty() && (std::isdigit(static_cast<unsigned char>(v[0])) != 0 || v[0] == '.')) {
      o.budget_seconds = number("budget", v);
      if (!(o.budget_seconds > 0)) throw Error("benerf: budget must be fast, balanced, quality or a positive number of seconds");
      o.iterations = 1000000;
    } else {
      o = benerfBudget(v);
    }
  }
  if (const auto p = settings.find("preset"); p != settings.end()) {
    if (p->second == "synthetic") {
      o.event_form = BenerfOptions::EventForm::kDirect;
    } else if (p->second == "real") {
      o.event_form = BenerfOptions::EventForm::kNormalised;
    } else {
      throw Error("benerf: unknown preset '" + p->second + "' (known: synthetic, real)");
    }
  }
  for (const auto& [key, value] : settings) {
    if (key == "budget" || key == "preset") continue;
    if (key == "field") {
      if (value != "hash" && value != "mlp") throw Error("benerf: field must be hash or mlp, not '" + value + "'");
      o.field = value;
    } else if (key == "iterations") {
      o.iterations = settingInt(key, value, 1);
    } else if (key == "views") {
      o.virtual_views = settingInt(key, value, 1);
    } else if (key == "knots") {
      o.knots = settingInt(key, value, 2);
    } else if (key == "trajectory") {
      try {
        o.trajectory = parseTrajectoryKind(value);
      } catch (const Error&) {
        throw Error("benerf: trajectory must be cubic, split or linear, not '" + value + "'");
      }
    } else if (key == "alpha") {
      o.alpha = number(key, value);
      if (!(o.alpha > 0 && o.alpha <= 1)) throw Error("benerf: alpha must lie in (0, 1]");
    } else if (key == "beta") {
      o.beta = number(key, value);
      if (!(o.beta >= 0)) throw Error("benerf: beta must be >= 0");
    } else if (key == "normalise") {
      o.event_form = number(key, value) != 0 ? BenerfOptions::EventForm::kNormalised : BenerfOptions::EventForm::kDirect;
    } else if (key == "windows") {
      o.windows = settingInt(key, value, 1);
    } else if (key == "rays") {
      o.blur_rays = o.event_rays = settingInt(key, value, 1);
    } else if (key == "blur_rays") {
      o.blur_rays = settingInt(key, value, 1);
    } else if (key == "event_rays") {
      o.event_rays = settingInt(key, value, 0);
    } else if (key == "samples") {
      o.samples = settingInt(key, value, 2);
    } else if (key == "contrast") {
      o.contrast = contrastSetting("benerf", value);
    } else if (key == "estimate_contrast") {
      o.estimate_contrast = number(key, value) != 0;
    } else if (key == "levels") {
      o.hash.grid.levels = settingInt(key, value, 1);
    } else if (key == "features") {
      o.hash.grid.features = settingInt(key, value, 1);
    } else if (key == "table") {
      o.hash.grid.log2_table = settingInt(key, value, 8);
      if (o.hash.grid.log2_table > 24) throw Error("benerf: table (log2 entries) must be at most 24");
    } else if (key == "depth_scale") {
      o.depth_scale = number(key, value);
      if (!(o.depth_scale > 0 && o.depth_scale <= 1)) throw Error("benerf: depth_scale must lie in (0, 1]");
    } else if (key == "resolution") {
      o.finest_resolution = settingInt(key, value, 2);
    } else if (key == "dim_frame") {
      o.dim_frame = number(key, value);
      if (!(o.dim_frame >= 0 && o.dim_frame <= 1)) throw Error("benerf: dim_frame must lie in [0, 1] (a mean linear brightness)");
    } else if (key == "prefit") {
      o.prefit = settingInt(key, value, 0);
    } else if (key == "coarse_to_fine") {
      o.coarse_to_fine = number(key, value);
      if (!(o.coarse_to_fine >= 0 && o.coarse_to_fine <= 1)) throw Error("benerf: coarse_to_fine must lie in [0, 1] (the fraction of the iterations over which the field's bands open)");
    } else if (key == "init") {
      if (value == "events") {
        o.init = BenerfOptions::Init::kEvents;
      } else if (value == "identity") {
        o.init = BenerfOptions::Init::kIdentity;
      } else {
        throw Error("benerf: init must be events or identity, not '" + value + "'");
      }
    } else if (key == "field_lr") {
      o.field_lr = number(key, value);
    } else if (key == "knot_lr") {
      o.knot_lr = number(key, value);
    } else if (key == "lr_final") {
      o.lr_final = number(key, value);
      if (!(o.lr_final > 0)) throw Error("benerf: setting lr_final=" + value + " must be positive (the fraction the learning rates decay to)");
    } else if (key == "seed") {
      o.seed = static_cast<uint64_t>(settingInt(key, value, 0));
    } else if (key == "threads") {
      o.threads = settingInt(key, value, 1);
    } else if (key == "checkpoint") {
      o.checkpoint = value;
    } else if (key == "resume") {
      o.resume = value;
    } else if (key == "stop_after") {
      o.stop_after = settingInt(key, value, 1);
    } else if (key == "lin_log") {
      o.log.lin_log = number(key, value) != 0;
    } else {
      throw Error("benerf: unknown setting '" + key +
                  "' (known: budget, preset, field, iterations, views, knots, trajectory, init, alpha, beta, normalise, contrast, estimate_contrast, windows, prefit, dim_frame, rays, blur_rays, event_rays, samples, levels, "
                  "features, table, resolution, depth_scale, coarse_to_fine, field_lr, knot_lr, lr_final, seed, threads, checkpoint, resume, stop_after, lin_log)");
    }
  }
  if (o.field == "mlp" && !settings.count("field_lr")) o.field_lr = 5e-4;  // the paper's rate for its MLP
  return std::make_unique<BenerfDeblurrer>(o);
}

}  // namespace evkit
