#include "evkit/nerf/ray_batch.h"

#include <omp.h>

#include <algorithm>
#include <cmath>

#include "evkit/nerf/train.h"

namespace evkit::nerf {

template <typename T>
void RayBatch<T>::setRays(const std::vector<SE3>& poses, std::vector<PixelRay> rays,
                          const float* jitter) {
  poses_ = poses;
  rays_ = std::move(rays);
  samples_ = options_.samples;
  const int R = size(), S = samples_;
  ndc_.resize(static_cast<size_t>(R));
  positions_.resize(3, static_cast<Eigen::Index>(R) * S);
  t_.resize(static_cast<size_t>(R) * S);
  delta_.resize(static_cast<size_t>(R) * S);
#pragma omp parallel for schedule(static)
  for (int r = 0; r < R; ++r) {
    const PixelRay& ray = rays_[static_cast<size_t>(r)];
    ndc_[static_cast<size_t>(r)] =
        toNdc(worldRay(camera_, poses_[static_cast<size_t>(ray.pose)], ray.x, ray.y), camera_,
              options_.near);
    T* t = &t_[static_cast<size_t>(r) * S];
    for (int j = 0; j < S; ++j) {
      const T u = jitter ? static_cast<T>(jitter[static_cast<size_t>(r) * S + j]) : T(0.5);
      t[j] = (static_cast<T>(j) + u) / static_cast<T>(S);
    }
    placeSamples(r, t);
  }
}

template <typename T>
void RayBatch<T>::placeSamples(int r, const T* t) {
  const NdcRay& ray = ndc_[static_cast<size_t>(r)];
  const int S = samples_;
  const size_t o = static_cast<size_t>(r) * S;
  const double length = ray.direction.norm();
  for (int j = 0; j < S; ++j) {
    t_[o + j] = t[j];
    delta_[o + j] = ((j + 1 < S ? t[j + 1] : T(1)) - t[j]) * static_cast<T>(length);
    const double tj = static_cast<double>(t[j]);
    const Eigen::Index col = static_cast<Eigen::Index>(o) + j;
    positions_(0, col) = static_cast<T>(ray.origin.x() + tj * ray.direction.x());
    positions_(1, col) = static_cast<T>(ray.origin.y() + tj * ray.direction.y());
    positions_(2, col) =
        static_cast<T>(options_.depth_scale * (ray.origin.z() + tj * ray.direction.z()));
  }
}

template <typename T>
void RayBatch<T>::refine(RadianceField<T>& field, int extra, float shift) {
  if (extra <= 0) return;
  const int R = size(), S = samples_;
  const Matrix out = field.forward(positions_);
  std::vector<float> u(static_cast<size_t>(extra));
  for (int k = 0; k < extra; ++k)
    u[static_cast<size_t>(k)] = (static_cast<float>(k) + shift) / static_cast<float>(extra);
  std::vector<std::vector<T>> refined(static_cast<size_t>(R));
#pragma omp parallel for schedule(static)
  for (int r = 0; r < R; ++r) {
    // Per-sample weights w_j = T_j alpha_j from the current densities.
    const size_t o = static_cast<size_t>(r) * S;
    std::vector<float> t(static_cast<size_t>(S)), w(static_cast<size_t>(S));
    T transmittance = 1;
    for (int j = 0; j < S; ++j) {
      const T tau =
          std::min(std::max(out(0, static_cast<Eigen::Index>(o) + j), T(0)) * delta_[o + j], T(80));
      const T alpha = T(1) - std::exp(-tau);
      w[static_cast<size_t>(j)] = static_cast<float>(transmittance * alpha);
      transmittance *= T(1) - alpha;
      t[static_cast<size_t>(j)] = static_cast<float>(t_[o + j]);
    }
    std::vector<float> all = t;
    const std::vector<float> fine = importanceSamples(t, w, u);
    all.insert(all.end(), fine.begin(), fine.end());
    std::sort(all.begin(), all.end());
    refined[static_cast<size_t>(r)].assign(all.begin(), all.end());
  }
  samples_ = S + extra;
  positions_.resize(3, static_cast<Eigen::Index>(R) * samples_);
  t_.resize(static_cast<size_t>(R) * samples_);
  delta_.resize(static_cast<size_t>(R) * samples_);
#pragma omp parallel for schedule(static)
  for (int r = 0; r < R; ++r) placeSamples(r, refined[static_cast<size_t>(r)].data());
}

template <typename T>
void RayBatch<T>::forward(RadianceField<T>& field, bool with_gradients) {
  const int R = size(), S = samples_, C = field.channels();
  if (with_gradients) {
    out_ = field.forward(positions_);
  } else {
    // In chunks: the MLP keeps every layer's activations, which for a whole image would be
    // gigabytes.
    constexpr Eigen::Index kFieldChunk = 16384;
    out_.resize(1 + C, positions_.cols());
    for (Eigen::Index c0 = 0; c0 < positions_.cols(); c0 += kFieldChunk) {
      const Eigen::Index count = std::min(kFieldChunk, positions_.cols() - c0);
      out_.middleCols(c0, count) = field.forward(positions_.middleCols(c0, count));
    }
  }
  renders_.resize(static_cast<size_t>(R));
#pragma omp parallel for schedule(static)
  for (int r = 0; r < R; ++r) {
    std::vector<T> sigma(static_cast<size_t>(S)), colours(static_cast<size_t>(S) * C);
    for (int j = 0; j < S; ++j) {
      const Eigen::Index col = static_cast<Eigen::Index>(r) * S + j;
      sigma[static_cast<size_t>(j)] = out_(0, col);
      for (int c = 0; c < C; ++c) colours[static_cast<size_t>(j) * C + c] = out_(1 + c, col);
    }
    const size_t o = static_cast<size_t>(r) * S;
    renders_[static_cast<size_t>(r)] = renderRay(sigma.data(), colours.data(), &delta_[o], &t_[o],
                                                 static_cast<size_t>(S), C, options_.render);
  }
}

template <typename T>
std::vector<Vector6> RayBatch<T>::backward(RadianceField<T>& field, const std::vector<T>& d_colour,
                                           bool pose_gradients) {
  const int R = size(), S = samples_, C = field.channels();
  Matrix d_out(1 + C, static_cast<Eigen::Index>(R) * S);
  // dL/d|d| per ray: the interval lengths scale with the NDC direction's length, tau_j = sigma_j
  // (t_{j+1} - t_j) |d|, so dL/d|d| = sum_j dL/dsigma_j sigma_j / |d|.
  std::vector<double> d_length(static_cast<size_t>(R), 0.0);
#pragma omp parallel for schedule(static)
  for (int r = 0; r < R; ++r) {
    const size_t o = static_cast<size_t>(r) * S;
    std::vector<T> sigma(static_cast<size_t>(S)), colours(static_cast<size_t>(S) * C);
    for (int j = 0; j < S; ++j) {
      sigma[static_cast<size_t>(j)] = out_(0, static_cast<Eigen::Index>(o) + j);
      for (int c = 0; c < C; ++c)
        colours[static_cast<size_t>(j) * C + c] = out_(1 + c, static_cast<Eigen::Index>(o) + j);
    }
    std::vector<T> d_sigma(static_cast<size_t>(S)), d_colours(static_cast<size_t>(S) * C);
    renderRayBackward(sigma.data(), colours.data(), &delta_[o], static_cast<size_t>(S), C,
                      options_.render, renders_[static_cast<size_t>(r)],
                      &d_colour[static_cast<size_t>(r) * 3], d_sigma.data(), d_colours.data());
    double dl = 0;
    for (int j = 0; j < S; ++j)
      dl += static_cast<double>(d_sigma[static_cast<size_t>(j)] * sigma[static_cast<size_t>(j)]);
    d_length[static_cast<size_t>(r)] = dl / ndc_[static_cast<size_t>(r)].direction.norm();
    for (int j = 0; j < S; ++j) {
      d_out(0, static_cast<Eigen::Index>(o) + j) = d_sigma[static_cast<size_t>(j)];
      for (int c = 0; c < C; ++c)
        d_out(1 + c, static_cast<Eigen::Index>(o) + j) = d_colours[static_cast<size_t>(j) * C + c];
    }
  }
  const Matrix d_positions = field.backward(d_out);
  if (!pose_gradients) return {};

  // Sample positions -> poses: p(t) is affine in t for a fixed pixel, so is its pose Jacobian:
  // sum_j J(t_j)^T g_j = J(0)^T sum_j (1 - t_j) g_j + J(1)^T sum_j t_j g_j; and d = p(1) - p(0), so
  // the length term adds (J(1) - J(0))^T (d / |d|) dL/d|d|.
  // Per lane (a fixed run of rays), added in lane order: the same sums whatever the threads.
  constexpr int kLanes = 16;
  std::vector<std::vector<Vector6>> per_lane(kLanes,
                                             std::vector<Vector6>(poses_.size(), Vector6::Zero()));
#pragma omp parallel for schedule(static)
  for (int lane = 0; lane < kLanes; ++lane) {
    for (int r = R * lane / kLanes; r < R * (lane + 1) / kLanes; ++r) {
      Eigen::Vector3d g0 = Eigen::Vector3d::Zero(), g1 = Eigen::Vector3d::Zero();
      for (int j = 0; j < S; ++j) {
        Eigen::Vector3d g =
            d_positions.col(static_cast<Eigen::Index>(r) * S + j).template cast<double>();
        g.z() *= options_.depth_scale;  // the field saw depth_scale * z
        const double t =
            static_cast<double>(t_[static_cast<size_t>(r) * S + static_cast<size_t>(j)]);
        g0 += (1 - t) * g;
        g1 += t * g;
      }
      const Eigen::Vector3d& d = ndc_[static_cast<size_t>(r)].direction;
      const Eigen::Vector3d g_length = d / d.norm() * d_length[static_cast<size_t>(r)];
      g0 -= g_length;
      g1 += g_length;
      if (g0.isZero(0) && g1.isZero(0)) continue;
      const PixelRay& ray = rays_[static_cast<size_t>(r)];
      const SE3& pose = poses_[static_cast<size_t>(ray.pose)];
      per_lane[static_cast<size_t>(lane)][static_cast<size_t>(ray.pose)] +=
          ndcPointPoseJacobian(camera_, pose, ray.x, ray.y, 0.0, options_.near).transpose() * g0 +
          ndcPointPoseJacobian(camera_, pose, ray.x, ray.y, 1.0, options_.near).transpose() * g1;
    }
  }
  std::vector<Vector6> gradient(poses_.size(), Vector6::Zero());
  for (size_t k = 0; k < poses_.size(); ++k) {
    for (const auto& g : per_lane) gradient[k] += g[k];
  }
  return gradient;
}

template class RayBatch<float>;
template class RayBatch<double>;

}  // namespace evkit::nerf
