// Where each view's pixel is seen on the pixel grid: the two lookups on the registered inverse
// depth, the nearest surface the ray meets around a depth edge (a z-buffer over the depths within
// the layers' parallax), and the layer behind, which holds what a near surface hides at
// mid-exposure (pixel_grid.h, PixelGridOptions::occlusion).

#include <algorithm>
#include <array>
#include <cmath>
#include <opencv2/imgproc.hpp>

#include "evkit/deblur/pixel_grid.h"
#include "pixel_grid_geometry.h"

namespace evkit {

using pixel_grid_detail::acrossDepthEdge;
using pixel_grid_detail::inverseDepthAt;
using pixel_grid_detail::kDepthEdgePx;
using pixel_grid_detail::kMostParallax;
using pixel_grid_detail::moveRate;
using pixel_grid_detail::nearestIndex;
using pixel_grid_detail::reproject;
using pixel_grid_detail::sample;
using pixel_grid_detail::Taps;
using pixel_grid_detail::tapsAt;

namespace {

// The layer behind's cells reach this many cells beyond its samples' stencils, so that the motion's
// refinements, which move the samples, find cells there.
constexpr int kBehindApron = 2;

}  // namespace

double PixelGridProblem::longestImagePath(const PinholeCamera& camera, const Trajectory& motion,
                                          const cv::Mat& inverse_depth, int64_t t0, int64_t t1) {
  constexpr int kGrid = 16, kSteps = 32;
  std::vector<Matrix3> rotations;
  std::vector<Vector3> translations;
  for (int k = 0; k <= kSteps; ++k) {
    const SE3 pose = motion.poseAt(t0 + (t1 - t0) * k / kSteps);
    rotations.push_back(pose.rotationMatrix());
    translations.push_back(pose.translation());
  }
  std::vector<double> paths;
  paths.reserve(kGrid * kGrid);
  for (int j = 0; j < kGrid; ++j) {
    for (int i = 0; i < kGrid; ++i) {
      const int x = (2 * i + 1) * camera.width / (2 * kGrid),
                y = (2 * j + 1) * camera.height / (2 * kGrid);
      const Vector3 d = nerf::pixelDirection(camera, x, y);
      double path = 0;
      Eigen::Vector2d last;
      for (size_t k = 0; k < rotations.size(); ++k) {
        const Eigen::Vector2d q =
            reproject(camera, inverse_depth, x, y, rotations[k] * d, translations[k], nullptr);
        if (k > 0) path += (q - last).norm();
        last = q;
      }
      paths.push_back(path);
    }
  }
  // The longest but for the 2% longest: a few pixels' own depths (registered from their flows)
  // can be far off, mostly along the image's border, where the flows are poorest.
  const auto at = paths.begin() + static_cast<std::ptrdiff_t>(paths.size() * 98 / 100);
  std::nth_element(paths.begin(), at, paths.end());
  return *at;
}

double PixelGridProblem::acrossShare() const {
  if (across_.empty()) return 0;
  return static_cast<double>(std::count(across_.begin(), across_.end(), uint8_t{1})) /
         static_cast<double>(across_.size());
}

double PixelGridProblem::behindShare() const {
  if (taps_.empty()) return 0;
  const auto count = std::count_if(taps_.begin(), taps_.end(), behind);
  return static_cast<double>(count) / static_cast<double>(taps_.size());
}

std::array<size_t, 4> PixelGridProblem::corners(const Taps& t) const {
  if (t.index >= 0) {
    const auto i = static_cast<size_t>(t.index), W = static_cast<size_t>(canvas_w_);
    return {i, i + 1, i + W, i + W + 1};
  }
  const auto i = static_cast<size_t>(-t.index - 1), W = static_cast<size_t>(behind_w_);
  const size_t front = static_cast<size_t>(canvas_w_) * canvas_h_;
  return {front + static_cast<size_t>(behind_slot_[i]),
          front + static_cast<size_t>(behind_slot_[i + 1]),
          front + static_cast<size_t>(behind_slot_[i + W]),
          front + static_cast<size_t>(behind_slot_[i + W + 1])};
}

void PixelGridProblem::sampleBehind(const double* x, const Taps& t, double* out) const {
  const int C = channels_;
  const std::array<size_t, 4> at = corners(t);
  const double w00 = (1 - t.ay) * (1 - t.ax), w01 = (1 - t.ay) * t.ax, w10 = t.ay * (1 - t.ax),
               w11 = t.ay * t.ax;
  for (int c = 0; c < C; ++c) {
    out[c] = w00 * x[at[0] * C + c] + w01 * x[at[1] * C + c] + w10 * x[at[2] * C + c] +
             w11 * x[at[3] * C + c];
  }
}

void PixelGridProblem::sampleTaps(const double* x, const Taps& t, double* out) const {
  if (behind(t))
    sampleBehind(x, t, out);
  else
    sample(x, canvas_w_, channels_, t, out);
}

bool PixelGridProblem::behindHolds(const Eigen::Vector2d& q) const {
  if (behind_slot_.empty()) return false;
  const Taps t = tapsAt(q.x() + margin_, q.y() + margin_, behind_w_, behind_h_);
  const auto i = static_cast<size_t>(t.index), W = static_cast<size_t>(behind_w_);
  return behind_slot_[i] >= 0 && behind_slot_[i + 1] >= 0 && behind_slot_[i + W] >= 0 &&
         behind_slot_[i + W + 1] >= 0;
}

void PixelGridProblem::allocateBehind() {
  // Every stencil's four cells, and kBehindApron cells around them, in the canvas's order.
  cv::Mat used = cv::Mat::zeros(behind_h_, behind_w_, CV_8U);
  for (const Taps& t : taps_) {
    if (!behind(t)) continue;
    const int i = -t.index - 1, x = i % behind_w_, y = i / behind_w_;
    used(cv::Rect(x, y, 2, 2)).setTo(1);
  }
  if (cv::countNonZero(used) == 0) return;
  cv::dilate(used, used, cv::Mat::ones(2 * kBehindApron + 1, 2 * kBehindApron + 1, CV_8U));
  behind_slot_.assign(static_cast<size_t>(behind_w_) * behind_h_, -1);
  behind_cell_.clear();
  for (int y = 0; y < behind_h_; ++y) {
    for (int x = 0; x < behind_w_; ++x) {
      if (!used.at<uint8_t>(y, x)) continue;
      const int cell = y * behind_w_ + x;
      behind_slot_[static_cast<size_t>(cell)] = static_cast<int>(behind_cell_.size());
      behind_cell_.push_back(cell);
    }
  }
}

// The surfaces a view's pixel may see besides the one its lookups settle on: the nearest and
// the farthest inverse depth within the layers' parallax (how far apart the map's nearest and
// farthest inverse depths put a pixel in any view, on a 16 x 16 grid of pixels; at most
// kMostParallax px).
void PixelGridProblem::findSurfaces() {
  const int W = camera_.width, H = camera_.height;
  double lowest = 0, highest = 0;
  cv::minMaxLoc(inverse_depth_, &lowest, &highest);
  double parallax = 0;
  for (int k = 0; k < views_ && options_.occlusion && highest > lowest; ++k) {
    const SE3 pose = motion_.poseAt(times_us_[static_cast<size_t>(k)]);
    const Matrix3 R = pose.rotationMatrix();
    constexpr int kGrid = 16;
    for (int j = 0; j < kGrid; ++j) {
      for (int i = 0; i < kGrid; ++i) {
        const Vector3 Rd = R * nerf::pixelDirection(camera_, (2 * i + 1) * W / (2 * kGrid),
                                                    (2 * j + 1) * H / (2 * kGrid));
        const double apart = (nerf::projectPoint(camera_, Rd + highest * pose.translation()) -
                              nerf::projectPoint(camera_, Rd + lowest * pose.translation()))
                                 .norm();
        if (std::isfinite(apart)) parallax = std::max(parallax, apart);
      }
    }
  }
  // Twice the most any view moves a pixel per unit of inverse depth, a bound for the candidates'
  // first test.
  most_move_ = highest > lowest ? 2 * parallax / (highest - lowest) : 0;
  if (options_.occlusion && parallax > kDepthEdgePx) {
    // Only around a depth edge: two neighbouring pixels whose inverse depths differ by what could
    // move a view's sample by more than kDepthEdgePx. Elsewhere the surface is taken as continuous
    // (a slant's neighbours differ a little everywhere), and its own depth is both.
    const double jump = kDepthEdgePx / (0.5 * most_move_);
    cv::Mat edge = cv::Mat::zeros(H, W, CV_8U);
    for (int y = 0; y < H; ++y) {
      const float* row = inverse_depth_.ptr<float>(y);
      const float* below = inverse_depth_.ptr<float>(std::min(y + 1, H - 1));
      uint8_t* out = edge.ptr<uint8_t>(y);
      for (int x = 0; x < W; ++x) {
        if (std::abs(row[std::min(x + 1, W - 1)] - row[x]) > jump ||
            std::abs(below[x] - row[x]) > jump)
          out[x] = 1;
      }
    }
    if (cv::countNonZero(edge) > 0) {
      const int radius = std::min(kMostParallax, static_cast<int>(std::ceil(parallax)));
      const cv::Mat window = cv::Mat::ones(2 * radius + 1, 2 * radius + 1, CV_8U);
      cv::dilate(inverse_depth_, nearest_, window, cv::Point(-1, -1), 1, cv::BORDER_REPLICATE);
      cv::erode(inverse_depth_, farthest_, window, cv::Point(-1, -1), 1, cv::BORDER_REPLICATE);
      cv::Mat near_edge;
      cv::dilate(edge, near_edge, window, cv::Point(-1, -1), 1, cv::BORDER_REPLICATE);
      inverse_depth_.copyTo(nearest_, near_edge == 0);
      inverse_depth_.copyTo(farthest_, near_edge == 0);
    }
  }
}

void PixelGridProblem::buildTaps(bool allocating, int stride) {
  const int W = camera_.width, H = camera_.height;
  const size_t N = directions_.size();
  taps_.resize(static_cast<size_t>(views_) * N);
  across_.resize(taps_.size());
  across_pixels_.assign(N, 0);
  for (int k = 0; k < views_; ++k) {
    const SE3 pose = motion_.poseAt(times_us_[static_cast<size_t>(k)]);
    const Matrix3 R = pose.rotationMatrix();
#pragma omp parallel for schedule(static)
    for (int y = 0; y < H; y += stride) {
      for (int x = 0; x < W; x += stride) {
        const size_t pixel = static_cast<size_t>(y) * W + x, slot = viewSlot(k, pixel);
        if (!occluding_) {  // the lookups alone, without viewSample's call
          const ViewSample s = lookups(x, y, R * directions_[pixel], pose.translation());
          taps_[slot] =
              tapsAt(cellCoordinate(s.q.x()), cellCoordinate(s.q.y()), canvas_w_, canvas_h_);
          across_[slot] = s.across;
          continue;
        }
        const ViewSample s = viewSample(x, y, R, pose.translation(), allocating);
        taps_[slot] = tapsOf(s.q, s.behind);
        across_[slot] = s.across;
      }
    }
  }
#pragma omp parallel for schedule(static)
  for (int y = 0; y < H; y += stride) {
    for (int x = 0; x < W; x += stride) {
      const size_t pixel = static_cast<size_t>(y) * W + x;
      for (int k = 0; k < views_; ++k) across_pixels_[pixel] |= across_[viewSlot(k, pixel)];
    }
  }
  if (!allocating && stride == 1) findBlockRows();  // else once the layer's cells are chosen
}

void PixelGridProblem::findBlockRows() {
  const int W = camera_.width;
  // The canvas rows each block of the frame's rows reaches: its views' stencils (two rows each)
  // and its pixels' own cells at mid-exposure.
  // The cells of the layer behind each reaches, likewise.
  const int S = options_.subdivision;
  const auto front = static_cast<size_t>(canvas_w_) * canvas_h_;
  block_rows_.resize(kRowBlocks);
  block_behind_.assign(kRowBlocks, {0, 0});
#pragma omp parallel for schedule(static)
  for (int block = 0; block < kRowBlocks; ++block) {
    int first = canvas_h_, last = 0;
    int first_behind = behindCells(), last_behind = 0;
    for (int y = blockBegin(block); y < blockBegin(block + 1); ++y) {
      first = std::min(first, (y + margin_) * S);
      last = std::max(last, (y + margin_) * S + 1);
      const auto begin = taps_.begin() +
                         static_cast<std::ptrdiff_t>(viewSlot(0, static_cast<size_t>(y) * W)),
                 end = begin + static_cast<std::ptrdiff_t>(W) * views_;
      for (auto t = begin; t != end; ++t) {
        if (!behind(*t)) {
          first = std::min(first, t->index / canvas_w_);
          last = std::max(last, t->index / canvas_w_ + 2);
        } else if (layered()) {
          for (const size_t cell : corners(*t)) {
            const int slot = static_cast<int>(cell - front);
            first_behind = std::min(first_behind, slot);
            last_behind = std::max(last_behind, slot + 1);
          }
        }
      }
    }
    block_rows_[static_cast<size_t>(block)] = {first, std::max(first, last)};
    block_behind_[static_cast<size_t>(block)] = {first_behind, std::max(first_behind, last_behind)};
  }
}

Eigen::Vector2d PixelGridProblem::cellOf(int x, int y, const Matrix3& R, const Vector3& t,
                                         double* rho_used) const {
  return reproject(camera_, inverse_depth_, x, y,
                   R * directions_[static_cast<size_t>(y) * camera_.width + x], t, rho_used);
}

PixelGridProblem::ViewSample PixelGridProblem::viewSample(int x, int y, const Matrix3& R,
                                                          const Vector3& t, bool allocating) const {
  const Vector3 Rd = R * directions_[static_cast<size_t>(y) * camera_.width + x];
  ViewSample s = lookups(x, y, Rd, t);
  if (!occluding_) return s;
  // The nearest and farthest surfaces around where the sample landed; where their parallax is
  // under a quarter of kDepthEdgePx (to first order), the lookups' surface is the one seen.
  const int u = nearestIndex(s.q.x(), camera_.width), v = nearestIndex(s.q.y(), camera_.height);
  const double near = nearest_.ptr<float>(v)[u], far = farthest_.ptr<float>(v)[u];
  if (!((near - far) * most_move_ >= 0.25 * kDepthEdgePx)) return s;  // most samples: one surface
  Eigen::Vector2d move;
  const double rate = moveRate(camera_, Rd, t, s.rho, &move);
  if (rate >= 0 && (near - far) * rate < 0.25 * kDepthEdgePx) return s;
  // The ray meets every surface whose depth where the mid image sees it moves the sample by under
  // kDepthEdgePx; the nearest of them hides the others (a z-buffer over the candidates: the
  // lookups' own, unless across, and the nearest and farthest around).
  bool settled = !s.across;
  for (const double rho : {near, far}) {
    // A settled sample looks only for a nearer surface, and one it would move by more than
    // kDepthEdgePx (to first order).
    if (settled && !(rate >= 0 && (rho - s.rho) * rate > kDepthEdgePx)) continue;
    // Where it lands to first order: a depth there that would move it by more than twice
    // kDepthEdgePx rules it out before the projections (most candidates near an edge land on the
    // other surface).
    if (rate >= 0) {
      const Eigen::Vector2d guess = s.q + (rho - s.rho) * move;
      if (std::abs(inverseDepthAt(camera_, inverse_depth_, guess.x(), guess.y()) - rho) * rate >
          2 * kDepthEdgePx)
        continue;
    }
    const Eigen::Vector2d q = nerf::projectPoint(camera_, Rd + rho * t);
    const double there = inverseDepthAt(camera_, inverse_depth_, q.x(), q.y());
    const Eigen::Vector2d at = nerf::projectPoint(camera_, Rd + there * t);
    if (!((at - q).norm() <= kDepthEdgePx) || (settled && !(there > s.rho))) continue;
    s = {at, there, false, false};
    settled = true;
  }
  if (settled || !(allocating || layered())) return s;
  // No surface seen at mid-exposure meets the ray: it sees what a nearer surface hides there, the
  // farthest surface around, from the layer behind (the background that the near surface's edge
  // uncovers as the camera moves).
  const Eigen::Vector2d q = nerf::projectPoint(camera_, Rd + far * t);
  const double there = inverseDepthAt(camera_, inverse_depth_, q.x(), q.y());
  if (there > far && (nerf::projectPoint(camera_, Rd + there * t) - q).norm() > kDepthEdgePx &&
      (allocating || behindHolds(q)))
    s = {q, far, true, false};
  return s;  // the one object every path returns (a copy of it stalled on its halves' stores)
}

cv::Mat PixelGridProblem::behindStart(const cv::Mat& image) const {
  // A pixel nearer its surroundings' nearest depth than their farthest (nearest_, farthest_) is on
  // the near side of an edge: it takes the mean of the nearest ring of pixels around it (in
  // Chebyshev distance) that are on the far side by its own measure; every other pixel keeps its
  // own value.
  const int C = channels_, W = image.cols, H = image.rows;
  cv::Mat filled = image.clone();
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      const double near = nearest_.ptr<float>(y)[x], far = farthest_.ptr<float>(y)[x];
      const double cut = far + 0.5 * (near - far);
      if (inverse_depth_.ptr<float>(y)[x] <= cut) continue;
      for (int ring = 1; ring <= kMostParallax + 1; ++ring) {
        double sum[3] = {0, 0, 0};
        int count = 0;
        const auto take = [&](int u, int v) {
          if (u < 0 || v < 0 || u >= W || v >= H || !(inverse_depth_.ptr<float>(v)[u] <= cut))
            return;
          for (int c = 0; c < C; ++c) sum[c] += image.ptr<double>(v)[u * C + c];
          ++count;
        };
        for (int d = -ring; d <= ring; ++d) {
          take(x + d, y - ring);
          take(x + d, y + ring);
          if (d > -ring && d < ring) {
            take(x - ring, y + d);
            take(x + ring, y + d);
          }
        }
        if (count == 0) continue;
        for (int c = 0; c < C; ++c) filled.ptr<double>(y)[x * C + c] = sum[c] / count;
        break;
      }
    }
  }
  return filled;
}

}  // namespace evkit
