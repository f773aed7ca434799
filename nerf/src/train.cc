#include "evkit/nerf/train.h"

#include <chrono>
#include <random>

namespace evkit::nerf {

RaySamples sampleRay(const NdcRay& ray, int samples, const std::vector<float>& jitter) {
  RaySamples s;
  s.positions.resize(3, samples);
  s.t.resize(static_cast<size_t>(samples));
  s.delta.resize(static_cast<size_t>(samples));
  const float length = static_cast<float>(ray.direction.norm());
  for (int j = 0; j < samples; ++j) s.t[static_cast<size_t>(j)] = (static_cast<float>(j) + jitter[static_cast<size_t>(j)]) / static_cast<float>(samples);
  for (int j = 0; j < samples; ++j) {
    const float t = s.t[static_cast<size_t>(j)];
    const float next = j + 1 < samples ? s.t[static_cast<size_t>(j + 1)] : 1.0f;
    s.delta[static_cast<size_t>(j)] = (next - t) * length;
    s.positions.col(j) = (ray.origin + static_cast<double>(t) * ray.direction).cast<float>();
  }
  return s;
}

template <typename T>
FitReport fitField(RadianceField<T>& field, const PinholeCamera& camera, const std::vector<TrainingView>& views, const FitOptions& o) {
  using Matrix = typename RadianceField<T>::Matrix;
  const auto start = std::chrono::steady_clock::now();
  FitReport report;
  Adam<T> adam(field.parameters(), o.adam);
  std::mt19937_64 rng(o.seed);
  const int C = field.channels();
  const int R = o.rays_per_step, S = o.samples_per_ray;
  std::vector<RaySamples> rays(static_cast<size_t>(R));
  std::vector<float> target(static_cast<size_t>(R * C));
  Matrix positions(3, R * S);
  for (int step = 0; step < o.steps; ++step) {
    // Rays: random view and pixel; jittered samples (drawn sequentially: deterministic).
    std::uniform_int_distribution<size_t> view(0, views.size() - 1);
    std::uniform_int_distribution<int> px(0, camera.width - 1), py(0, camera.height - 1);
    std::uniform_real_distribution<float> u(0.0f, 1.0f);
    std::vector<float> jitter(static_cast<size_t>(S));
    for (int r = 0; r < R; ++r) {
      const TrainingView& v = views[view(rng)];
      const int x = px(rng), y = py(rng);
      for (float& j : jitter) j = u(rng);
      rays[static_cast<size_t>(r)] = sampleRay(toNdc(worldRay(camera, v.pose, x, y), camera, o.near), S, jitter);
      positions.middleCols(r * S, S) = rays[static_cast<size_t>(r)].positions.template cast<T>();
      for (int c = 0; c < C; ++c) {
        target[static_cast<size_t>(r * C + c)] = C == 1 ? v.image.at<float>(y, x) : v.image.at<cv::Vec3f>(y, x)[c];
      }
    }
    field.zeroGradients();
    const Matrix out = field.forward(positions);
    Matrix d_out = Matrix::Zero(out.rows(), out.cols());
    double loss = 0;
#pragma omp parallel for schedule(static) reduction(+ : loss)
    for (int r = 0; r < R; ++r) {
      std::vector<T> sigma(static_cast<size_t>(S)), colours(static_cast<size_t>(S * C)), delta(static_cast<size_t>(S)), ts(static_cast<size_t>(S));
      for (int j = 0; j < S; ++j) {
        sigma[static_cast<size_t>(j)] = out(0, r * S + j);
        for (int c = 0; c < C; ++c) colours[static_cast<size_t>(j * C + c)] = out(1 + c, r * S + j);
        delta[static_cast<size_t>(j)] = static_cast<T>(rays[static_cast<size_t>(r)].delta[static_cast<size_t>(j)]);
        ts[static_cast<size_t>(j)] = static_cast<T>(rays[static_cast<size_t>(r)].t[static_cast<size_t>(j)]);
      }
      const RayRender<T> f = renderRay(sigma.data(), colours.data(), delta.data(), ts.data(), static_cast<size_t>(S), C, o.render);
      T d_colour[3];
      for (int c = 0; c < C; ++c) {
        const T e = f.colour[c] - static_cast<T>(target[static_cast<size_t>(r * C + c)]);
        loss += static_cast<double>(e * e);
        d_colour[c] = T(2) * e / static_cast<T>(R * C);
      }
      std::vector<T> d_sigma(static_cast<size_t>(S)), d_colours(static_cast<size_t>(S * C));
      renderRayBackward(sigma.data(), colours.data(), delta.data(), static_cast<size_t>(S), C, o.render, f, d_colour, d_sigma.data(), d_colours.data());
      for (int j = 0; j < S; ++j) {
        d_out(0, r * S + j) = d_sigma[static_cast<size_t>(j)];
        for (int c = 0; c < C; ++c) d_out(1 + c, r * S + j) = d_colours[static_cast<size_t>(j * C + c)];
      }
    }
    field.backward(d_out);
    adam.step();
    report.loss.emplace_back(step, loss / (R * C));
  }
  report.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return report;
}

template <typename T>
cv::Mat renderImage(RadianceField<T>& field, const PinholeCamera& camera, const SE3& pose, int samples, double near,
                    const RenderSettings& settings) {
  using Matrix = typename RadianceField<T>::Matrix;
  const int C = field.channels();
  cv::Mat image(camera.height, camera.width, CV_MAKETYPE(CV_32F, C));
  const std::vector<float> centres(static_cast<size_t>(samples), 0.5f);
  for (int y = 0; y < camera.height; ++y) {
    std::vector<RaySamples> rays(static_cast<size_t>(camera.width));
    Matrix positions(3, camera.width * samples);
    for (int x = 0; x < camera.width; ++x) {
      rays[static_cast<size_t>(x)] = sampleRay(toNdc(worldRay(camera, pose, x, y), camera, near), samples, centres);
      positions.middleCols(x * samples, samples) = rays[static_cast<size_t>(x)].positions.template cast<T>();
    }
    const Matrix out = field.forward(positions);
    for (int x = 0; x < camera.width; ++x) {
      std::vector<T> sigma(static_cast<size_t>(samples)), colours(static_cast<size_t>(samples * C)), delta(static_cast<size_t>(samples));
      for (int j = 0; j < samples; ++j) {
        sigma[static_cast<size_t>(j)] = out(0, x * samples + j);
        for (int c = 0; c < C; ++c) colours[static_cast<size_t>(j * C + c)] = out(1 + c, x * samples + j);
        delta[static_cast<size_t>(j)] = static_cast<T>(rays[static_cast<size_t>(x)].delta[static_cast<size_t>(j)]);
      }
      const RayRender<T> f = renderRay(sigma.data(), colours.data(), delta.data(), static_cast<const T*>(nullptr), static_cast<size_t>(samples), C, settings);
      for (int c = 0; c < C; ++c) image.ptr<float>(y)[x * C + c] = static_cast<float>(f.colour[c]);
    }
  }
  return image;
}

template FitReport fitField(RadianceField<float>&, const PinholeCamera&, const std::vector<TrainingView>&, const FitOptions&);
template FitReport fitField(RadianceField<double>&, const PinholeCamera&, const std::vector<TrainingView>&, const FitOptions&);
template cv::Mat renderImage(RadianceField<float>&, const PinholeCamera&, const SE3&, int, double, const RenderSettings&);
template cv::Mat renderImage(RadianceField<double>&, const PinholeCamera&, const SE3&, int, double, const RenderSettings&);

}  // namespace evkit::nerf
