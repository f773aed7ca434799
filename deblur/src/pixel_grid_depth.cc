// The pixel grid's inverse depth from its solved image (BenerfOptions::depth_steps): the loss's
// gradient and a Gauss-Newton curvature in each mid-frame pixel's depth, the step they give over a
// window of pixels, and the solved image carried into a problem rebuilt on the new depth.

#include <algorithm>
#include <array>
#include <cmath>
#include <opencv2/core.hpp>

#include "evkit/deblur/pixel_grid.h"
#include "evkit/nerf/volume_render.h"
#include "pixel_grid_geometry.h"

namespace evkit {

using pixel_grid_detail::Taps;

PixelGridProblem::DepthNormals PixelGridProblem::depthNormals(const std::vector<double>& u) const {
  // A view's sample of pixel (x, y) is taken through the inverse depth at the mid-frame pixel
  // nearest where the first lookup landed (reproject): its comparison's derivative goes to that
  // pixel, dq / drho there being moveRate's. Accumulated by row blocks, each block's maps summed in
  // block order (the same bits at any thread count).
  const std::vector<double> x = intensities(u);
  const int W = camera_.width, H = camera_.height, C = channels_, V = views_, M = referencePlays();
  const LogMapping& log = options_.log;
  const int lag = eventLag();
  // In the loss's units (evaluate's): as dataTerms weighs the two terms.
  const auto [blur_scale, scale, window_scale] = termScales();
  std::vector<Matrix3> rotations(static_cast<size_t>(V));
  std::vector<Vector3> translations(static_cast<size_t>(V));
  for (int k = 0; k < V; ++k) {
    const SE3 pose = motion_.poseAt(times_us_[static_cast<size_t>(k)]);
    rotations[static_cast<size_t>(k)] = pose.rotationMatrix();
    translations[static_cast<size_t>(k)] = pose.translation();
  }
  std::vector<cv::Mat> curvatures(kRowBlocks), gradients(kRowBlocks);
  // Each pixel's row is its own block's: no two blocks write one.
  cv::Mat rates = cv::Mat::zeros(H, W, CV_64F);
#pragma omp parallel
  {
    // Per sample of the reference (the views, mid-exposure, the samples between views:
    // referenceLevels' indices).
    const auto L = static_cast<size_t>(2 * V);
    std::vector<double> levels(L), reference(L), d_reference(L), d_level(L),
        d_log(static_cast<size_t>(V)), curve(static_cast<size_t>(V));
    std::vector<int> source(L * M), order(L), at(static_cast<size_t>(V));
    // Per sample between views: its channels and its log level's derivative in its position.
    std::vector<double> between(L * C);
    std::vector<Eigen::Vector2d> between_slope(L);
    // Per view: its sample's channels, their moves per unit of its inverse depth, those weighed
    // as the blur term's mean takes them (with its samples between views), and its sample's move
    // on the mid image per unit of inverse depth (moveRate).
    std::vector<double> sums(3), colours(static_cast<size_t>(V) * C),
        moves(static_cast<size_t>(V) * 3), blur_moves(static_cast<size_t>(V) * 3);
    std::vector<Eigen::Vector2d> view_moves(static_cast<size_t>(V));
    BlurQuadrature quadrature;
#pragma omp for schedule(dynamic)
    for (int block = 0; block < kRowBlocks; ++block) {
      cv::Mat& Hm = curvatures[static_cast<size_t>(block)];
      cv::Mat& gm = gradients[static_cast<size_t>(block)];
      Hm = cv::Mat::zeros(H, W, CV_64F);
      gm = cv::Mat::zeros(H, W, CV_64F);
      for (int y = blockBegin(block); y < blockBegin(block + 1); ++y) {
        for (int px = 0; px < W; ++px) {
          const size_t pixel = static_cast<size_t>(y) * W + px;
          const size_t mid = midCell(px, y);
          levels[static_cast<size_t>(V)] = log.logOf(std::max(0.0, nerf::greyOf(&x[mid], C)));
          for (int k = 0; k < V; ++k) {
            const auto ki = static_cast<size_t>(k);
            const Vector3 Rd = rotations[ki] * directions_[pixel];
            const Vector3& t = translations[ki];
            const ViewSample s = viewSample(px, y, rotations[ki], t);
            double* value = &colours[ki * C];
            sampleTaps(x.data(), taps_[viewSlot(k, pixel)], value);
            const double grey = nerf::greyOf(value, C);
            levels[ki] = log.logOf(std::max(0.0, grey));
            d_log[ki] = 0;
            at[ki] = -1;
            if (s.behind || s.across || !(grey > 0)) continue;
            // The first lookup, whose landing picks the depth the sample is taken through.
            const Eigen::Vector2d q0 =
                pixel_grid_detail::firstLanding(camera_, inverse_depth_, px, y, Rd, t);
            const int u0 = pixel_grid_detail::nearestIndex(q0.x(), W),
                      v0 = pixel_grid_detail::nearestIndex(q0.y(), H);
            if (inverse_depth_.at<float>(v0, u0) != s.rho) continue;  // another surface's
            Eigen::Vector2d move;
            if (pixel_grid_detail::moveRate(camera_, Rd, t, s.rho, &move) < 0) continue;
            double unused[3], du[3], dv[3];
            sampleSlopes(x.data(), tapsOf(s.q, false), unused, du, dv);
            rates.at<double>(y, px) = std::max(rates.at<double>(y, px), move.norm());
            for (int c = 0; c < C; ++c)
              moves[ki * 3 + static_cast<size_t>(c)] = du[c] * move.x() + dv[c] * move.y();
            d_log[ki] = log.logSlope(grey) *
                        (nerf::greyOf(du, C) * move.x() + nerf::greyOf(dv, C) * move.y());
            view_moves[ki] = move;
            at[ki] = v0 * W + u0;
          }
          // The blur term's mean (blurQuadrature): each view's sample's move weighed as the mean
          // takes it, and each sample between two views moving by half of each one's.
          blurQuadrature(&taps_[viewSlot(0, pixel)], quadrature);
          for (int k = 0; k < V; ++k) {
            const auto ki = static_cast<size_t>(k);
            for (int c = 0; c < C; ++c)
              blur_moves[ki * 3 + c] = quadrature.view_weight[ki] * moves[ki * 3 + c];
          }
          for (size_t i = 0; i < quadrature.between.size(); ++i) {
            if (!quadrature.sampled[i]) continue;
            double du[3], dv[3];
            between_slope[i] = betweenLevel(x.data(), quadrature, i, &between[i * C], du, dv,
                                            &levels[static_cast<size_t>(V) + 1 + i]);
            for (const size_t k : {i, i + 1}) {
              if (at[k] < 0) continue;
              const double w = 0.5 * quadrature.between_weight;
              for (int c = 0; c < C; ++c)
                blur_moves[k * 3 + c] +=
                    w * (du[c] * view_moves[k].x() + dv[c] * view_moves[k].y());
            }
          }
          // The comparisons as dataTerms makes them (each view against mid-exposure, robust; each
          // view `lag` views on against it, squares), their gradient through the references to
          // each view's level (referenceGradient); the curvature as if each view's level were its
          // own reference.
          blurMean(colours.data(), between.data(), quadrature, sums.data());
          const int count = sampleOrder(quadrature, order.data());
          referenceLevels(levels.data(), order.data(), count, reference.data(), source.data());
          std::fill(d_reference.begin(), d_reference.end(), 0.0);
          std::fill(curve.begin(), curve.end(), 0.0);
          const bool across = across_pixels_[pixel] != 0;
          for (int k = 0; k < V; ++k) {
            const auto a = static_cast<size_t>(k);
            if (across && across_[viewSlot(k, pixel)]) continue;
            const double r =
                reference[a] - reference[static_cast<size_t>(V)] - change_[viewSlot(k, pixel)];
            double weight;
            eventPenalty(r, &weight);
            d_reference[a] += 2 * scale * weight * r;
            d_reference[static_cast<size_t>(V)] -= 2 * scale * weight * r;
            curve[a] += 2 * scale * weight;
            if (lag == 0 || k + lag >= V) continue;
            const auto b = static_cast<size_t>(k + lag);
            if (across && across_[viewSlot(k + lag, pixel)]) continue;
            const double rw = reference[b] - change_[viewSlot(k + lag, pixel)] -
                              (reference[a] - change_[viewSlot(k, pixel)]);
            d_reference[b] += 2 * window_scale * rw;
            d_reference[a] -= 2 * window_scale * rw;
            curve[a] += 2 * window_scale;
            curve[b] += 2 * window_scale;
          }
          referenceGradient(d_reference.data(), order.data(), count, source.data(), d_level.data());
          for (int k = 0; k < V; ++k) {
            const auto ki = static_cast<size_t>(k);
            if (at[ki] < 0) continue;
            Hm.at<double>(at[ki]) += curve[ki] * d_log[ki] * d_log[ki];
            gm.at<double>(at[ki]) += d_level[ki] * d_log[ki];
          }
          // A sample between views that a reference took moves by half of each view's move.
          for (size_t i = 0; i < quadrature.between.size(); ++i) {
            const double d = d_level[static_cast<size_t>(V) + 1 + i];
            if (d == 0) continue;
            for (const size_t k : {i, i + 1}) {
              if (at[k] < 0) continue;
              gm.at<double>(at[k]) += 0.5 * d * between_slope[i].dot(view_moves[k]);
            }
          }
          // The blur term: the mean of the views' samples against the frame, each sample's
          // derivative to the pixel whose depth it is taken through; the curvature of the whole
          // mean's change goes to the pixel itself (its views' depths are its neighbours').
          for (int c = 0; c < C; ++c) {
            bool flat = false;
            const double r = blurResidual(sums[static_cast<size_t>(c)],
                                          blurry_.ptr<float>(y)[px * C + c], &flat);
            if (flat) continue;
            double total = 0;
            for (int k = 0; k < V; ++k) {
              const auto ki = static_cast<size_t>(k);
              if (at[ki] < 0) continue;
              const double j = blur_moves[ki * 3 + static_cast<size_t>(c)];
              total += j;
              gm.at<double>(at[ki]) += 2 * blur_scale * r * j;
            }
            Hm.at<double>(y, px) += 2 * blur_scale * total * total;
          }
        }
      }
    }
  }
  DepthNormals out{cv::Mat::zeros(H, W, CV_64F), cv::Mat::zeros(H, W, CV_64F), rates};
  for (int block = 0; block < kRowBlocks; ++block) {
    out.curvature += curvatures[static_cast<size_t>(block)];
    out.gradient += gradients[static_cast<size_t>(block)];
  }
  return out;
}

cv::Mat PixelGridProblem::refinedInverseDepth(const std::vector<double>& u, int radius) const {
  // The most a step may move a view's sample of a pixel: half a pixel, the cells' resolution,
  // within which the image's derivative holds.
  constexpr double kMostMovePx = 0.5;
  const DepthNormals n = depthNormals(u);
  // Each window sums the pixels of the centre's own surface: those whose depth differs from the
  // centre's by under kDepthEdgePx of parallax, at the faster of the two pixels' move rates.
  const int W = inverse_depth_.cols, H = inverse_depth_.rows;
  cv::Mat curvature = cv::Mat::zeros(H, W, CV_64F), gradient = cv::Mat::zeros(H, W, CV_64F);
#pragma omp parallel for schedule(static)
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      const double rho = inverse_depth_.at<float>(y, x), rate = n.move_rate.at<double>(y, x);
      double h = 0, g = 0;
      for (int j = std::max(0, y - radius); j <= std::min(H - 1, y + radius); ++j) {
        for (int i = std::max(0, x - radius); i <= std::min(W - 1, x + radius); ++i) {
          const double parallax = std::abs(inverse_depth_.at<float>(j, i) - rho) *
                                  std::max(rate, n.move_rate.at<double>(j, i));
          if (!(parallax < pixel_grid_detail::kDepthEdgePx)) continue;
          h += n.curvature.at<double>(j, i);
          g += n.gradient.at<double>(j, i);
        }
      }
      curvature.at<double>(y, x) = h;
      gradient.at<double>(y, x) = g;
    }
  }
  // Levenberg's damping: a thousandth of the windows' mean curvature, so that a window that the
  // events barely see keeps its depth.
  const double damping = 1e-3 * cv::mean(curvature)[0];
  cv::Mat out = inverse_depth_.clone();
  for (int y = 0; y < out.rows; ++y) {
    for (int x = 0; x < out.cols; ++x) {
      const double rho = inverse_depth_.at<float>(y, x);
      const double h = curvature.at<double>(y, x);
      if (!(h + damping > 0)) continue;
      const double most =
          n.move_rate.at<double>(y, x) > 0 ? kMostMovePx / n.move_rate.at<double>(y, x) : 0.0;
      const double step = std::clamp(-gradient.at<double>(y, x) / (h + damping), -most, most);
      out.at<float>(y, x) = static_cast<float>(std::max(rho + step, 0.0));
    }
  }
  return out;
}

std::vector<double> PixelGridProblem::carriedFrom(const PixelGridProblem& other,
                                                  const std::vector<double>& u) const {
  std::vector<double> x = start(other.render(u, mid_us_));
  const int C = channels_, S = options_.subdivision;
  const int shift = (margin_ - other.margin_) * S;  // this canvas's cell i is other's i - shift
  for (int j = 0; j < canvas_h_; ++j) {
    const int oj = j - shift;
    if (oj < 0 || oj >= other.canvas_h_) continue;
    for (int i = 0; i < canvas_w_; ++i) {
      const int oi = i - shift;
      if (oi < 0 || oi >= other.canvas_w_) continue;
      for (int c = 0; c < C; ++c) {
        x[(static_cast<size_t>(j) * canvas_w_ + i) * C + c] =
            u[(static_cast<size_t>(oj) * other.canvas_w_ + oi) * C + c];
      }
    }
  }
  // The layer behind: each of this one's cells that the other held.
  if (!layered() || !other.layered()) return x;
  std::vector<int> slot_of(static_cast<size_t>(other.behind_w_) * other.behind_h_, -1);
  for (size_t slot = 0; slot < other.behind_cell_.size(); ++slot)
    slot_of[static_cast<size_t>(other.behind_cell_[slot])] = static_cast<int>(slot);
  const int behind_shift = margin_ - other.margin_;
  const size_t first = static_cast<size_t>(canvas_w_) * canvas_h_ * C,
               other_first = static_cast<size_t>(other.canvas_w_) * other.canvas_h_ * C;
  for (size_t slot = 0; slot < behind_cell_.size(); ++slot) {
    const int cell = behind_cell_[slot];
    const int ox = cell % behind_w_ - behind_shift, oy = cell / behind_w_ - behind_shift;
    if (ox < 0 || oy < 0 || ox >= other.behind_w_ || oy >= other.behind_h_) continue;
    const int from = slot_of[static_cast<size_t>(oy) * other.behind_w_ + ox];
    if (from < 0) continue;
    for (int c = 0; c < C; ++c)
      x[first + slot * C + c] = u[other_first + static_cast<size_t>(from) * C + c];
  }
  return x;
}

}  // namespace evkit
