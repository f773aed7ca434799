// BeNeRF's scene as a pixel grid: the mid-exposure camera's frustum with one cell per pixel (and a
// margin for what the exposure's other views see), each cell at the inverse depth registered
// between EDI's latent frames. A view at time t sees a cell through the camera's pose at t, so the
// virtual views are reprojections of one image. The image is found by L-BFGS on BeNeRF's two terms:
// the views' mean against the blurry frame (linear) and each view's log change from mid-exposure
// and over short windows against the events in between (the direct form, C-weighted).
// Where each view's pixel lands, the surfaces around depth edges and the layer behind are in
// pixel_grid_views.cc; the step in the inverse depth from the solved image in pixel_grid_depth.cc.

#include "evkit/deblur/pixel_grid.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <stdexcept>

#include "benerf_common.h"
#include "evkit/base/error.h"
#include "evkit/nerf/volume_render.h"
#include "pixel_grid_geometry.h"

namespace evkit {

using pixel_grid_detail::sample;
using pixel_grid_detail::sampleBackward;
using pixel_grid_detail::Taps;

namespace {

// The cells a pixel along each axis at which PixelGridOptions::smoothness is set (BeNeRF's
// default `cells`).
constexpr int kDefaultCells = 2;

// The sum of body(j) over j in [0, n), the range cut into kPieces pieces whatever the thread
// count, each summed on its own and the pieces added in order: the same bits on one thread and on
// many (an OpenMP reduction adds the threads' sums in the order they finish).
constexpr int kPieces = 64;
template <class Body>
double orderedSum(std::ptrdiff_t n, Body&& body) {
  std::array<double, kPieces> parts{};
#pragma omp parallel for schedule(static)
  for (int piece = 0; piece < kPieces; ++piece) {
    double sum = 0;
    for (std::ptrdiff_t j = n * piece / kPieces, end = n * (piece + 1) / kPieces; j < end; ++j)
      sum += body(j);
    parts[static_cast<size_t>(piece)] = sum;
  }
  double total = 0;
  for (const double part : parts) total += part;
  return total;
}

}  // namespace

double PixelGridProblem::eventPenalty(double r, double* weight) const {
  const double d = options_.event_robust;
  if (!(d > 0)) {
    *weight = 1;
    return r * r;
  }
  const double root = std::sqrt(1 + (r / d) * (r / d));
  *weight = 1 / root;
  return 2 * d * d * (root - 1);
}

void PixelGridProblem::referenceLevels(const double* levels, const int* order, int count,
                                       double* reference, int* source) const {
  // No play: each sample's own level (a tie with the one before stays its own).
  if (referencePlays() == 1) {
    for (int s = 0; s < count; ++s) {
      const int i = order[s];
      reference[i] = levels[i];
      source[i] = i;
    }
    return;
  }
  // The plays side by side, sample by sample (each sample's level and band read once), without
  // branches.
  constexpr int M = kReferencePlays;
  double before[M];
  int* from = source + static_cast<size_t>(order[0]) * M;
  {
    const int i = order[0];
    const double l = levels[i];
    double sum = 0;
    for (int m = 0; m < M; ++m) {
      // The play's start: the first sample's level less an offset at the midpoint of the m-th of
      // M equal parts of the band [level - band_up_, level + band_down_].
      before[m] = l - band_up_ + (m + 0.5) / M * (band_up_ + band_down_);
      from[m] = i;
      sum += before[m];
    }
    reference[i] = sum / M;
  }
  for (int s = 1; s < count; ++s) {
    const int i = order[s];
    const double l = levels[i], low = l - band_up_, high = l + band_down_;
    int* const previous = from;
    from = source + static_cast<size_t>(i) * M;
#pragma omp simd
    for (int m = 0; m < M; ++m) {  // a play out of the band moves to its edge, from here
      const double play = before[m];
      const double held = play < low ? low : (play > high ? high : play);
      from[m] = held != play ? i : previous[m];
      before[m] = held;
    }
    double sum = 0;
    for (int m = 0; m < M; ++m) sum += before[m];
    reference[i] = sum / M;
  }
}

void PixelGridProblem::referenceGradient(const double* d_reference, const int* order, int count,
                                         const int* source, double* d_level) const {
  std::fill(d_level, d_level + 2 * views_, 0.0);
  if (referencePlays() == 1) {
    for (int s = 0; s < count; ++s) d_level[order[s]] = d_reference[order[s]];
    return;
  }
  // A play holds its source's level over a run of samples in time order, the source first. From
  // the last sample back, each sample's share is carried until its run's source, which takes it
  // (no sample's level is written more than once).
  constexpr int M = kReferencePlays;
  double carry[M] = {};
  for (int s = count - 1; s >= 0; --s) {
    const int i = order[s];
    const double share = d_reference[i] / M;
    const int* from = source + static_cast<size_t>(i) * M;
    double taken[M];
#pragma omp simd
    for (int m = 0; m < M; ++m) {
      carry[m] += share;
      taken[m] = from[m] == i ? carry[m] : 0.0;
      carry[m] = from[m] == i ? 0.0 : carry[m];
    }
    double own = 0;
    for (int m = 0; m < M; ++m) own += taken[m];
    d_level[i] = own;
  }
}

int PixelGridProblem::sampleOrder(const BlurQuadrature& quadrature, int* order) const {
  const int V = views_;
  const bool between = referencePlays() > 1;
  int count = 0;
  for (int k = 0; k < V; ++k) {
    if (k == mid_slot_) order[count++] = V;  // before the first view not before it
    order[count++] = k;
    // The sample between views k and k + 1, but for the one at mid-exposure's time (V even).
    if (between && k + 1 < V && quadrature.sampled[static_cast<size_t>(k)] && 2 * (k + 1) != V)
      order[count++] = V + 1 + k;
  }
  if (mid_slot_ == V) order[count++] = V;
  return count;
}

double dimFrameWeight(const cv::Mat& blurry, double dim_frame) {
  const cv::Scalar mean = cv::mean(blurry);
  double brightness = 0;
  for (int c = 0; c < blurry.channels(); ++c) brightness += mean[c] / blurry.channels();
  return brightness < dim_frame ? std::pow(dim_frame / std::max(brightness, 1e-3), 2) : 1.0;
}

PixelGridProblem::PixelGridProblem(const Observation& obs, const PinholeCamera& camera,
                                   const Trajectory& motion, const cv::Mat& inverse_depth,
                                   const Contrast& contrast, const PixelGridOptions& options)
    : camera_(camera),
      options_(options),
      channels_(obs.blurry.image.channels()),
      motion_(motion),
      inverse_depth_(inverse_depth.empty() ? cv::Mat::zeros(camera.height, camera.width, CV_32F)
                                           : inverse_depth) {
  const int W = camera_.width, H = camera_.height;
  if (channels_ != 1 && channels_ != 3)
    throw Error("benerf: the blurry frame must be grey or colour, not " +
                std::to_string(channels_) + " channels");
  if (inverse_depth_.size() != cv::Size(W, H) || inverse_depth_.type() != CV_32F)
    throw Error("benerf: the inverse depth map must be float32 at the camera's size");
  directions_.resize(static_cast<size_t>(W) * H);
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x)
      directions_[static_cast<size_t>(y) * W + x] = nerf::pixelDirection(camera_, x, y);
  }
  const int64_t t0 = obs.blurry.exposure_start_us, t1 = obs.blurry.exposure_end_us;
  mid_us_ = obs.blurry.midExposure();

  // The views: views_per_px for each pixel of the longest image path over the exposure (the blur
  // integral by the midpoint rule), within the options' bounds.
  blur_px_ = longestImagePath(camera_, motion_, inverse_depth_, t0, t1);
  views_ = std::clamp(static_cast<int>(std::ceil(options_.views_per_px * blur_px_)) + 1,
                      options_.min_views, options_.max_views);
  for (int k = 0; k < views_; ++k) {
    times_us_.push_back(t0 + std::llround((k + 0.5) / views_ * static_cast<double>(t1 - t0)));
  }
  mid_slot_ = static_cast<int>(
      std::count_if(times_us_.begin(), times_us_.end(), [&](int64_t t) { return t < mid_us_; }));
  band_up_ = std::max(0.0, options_.hysteresis) * contrast.on;
  band_down_ = std::max(0.0, options_.hysteresis) * contrast.off;
  // Samples between views for the reference's plays (and the blur term, which takes them as they
  // are there), where the views are over between_views_px apart along the longest path. Without
  // the plays they gained the blur term nothing measurable (the natural suite at `fast`, +0.001
  // dB); with views closer than that (the natural suite's 15 px frames, 0.48 px apart at `fast`)
  // they moved no frame by more than 0.04 dB and took 1.2-1.8 times as long (BENCHMARKS.md, "The
  // samples between the views").
  const double gap = options_.subdivision * (2 * blur_px_ / views_ + 1);
  between_gap_ =
      referencePlays() > 1 && blur_px_ / views_ > options_.between_views_px ? gap * gap : -1.0;

  // The margin that holds what every view sees.
  double reach = 0;
  for (int k = 0; k < views_; ++k) {
    const SE3 pose = motion_.poseAt(times_us_[static_cast<size_t>(k)]);
    const Matrix3 R = pose.rotationMatrix();
#pragma omp parallel for reduction(max : reach) schedule(static)
    for (int y = 0; y < H; ++y) {
      for (int x = 0; x < W; ++x) {
        const Eigen::Vector2d q = cellOf(x, y, R, pose.translation());
        reach = std::max(reach, std::max(std::abs(q.x() - x), std::abs(q.y() - y)));
      }
    }
  }
  margin_ = std::min(static_cast<int>(std::ceil(reach)) + 2, std::max(W, H));
  const int S = options_.subdivision;
  canvas_w_ = (W + 2 * margin_) * S;
  canvas_h_ = (H + 2 * margin_) * S;
  behind_w_ = W + 2 * margin_;
  behind_h_ = H + 2 * margin_;

  findSurfaces();
  occluding_ = !nearest_.empty();
  // The layer behind's cells where the views' samples at this motion need them: the stencils are
  // taken first as if it held every cell.
  buildTaps(occluding_);
  if (occluding_) {
    allocateBehind();
    findBlockRows();
  }

  // The blurry frame, and the events accumulated from mid-exposure to each view's time.
  obs.blurry.image.convertTo(blurry_, CV_MAKETYPE(CV_32F, channels_));
  blur_weight_ = dimFrameWeight(blurry_, options_.dim_frame);
  accumulateEvents(obs.events.sliceTime(t0, t1 + 1), contrast);
}

void PixelGridProblem::accumulateEvents(const EventSpan& ev, const Contrast& contrast) {
  // An event after mid-exposure raises the level of the views at or after it; one before lowers
  // the views before it (their level is below mid's by the events in between). Each event is
  // counted once, by polarity, at the view nearest mid-exposure that it reaches; the counts are
  // then summed outwards from mid-exposure, so that each view's change is whole counts times the
  // thresholds (no float sum over the events).
  const int W = camera_.width, H = camera_.height, V = views_;
  const size_t N = directions_.size();
  std::vector<int32_t> on(N * V, 0), off(N * V, 0);
  for (size_t e = 0; e < ev.size(); ++e) {
    if (ev.x[e] >= W || ev.y[e] >= H) continue;
    const size_t pixel = static_cast<size_t>(ev.y[e]) * W + ev.x[e];
    // The first view at or after the event.
    const auto first = static_cast<int>(
        std::lower_bound(times_us_.begin(), times_us_.end(), ev.t[e]) - times_us_.begin());
    const int k = ev.t[e] > mid_us_ ? first : first - 1;
    if (k < 0 || k >= V) continue;
    ++(ev.p[e] > 0 ? on : off)[viewSlot(k, pixel)];
  }
  change_.assign(N * V, 0.0f);
  for (size_t pixel = 0; pixel < N; ++pixel) {
    const size_t at = viewSlot(0, pixel);
    const int32_t *up = &on[at], *down = &off[at];
    float* change = &change_[at];
    int32_t n_on = 0, n_off = 0;
    for (int k = mid_slot_; k < V; ++k) {  // the views at or after mid-exposure
      n_on += up[k], n_off += down[k];
      change[k] = static_cast<float>(n_on * contrast.on - n_off * contrast.off);
    }
    n_on = n_off = 0;
    for (int k = mid_slot_ - 1; k >= 0; --k) {  // the views before it
      n_on += up[k], n_off += down[k];
      change[k] = static_cast<float>(n_off * contrast.off - n_on * contrast.on);
    }
  }
}

double PixelGridProblem::intensityOf(double u, double* slope) const {
  const LogMapping& log = options_.log;
  if (!log.lin_log || u >= std::log(LogMapping::kLinLogThreshold)) {
    const double e = std::exp(u);
    *slope = e;
    return log.lin_log ? e : e - log.eps;
  }
  *slope =
      LogMapping::kLinLogThreshold / std::log(20.0);  // the linear part: x ln(20) / 20 - ln 255
  return (u + std::log(255.0)) * *slope;
}

std::vector<double> PixelGridProblem::intensities(const std::vector<double>& u,
                                                  std::vector<double>* slopes) const {
  std::vector<double> x;
  intensities(u, x, slopes);
  return x;
}

void PixelGridProblem::intensities(const std::vector<double>& u, std::vector<double>& x,
                                   std::vector<double>* slopes) const {
  x.resize(u.size());
  if (slopes) slopes->resize(u.size());
#pragma omp parallel for schedule(static)
  for (size_t i = 0; i < u.size(); ++i) {
    double slope;
    x[i] = intensityOf(u[i], slopes ? &(*slopes)[i] : &slope);
  }
}

double PixelGridProblem::canvasValue(const cv::Mat& f, int i, int j, int c, int S) const {
  const int C = channels_, W = f.cols, H = f.rows;
  const double v = std::clamp(static_cast<double>(j) / S - margin_, 0.0, H - 1.0);
  const int y0 = std::min(static_cast<int>(v), H - 2 < 0 ? 0 : H - 2), y1 = std::min(y0 + 1, H - 1);
  const double ay = v - y0;
  const double u = std::clamp(static_cast<double>(i) / S - margin_, 0.0, W - 1.0);
  const int x0 = std::min(static_cast<int>(u), W - 2 < 0 ? 0 : W - 2), x1 = std::min(x0 + 1, W - 1);
  const double ax = u - x0;
  return (1 - ay) *
             ((1 - ax) * f.ptr<double>(y0)[x0 * C + c] + ax * f.ptr<double>(y0)[x1 * C + c]) +
         ay * ((1 - ax) * f.ptr<double>(y1)[x0 * C + c] + ax * f.ptr<double>(y1)[x1 * C + c]);
}

std::vector<double> PixelGridProblem::start(const cv::Mat& mid_image) const {
  cv::Mat front;
  mid_image.convertTo(front, CV_MAKETYPE(CV_64F, channels_));
  const int C = channels_;
  std::vector<double> x(static_cast<size_t>(size()));
  for (int j = 0; j < canvas_h_; ++j) {
    for (int i = 0; i < canvas_w_; ++i) {
      for (int c = 0; c < C; ++c) {
        x[(static_cast<size_t>(j) * canvas_w_ + i) * C + c] =
            options_.log.logOf(std::max(canvasValue(front, i, j, c, options_.subdivision), 0.0));
      }
    }
  }
  if (!layered()) return x;
  const cv::Mat behind = behindStart(front);
  const size_t first = static_cast<size_t>(canvas_w_) * canvas_h_ * C;
  for (size_t slot = 0; slot < behind_cell_.size(); ++slot) {
    const int cell = behind_cell_[slot];
    for (int c = 0; c < C; ++c) {
      x[first + slot * C + c] = options_.log.logOf(
          std::max(canvasValue(behind, cell % behind_w_, cell / behind_w_, c, 1), 0.0));
    }
  }
  return x;
}

bool PixelGridProblem::clipped(float frame) const {
  return options_.saturated > 0 && frame >= options_.saturated;
}

// The blur term's residual: the views' mean less the frame, where a clipped channel reads its
// top for any mean above it (`flat`: there, where the residual moves with nothing).
double PixelGridProblem::blurResidual(double mean, float frame, bool* flat) const {
  const bool above = clipped(frame) && mean >= frame;
  if (flat) *flat = above;
  return above ? 0.0 : mean - frame;
}

void PixelGridProblem::sampleSlopes(const double* x, const Taps& t, double* value, double* du,
                                    double* dv) const {
  const std::array<size_t, 4> at = corners(t);  // top-left, top-right, bottom-left, bottom-right
  const double *a = x + at[0] * channels_, *a1 = x + at[1] * channels_, *b = x + at[2] * channels_,
               *b1 = x + at[3] * channels_;
  const int cells = behind(t) ? 1 : options_.subdivision;  // per pixel: the layer behind has one
  for (int c = 0; c < channels_; ++c) {
    value[c] =
        (1 - t.ay) * ((1 - t.ax) * a[c] + t.ax * a1[c]) + t.ay * ((1 - t.ax) * b[c] + t.ax * b1[c]);
    du[c] = cells * ((1 - t.ay) * (a1[c] - a[c]) + t.ay * (b1[c] - b[c]));
    dv[c] = cells * ((1 - t.ax) * (b[c] - a[c]) + t.ax * (b1[c] - a1[c]));
  }
}

void PixelGridProblem::blurQuadrature(const Taps* taps, BlurQuadrature& out) const {
  const int V = views_;
  out.view_weight.resize(static_cast<size_t>(V));
  out.between.resize(static_cast<size_t>(std::max(0, V - 1)));
  out.sampled.resize(out.between.size());
  if (V == 1) {
    out.view_weight[0] = 1;
    return;
  }
  if (!(between_gap_ >= 0)) {  // the views alone, each a V-th
    std::fill(out.view_weight.begin(), out.view_weight.end(), 1.0 / V);
    std::fill(out.sampled.begin(), out.sampled.end(), uint8_t{0});
    return;
  }
  const double half = 0.5 / V;
  out.between_weight = half;
  for (int k = 0; k < V; ++k)
    out.view_weight[static_cast<size_t>(k)] = k == 0 || k == V - 1 ? 1.5 * half : half;
  for (int k = 0; k + 1 < V; ++k) {
    const auto i = static_cast<size_t>(k);
    const Taps &a = taps[k], &b = taps[k + 1];
    out.sampled[i] = 0;
    if (!behind(a) && !behind(b)) {
      const double au = a.index % canvas_w_ + a.ax, av = a.index / canvas_w_ + a.ay,
                   bu = b.index % canvas_w_ + b.ax, bv = b.index / canvas_w_ + b.ay;
      if ((au - bu) * (au - bu) + (av - bv) * (av - bv) <= between_gap_) {
        out.between[i] =
            pixel_grid_detail::tapsAt(0.5 * (au + bu), 0.5 * (av + bv), canvas_w_, canvas_h_);
        out.sampled[i] = 1;
        continue;
      }
    }
    out.view_weight[i] += 0.5 * half;  // the mean of the two stands for the sample between
    out.view_weight[i + 1] += 0.5 * half;
  }
}

Eigen::Vector2d PixelGridProblem::betweenLevel(const double* x, const BlurQuadrature& quadrature,
                                               size_t i, double* value, double* du, double* dv,
                                               double* level) const {
  const LogMapping& log = options_.log;
  sampleSlopes(x, quadrature.between[i], value, du, dv);
  const double grey = nerf::greyOf(value, channels_);
  *level = log.logOf(std::max(0.0, grey));
  if (!(grey > 0)) return Eigen::Vector2d::Zero();
  return log.logSlope(grey) *
         Eigen::Vector2d(nerf::greyOf(du, channels_), nerf::greyOf(dv, channels_));
}

void PixelGridProblem::sampleBetween(const double* x, const BlurQuadrature& quadrature,
                                     double* between) const {
  for (size_t i = 0; i < quadrature.between.size(); ++i) {
    if (quadrature.sampled[i])
      sample(x, canvas_w_, channels_, quadrature.between[i], between + i * channels_);
  }
}

int PixelGridProblem::pixelLevels(const double* x, size_t pixel, size_t mid,
                                  BlurQuadrature& quadrature, double* colour, double* between,
                                  double* greys, double* levels, int* order) const {
  const int V = views_, C = channels_;
  const LogMapping& log = options_.log;
  greys[V] = std::max(0.0, nerf::greyOf(&x[mid], C));
  levels[V] = log.logOf(greys[V]);
  // The views' samples first, then their levels (the loads of one pass, the logs of the other).
  for (int k = 0; k < V; ++k) sampleTaps(x, taps_[viewSlot(k, pixel)], colour + k * C);
  for (int k = 0; k < V; ++k) {
    greys[k] = std::max(0.0, nerf::greyOf(colour + k * C, C));
    levels[k] = log.logOf(greys[k]);
  }
  blurQuadrature(&taps_[viewSlot(0, pixel)], quadrature);
  sampleBetween(x, quadrature, between);
  const int count = sampleOrder(quadrature, order);
  for (int s = 0; s < count; ++s) {
    const int i = order[s];
    if (i <= V) continue;
    greys[i] = std::max(0.0, nerf::greyOf(between + static_cast<ptrdiff_t>(i - V - 1) * C, C));
    levels[i] = log.logOf(greys[i]);
  }
  return count;
}

void PixelGridProblem::blurMean(const double* colours, const double* between,
                                const BlurQuadrature& quadrature, double* mean) const {
  const int C = channels_;
  double sum[3] = {0, 0, 0};  // in registers, not through `mean` (which may alias the inputs)
  for (int k = 0; k < views_; ++k) {
    const double w = quadrature.view_weight[static_cast<size_t>(k)];
    for (int c = 0; c < C; ++c) sum[c] += w * colours[k * C + c];
  }
  for (size_t i = 0; i < quadrature.between.size(); ++i) {
    if (!quadrature.sampled[i]) continue;
    for (int c = 0; c < C; ++c) sum[c] += quadrature.between_weight * between[i * C + c];
  }
  for (int c = 0; c < C; ++c) mean[c] = sum[c];
}

double PixelGridProblem::evaluate(const std::vector<double>& u, std::vector<double>* gradient,
                                  Terms* terms) const {
  // The unknowns are the cells' log intensities (the event model's mapping); the views sample the
  // cells' intensities bilinearly (linear light).
  std::vector<double>&x = scratch_.x, &slope = scratch_.slope;
  intensities(u, x, &slope);
  const int C = channels_;
  if (gradient) gradient->resize(x.size());
  BlockGradients& blocks = scratch_.blocks;
  const DataTerms data = dataTerms(x, 1, gradient ? &blocks : nullptr);
  const std::vector<std::vector<double>>&partial = blocks.front, &partial_behind = blocks.behind;
  const auto row = static_cast<size_t>(canvas_w_) * C;
  // The blocks' gradients added, through the log mapping to the unknowns, and the smoothness of
  // the log image between neighbouring cells (sub-pixel detail only where the data asks for it),
  // each cell's share of the squared differences to its right and lower neighbours and its
  // gradient from all four. In colour the chroma (each channel's log less the channels' mean) is
  // smoothed more (chroma_smoothness): the events see brightness only, so nothing but the blur
  // term holds it.
  // The layer behind is smoothed alike between its own neighbouring cells (behindSmoothness), with
  // the weights of the canvas's.
  // The weights are per pixel of the canvas at the default 2 x 2 cells a pixel, the same prior at
  // any `subdivision` S: a smooth image's difference between neighbouring cells falls as 1 / S and
  // its pairs of cells grow as S^2, so the squares' sum over the canvas does not move with S. (Once
  // per cell, 3 x 3 cells smoothed 4/9 as much as 2 x 2.)
  const double per_pixel = smoothnessPixels();
  const double scale = options_.smoothness / per_pixel;
  const double chroma = C > 1 ? options_.chroma_smoothness / per_pixel : 0.0;
  // The penalty's derivative with respect to the difference u[b + c] - u[a + c] of two
  // neighbouring cells a and b, in each channel; adds the penalty to `sum`.
  const auto pair = [&](size_t a, size_t b, double* d_pair, double& sum) {
    double mean = 0;
    for (int c = 0; c < C; ++c) mean += (u[b + c] - u[a + c]) / C;
    for (int c = 0; c < C; ++c) {
      const double d = u[b + c] - u[a + c], k = d - mean;
      sum += scale * d * d + chroma * k * k;
      d_pair[c] = 2 * scale * d + 2 * chroma * k;
    }
  };
  const double smooth = orderedSum(canvas_h_, [&](std::ptrdiff_t j) {
    double smooth_row = 0;
    // Row j of each block's gradient that reaches it, in block order (none without a gradient:
    // the scratch's blocks are then a call before's).
    std::array<const double*, kRowBlocks> from_blocks{};
    int reaching = 0;
    for (size_t block = 0; gradient && block < partial.size(); ++block) {
      const auto [first, last] = block_rows_[block];
      if (j >= first && j < last)
        from_blocks[static_cast<size_t>(reaching++)] =
            partial[block].data() + static_cast<size_t>(j - first) * row;
    }
    double d_pair[3], d_right[3] = {0, 0, 0},
                      d_left[3] = {0, 0, 0};  // the pairs with the right and the left neighbour
    for (int i = 0; i < canvas_w_; ++i) {
      const size_t a = (static_cast<size_t>(j) * canvas_w_ + i) * C;
      double d_smooth[3] = {0, 0, 0};
      if (scale > 0 || chroma > 0) {
        // The right and lower neighbours' pairs (this row's share of the sum), and the left and
        // upper ones' (their gradient reaches this cell too; the left one is the cell before's
        // right one).
        if (i + 1 < canvas_w_) {
          pair(a, a + C, d_right, smooth_row);
          for (int c = 0; c < C; ++c) d_smooth[c] -= d_right[c];
        }
        if (j + 1 < canvas_h_) {
          pair(a, a + row, d_pair, smooth_row);
          for (int c = 0; c < C; ++c) d_smooth[c] -= d_pair[c];
        }
        double unused = 0;
        if (i > 0) {
          for (int c = 0; c < C; ++c) d_smooth[c] += d_left[c];
        }
        for (int c = 0; c < C; ++c) d_left[c] = d_right[c];
        if (j > 0) {
          pair(a - row, a, d_pair, unused);
          for (int c = 0; c < C; ++c) d_smooth[c] += d_pair[c];
        }
      }
      if (!gradient) continue;
      for (int c = 0; c < C; ++c) {
        double sum = 0;
        for (int b = 0; b < reaching; ++b) sum += from_blocks[static_cast<size_t>(b)][i * C + c];
        (*gradient)[a + c] = sum * slope[a + c] + d_smooth[c];
      }
    }
    return smooth_row;
  });
  // The layer behind: the smoothness between its neighbouring cells (each cell's right and lower
  // neighbour where that has a cell there too), and its blocks' gradients added in block order.
  double smooth_behind = 0;
  if (layered()) {
    const size_t first = static_cast<size_t>(canvas_w_) * canvas_h_ * C, B = behind_cell_.size();
    std::vector<double> d_behind(gradient ? B * C : 0, 0.0);
    double d_pair[3];
    for (size_t slot = 0; slot < B; ++slot) {
      const int cell = behind_cell_[slot];
      const int right = cell % behind_w_ + 1 < behind_w_ ? cell + 1 : -1,
                below = cell / behind_w_ + 1 < behind_h_ ? cell + behind_w_ : -1;
      for (const int next : {right, below}) {
        const int other = next < 0 ? -1 : behind_slot_[static_cast<size_t>(next)];
        if (other < 0) continue;
        pair(first + slot * C, first + static_cast<size_t>(other) * C, d_pair, smooth_behind);
        if (!gradient) continue;
        for (int c = 0; c < C; ++c) {
          d_behind[slot * C + c] -= d_pair[c];
          d_behind[static_cast<size_t>(other) * C + c] += d_pair[c];
        }
      }
    }
    if (gradient) {
      // The blocks' sums added in order in the gradient's own slots, then through the slope.
      double* g = gradient->data() + first;
      std::fill(g, g + B * C, 0.0);
      for (size_t block = 0; block < partial_behind.size(); ++block) {
        const auto from = static_cast<size_t>(block_behind_[block][0]) * C;
        const std::vector<double>& part = partial_behind[block];
        for (size_t j = 0; j < part.size(); ++j) g[from + j] += part[j];
      }
      for (size_t j = 0; j < B * C; ++j) g[j] = g[j] * slope[first + j] + d_behind[j];
    }
  }
  const double blur = data.blur, event = data.event + smooth + smooth_behind;
  if (terms) *terms = {blur / blur_weight_, event / options_.beta};
  return blur + event;
}

double PixelGridProblem::smoothnessPixels() const {
  return static_cast<double>(behind_w_) * behind_h_ * channels_ * (kDefaultCells * kDefaultCells);
}

PixelGridProblem::TermScales PixelGridProblem::termScales() const {
  const auto N = static_cast<double>(directions_.size());
  const int lag = eventLag();
  return {blur_weight_ / (N * channels_), options_.beta / (N * views_),
          lag > 0 ? options_.beta / (N * (views_ - lag)) : 0.0};
}

PixelGridProblem::DataTerms PixelGridProblem::dataTerms(const std::vector<double>& x, int stride,
                                                        BlockGradients* blocks) const {
  if (stride != 1 && blocks)
    throw std::invalid_argument("PixelGridProblem::dataTerms: a gradient needs every pixel");
  const int W = camera_.width, C = channels_, V = views_;
  const int lag = eventLag();
  const auto [blur_scale, event_scale, window_scale] = termScales();
  const LogMapping& log = options_.log;
  // Each row block's sums and gradient on its own (block_rows_), added in block order.
  const auto row = static_cast<size_t>(canvas_w_) * C;
  if (blocks) {  // each block's vector is assigned below, within its capacity after a first call
    blocks->front.resize(kRowBlocks);
    blocks->behind.resize(layered() ? kRowBlocks : 0);
  }
  std::array<double, kRowBlocks> blur_sums{}, event_sums{};
#pragma omp parallel
  {
    // Per sample (the views, mid-exposure, the samples between views: referenceLevels' indices)
    // and per view or sample between views (their channels).
    const auto L = static_cast<size_t>(2 * V);
    std::vector<double> colour(static_cast<size_t>(V) * C), between(L * C),
        d_grey(static_cast<size_t>(V)), levels(L), greys(L), reference(L), d_reference(L),
        d_level(L);
    const int M = referencePlays();
    std::vector<int> source(L * M), order(L);
    BlurQuadrature quadrature;
#pragma omp for schedule(dynamic)
    for (int block = 0; block < kRowBlocks; ++block) {
      const auto bi = static_cast<size_t>(block);
      double blur_sum = 0, event_sum = 0;
      // The block's gradient over the canvas rows it reaches: a stencil's index less the cells of
      // the rows before the first.
      double* g = nullptr;
      const int skipped = block_rows_[bi][0] * canvas_w_;
      if (blocks) {
        std::vector<double>& part = blocks->front[bi];
        part.assign(static_cast<size_t>(block_rows_[bi][1] - block_rows_[bi][0]) * row, 0.0);
        g = part.data();
      }
      // Likewise over the layer behind's cells it reaches, from the first.
      double* g_behind = nullptr;
      const size_t behind_skipped = static_cast<size_t>(canvas_w_) * canvas_h_ +
                                    (layered() ? static_cast<size_t>(block_behind_[bi][0]) : 0);
      if (blocks && layered()) {
        std::vector<double>& part = blocks->behind[bi];
        part.assign(static_cast<size_t>(block_behind_[bi][1] - block_behind_[bi][0]) * C, 0.0);
        g_behind = part.data();
      }
      for (int y = blockBegin(block); y < blockBegin(block + 1); ++y) {
        if (y % stride != 0) continue;
        for (int px = 0; px < W; px += stride) {
          const size_t pixel = static_cast<size_t>(y) * W + px;
          const size_t mid = midCell(px, y);
          const int count = pixelLevels(x.data(), pixel, mid, quadrature, colour.data(),
                                        between.data(), greys.data(), levels.data(), order.data());
          const double mid_grey = greys[static_cast<size_t>(V)];
          double sum[3];
          blurMean(colour.data(), between.data(), quadrature, sum);
          // Each view against mid-exposure (robust), and each view `lag` views on against it
          // (squares): the change of the sensor's reference level against the events in between
          // (the change since mid telescopes). Each reference is the mean of its plays' levels of
          // their source samples (index V: mid), which take its gradient.
          const bool held = !held_out_.empty() && held_out_[pixel];
          referenceLevels(levels.data(), order.data(), count, reference.data(), source.data());
          std::fill(d_reference.begin(), d_reference.end(), 0.0);
          const bool across = across_pixels_[pixel] != 0;
          for (int k = 0; k < V && !held; ++k) {
            const auto a = static_cast<size_t>(k);
            if (across && across_[viewSlot(k, pixel)]) continue;
            const double r =
                reference[a] - reference[static_cast<size_t>(V)] - change_[viewSlot(k, pixel)];
            double weight;
            event_sum += event_scale * eventPenalty(r, &weight);
            const double d = 2 * event_scale * weight * r;
            d_reference[a] += d;
            d_reference[static_cast<size_t>(V)] -= d;
            if (lag == 0 || k + lag >= V) continue;
            const auto b = static_cast<size_t>(k + lag);
            if (across && across_[viewSlot(k + lag, pixel)]) continue;
            const double rw = reference[b] - change_[viewSlot(k + lag, pixel)] -
                              (reference[a] - change_[viewSlot(k, pixel)]);
            event_sum += window_scale * rw * rw;
            const double dw = 2 * window_scale * rw;
            d_reference[b] += dw;
            d_reference[a] -= dw;
          }
          referenceGradient(d_reference.data(), order.data(), count, source.data(), d_level.data());
          const double d_mid_log = d_level[static_cast<size_t>(V)];
          for (int k = 0; k < V; ++k) {
            const auto a = static_cast<size_t>(k);
            d_grey[a] = d_level[a] * log.logSlope(greys[a]);
          }
          double d_sum[3] = {0, 0, 0};
          for (int c = 0; c < C; ++c) {
            const double r = blurResidual(sum[c], blurry_.ptr<float>(y)[px * C + c]);
            blur_sum += r * r;
            d_sum[c] = 2 * blur_scale * r;
          }
          if (!g) continue;
          double d_colour[3];
          for (size_t i = 0; i < quadrature.between.size(); ++i) {
            if (!quadrature.sampled[i]) continue;
            // Its level's share where the reference took it (d_level is 0 elsewhere).
            const size_t b = static_cast<size_t>(V) + 1 + i;
            nerf::greyBackward(d_level[b] != 0 ? d_level[b] * log.logSlope(greys[b]) : 0.0, C,
                               d_colour);
            for (int c = 0; c < C; ++c) d_colour[c] += quadrature.between_weight * d_sum[c];
            Taps t = quadrature.between[i];
            t.index -= skipped;
            sampleBackward(g, canvas_w_, C, t, d_colour);
          }
          for (int k = 0; k < V; ++k) {
            nerf::greyBackward(d_grey[static_cast<size_t>(k)], C, d_colour);
            const double share = quadrature.view_weight[static_cast<size_t>(k)];
            for (int c = 0; c < C; ++c) d_colour[c] += share * d_sum[c];
            Taps t = taps_[viewSlot(k, pixel)];
            if (!behind(t)) {
              t.index -= skipped;
              sampleBackward(g, canvas_w_, C, t, d_colour);
              continue;
            }
            const std::array<size_t, 4> at = corners(t);
            const double w[4] = {(1 - t.ay) * (1 - t.ax), (1 - t.ay) * t.ax, t.ay * (1 - t.ax),
                                 t.ay * t.ax};
            for (int n = 0; n < 4; ++n) {
              double* cell = g_behind + (at[static_cast<size_t>(n)] - behind_skipped) * C;
              for (int c = 0; c < C; ++c) cell[c] += w[n] * d_colour[c];
            }
          }
          nerf::greyBackward(d_mid_log * log.logSlope(mid_grey), C, d_colour);
          for (int c = 0; c < C; ++c) g[mid - static_cast<size_t>(skipped) * C + c] += d_colour[c];
        }
      }
      blur_sums[bi] = blur_sum;
      event_sums[bi] = event_sum;
    }
  }
  double blur_sum = 0, event_sum = 0;
  for (int block = 0; block < kRowBlocks; ++block) {
    blur_sum += blur_sums[static_cast<size_t>(block)];
    event_sum += event_sums[static_cast<size_t>(block)];
  }
  return {blur_sum * blur_scale, event_sum};
}

std::vector<double> PixelGridProblem::curvature(const std::vector<double>& u) const {
  std::vector<double> x, slope;
  intensities(u, x, &slope);
  const int W = camera_.width, C = channels_, V = views_;
  const int lag = eventLag();
  const auto [blur_scale, event_scale, window_scale] = termScales();
  const LogMapping& log = options_.log;
  const size_t front = static_cast<size_t>(canvas_w_) * canvas_h_, cells = x.size() / C;
  double grey_weight[3];
  nerf::greyBackward(1.0, C, grey_weight);
  // Each row block's sums over the canvas rows and the layer behind's cells it reaches
  // (block_rows_, block_behind_), added in block order below: the same bits at any thread count.
  std::vector<std::vector<double>> front_parts(kRowBlocks), behind_parts(kRowBlocks);
#pragma omp parallel
  {
    std::vector<double> colour(static_cast<size_t>(C));
    BlurQuadrature quadrature;
    // A pixel's shares of its blur mean by cell, and the cells it touched: its samples in one cell
    // add before the square (the blur term's residual is the pixel's mean).
    std::vector<double> share(cells, 0.0);
    std::vector<size_t> touched;
#pragma omp for schedule(dynamic)
    for (int block = 0; block < kRowBlocks; ++block) {
      const auto bi = static_cast<size_t>(block);
      const auto [first, last] = block_rows_[bi];
      std::vector<double>& part = front_parts[bi];
      part.assign(static_cast<size_t>(last - first) * canvas_w_ * C, 0.0);
      std::vector<double>& part_behind = behind_parts[bi];
      const size_t first_behind = layered() ? static_cast<size_t>(block_behind_[bi][0]) : 0;
      if (layered())
        part_behind.assign(static_cast<size_t>(block_behind_[bi][1]) * C - first_behind * C, 0.0);
      const auto at = [&](size_t cell) -> double* {
        return cell < front ? &part[(cell - static_cast<size_t>(first) * canvas_w_) * C]
                            : &part_behind[(cell - front - first_behind) * C];
      };
      // A sample's four cells: its share of the blur mean, and its log level's in `comparisons`
      // squared comparisons of weight 1 each (the weights summed).
      const auto add = [&](const Taps& t, double blur_share, double comparisons) {
        const std::array<size_t, 4> corner = corners(t);
        const double w[4] = {(1 - t.ay) * (1 - t.ax), (1 - t.ay) * t.ax, t.ay * (1 - t.ax),
                             t.ay * t.ax};
        double level_slope = 0;
        if (comparisons > 0) {
          if (behind(t))
            sampleBehind(x.data(), t, colour.data());
          else
            sample(x.data(), canvas_w_, C, t, colour.data());
          const double grey = nerf::greyOf(colour.data(), C);
          level_slope = grey > 0 ? log.logSlope(grey) : 0.0;
        }
        for (int n = 0; n < 4; ++n) {
          const size_t cell = corner[static_cast<size_t>(n)];
          if (share[cell] == 0) touched.push_back(cell);
          share[cell] += blur_share * w[n];
          double* d = at(cell);
          for (int c = 0; c < C; ++c) {
            const double event = level_slope * grey_weight[c] * w[n];
            d[c] += 2 * comparisons * event * event;
          }
        }
      };
      for (int y = blockBegin(block); y < blockBegin(block + 1); ++y) {
        for (int px = 0; px < W; ++px) {
          const size_t pixel = static_cast<size_t>(y) * W + px;
          touched.clear();
          blurQuadrature(&taps_[viewSlot(0, pixel)], quadrature);
          for (int k = 0; k < V; ++k) {
            const double windows = (lag > 0 && k + lag < V ? 1 : 0) + (lag > 0 && k >= lag ? 1 : 0);
            add(taps_[viewSlot(k, pixel)], quadrature.view_weight[static_cast<size_t>(k)],
                event_scale + windows * window_scale);
          }
          for (size_t i = 0; i < quadrature.between.size(); ++i)
            if (quadrature.sampled[i]) add(quadrature.between[i], quadrature.between_weight, 0);
          // Mid-exposure's cell, compared with every view.
          const size_t mid = midCell(px, y);
          const double grey = nerf::greyOf(&x[mid], C);
          const double level_slope = grey > 0 ? log.logSlope(grey) : 0.0;
          double* d = at(mid / static_cast<size_t>(C));
          for (int c = 0; c < C; ++c) {
            const double event = level_slope * grey_weight[c];
            d[c] += 2 * V * event_scale * event * event;
          }
          for (const size_t cell : touched) {
            const double a = share[cell];
            double* dc = at(cell);
            for (int c = 0; c < C; ++c) dc[c] += 2 * blur_scale * a * a;
            share[cell] = 0;
          }
        }
      }
    }
  }
  std::vector<double> d(x.size(), 0.0);
  for (int block = 0; block < kRowBlocks; ++block) {
    const auto bi = static_cast<size_t>(block);
    const size_t from = static_cast<size_t>(block_rows_[bi][0]) * canvas_w_ * C;
    for (size_t i = 0; i < front_parts[bi].size(); ++i) d[from + i] += front_parts[bi][i];
    if (!layered()) continue;
    const size_t from_behind = (front + static_cast<size_t>(block_behind_[bi][0])) * C;
    for (size_t i = 0; i < behind_parts[bi].size(); ++i) d[from_behind + i] += behind_parts[bi][i];
  }
  // Through the log mapping to the unknowns, and the smoothness's pairs (each cell is in up to
  // four, each of curvature 2 scale in either cell, as evaluate weighs them).
  const double pair_curvature = 2 * options_.smoothness / smoothnessPixels();
  double sum = 0;
  for (size_t j = 0; j < d.size(); ++j) {
    d[j] = d[j] * slope[j] * slope[j] + 4 * pair_curvature;
    sum += d[j];
  }
  // No cell softer than a thousandth of the mean: one that no sample reaches and no smoothness
  // holds would take an unbounded step.
  const double floor = 1e-3 * sum / static_cast<double>(std::max<size_t>(1, d.size()));
  for (double& v : d) v = std::max(v, floor);
  return d;
}

int PixelGridProblem::solve(std::vector<double>& x, int iterations, Terms* terms,
                            std::chrono::steady_clock::time_point deadline,
                            const std::function<void(int, double)>& progress,
                            double converged) const {
  // L-BFGS (Nocedal and Wright, Numerical Optimization, algorithm 7.4) with a backtracking line
  // search on the Armijo condition, its initial inverse Hessian gamma M^-1 where M is the loss's
  // curvature at the start (curvature(); PixelGridOptions::precondition, else the identity) and
  // gamma = s.y / y.M^-1.y of the newest pair (the scaling of their eq. 7.20 in M's metric). With a
  // million cells the two-loop recursion is bound by memory traffic, not arithmetic: the history is
  // kept in float (it only shapes the direction), in a ring that is allocated once, and each pass
  // over the cells both finishes one pair's update and takes the next pair's dot product.
  constexpr int kMemory = 8;
  const auto n = static_cast<std::ptrdiff_t>(x.size());
  std::vector<std::vector<float>> s_ring(kMemory), y_ring(kMemory);
  std::array<double, kMemory> rho{}, alpha{};
  int stored = 0, newest = -1;  // pairs held; the ring slot of the newest
  const auto slot = [&](int age) { return (newest - age + kMemory) % kMemory; };  // age 0: newest
  std::vector<double> g, g_new, q(x.size()), x_new(x.size());
  Terms at_x, at_new;  // the loss's terms at x and at the line search's trial
  double f = evaluate(x, &g, &at_x);
  std::vector<double> losses{f};  // after each step, the start's first
  std::vector<double> inverse_curvature;
  if (options_.precondition) {
    inverse_curvature = curvature(x);
    for (double& v : inverse_curvature) v = 1 / v;
  }
  const bool preconditioned = !inverse_curvature.empty();
  const double* m = inverse_curvature.data();
  int done = 0;
  for (; done < iterations && std::chrono::steady_clock::now() < deadline; ++done) {
    // First loop, newest pair to oldest: alpha_i = rho_i s_i.q, q -= alpha_i y_i (q starts as g).
    double dot = 0;
    if (stored > 0) {
      const float* s0 = s_ring[slot(0)].data();
      dot = orderedSum(n, [&](std::ptrdiff_t j) {
        q[j] = g[j];
        return s0[j] * g[j];
      });
    } else {
      q = g;
    }
    for (int age = 0; age < stored; ++age) {
      alpha[age] = rho[slot(age)] * dot;
      const float* y = y_ring[slot(age)].data();
      const float* s_next = age + 1 < stored ? s_ring[slot(age + 1)].data() : nullptr;
      const double a_i = alpha[age];
      if (s_next) {
        dot = orderedSum(n, [&](std::ptrdiff_t j) {
          q[j] -= a_i * y[j];
          return s_next[j] * q[j];
        });
      } else {
#pragma omp parallel for schedule(static)
        for (std::ptrdiff_t j = 0; j < n; ++j) q[j] -= a_i * y[j];
      }
    }
    // The initial Hessian's scale: s.y / y.M^-1.y of the newest pair, or a first step of 1e-3 in
    // intensity.
    double gamma = 0;
    if (stored > 0) {
      const float* s0 = s_ring[slot(0)].data();
      const float* y0 = y_ring[slot(0)].data();
      const double sy = orderedSum(n, [&](std::ptrdiff_t j) { return double(s0[j]) * y0[j]; });
      const double yy = orderedSum(n, [&](std::ptrdiff_t j) {
        return double(y0[j]) * y0[j] * (preconditioned ? m[j] : 1.0);
      });
      gamma = sy / yy;
    } else {
      const double gg = orderedSum(n, [&](std::ptrdiff_t j) {
        const double mg = preconditioned ? m[j] * g[j] : g[j];
        return mg * mg;
      });
      gamma = 1e-3 / std::sqrt(std::max(gg, 1e-300));
    }
    // Second loop, oldest pair to newest: beta_i = rho_i y_i.r, r += (alpha_i - beta_i) s_i, where
    // r starts as gamma q and is kept in q.
    if (stored > 0) {
      const float* y = y_ring[slot(stored - 1)].data();
      dot = orderedSum(n, [&](std::ptrdiff_t j) {
        q[j] *= preconditioned ? gamma * m[j] : gamma;
        return y[j] * q[j];
      });
    } else {
#pragma omp parallel for schedule(static)
      for (std::ptrdiff_t j = 0; j < n; ++j) q[j] *= preconditioned ? gamma * m[j] : gamma;
    }
    for (int age = stored - 1; age >= 0; --age) {
      const double c = alpha[age] - rho[slot(age)] * dot;
      const float* s_i = s_ring[slot(age)].data();
      const float* y_next = age > 0 ? y_ring[slot(age - 1)].data() : nullptr;
      if (y_next) {
        dot = orderedSum(n, [&](std::ptrdiff_t j) {
          q[j] += c * s_i[j];
          return y_next[j] * q[j];
        });
      } else {
#pragma omp parallel for schedule(static)
        for (std::ptrdiff_t j = 0; j < n; ++j) q[j] += c * s_i[j];
      }
    }
    // q approximates the inverse Hessian times g: the step is -q.
    const double slope = -orderedSum(n, [&](std::ptrdiff_t j) { return g[j] * q[j]; });
    if (!(slope < 0)) break;  // not a descent direction: converged or lost
    double step = 1, f_new = f;
    bool accepted = false;
    for (int tries = 0; tries < 20; ++tries, step *= 0.5) {
#pragma omp parallel for schedule(static)
      for (std::ptrdiff_t j = 0; j < n; ++j) x_new[j] = x[j] - step * q[j];
      f_new = evaluate(x_new, &g_new, &at_new);
      if (f_new <= f + 1e-4 * step * slope) {
        accepted = true;
        break;
      }
    }
    if (!accepted) break;
    // The new pair goes into the oldest slot (or a fresh one while the ring fills).
    const int target = (newest + 1) % kMemory;
    std::vector<float>& s_new = s_ring[target];
    std::vector<float>& y_new = y_ring[target];
    s_new.resize(x.size());
    y_new.resize(x.size());
    const double sy = orderedSum(n, [&](std::ptrdiff_t j) {
      s_new[j] = static_cast<float>(x_new[j] - x[j]);
      y_new[j] = static_cast<float>(g_new[j] - g[j]);
      return double(s_new[j]) * y_new[j];
    });
    x.swap(x_new);
    g.swap(g_new);
    f = f_new;
    at_x = at_new;
    losses.push_back(f);
    if (progress) progress(done + 1, f);
    if (converged > 0 && done + 1 >= kConvergedSteps) {
      const double before = losses[losses.size() - 1 - kConvergedSteps];
      if (before - f < converged * std::abs(before)) {
        ++done;
        break;
      }
    }
    if (sy > 1e-300) {
      newest = target;
      rho[newest] = 1 / sy;
      stored = std::min(stored + 1, kMemory);
    } else if (stored == kMemory) {
      --stored;  // the pair is not kept, and its slot held the oldest
    }
  }
  if (terms) *terms = at_x;
  return done;
}

void PixelGridProblem::normalEquations(const std::vector<double>& x, int stride,
                                       Eigen::MatrixXd& hessian, Eigen::VectorXd& gradient) const {
  // Gauss-Newton on both terms' residuals with respect to the knots' right perturbations, through
  // the image's gradient where each view sees it (each pixel's point at its inverse depth moved by
  // the view's pose); every `stride`-th row and column.
  const int W = camera_.width, H = camera_.height, C = channels_, V = views_;
  const LogMapping& log = options_.log;
  const Eigen::Index dim = 6 * static_cast<Eigen::Index>(motion_.knots().size());
  const TermScales scales = termScales();
  const double blur_scale = scales.blur, event_scale = scales.event;
  std::vector<SE3> poses(static_cast<size_t>(V));
  std::vector<Matrix3> rotations(static_cast<size_t>(V));
  std::vector<std::array<SE3, 6>> moved(static_cast<size_t>(V));
  std::vector<KnotJacobians> jacobians(static_cast<size_t>(V));
  constexpr double h = 1e-6;
  for (int k = 0; k < V; ++k) {
    const auto i = static_cast<size_t>(k);
    poses[i] = motion_.poseAt(times_us_[i], &jacobians[i]);
    rotations[i] = poses[i].rotationMatrix();
    for (int j = 0; j < 6; ++j)
      moved[i][static_cast<size_t>(j)] = poses[i] * expSE3(Vector6::Unit(j) * h);
  }
  // Each row block's sums on their own (kRowBlocks), added in block order.
  std::vector<Eigen::MatrixXd> hessians(kRowBlocks, Eigen::MatrixXd::Zero(dim, dim));
  std::vector<Eigen::VectorXd> gradients(kRowBlocks, Eigen::VectorXd::Zero(dim));
  const int rows = (H + stride - 1) / stride;  // every stride-th row
#pragma omp parallel
  {
    std::vector<Matrix6> He(static_cast<size_t>(V));  // event term, per view
    // The event term's blocks between two views (a comparison whose references come from more than
    // one view), [a * V + b] for a != b.
    std::vector<Matrix6> cross;
    std::vector<Vector6> be(static_cast<size_t>(V));
    std::array<Eigen::VectorXd, 3> jb;  // d (mean of the views) / d knots, per channel
    // Per view: its log level and that level's derivative in its pose (0 where it is dark), and
    // the sensor's reference levels (referenceLevels).
    // Per sample of the reference (the views, mid-exposure, the samples between views:
    // referenceLevels' indices), its log level.
    std::vector<Vector6> d_log(static_cast<size_t>(V));
    const auto L = static_cast<size_t>(2 * V);
    std::vector<double> levels(L), reference(L);
    const int M = referencePlays();
    std::vector<int> source(L * M), order(L);
    std::vector<uint8_t> lit(static_cast<size_t>(V));
    // Per sample between views: its channels, and its log level's derivative in its position
    // (along x and y; 0 where it is dark), which moves by half of each of its two views' moves.
    std::vector<double> between(L * C);
    std::vector<Eigen::Vector2d> between_slope(L);
    // Per view: its stencil, its sample's channels, their derivatives in its position (along x,
    // then along y) and those weighed as the blur term's mean takes them, and its position's
    // derivative in its pose.
    std::vector<Taps> taps(static_cast<size_t>(V));
    std::vector<double> values(static_cast<size_t>(V) * C), slopes(static_cast<size_t>(V) * 2 * C),
        moves(static_cast<size_t>(V) * 2 * C);
    std::vector<Eigen::Matrix<double, 2, 6>> dqs(static_cast<size_t>(V));
    BlurQuadrature quadrature;
    // A comparison's derivative as a sum over views of each one's part in its pose.
    std::vector<std::pair<int, Vector6>> terms;
    const auto addTerm = [&](int view, const Vector6& part) {
      auto same = std::find_if(terms.begin(), terms.end(),
                               [&](const auto& term) { return term.first == view; });
      if (same == terms.end())
        terms.emplace_back(view, part);
      else
        same->second += part;
    };
    const auto addSources = [&](int i, double share) {
      for (int m = 0; m < M; ++m) {
        const int from = source[static_cast<size_t>(i) * M + m];
        if (from == V) continue;  // mid-exposure's own cell does not move
        if (from < V) {
          addTerm(from, share / M * d_log[static_cast<size_t>(from)]);
          continue;
        }
        const auto b = static_cast<size_t>(from - V - 1);  // between views b and b + 1
        const Eigen::Vector2d& slope = between_slope[b];
        for (const size_t k : {b, b + 1}) {
          addTerm(static_cast<int>(k),
                  0.5 * share / M *
                      (slope.x() * dqs[k].row(0) + slope.y() * dqs[k].row(1)).transpose());
        }
      }
    };
#pragma omp for schedule(dynamic)
    for (int block = 0; block < kRowBlocks; ++block) {
      Eigen::MatrixXd& Hl = hessians[static_cast<size_t>(block)];
      Eigen::VectorXd& bl = gradients[static_cast<size_t>(block)];
      std::fill(He.begin(), He.end(), Matrix6::Zero());
      std::fill(be.begin(), be.end(), Vector6::Zero());
      std::fill(cross.begin(), cross.end(), Matrix6::Zero());
      for (int y = rows * block / kRowBlocks * stride; y < rows * (block + 1) / kRowBlocks * stride;
           y += stride) {
        for (int px = 0; px < W; px += stride) {
          const size_t pixel = static_cast<size_t>(y) * W + px;
          const size_t mid = midCell(px, y);
          levels[static_cast<size_t>(V)] = log.logOf(std::max(0.0, nerf::greyOf(&x[mid], C)));
          for (int k = 0; k < V; ++k) {
            const auto ki = static_cast<size_t>(k);
            const ViewSample s = viewSample(px, y, rotations[ki], poses[ki].translation());
            const Eigen::Vector2d& q = s.q;
            const double rho = s.rho;
            taps[ki] = tapsOf(q, s.behind);
            double* value = &values[ki * C];
            double *du = &slopes[ki * 2 * C], *dv = du + C;
            sampleSlopes(x.data(), taps[ki], value, du, dv);
            Eigen::Matrix<double, 2, 6>& dq = dqs[ki];
            const Vector3& d = directions_[pixel];
            for (int j = 0; j < 6; ++j) {
              const SE3& m = moved[ki][static_cast<size_t>(j)];
              dq.col(j) =
                  (nerf::projectPoint(camera_, m.rotation() * d + rho * m.translation()) - q) / h;
            }
            const double grey = nerf::greyOf(value, C);
            lit[ki] = grey > 0;
            levels[ki] = log.logOf(std::max(0.0, grey));
            d_log[ki].setZero();
            if (!lit[ki]) continue;
            const double slope = log.logSlope(grey);
            d_log[ki] =
                (slope * nerf::greyOf(du, C) * dq.row(0) + slope * nerf::greyOf(dv, C) * dq.row(1))
                    .transpose();
          }
          // The blur term's mean (blurQuadrature) and its derivative in the knots: each view's
          // sample moves with its pose, each sample between two views with half of each one's.
          blurQuadrature(taps.data(), quadrature);
          for (int k = 0; k < V; ++k) {
            const auto ki = static_cast<size_t>(k);
            const double w = quadrature.view_weight[ki];
            for (int j = 0; j < 2 * C; ++j) moves[ki * 2 * C + j] = w * slopes[ki * 2 * C + j];
          }
          for (size_t i = 0; i < quadrature.between.size(); ++i) {
            if (!quadrature.sampled[i]) continue;
            double du[3], dv[3];
            between_slope[i] = betweenLevel(x.data(), quadrature, i, &between[i * C], du, dv,
                                            &levels[static_cast<size_t>(V) + 1 + i]);
            const double w = 0.5 * quadrature.between_weight;
            for (const size_t k : {i, i + 1}) {
              for (int c = 0; c < C; ++c) {
                moves[k * 2 * C + c] += w * du[c];
                moves[k * 2 * C + C + c] += w * dv[c];
              }
            }
          }
          for (int c = 0; c < C; ++c) jb[static_cast<size_t>(c)] = Eigen::VectorXd::Zero(dim);
          for (int k = 0; k < V; ++k) {
            const auto ki = static_cast<size_t>(k);
            const KnotJacobians& J = jacobians[ki];
            for (int c = 0; c < C; ++c) {
              const Vector6 dvalue = (moves[ki * 2 * C + c] * dqs[ki].row(0) +
                                      moves[ki * 2 * C + C + c] * dqs[ki].row(1))
                                         .transpose();
              for (int n = 0; n < J.count; ++n) {
                jb[static_cast<size_t>(c)].segment<6>(6 * (J.first_knot + n)) +=
                    J.d_pose_d_knot[static_cast<size_t>(n)].transpose() * dvalue;
              }
            }
          }
          double sum[3];
          blurMean(values.data(), between.data(), quadrature, sum);
          // Each view's comparison with mid-exposure moves with the poses of its reference's
          // sources less those of mid-exposure's: its derivative is a sum over views of a part in
          // each one's pose (a view's share of its d_log, or half a sample between views' move),
          // which gives the blocks of each view and of each pair of views.
          const int count = sampleOrder(quadrature, order.data());
          referenceLevels(levels.data(), order.data(), count, reference.data(), source.data());
          for (int k = 0; k < V; ++k) {
            const auto ki = static_cast<size_t>(k);
            if (!lit[ki] || (across_pixels_[pixel] && across_[viewSlot(k, pixel)])) continue;
            terms.clear();
            addSources(k, 1.0);
            addSources(V, -1.0);
            const double r =
                reference[ki] - reference[static_cast<size_t>(V)] - change_[viewSlot(k, pixel)];
            double weight;
            eventPenalty(r, &weight);  // iteratively reweighted: the penalty's gradient is 2 w r
            const double w = event_scale * weight;
            for (size_t p = 0; p < terms.size(); ++p) {
              const auto v = static_cast<size_t>(terms[p].first);
              const Vector6& a = terms[p].second;
              if (a.isZero(0)) continue;
              He[v] += w * a * a.transpose();
              be[v] += w * a * r;
              for (size_t q = p + 1; q < terms.size(); ++q) {
                const auto u = static_cast<size_t>(terms[q].first);
                if (cross.empty()) cross.assign(static_cast<size_t>(V) * V, Matrix6::Zero());
                cross[v * V + u] += w * a * terms[q].second.transpose();
              }
            }
          }
          for (int c = 0; c < C; ++c) {
            bool flat = false;
            const double r = blurResidual(sum[c], blurry_.ptr<float>(y)[px * C + c], &flat);
            if (flat) continue;  // flat in the motion as well
            const Eigen::VectorXd& j = jb[static_cast<size_t>(c)];
            Hl.noalias() += blur_scale * j * j.transpose();
            bl += blur_scale * r * j;
          }
        }
      }
      for (int k = 0; k < V; ++k) {
        const KnotJacobians& J = jacobians[static_cast<size_t>(k)];
        for (int a = 0; a < J.count; ++a) {
          const Eigen::Index ia = 6 * (J.first_knot + a);
          const Matrix6& Ja = J.d_pose_d_knot[static_cast<size_t>(a)];
          bl.segment<6>(ia) += Ja.transpose() * be[static_cast<size_t>(k)];
          for (int b = 0; b < J.count; ++b) {
            Hl.block<6, 6>(ia, 6 * (J.first_knot + b)) += Ja.transpose() *
                                                          He[static_cast<size_t>(k)] *
                                                          J.d_pose_d_knot[static_cast<size_t>(b)];
          }
        }
      }
      // The blocks between two views, and their transposes.
      for (size_t pair = 0; pair < cross.size(); ++pair) {
        const Matrix6& between = cross[pair];
        if (between.isZero(0)) continue;
        const KnotJacobians& J1 = jacobians[pair / static_cast<size_t>(V)];
        const KnotJacobians& J2 = jacobians[pair % static_cast<size_t>(V)];
        for (int a = 0; a < J1.count; ++a) {
          for (int b = 0; b < J2.count; ++b) {
            const Matrix6 product = J1.d_pose_d_knot[static_cast<size_t>(a)].transpose() * between *
                                    J2.d_pose_d_knot[static_cast<size_t>(b)];
            Hl.block<6, 6>(6 * (J1.first_knot + a), 6 * (J2.first_knot + b)) += product;
            Hl.block<6, 6>(6 * (J2.first_knot + b), 6 * (J1.first_knot + a)) += product.transpose();
          }
        }
      }
    }
  }
  hessian = Eigen::MatrixXd::Zero(dim, dim);
  gradient = Eigen::VectorXd::Zero(dim);
  for (int block = 0; block < kRowBlocks; ++block) {
    hessian += hessians[static_cast<size_t>(block)];
    gradient += gradients[static_cast<size_t>(block)];
  }
}

Eigen::VectorXd PixelGridProblem::motionGradient(const std::vector<double>& u, int stride) const {
  const std::vector<double> x = intensities(u);
  Eigen::MatrixXd hessian;
  Eigen::VectorXd gradient;
  normalEquations(x, stride, hessian, gradient);
  return 2 * gradient;  // of the sum of weighted squares
}

void PixelGridProblem::holdOutEvents() {
  const int W = camera_.width, H = camera_.height;
  held_out_.assign(directions_.size(), 0);
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      // Every fourth block of each row of blocks, shifted by one block from row to row.
      if ((x / 8 + y / 8) % 4 == 0) held_out_[static_cast<size_t>(y) * W + x] = 1;
    }
  }
}

double PixelGridProblem::heldOutEventTerm(const std::vector<double>& u) const {
  if (held_out_.empty()) return 0;
  const std::vector<double> x = intensities(u);
  const int W = camera_.width, H = camera_.height, C = channels_, V = views_;
  // In a fixed order (orderedSum), so that a close choice between candidates is the same on every
  // run.
  const double sum = orderedSum(H, [&](std::ptrdiff_t row) {
    const int y = static_cast<int>(row);
    double row_sum = 0;
    const auto L = static_cast<size_t>(2 * V);
    std::vector<double> colour(L * C), between(L * C), greys(L), levels(L), reference(L);
    std::vector<int> source(L * referencePlays()), order(L);
    BlurQuadrature quadrature;
    for (int px = 0; px < W; ++px) {
      const size_t pixel = static_cast<size_t>(y) * W + px;
      if (!held_out_[pixel]) continue;
      const size_t mid = midCell(px, y);
      const int count = pixelLevels(x.data(), pixel, mid, quadrature, colour.data(), between.data(),
                                    greys.data(), levels.data(), order.data());
      referenceLevels(levels.data(), order.data(), count, reference.data(), source.data());
      for (int k = 0; k < V; ++k) {
        if (across_pixels_[pixel] && across_[viewSlot(k, pixel)]) continue;
        const double r = reference[static_cast<size_t>(k)] - reference[static_cast<size_t>(V)] -
                         change_[viewSlot(k, pixel)];
        double weight;
        row_sum += eventPenalty(r, &weight);
      }
    }
    return row_sum;
  });
  const auto held = std::count(held_out_.begin(), held_out_.end(), uint8_t{1});
  return held ? sum / (static_cast<double>(held) * V) : 0.0;
}

cv::Mat PixelGridProblem::blurResiduals(const std::vector<double>& u) const {
  const std::vector<double> x = intensities(u);
  const int W = camera_.width, H = camera_.height, C = channels_, V = views_;
  cv::Mat out(H, W, CV_64F);
#pragma omp parallel
  {
    std::vector<double> colours(static_cast<size_t>(V) * C), between(static_cast<size_t>(V) * C);
    BlurQuadrature quadrature;
#pragma omp for schedule(static)
    for (int y = 0; y < H; ++y) {
      for (int px = 0; px < W; ++px) {
        const size_t pixel = static_cast<size_t>(y) * W + px;
        for (int k = 0; k < V; ++k)
          sampleTaps(x.data(), taps_[viewSlot(k, pixel)], &colours[static_cast<size_t>(k) * C]);
        blurQuadrature(&taps_[viewSlot(0, pixel)], quadrature);
        sampleBetween(x.data(), quadrature, between.data());
        double mean[3];
        blurMean(colours.data(), between.data(), quadrature, mean);
        double squares = 0;
        for (int c = 0; c < C; ++c) {
          const double r = blurResidual(mean[c], blurry_.ptr<float>(y)[px * C + c]);
          squares += r * r;
        }
        out.at<double>(y, px) = squares;
      }
    }
  }
  return out;
}

void PixelGridProblem::setMotion(const Trajectory& motion) {
  motion_ = motion;
  buildTaps();
}

// The least damping a step that failed is tried again with. Below it the damped step is the
// Gauss-Newton step but for a few percent (the predicted reduction on nat_cat_bricks_blur30:
// 3.14e-7 at 9e-5, 3.11e-7 at 9e-3, 3.06e-7 at 9e-2), so a retry there fails as the step did; the
// steps that followed a failure were taken at 0.3-9 (BENCHMARKS.md, "The motion's retries").
constexpr double kRetryDamping = 0.1;

double PixelGridProblem::refineMotion(const std::vector<double>& u, int iterations) {
  // Levenberg-Marquardt on the knots with the image fixed, on every other row and column: the
  // normal equations there, and each trial motion's stencils and loss there too (the whole frame's
  // took 0.22 + 0.14 s a trial on nat_cat_bricks_blur30 at 32 views, two thirds of the
  // refinement; BENCHMARKS.md, "The motion's trials on every other pixel"). Called before the
  // image is solved for (EDI's frame, which has not yet taken up the motion's errors into its
  // texture) and again after (BenerfOptions::motion_rounds).
  constexpr int kStride = 2;
  const std::vector<double> x = intensities(u);
  const Eigen::Index dim = 6 * static_cast<Eigen::Index>(motion_.knots().size());
  // The loss the trials compare is the blur and event terms there: the smoothness does not move
  // with the motion.
  const auto dataLoss = [&] {
    const DataTerms data = dataTerms(x, kStride, nullptr);
    return data.blur + data.event;
  };
  double loss = dataLoss();
  double damping = 1e-3;
  bool tried = false;
  for (int iteration = 0; iteration < iterations; ++iteration) {
    Eigen::MatrixXd hessian;
    Eigen::VectorXd gradient;
    normalEquations(x, kStride, hessian, gradient);
    bool improved = false;
    for (int attempt = 0; attempt < 6 && !improved; ++attempt) {
      Eigen::MatrixXd A = hessian;
      A.diagonal() += damping * hessian.diagonal() + Eigen::VectorXd::Constant(dim, 1e-12);
      const Eigen::VectorXd step = A.ldlt().solve(-gradient);
      if (!step.allFinite()) break;
      const std::vector<SE3> saved = motion_.knots();
      motion_.applyKnotSteps(step);
      // The canvas is the mid-exposure camera's: the trajectory is moved back to pass through
      // identity there (a constant transform of every knot moves the whole spline with it).
      const SE3 anchor = motion_.poseAt(mid_us_).inverse();
      for (SE3& knot : motion_.knots()) knot = anchor * knot;
      buildTaps(false, kStride);
      tried = true;
      const double trial = dataLoss();
      if (trial < loss) {
        loss = trial;
        damping = std::max(1e-6, damping * 0.3);
        improved = true;
      } else {
        motion_.knots() = saved;
        damping = std::max(10 * damping, kRetryDamping);
      }
    }
    if (!improved) break;
  }
  if (tried) buildTaps();  // every pixel's, from the motion kept
  return loss;
}

cv::Mat PixelGridProblem::render(const std::vector<double>& u, int64_t t_us) const {
  const std::vector<double> x = intensities(u);
  const int W = camera_.width, H = camera_.height, C = channels_;
  cv::Mat out(H, W, CV_MAKETYPE(CV_32F, C));
  const SE3 pose = motion_.poseAt(t_us);
  const Matrix3 R = pose.rotationMatrix();
#pragma omp parallel for schedule(static)
  for (int y = 0; y < H; ++y) {
    float* row = out.ptr<float>(y);
    for (int px = 0; px < W; ++px) {
      const ViewSample s = viewSample(px, y, R, pose.translation());
      const Taps t = tapsOf(s.q, s.behind);
      double value[3];
      sampleTaps(x.data(), t, value);
      for (int c = 0; c < C; ++c) row[px * C + c] = static_cast<float>(value[c]);
    }
  }
  return out;
}

}  // namespace evkit
