// Fitting a radiance field to posed sharp images, and rendering one: the ray pipeline (ray_batch.h)
// that BeNeRF trains with, here with the plainest loss. Each step renders a random batch of rays
// (stratified samples in NDC t, jittered), takes the mean squared error against the pixels,
// back-propagates through the volume renderer and the field, and takes an Adam step. Deterministic
// for a seed with one thread.
#pragma once

#include <opencv2/core.hpp>
#include <utility>
#include <vector>

#include "evkit/nerf/adam.h"
#include "evkit/nerf/camera.h"
#include "evkit/nerf/field.h"
#include "evkit/nerf/volume_render.h"

namespace evkit::nerf {

struct TrainingView {
  cv::Mat image;  // float32 linear, 1 or 3 channels, camera size
  SE3 pose;       // T_world_cam (world = the NDC reference frame)
};

struct FitOptions {
  int steps = 500;
  int rays_per_step = 1024;
  int samples_per_ray = 64;
  // Hierarchical sampling: a first pass with samples_per_ray stratified samples (no gradient), then
  // importance_samples more drawn from its weights; the loss uses the union. 0: off.
  int importance_samples = 0;
  double near = 1.0;  // NDC near plane (scene units)
  AdamOptions adam;
  RenderSettings render;
  uint64_t seed = 1;
};

struct FitReport {
  std::vector<std::pair<int, double>> loss;  // (step, batch MSE)
  double seconds = 0;
};

// Importance sampling (NeRF's hierarchical sampling, Mildenhall et al. 2020 §5.2): `count` new
// sample positions in [0, 1) drawn by inverting the piecewise-constant density of `weights` over
// the intervals [t_j, t_{j+1}) (t_n = 1), at the quantiles u (sorted, in [0, 1)); a small floor on
// the weights keeps every interval reachable. Returned sorted.
std::vector<float> importanceSamples(const std::vector<float>& t, const std::vector<float>& weights,
                                     const std::vector<float>& u);

template <typename T>
FitReport fitField(RadianceField<T>& field, const PinholeCamera& camera,
                   const std::vector<TrainingView>& views, const FitOptions& options);

// Renders a whole image (sample centres, no jitter; plus importance samples when asked), in batches
// of rows.
template <typename T>
cv::Mat renderImage(RadianceField<T>& field, const PinholeCamera& camera, const SE3& pose,
                    int samples, double near, const RenderSettings& settings = {},
                    int importance_samples = 0);

}  // namespace evkit::nerf
