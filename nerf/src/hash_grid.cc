#include "evkit/nerf/hash_grid.h"

#include <algorithm>
#include <cmath>
#include <random>

namespace evkit::nerf {

template <typename T>
HashGrid<T>::HashGrid(const HashGridConfig& config, uint64_t seed) : config_(config), entries_(size_t{1} << config.log2_table) {
  for (int l = 0; l < config.levels; ++l) {
    resolution_.push_back(static_cast<int>(std::floor(config.base_resolution * std::pow(config.per_level_scale, l))));
  }
  const size_t n = static_cast<size_t>(config.levels) * entries_ * static_cast<size_t>(config.features);
  table_.resize(n);
  grad_.assign(n, T(0));
  touched_.assign(static_cast<size_t>(config.levels) * entries_, 0);
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-1e-4, 1e-4);  // as instant-ngp
  for (T& v : table_) v = static_cast<T>(u(rng));
}

template <typename T>
size_t HashGrid<T>::index(int level, int x, int y, int z) const {
  const int64_t side = resolution_[static_cast<size_t>(level)] + 1;
  uint64_t i;
  if (static_cast<uint64_t>(side * side * side) <= entries_) {
    i = static_cast<uint64_t>(x + side * (y + side * z));
  } else {
    i = (static_cast<uint64_t>(x) * 1u) ^ (static_cast<uint64_t>(y) * 2654435761u) ^ (static_cast<uint64_t>(z) * 805459861u);
    i &= entries_ - 1;
  }
  return static_cast<size_t>(level) * entries_ + static_cast<size_t>(i);
}

// Trilinear weights of the 8 corners (bit a of `corner` = upper vertex along axis a) and their
// derivatives with respect to the fractional position f.
template <typename T>
inline void cornerWeights(const T* f, T* w, T (*dw)[3]) {
  const T lo[3] = {T(1) - f[0], T(1) - f[1], T(1) - f[2]};
  for (int corner = 0; corner < 8; ++corner) {
    const bool bx = corner & 1, by = (corner >> 1) & 1, bz = (corner >> 2) & 1;
    const T wx = bx ? f[0] : lo[0], wy = by ? f[1] : lo[1], wz = bz ? f[2] : lo[2];
    w[corner] = wx * wy * wz;
    if (dw) {
      dw[corner][0] = (bx ? T(1) : T(-1)) * wy * wz;
      dw[corner][1] = wx * (by ? T(1) : T(-1)) * wz;
      dw[corner][2] = wx * wy * (bz ? T(1) : T(-1));
    }
  }
}

template <typename T>
typename HashGrid<T>::Matrix HashGrid<T>::forward(const Matrix& positions) {
  const Eigen::Index n = positions.cols();
  const int F = config_.features;
  Matrix out(outputSize(), n);
  // Kept for backward: per level and sample, the 8 corner entries and the fractional position.
  corners_.resize(static_cast<size_t>(config_.levels) * static_cast<size_t>(n) * 8);
  fractions_.resize(static_cast<size_t>(config_.levels) * static_cast<size_t>(n) * 3);
  inside_.resize(static_cast<size_t>(n));
  for (Eigen::Index k = 0; k < n; ++k) {
    uint8_t mask = 0;
    for (int a = 0; a < 3; ++a) mask |= (positions(a, k) > T(0) && positions(a, k) < T(1)) ? uint8_t(1 << a) : uint8_t(0);
    inside_[static_cast<size_t>(k)] = mask;  // the clamp has zero gradient outside
  }
#pragma omp parallel for schedule(static, 1)  // interleaved: coarse (cheap) and fine levels mix
  for (int l = 0; l < config_.levels; ++l) {
    const int res = resolution_[static_cast<size_t>(l)];
    uint32_t* corners = corners_.data() + static_cast<size_t>(l) * static_cast<size_t>(n) * 8;
    T* fractions = fractions_.data() + static_cast<size_t>(l) * static_cast<size_t>(n) * 3;
    for (Eigen::Index k = 0; k < n; ++k) {
      int i0[3];
      T* f = fractions + k * 3;
      for (int a = 0; a < 3; ++a) {
        const T p = std::clamp(positions(a, k), T(0), T(1)) * T(res);
        i0[a] = std::min(static_cast<int>(p), res - 1);
        f[a] = p - T(i0[a]);
      }
      T w[8];
      cornerWeights<T>(f, w, nullptr);
      T* dst = out.data() + k * outputSize() + l * F;
      std::fill(dst, dst + F, T(0));
      for (int corner = 0; corner < 8; ++corner) {
        const size_t idx = index(l, i0[0] + (corner & 1), i0[1] + ((corner >> 1) & 1), i0[2] + ((corner >> 2) & 1));
        corners[k * 8 + corner] = static_cast<uint32_t>(idx);
        const T* feat = table_.data() + idx * static_cast<size_t>(F);
        for (int c = 0; c < F; ++c) dst[c] += w[corner] * feat[c];
      }
    }
  }
  return out;
}

template <typename T>
typename HashGrid<T>::Matrix HashGrid<T>::backward(const Matrix& d_features) {
  const Eigen::Index n = d_features.cols();
  const int F = config_.features;
  Matrix d_positions = Matrix::Zero(3, n);
#pragma omp parallel
  {
    // Each thread owns whole levels (their table slices: no atomics) and its own position sums.
    Matrix local = Matrix::Zero(3, n);
#pragma omp for schedule(static, 1)
    for (int l = 0; l < config_.levels; ++l) {
      const T res = T(resolution_[static_cast<size_t>(l)]);
      const uint32_t* corners = corners_.data() + static_cast<size_t>(l) * static_cast<size_t>(n) * 8;
      const T* fractions = fractions_.data() + static_cast<size_t>(l) * static_cast<size_t>(n) * 3;
      for (Eigen::Index k = 0; k < n; ++k) {
        T w[8], dw[8][3];
        cornerWeights<T>(fractions + k * 3, w, dw);
        const T* g = d_features.data() + k * outputSize() + l * F;
        T dp[3] = {0, 0, 0};
        for (int corner = 0; corner < 8; ++corner) {
          const size_t idx = corners[k * 8 + corner];
          const T* feat = table_.data() + idx * static_cast<size_t>(F);
          T* grad = grad_.data() + idx * static_cast<size_t>(F);
          T dot = 0;
          for (int c = 0; c < F; ++c) {
            grad[c] += w[corner] * g[c];
            dot += g[c] * feat[c];
          }
          touched_[idx] = 1;
          for (int a = 0; a < 3; ++a) dp[a] += dot * dw[corner][a];
        }
        const uint8_t inside = inside_[static_cast<size_t>(k)];
        for (int a = 0; a < 3; ++a) {
          if (inside & (1 << a)) local(a, k) += dp[a] * res;
        }
      }
    }
#pragma omp critical
    d_positions += local;
  }
  return d_positions;
}

template <typename T>
void HashGrid<T>::zeroGradients() {
  // Only touched entries carry gradient: clear those, not the whole table.
  const size_t F = static_cast<size_t>(config_.features);
  for (size_t e = 0; e < touched_.size(); ++e) {
    if (!touched_[e]) continue;
    std::fill(grad_.begin() + static_cast<std::ptrdiff_t>(e * F), grad_.begin() + static_cast<std::ptrdiff_t>((e + 1) * F), T(0));
    touched_[e] = 0;
  }
}

template class HashGrid<float>;
template class HashGrid<double>;

}  // namespace evkit::nerf
