#include "evkit/nerf/train.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <random>

namespace evkit::nerf {

RaySamples sampleRay(const NdcRay& ray, int samples, const std::vector<float>& jitter) {
  std::vector<float> t(static_cast<size_t>(samples));
  for (int j = 0; j < samples; ++j) t[static_cast<size_t>(j)] = (static_cast<float>(j) + jitter[static_cast<size_t>(j)]) / static_cast<float>(samples);
  return samplesAt(ray, std::move(t));
}

RaySamples samplesAt(const NdcRay& ray, std::vector<float> t) {
  RaySamples s;
  const int samples = static_cast<int>(t.size());
  s.t = std::move(t);
  s.positions.resize(3, samples);
  s.delta.resize(static_cast<size_t>(samples));
  const float length = static_cast<float>(ray.direction.norm());
  for (int j = 0; j < samples; ++j) {
    const float t = s.t[static_cast<size_t>(j)];
    const float next = j + 1 < samples ? s.t[static_cast<size_t>(j + 1)] : 1.0f;
    s.delta[static_cast<size_t>(j)] = (next - t) * length;
    s.positions.col(j) = (ray.origin + static_cast<double>(t) * ray.direction).cast<float>();
  }
  return s;
}

std::vector<float> importanceSamples(const std::vector<float>& t, const std::vector<float>& weights, const std::vector<float>& u) {
  const size_t n = t.size();
  std::vector<double> cdf(n + 1, 0.0);
  for (size_t j = 0; j < n; ++j) cdf[j + 1] = cdf[j] + std::max(0.0f, std::isfinite(weights[j]) ? weights[j] : 0.0f) + 1e-5;
  std::vector<float> out;
  out.reserve(u.size());
  for (float q : u) {
    const double target = static_cast<double>(q) * cdf[n];
    const size_t j = std::min<size_t>(n - 1, static_cast<size_t>(std::upper_bound(cdf.begin(), cdf.end(), target) - cdf.begin()) - 1);
    const double lo = t[j], hi = j + 1 < n ? t[j + 1] : 1.0;
    const double frac = (target - cdf[j]) / std::max(cdf[j + 1] - cdf[j], 1e-12);
    out.push_back(static_cast<float>(lo + std::clamp(frac, 0.0, 1.0) * (hi - lo)));
  }
  std::sort(out.begin(), out.end());
  return out;
}

namespace {

// Renders the rays' current samples without gradients and replaces each ray's samples by the union
// with `extra` importance samples (u at the centres of `extra` equal quantile bins, shifted by
// `shift` in [0, 1)).
template <typename T>
void refineRays(RadianceField<T>& field, std::vector<RaySamples>& rays, const std::vector<NdcRay>& ndc, int extra, float shift) {
  using Matrix = typename RadianceField<T>::Matrix;
  const int S = static_cast<int>(rays.front().t.size());
  Matrix positions(3, static_cast<Eigen::Index>(rays.size()) * S);
  for (size_t r = 0; r < rays.size(); ++r) positions.middleCols(static_cast<Eigen::Index>(r) * S, S) = rays[r].positions.template cast<T>();
  const Matrix out = field.forward(positions);
  std::vector<float> u(static_cast<size_t>(extra));
  for (int k = 0; k < extra; ++k) u[static_cast<size_t>(k)] = (static_cast<float>(k) + shift) / static_cast<float>(extra);
#pragma omp parallel for schedule(static)
  for (size_t r = 0; r < rays.size(); ++r) {
    // Per-sample weights w_j = T_j alpha_j from the coarse densities.
    std::vector<float> w(static_cast<size_t>(S));
    T transmittance = 1;
    for (int j = 0; j < S; ++j) {
      const T tau = std::min(std::max(out(0, static_cast<Eigen::Index>(r) * S + j), T(0)) * static_cast<T>(rays[r].delta[static_cast<size_t>(j)]), T(80));
      const T alpha = T(1) - std::exp(-tau);
      w[static_cast<size_t>(j)] = static_cast<float>(transmittance * alpha);
      transmittance *= T(1) - alpha;
    }
    std::vector<float> t = rays[r].t;
    const std::vector<float> fine = importanceSamples(rays[r].t, w, u);
    t.insert(t.end(), fine.begin(), fine.end());
    std::sort(t.begin(), t.end());
    rays[r] = samplesAt(ndc[r], std::move(t));
  }
}

}  // namespace

template <typename T>
FitReport fitField(RadianceField<T>& field, const PinholeCamera& camera, const std::vector<TrainingView>& views, const FitOptions& o) {
  using Matrix = typename RadianceField<T>::Matrix;
  const auto start = std::chrono::steady_clock::now();
  FitReport report;
  Adam<T> adam(field.parameters(), o.adam);
  std::mt19937_64 rng(o.seed);
  const int C = field.channels();
  const int R = o.rays_per_step, S0 = o.samples_per_ray;
  std::vector<RaySamples> rays(static_cast<size_t>(R));
  std::vector<NdcRay> ndc(static_cast<size_t>(R));
  std::vector<float> target(static_cast<size_t>(R * C));
  for (int step = 0; step < o.steps; ++step) {
    // Rays: random view and pixel; jittered samples (drawn sequentially: deterministic).
    std::uniform_int_distribution<size_t> view(0, views.size() - 1);
    std::uniform_int_distribution<int> px(0, camera.width - 1), py(0, camera.height - 1);
    std::uniform_real_distribution<float> u(0.0f, 1.0f);
    std::vector<float> jitter(static_cast<size_t>(S0));
    for (int r = 0; r < R; ++r) {
      const TrainingView& v = views[view(rng)];
      const int x = px(rng), y = py(rng);
      for (float& j : jitter) j = u(rng);
      ndc[static_cast<size_t>(r)] = toNdc(worldRay(camera, v.pose, x, y), camera, o.near);
      rays[static_cast<size_t>(r)] = sampleRay(ndc[static_cast<size_t>(r)], S0, jitter);
      for (int c = 0; c < C; ++c) {
        target[static_cast<size_t>(r * C + c)] = C == 1 ? v.image.at<float>(y, x) : v.image.at<cv::Vec3f>(y, x)[c];
      }
    }
    if (o.importance_samples > 0) refineRays(field, rays, ndc, o.importance_samples, u(rng));
    const int S = static_cast<int>(rays.front().t.size());
    Matrix positions(3, R * S);
    for (int r = 0; r < R; ++r) positions.middleCols(r * S, S) = rays[static_cast<size_t>(r)].positions.template cast<T>();
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
cv::Mat renderImage(RadianceField<T>& field, const PinholeCamera& camera, const SE3& pose, int coarse, double near,
                    const RenderSettings& settings, int importance_samples) {
  using Matrix = typename RadianceField<T>::Matrix;
  const int C = field.channels();
  cv::Mat image(camera.height, camera.width, CV_MAKETYPE(CV_32F, C));
  const std::vector<float> centres(static_cast<size_t>(coarse), 0.5f);
  for (int y = 0; y < camera.height; ++y) {
    std::vector<RaySamples> rays(static_cast<size_t>(camera.width));
    std::vector<NdcRay> ndc(static_cast<size_t>(camera.width));
    for (int x = 0; x < camera.width; ++x) {
      ndc[static_cast<size_t>(x)] = toNdc(worldRay(camera, pose, x, y), camera, near);
      rays[static_cast<size_t>(x)] = sampleRay(ndc[static_cast<size_t>(x)], coarse, centres);
    }
    if (importance_samples > 0) refineRays(field, rays, ndc, importance_samples, 0.5f);
    const int samples = static_cast<int>(rays.front().t.size());
    Matrix positions(3, camera.width * samples);
    for (int x = 0; x < camera.width; ++x) positions.middleCols(x * samples, samples) = rays[static_cast<size_t>(x)].positions.template cast<T>();
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
template cv::Mat renderImage(RadianceField<float>&, const PinholeCamera&, const SE3&, int, double, const RenderSettings&, int);
template cv::Mat renderImage(RadianceField<double>&, const PinholeCamera&, const SE3&, int, double, const RenderSettings&, int);

}  // namespace evkit::nerf
