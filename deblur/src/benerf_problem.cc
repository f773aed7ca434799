// The BeNeRF problem: the observation's data, the field and the trajectory; the loss of a batch
// of rays and its gradients; renders.

#include <omp.h>

#include <algorithm>
#include <cmath>

#include "benerf_common.h"
#include "evkit/base/error.h"
#include "evkit/deblur/benerf.h"
#include "evkit/deblur/pixel_grid.h"
#include "evkit/nerf/ray_batch.h"

namespace evkit {

using benerf_detail::secondsSince;
using benerf_detail::toFloat;

namespace {

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
    c.grid.per_level_scale =
        std::pow(static_cast<double>(finest) / c.grid.base_resolution, 1.0 / (c.grid.levels - 1));
  }
  return c;
}

}  // namespace

template <typename T>
BenerfProblem<T>::BenerfProblem(const Observation& obs, const BenerfOptions& options,
                                int virtual_views)
    : options_(options),
      camera_(obs.camera.withSize(obs.blurry.image.cols, obs.blurry.image.rows)),
      channels_(obs.blurry.image.channels()),
      views_(virtual_views),
      blurry_(toFloat(obs.blurry.image)),
      trajectory_(options.trajectory, obs.blurry.exposure_start_us, obs.blurry.exposure_end_us,
                  initialKnots(std::max(options.knots > 0 ? options.knots : 4,
                                        Trajectory::minimumKnots(options.trajectory)),
                               options.knot_init, options.seed)),
      rays_options_{.samples = options.samples,
                    .near = options.near,
                    .depth_scale = options.depth_scale,
                    .render = {}},
      rays_(camera_, rays_options_) {
  if (channels_ != 1 && channels_ != 3)
    throw Error("benerf: the blurry frame must be grey or colour, not " +
                std::to_string(channels_) + " channels");
  if (views_ < 1) throw Error("benerf: need at least one virtual view");
  if (options.field == BenerfOptions::FieldKind::kPixels)
    throw Error("benerf: the pixel grid is PixelGridProblem's, not a field of BenerfProblem");
  if (options.field == BenerfOptions::FieldKind::kHash) {
    const int finest = options.finest_resolution > 0 ? options.finest_resolution
                                                     : std::max(camera_.width, camera_.height);
    field_ = nerf::makeHashField<T>(adaptedHash(options.hash, finest), channels_, options.seed);
  } else {
    field_ = nerf::makeMlpField<T>(options.mlp, channels_, options.seed);
  }
  if (const auto thresholds = resolveContrast(options.contrast, obs)) {
    c_on_ = thresholds->on;
    c_off_ = thresholds->off;
    known_contrast_ = true;
  }
  normalised_ = !known_contrast_ || options.event_form == BenerfOptions::EventForm::kNormalised;
  // The presets are the paper's β at its 1,024 event pixels per step. The normalised term is a mean
  // over the batch of the squared differences of two unit vectors, so it shrinks as 1 / pixels:
  // its β grows with them to keep the same weight (the direct term is a plain mean and does not).
  beta_ = options.beta >= 0 ? options.beta
                            : (normalised_ ? 2.0 * std::max(1, options.event_rays) / 1024.0 : 0.1);
  blur_weight_ = dimFrameWeight(blurry_, options.dim_frame);  // pixel_grid.h
  // Events of the exposure by pixel, with the accumulated level after each.
  events_ = PixelEventIndex(
      obs.events.sliceTime(obs.blurry.exposure_start_us, obs.blurry.exposure_end_us + 1),
      camera_.width, camera_.height);
  event_level_.resize(events_.size());
  for (size_t p = 0; p < static_cast<size_t>(camera_.width) * camera_.height; ++p) {
    double level = 0;
    for (uint32_t e = events_.begin(p); e < events_.end(p); ++e) {
      level += events_.polarity()[e] > 0 ? (known_contrast_ ? c_on_ : 1.0)
                                         : -(known_contrast_ ? c_off_ : 1.0);
      event_level_[e] = level;
    }
  }
}

template <typename T>
double BenerfProblem<T>::accumulatedEvents(int pixel, int64_t t_begin, int64_t t_end) const {
  const std::vector<int64_t>& times = events_.t();
  const auto first = times.begin() + events_.begin(static_cast<size_t>(pixel));
  const auto last = times.begin() + events_.end(static_cast<size_t>(pixel));
  // The level after the last event before t (0 before the first).
  const auto levelAt = [&](int64_t t) {
    const auto it = std::lower_bound(first, last, t);
    return it == first ? 0.0 : event_level_[static_cast<size_t>(it - times.begin()) - 1];
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
  const int64_t length = std::max<int64_t>(
      1, static_cast<int64_t>(std::llround(options_.alpha * static_cast<double>(t1 - t0))));
  std::uniform_int_distribution<int64_t> begin(t0, std::max(t0, t1 - length));
  const int windows =
      std::min(std::max(1, options_.windows), options_.event_rays);  // none without event pixels
  for (int w = 0; w < windows; ++w) {
    b.window_begin.push_back(begin(rng));
    b.window_end.push_back(std::min(t1, b.window_begin.back() + length));
  }
  const size_t rays =
      b.blur_pixels.size() * static_cast<size_t>(views_) + 2 * b.event_pixels.size();
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  b.jitter.resize(rays * static_cast<size_t>(options_.samples));
  for (float& j : b.jitter) j = u(rng);
  return b;
}

template <typename T>
typename BenerfProblem<T>::Loss BenerfProblem<T>::evaluate(const Batch& batch,
                                                           Eigen::VectorXd* knot_gradient) {
  const int V = views_, W = camera_.width;
  const int Pb = static_cast<int>(batch.blur_pixels.size()),
            Pe = static_cast<int>(batch.event_pixels.size());
  // Poses: the V virtual views, then the ends of each event window; event pixel i has window
  // i mod windows.
  const int windows = static_cast<int>(batch.window_begin.size());
  std::vector<double> s(static_cast<size_t>(V + 2 * windows));
  for (int k = 0; k < V; ++k) s[static_cast<size_t>(k)] = viewTime(k);
  for (int w = 0; w < windows; ++w) {
    s[static_cast<size_t>(V + 2 * w)] =
        trajectory_.normalizedTime(batch.window_begin[static_cast<size_t>(w)]);
    s[static_cast<size_t>(V + 2 * w + 1)] =
        trajectory_.normalizedTime(batch.window_end[static_cast<size_t>(w)]);
  }
  std::vector<SE3> poses(s.size());
  std::vector<KnotJacobians> jacobians(s.size());
  for (size_t k = 0; k < s.size(); ++k)
    poses[k] = trajectory_.evaluate(s[k], knot_gradient ? &jacobians[k] : nullptr);
  // The rays: each blur pixel from the V views, then each event pixel from its window's two ends.
  std::vector<typename nerf::RayBatch<T>::PixelRay> rays;
  rays.reserve(static_cast<size_t>(Pb * V + 2 * Pe));
  for (int i = 0; i < Pb; ++i) {
    const int p = batch.blur_pixels[static_cast<size_t>(i)];
    for (int k = 0; k < V; ++k) rays.push_back({p % W, p / W, k});
  }
  for (int i = 0; i < Pe; ++i) {
    const int p = batch.event_pixels[static_cast<size_t>(i)];
    for (int end = 0; end < 2; ++end) rays.push_back({p % W, p / W, V + 2 * (i % windows) + end});
  }
  rays_.setRays(poses, std::move(rays), batch.jitter.data());
  if (knot_gradient) field_->zeroGradients();
  rays_.forward(*field_, knot_gradient != nullptr);

  Loss loss;
  std::vector<T> d_colour(static_cast<size_t>(rays_.size()) * 3,
                          T(0));  // dL/d(rendered colour) per ray
  loss.blur = blurTerm(batch, d_colour);
  loss.event = eventTerm(batch, d_colour);
  loss.total = blur_weight_ * loss.blur + beta_ * loss.event;
  if (!knot_gradient) return loss;

  const std::vector<Vector6> pose_gradient = rays_.backward(*field_, d_colour, true);
  knot_gradient->setZero(6 * static_cast<Eigen::Index>(trajectory_.knots().size()));
  for (size_t k = 0; k < poses.size(); ++k) {
    const KnotJacobians& J = jacobians[k];
    for (int i = 0; i < J.count; ++i) {
      knot_gradient->segment<6>(6 * (J.first_knot + i)) +=
          J.d_pose_d_knot[static_cast<size_t>(i)].transpose() * pose_gradient[k];
    }
  }
  return loss;
}

template <typename T>
double BenerfProblem<T>::blurTerm(const Batch& batch, std::vector<T>& d_colour) const {
  // The mean of the V renders against the blurry pixel (or each render against its view's target).
  const int C = channels_, V = views_, W = camera_.width;
  const int Pb = static_cast<int>(batch.blur_pixels.size());
  const auto colour = [&](int i, int k, int c) { return rays_.render(i * V + k).colour[c]; };
  double term = 0;
  for (int i = 0; i < Pb; ++i) {
    const int p = batch.blur_pixels[static_cast<size_t>(i)];
    if (!view_targets_.empty()) {
      for (int k = 0; k < V; ++k) {
        const float* b = view_targets_[static_cast<size_t>(k)].ptr<float>(p / W) + (p % W) * C;
        for (int c = 0; c < C; ++c) {
          const T e = colour(i, k, c) - static_cast<T>(b[c]);
          term += static_cast<double>(e * e) / (Pb * C * V);
          d_colour[static_cast<size_t>(i * V + k) * 3 + c] =
              static_cast<T>(2 * blur_weight_) * e / static_cast<T>(Pb * C * V);
        }
      }
      continue;
    }
    const float* b = blurry_.ptr<float>(p / W) + (p % W) * C;
    for (int c = 0; c < C; ++c) {
      T mean = 0;
      for (int k = 0; k < V; ++k) mean += colour(i, k, c);
      mean /= T(V);
      const T e = mean - static_cast<T>(b[c]);
      term += static_cast<double>(e * e) / (Pb * C);
      const T g = static_cast<T>(2 * blur_weight_) * e / static_cast<T>(Pb * C * V);
      for (int k = 0; k < V; ++k) d_colour[static_cast<size_t>(i * V + k) * 3 + c] = g;
    }
  }
  return term;
}

template <typename T>
double BenerfProblem<T>::eventTerm(const Batch& batch, std::vector<T>& d_colour) const {
  // Accumulated events against the change of the log grey renders at the window's ends.
  const int C = channels_, first = static_cast<int>(batch.blur_pixels.size()) * views_;
  const int Pe = static_cast<int>(batch.event_pixels.size()),
            windows = static_cast<int>(batch.window_begin.size());
  if (Pe == 0) return 0;
  std::vector<T> grey_a(static_cast<size_t>(Pe)), grey_b(static_cast<size_t>(Pe)),
      change(static_cast<size_t>(Pe));
  std::vector<double> target(static_cast<size_t>(Pe));
  double target_norm2 = 0;
  T change_norm2 = 0;
  for (int i = 0; i < Pe; ++i) {
    const size_t n = static_cast<size_t>(i);
    grey_a[n] = nerf::greyOf(rays_.render(first + 2 * i).colour, C);
    grey_b[n] = nerf::greyOf(rays_.render(first + 2 * i + 1).colour, C);
    change[n] = options_.log.logOf(grey_b[n]) - options_.log.logOf(grey_a[n]);
    target[n] = accumulatedEvents(batch.event_pixels[n],
                                  batch.window_begin[static_cast<size_t>(i % windows)],
                                  batch.window_end[static_cast<size_t>(i % windows)]);
    target_norm2 += target[n] * target[n];
    change_norm2 += change[n] * change[n];
  }
  double term = 0;
  std::vector<T> d_change(static_cast<size_t>(Pe));
  // Normalised comparison unless the thresholds are known and normalisation is off; a window
  // without events compares directly with zero change.
  if (target_norm2 > 0 && normalised_) {
    const T tiny = T(1e-6);
    const T norm = std::sqrt(change_norm2 + tiny * tiny);
    const double target_norm = std::sqrt(target_norm2);
    T dot = 0;
    std::vector<T> g(static_cast<size_t>(Pe));
    for (size_t n = 0; n < static_cast<size_t>(Pe); ++n) {
      const T e = change[n] / norm - static_cast<T>(target[n] / target_norm);
      term += static_cast<double>(e * e) / Pe;
      g[n] = T(2) * e / static_cast<T>(Pe);
      dot += change[n] * g[n];
    }
    for (size_t n = 0; n < static_cast<size_t>(Pe); ++n)
      d_change[n] = g[n] / norm - change[n] * dot / (norm * norm * norm);
  } else {
    for (size_t n = 0; n < static_cast<size_t>(Pe); ++n) {
      const T e = change[n] - static_cast<T>(target[n]);
      term += static_cast<double>(e * e) / Pe;
      d_change[n] = T(2) * e / static_cast<T>(Pe);
    }
  }
  const T beta = static_cast<T>(beta_);
  for (int i = 0; i < Pe; ++i) {
    const size_t n = static_cast<size_t>(i), ra = static_cast<size_t>(first + 2 * i);
    const T d = beta * d_change[n];
    nerf::greyBackward(-d * options_.log.logSlope(grey_a[n]), C, &d_colour[ra * 3]);
    nerf::greyBackward(d * options_.log.logSlope(grey_b[n]), C, &d_colour[(ra + 1) * 3]);
  }
  return term;
}

template <typename T>
void BenerfProblem<T>::setViewTargets(std::vector<cv::Mat> targets) {
  if (!targets.empty() && static_cast<int>(targets.size()) != views_)
    throw Error("benerf: one view target per virtual view");
  for (const cv::Mat& t : targets) {
    if (t.type() != CV_MAKETYPE(CV_32F, channels_) || t.size() != blurry_.size())
      throw Error("benerf: a view target must be float32 like the blurry frame");
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
  const int C = channels_, W = camera_.width;
  const std::vector<SE3> pose = {trajectory_.poseAt(t_us)};
  cv::Mat image(H, W, CV_MAKETYPE(CV_32F, C));
  if (disparity) disparity->create(H, W, CV_32F);
  nerf::RayBatch<T> batch(camera_, rays_options_);
  const int rows_per_batch = rowsPerRenderBatch();
  for (int y0 = 0; y0 < H; y0 += rows_per_batch) {
    const int rows = std::min(rows_per_batch, H - y0), R = rows * W;
    std::vector<typename nerf::RayBatch<T>::PixelRay> rays(static_cast<size_t>(R));
    for (int r = 0; r < R; ++r) rays[static_cast<size_t>(r)] = {r % W, y0 + r / W, 0};
    batch.setRays(pose, std::move(rays), nullptr);  // the samples' centres
    batch.forward(*field_, false);
    for (int r = 0; r < R; ++r) {
      const nerf::RayRender<T>& f = batch.render(r);
      const int y = y0 + r / W, x = r % W;
      for (int c = 0; c < C; ++c) image.ptr<float>(y)[x * C + c] = static_cast<float>(f.colour[c]);
      if (disparity) {
        // Expected NDC parameter, the background at t = 1 (infinity); NDC z = 2t - 1 = 1 - 2 near /
        // z.
        const double t_mean = static_cast<double>(f.depth) + (1.0 - static_cast<double>(f.opacity));
        disparity->at<float>(y, x) =
            static_cast<float>(std::max(0.0, 1.0 - t_mean) / options_.near);
      }
    }
  }
  return image;
}

template class BenerfProblem<float>;
template class BenerfProblem<double>;

}  // namespace evkit
