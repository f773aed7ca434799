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

template <typename T>
typename HashGrid<T>::Matrix HashGrid<T>::forward(const Matrix& positions) {
  positions_ = positions;
  const Eigen::Index n = positions.cols();
  const int F = config_.features;
  Matrix out(outputSize(), n);
#pragma omp parallel for schedule(static)
  for (int l = 0; l < config_.levels; ++l) {
    const int res = resolution_[static_cast<size_t>(l)];
    for (Eigen::Index k = 0; k < n; ++k) {
      int i0[3];
      T f[3];
      for (int a = 0; a < 3; ++a) {
        const T p = std::clamp(positions(a, k), T(0), T(1)) * T(res);
        i0[a] = std::min(static_cast<int>(p), res - 1);
        f[a] = p - T(i0[a]);
      }
      T* dst = out.data() + k * outputSize() + l * F;
      std::fill(dst, dst + F, T(0));
      for (int corner = 0; corner < 8; ++corner) {
        T w = 1;
        for (int a = 0; a < 3; ++a) w *= (corner >> a) & 1 ? f[a] : T(1) - f[a];
        const T* feat = table_.data() + index(l, i0[0] + (corner & 1), i0[1] + ((corner >> 1) & 1), i0[2] + ((corner >> 2) & 1)) * F;
        for (int c = 0; c < F; ++c) dst[c] += w * feat[c];
      }
    }
  }
  return out;
}

template <typename T>
typename HashGrid<T>::Matrix HashGrid<T>::backward(const Matrix& d_features) {
  const Eigen::Index n = positions_.cols();
  const int F = config_.features;
  std::vector<Matrix> d_pos_level(static_cast<size_t>(config_.levels), Matrix::Zero(3, n));
#pragma omp parallel for schedule(static)
  for (int l = 0; l < config_.levels; ++l) {
    const int res = resolution_[static_cast<size_t>(l)];
    Matrix& dpos = d_pos_level[static_cast<size_t>(l)];
    for (Eigen::Index k = 0; k < n; ++k) {
      int i0[3];
      T f[3];
      bool inside[3];
      for (int a = 0; a < 3; ++a) {
        const T raw = positions_(a, k);
        inside[a] = raw > T(0) && raw < T(1);  // the clamp has zero gradient outside
        const T p = std::clamp(raw, T(0), T(1)) * T(res);
        i0[a] = std::min(static_cast<int>(p), res - 1);
        f[a] = p - T(i0[a]);
      }
      const T* g = d_features.data() + k * outputSize() + l * F;
      for (int corner = 0; corner < 8; ++corner) {
        T w = 1;
        T dw[3];
        for (int a = 0; a < 3; ++a) {
          const bool hi = (corner >> a) & 1;
          w *= hi ? f[a] : T(1) - f[a];
        }
        for (int a = 0; a < 3; ++a) {
          // d w / d f_a: the product of the other two factors, times +1 (hi) or -1 (lo).
          T others = 1;
          for (int b = 0; b < 3; ++b) {
            if (b != a) others *= (corner >> b) & 1 ? f[b] : T(1) - f[b];
          }
          dw[a] = ((corner >> a) & 1 ? T(1) : T(-1)) * others;
        }
        const size_t idx = index(l, i0[0] + (corner & 1), i0[1] + ((corner >> 1) & 1), i0[2] + ((corner >> 2) & 1));
        const T* feat = table_.data() + idx * F;
        T* grad = grad_.data() + idx * F;
        T dot = 0;
        for (int c = 0; c < F; ++c) {
          grad[c] += w * g[c];
          dot += g[c] * feat[c];
        }
        touched_[idx] = 1;
        for (int a = 0; a < 3; ++a) {
          if (inside[a]) dpos(a, k) += dot * dw[a] * T(res);
        }
      }
    }
  }
  Matrix d_positions = Matrix::Zero(3, n);
  for (const Matrix& d : d_pos_level) d_positions += d;
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
