// One batch of rays through a radiance field, forward and back: the NDC ray of each pixel from its
// pose, stratified samples along it (optionally refined by importance sampling), the field at every
// sample, the volume render of every ray; then, from the loss's gradient with respect to each
// rendered colour, the field's parameter gradients and, when asked, each pose's gradient.
//
// The one ray pipeline of evkit: fitting a field to posed images (train.h), rendering an image, and
// BeNeRF's loss all run through it.
//
//   RayBatch<float> batch(camera, {.samples = 8, .near = 1});
//   batch.setRays(poses, rays, jitter.data());   // rays: pixel and pose index
//   batch.forward(field, true);                  // true: backward() follows
//   ... loss from batch.render(r).colour, dL/dcolour into d_colour (3 per ray) ...
//   std::vector<Vector6> d_pose = batch.backward(field, d_colour, true);
#pragma once

#include <vector>

#include "evkit/nerf/camera.h"
#include "evkit/nerf/field.h"
#include "evkit/nerf/volume_render.h"
#include "evkit/spline/lie.h"

namespace evkit::nerf {

struct RayBatchOptions {
  int samples = 8;    // stratified samples per ray
  double near = 1.0;  // NDC near plane (scene units)
  // The field sees NDC (x, y, depth_scale z): below 1 its encoding has fewer cells along depth
  // than across the image (BeNeRF's views differ by millimetres, so depth is weakly observed).
  double depth_scale = 1.0;
  RenderSettings render;
};

template <typename T>
class RayBatch {
 public:
  using Matrix = typename RadianceField<T>::Matrix;

  struct PixelRay {
    int x = 0, y = 0;  // pixel
    int pose = 0;      // index into the poses given to setRays
  };

  RayBatch(const PinholeCamera& camera, const RayBatchOptions& options)
      : camera_(camera), options_(options) {}

  // The rays and their samples: t_j = (j + jitter_j) / samples, jitter `samples` values per ray in
  // [0, 1) (nullptr: the centres, 0.5).
  void setRays(const std::vector<SE3>& poses, std::vector<PixelRay> rays, const float* jitter);
  // NeRF's hierarchical sampling (Mildenhall et al. 2020, §5.2): renders the current samples
  // without gradients and adds `extra` samples per ray drawn from their weights at the quantiles
  // (k + shift) / extra (importanceSamples in train.h).
  void refine(RadianceField<T>& field, int extra, float shift);

  // The field at every sample and the render of every ray. With gradients the field runs in one
  // call, keeping its activations for backward(); without, in chunks of bounded memory.
  void forward(RadianceField<T>& field, bool with_gradients);
  const RayRender<T>& render(int ray) const { return renders_[static_cast<size_t>(ray)]; }

  // Accumulates the field's parameter gradients from d_colour (dL/d rendered colour, 3 values per
  // ray, the field's channels used) and returns dL/d pose for each pose (right perturbation
  // (rho, phi), as ndcPointPoseJacobian) when pose_gradients, otherwise nothing.
  std::vector<Vector6> backward(RadianceField<T>& field, const std::vector<T>& d_colour,
                                bool pose_gradients);

  int size() const { return static_cast<int>(rays_.size()); }
  int samplesPerRay() const { return samples_; }

 private:
  void placeSamples(int ray, const T* t);  // positions and interval lengths from the ray's t

  PinholeCamera camera_;
  RayBatchOptions options_;
  std::vector<SE3> poses_;
  std::vector<PixelRay> rays_;
  std::vector<NdcRay> ndc_;
  int samples_ = 0;           // per ray (options.samples, more after refine)
  Matrix positions_;          // 3 x (rays * samples)
  std::vector<T> t_, delta_;  // per sample: NDC parameter, interval length (t_{j+1} - t_j) |d|
  Matrix out_;                // (1 + channels) x (rays * samples): the field's density and colour
  std::vector<RayRender<T>> renders_;
};

}  // namespace evkit::nerf
