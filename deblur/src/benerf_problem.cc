// The BeNeRF problem: the observation's data, the field and the trajectory; the loss of a batch
// of rays and its gradients; renders.

#include <omp.h>

#include <algorithm>
#include <cmath>

#include "benerf_common.h"
#include "evkit/base/error.h"
#include "evkit/deblur/benerf.h"
#include "evkit/nerf/train.h"

namespace evkit {

using benerf_detail::pinhole;
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

}  // namespace evkit
