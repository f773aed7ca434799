#include "evkit/nerf/train.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <random>

#include "evkit/nerf/ray_batch.h"

namespace evkit::nerf {

std::vector<float> importanceSamples(const std::vector<float>& t, const std::vector<float>& weights,
                                     const std::vector<float>& u) {
  const size_t n = t.size();
  std::vector<double> cdf(n + 1, 0.0);
  for (size_t j = 0; j < n; ++j)
    cdf[j + 1] = cdf[j] + std::max(0.0f, std::isfinite(weights[j]) ? weights[j] : 0.0f) + 1e-5;
  std::vector<float> out;
  out.reserve(u.size());
  for (float q : u) {
    const double target = static_cast<double>(q) * cdf[n];
    const size_t j = std::min<size_t>(
        n - 1,
        static_cast<size_t>(std::upper_bound(cdf.begin(), cdf.end(), target) - cdf.begin()) - 1);
    const double lo = t[j], hi = j + 1 < n ? t[j + 1] : 1.0;
    const double frac = (target - cdf[j]) / std::max(cdf[j + 1] - cdf[j], 1e-12);
    out.push_back(static_cast<float>(lo + std::clamp(frac, 0.0, 1.0) * (hi - lo)));
  }
  std::sort(out.begin(), out.end());
  return out;
}

template <typename T>
FitReport fitField(RadianceField<T>& field, const PinholeCamera& camera,
                   const std::vector<TrainingView>& views, const FitOptions& o) {
  const auto start = std::chrono::steady_clock::now();
  FitReport report;
  Adam<T> adam(field.parameters(), o.adam);
  std::mt19937_64 rng(o.seed);
  const int C = field.channels();
  const int R = o.rays_per_step, S0 = o.samples_per_ray;
  std::vector<SE3> poses;
  for (const TrainingView& v : views) poses.push_back(v.pose);
  RayBatch<T> batch(camera,
                    {.samples = S0, .near = o.near, .depth_scale = 1.0, .render = o.render});
  std::vector<typename RayBatch<T>::PixelRay> rays(static_cast<size_t>(R));
  std::vector<float> jitter(static_cast<size_t>(R) * S0), target(static_cast<size_t>(R * C));
  std::vector<T> d_colour(static_cast<size_t>(R) * 3, T(0));
  for (int step = 0; step < o.steps; ++step) {
    // Rays: random view and pixel; jittered samples (drawn sequentially: deterministic).
    std::uniform_int_distribution<size_t> view(0, views.size() - 1);
    std::uniform_int_distribution<int> px(0, camera.width - 1), py(0, camera.height - 1);
    std::uniform_real_distribution<float> u(0.0f, 1.0f);
    for (int r = 0; r < R; ++r) {
      const size_t k = view(rng);
      const int x = px(rng), y = py(rng);
      for (int j = 0; j < S0; ++j) jitter[static_cast<size_t>(r) * S0 + j] = u(rng);
      rays[static_cast<size_t>(r)] = {x, y, static_cast<int>(k)};
      const cv::Mat& image = views[k].image;
      for (int c = 0; c < C; ++c) {
        target[static_cast<size_t>(r * C + c)] =
            C == 1 ? image.at<float>(y, x) : image.at<cv::Vec3f>(y, x)[c];
      }
    }
    batch.setRays(poses, rays, jitter.data());
    if (o.importance_samples > 0) batch.refine(field, o.importance_samples, u(rng));
    field.zeroGradients();
    batch.forward(field, true);
    double loss = 0;
    for (int r = 0; r < R; ++r) {
      for (int c = 0; c < C; ++c) {
        const T e =
            batch.render(r).colour[c] - static_cast<T>(target[static_cast<size_t>(r * C + c)]);
        loss += static_cast<double>(e * e);
        d_colour[static_cast<size_t>(r) * 3 + c] = T(2) * e / static_cast<T>(R * C);
      }
    }
    batch.backward(field, d_colour, false);
    adam.step();
    report.loss.emplace_back(step, loss / (R * C));
  }
  report.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return report;
}

template <typename T>
cv::Mat renderImage(RadianceField<T>& field, const PinholeCamera& camera, const SE3& pose,
                    int samples, double near, const RenderSettings& settings,
                    int importance_samples) {
  const int C = field.channels();
  cv::Mat image(camera.height, camera.width, CV_MAKETYPE(CV_32F, C));
  RayBatch<T> batch(camera,
                    {.samples = samples, .near = near, .depth_scale = 1.0, .render = settings});
  std::vector<typename RayBatch<T>::PixelRay> rays(static_cast<size_t>(camera.width));
  for (int y = 0; y < camera.height; ++y) {
    for (int x = 0; x < camera.width; ++x) rays[static_cast<size_t>(x)] = {x, y, 0};
    batch.setRays({pose}, rays, nullptr);
    batch.refine(field, importance_samples, 0.5f);
    batch.forward(field, false);
    for (int x = 0; x < camera.width; ++x) {
      for (int c = 0; c < C; ++c)
        image.ptr<float>(y)[x * C + c] = static_cast<float>(batch.render(x).colour[c]);
    }
  }
  return image;
}

template FitReport fitField(RadianceField<float>&, const PinholeCamera&,
                            const std::vector<TrainingView>&, const FitOptions&);
template FitReport fitField(RadianceField<double>&, const PinholeCamera&,
                            const std::vector<TrainingView>&, const FitOptions&);
template cv::Mat renderImage(RadianceField<float>&, const PinholeCamera&, const SE3&, int, double,
                             const RenderSettings&, int);
template cv::Mat renderImage(RadianceField<double>&, const PinholeCamera&, const SE3&, int, double,
                             const RenderSettings&, int);

}  // namespace evkit::nerf
