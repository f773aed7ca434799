#include "evkit/nerf/hash_grid.h"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <stdexcept>

namespace evkit::nerf {

template <typename T>
HashGrid<T>::HashGrid(const HashGridConfig& config, uint64_t seed) : config_(config) {
  if (config.levels < 1 || config.features < 1 || config.features > 16 || config.log2_table < 1 || config.log2_table > 30 ||
      config.base_resolution < 1 || !(config.per_level_scale >= 1.0)) {
    throw std::invalid_argument("hash grid: needs levels >= 1, features 1..16, log2_table 1..30, base_resolution >= 1, per_level_scale >= 1");
  }
  entries_ = size_t{1} << config.log2_table;
  for (int l = 0; l < config.levels; ++l) {
    const int res = static_cast<int>(std::floor(config.base_resolution * std::pow(config.per_level_scale, l)));
    const uint64_t side = static_cast<uint64_t>(res) + 1;
    resolution_.push_back(res);
    dense_.push_back(side * side * side <= entries_ ? 1 : 0);
  }
  const size_t n = static_cast<size_t>(config.levels) * entries_ * static_cast<size_t>(config.features);
  table_.resize(n);
  grad_.assign(n, T(0));
  touched_.assign(static_cast<size_t>(config.levels) * entries_, 0);
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-1e-4, 1e-4);  // as instant-ngp
  for (T& v : table_) v = static_cast<T>(u(rng));
}

namespace {

constexpr int kChunk = 64;  // samples whose corners and weights are computed together (SIMD over samples)

// One level's geometry: the corner entries (offsets within the level's slice) and trilinear
// weights of a chunk of samples, in structure-of-arrays form so that the compiler vectorises over
// samples. Bit a of a corner's number = the upper vertex along axis a.
template <typename T>
struct LevelChunk {
  uint32_t idx[8][kChunk];
  T f[3][kChunk];  // fractional position in the cell

  void compute(const T* px, const T* py, const T* pz, int count, int res, bool dense, uint32_t mask) {
    const T scale = T(res);
    const int last = res - 1;
    const uint32_t side = static_cast<uint32_t>(res) + 1;
    for (int k = 0; k < count; ++k) {
      const T qx = px[k] * scale, qy = py[k] * scale, qz = pz[k] * scale;  // p is clamped to [0, 1]
      const int ix = std::min(static_cast<int>(qx), last), iy = std::min(static_cast<int>(qy), last),
                iz = std::min(static_cast<int>(qz), last);
      f[0][k] = qx - T(ix), f[1][k] = qy - T(iy), f[2][k] = qz - T(iz);
      const uint32_t x = static_cast<uint32_t>(ix), y = static_cast<uint32_t>(iy), z = static_cast<uint32_t>(iz);
      uint32_t hx[2], hy[2], hz[2];
      if (dense) {
        hx[0] = x, hx[1] = x + 1, hy[0] = y * side, hy[1] = (y + 1) * side, hz[0] = z * side * side, hz[1] = (z + 1) * side * side;
        for (int c = 0; c < 8; ++c) idx[c][k] = hx[c & 1] + hy[(c >> 1) & 1] + hz[c >> 2];
      } else {
        // The spatial hash; its low bits are those of 32-bit products.
        hx[0] = x, hx[1] = x + 1, hy[0] = y * 2654435761u, hy[1] = (y + 1) * 2654435761u, hz[0] = z * 805459861u,
        hz[1] = (z + 1) * 805459861u;
        for (int c = 0; c < 8; ++c) idx[c][k] = (hx[c & 1] ^ hy[(c >> 1) & 1] ^ hz[c >> 2]) & mask;
      }
    }
  }
  T weight(int c, int k) const {
    return (c & 1 ? f[0][k] : T(1) - f[0][k]) * ((c >> 1) & 1 ? f[1][k] : T(1) - f[1][k]) * (c >> 2 ? f[2][k] : T(1) - f[2][k]);
  }
};

// Encodes one level of n samples: out[k stride + j]. F > 0 is a compile-time feature count
// (unrolled and vectorised), F = 0 takes it from `features`.
template <int F, typename T>
void encodeLevel(const T* const* p, Eigen::Index n, int res, bool dense, uint32_t mask, const T* slice, int features, T* out,
                 Eigen::Index stride) {
  const int nf = F > 0 ? F : features;
  LevelChunk<T> chunk;
  for (Eigen::Index begin = 0; begin < n; begin += kChunk) {
    const int count = static_cast<int>(std::min<Eigen::Index>(kChunk, n - begin));
    chunk.compute(p[0] + begin, p[1] + begin, p[2] + begin, count, res, dense, mask);
    for (int k = 0; k < count; ++k) {
      T acc[F > 0 ? F : 16] = {};
      for (int c = 0; c < 8; ++c) {
        const T w = chunk.weight(c, k);
        const T* feat = slice + static_cast<size_t>(chunk.idx[c][k]) * static_cast<size_t>(nf);
        for (int j = 0; j < nf; ++j) acc[j] += w * feat[j];
      }
      T* dst = out + (begin + k) * stride;
      for (int j = 0; j < nf; ++j) dst[j] = acc[j];
    }
  }
}

// Backward of one level: scatters g (k F + j) into the level's gradient slice, marks touched
// entries, and adds d(sum g . features)/d(position) (in grid units times res) into dp (3 x n,
// masked by `inside`).
template <int F, typename T>
void encodeLevelBackward(const T* const* p, Eigen::Index n, int res, bool dense, uint32_t mask, const T* slice, int features, const T* g,
                         T* grad, uint8_t* touched, const uint8_t* inside, T* dp) {
  const int nf = F > 0 ? F : features;
  const T scale = T(res);
  // Consecutive samples of a ray mostly share a cell: each corner's gradient is summed in a
  // register while its entry stays the same, and written once when it changes (instead of a
  // read-modify-write chain through memory per sample).
  using Vec = Eigen::Array<T, (F > 0 ? F : 1), 1>;
  constexpr uint32_t kNone = ~uint32_t{0};
  uint32_t pending_entry[8];
  Vec pending[8];
  std::fill(pending_entry, pending_entry + 8, kNone);
  const auto flush = [&](int c) {
    if (pending_entry[c] == kNone) return;
    Eigen::Map<Vec>(grad + static_cast<size_t>(pending_entry[c]) * static_cast<size_t>(nf)) += pending[c];
    touched[pending_entry[c]] = 1;
  };
  LevelChunk<T> chunk;
  for (Eigen::Index begin = 0; begin < n; begin += kChunk) {
    const int count = static_cast<int>(std::min<Eigen::Index>(kChunk, n - begin));
    chunk.compute(p[0] + begin, p[1] + begin, p[2] + begin, count, res, dense, mask);
    for (int k = 0; k < count; ++k) {
      const T* gk = g + (begin + k) * nf;
      T dot[8];
      for (int c = 0; c < 8; ++c) {
        const T w = chunk.weight(c, k);
        const uint32_t e = chunk.idx[c][k];
        const T* feat = slice + static_cast<size_t>(e) * static_cast<size_t>(nf);
        if constexpr (F > 0) {
          const Eigen::Map<const Vec> gv(gk);
          Eigen::Map<Vec>(grad + static_cast<size_t>(e) * static_cast<size_t>(nf)) += w * gv;
          touched[e] = 1;
          dot[c] = (gv * Eigen::Map<const Vec>(feat)).sum();
        } else {
          T* ge = grad + static_cast<size_t>(e) * static_cast<size_t>(nf);
          T d = 0;
          for (int j = 0; j < nf; ++j) {
            ge[j] += w * gk[j];
            d += gk[j] * feat[j];
          }
          dot[c] = d;
          touched[e] = 1;
        }
      }
      // d/df of the trilinear sum: differences of the dots along each axis, weighted by the other two.
      const T fx = chunk.f[0][k], fy = chunk.f[1][k], fz = chunk.f[2][k];
      const T gx = fx, hx = T(1) - fx, gy = fy, hy = T(1) - fy, gz = fz, hz = T(1) - fz;
      const T ddx = hy * hz * (dot[1] - dot[0]) + gy * hz * (dot[3] - dot[2]) + hy * gz * (dot[5] - dot[4]) + gy * gz * (dot[7] - dot[6]);
      const T ddy = hx * hz * (dot[2] - dot[0]) + gx * hz * (dot[3] - dot[1]) + hx * gz * (dot[6] - dot[4]) + gx * gz * (dot[7] - dot[5]);
      const T ddz = hx * hy * (dot[4] - dot[0]) + gx * hy * (dot[5] - dot[1]) + hx * gy * (dot[6] - dot[2]) + gx * gy * (dot[7] - dot[3]);
      const uint8_t in = inside[begin + k];
      T* d = dp + 3 * (begin + k);
      if (in & 1) d[0] += ddx * scale;
      if (in & 2) d[1] += ddy * scale;
      if (in & 4) d[2] += ddz * scale;
    }
  }
  if constexpr (F > 0) {
    for (int c = 0; c < 8; ++c) flush(c);
  }
}

}  // namespace

template <typename T>
void HashGrid<T>::setPositions(const Matrix& positions) {
  const Eigen::Index n = positions.cols();
  positions_.resize(n, 3);  // structure of arrays: one column per axis
  inside_.resize(static_cast<size_t>(n));
  for (Eigen::Index k = 0; k < n; ++k) {
    uint8_t mask = 0;
    for (int a = 0; a < 3; ++a) {
      const T v = positions(a, k);
      mask |= (v > T(0) && v < T(1)) ? uint8_t(1 << a) : uint8_t(0);
      positions_(k, a) = std::clamp(v, T(0), T(1));
    }
    inside_[static_cast<size_t>(k)] = mask;
  }
}

template <typename T>
void HashGrid<T>::encode(Eigen::Index begin, Eigen::Index count, T* out, Eigen::Index stride) const {
  const int F = config_.features;
  const T* p[3] = {positions_.col(0).data() + begin, positions_.col(1).data() + begin, positions_.col(2).data() + begin};
  const uint32_t mask = static_cast<uint32_t>(entries_ - 1);
  for (int l = 0; l < config_.levels; ++l) {
    const int res = resolution_[static_cast<size_t>(l)];
    const bool dense = dense_[static_cast<size_t>(l)];
    const T* slice = table_.data() + static_cast<size_t>(l) * entries_ * static_cast<size_t>(F);
    T* o = out + l * F;
    switch (F) {
      case 2: encodeLevel<2>(p, count, res, dense, mask, slice, F, o, stride); break;
      case 4: encodeLevel<4>(p, count, res, dense, mask, slice, F, o, stride); break;
      case 8: encodeLevel<8>(p, count, res, dense, mask, slice, F, o, stride); break;
      default: encodeLevel<0>(p, count, res, dense, mask, slice, F, o, stride); break;
    }
  }
}

template <typename T>
typename HashGrid<T>::Matrix HashGrid<T>::backwardLevelMajor(const T* d_features) {
  const Eigen::Index n = positions_.rows();
  const int F = config_.features;
  const T* p[3] = {positions_.col(0).data(), positions_.col(1).data(), positions_.col(2).data()};
  const uint32_t mask = static_cast<uint32_t>(entries_ - 1);
  // Each thread owns whole levels (their table slices: no atomics) and its own position sums,
  // added in thread order afterwards (the same sums for the same thread count).
  std::vector<Matrix> partial(static_cast<size_t>(omp_get_max_threads()));
#pragma omp parallel
  {
    Matrix& local = partial[static_cast<size_t>(omp_get_thread_num())];
    local = Matrix::Zero(3, n);
#pragma omp for schedule(static, 1)
    for (int l = 0; l < config_.levels; ++l) {
      const int res = resolution_[static_cast<size_t>(l)];
      const bool dense = dense_[static_cast<size_t>(l)];
      const size_t offset = static_cast<size_t>(l) * entries_;
      const T* slice = table_.data() + offset * static_cast<size_t>(F);
      T* grad = grad_.data() + offset * static_cast<size_t>(F);
      uint8_t* touched = touched_.data() + offset;
      const T* g = d_features + static_cast<size_t>(l) * static_cast<size_t>(n) * static_cast<size_t>(F);
      switch (F) {
        case 2: encodeLevelBackward<2>(p, n, res, dense, mask, slice, F, g, grad, touched, inside_.data(), local.data()); break;
        case 4: encodeLevelBackward<4>(p, n, res, dense, mask, slice, F, g, grad, touched, inside_.data(), local.data()); break;
        case 8: encodeLevelBackward<8>(p, n, res, dense, mask, slice, F, g, grad, touched, inside_.data(), local.data()); break;
        default: encodeLevelBackward<0>(p, n, res, dense, mask, slice, F, g, grad, touched, inside_.data(), local.data()); break;
      }
    }
  }
  Matrix d_positions = Matrix::Zero(3, n);
  for (const Matrix& local : partial) {
    if (local.size()) d_positions += local;
  }
  return d_positions;
}

template <typename T>
typename HashGrid<T>::Matrix HashGrid<T>::forward(const Matrix& positions) {
  const Eigen::Index n = positions.cols();
  setPositions(positions);
  Matrix out(outputSize(), n);
  constexpr Eigen::Index kBlock = 256;  // samples per thread's block
#pragma omp parallel for schedule(static)
  for (Eigen::Index begin = 0; begin < n; begin += kBlock) {
    encode(begin, std::min(kBlock, n - begin), out.col(begin).data(), outputSize());
  }
  return out;
}

template <typename T>
typename HashGrid<T>::Matrix HashGrid<T>::backward(const Matrix& d_features) {
  const Eigen::Index n = d_features.cols();
  const Eigen::Index F = config_.features;
  std::vector<T> level_major(static_cast<size_t>(outputSize() * n));
  for (int l = 0; l < config_.levels; ++l) {
    for (Eigen::Index k = 0; k < n; ++k) {
      for (Eigen::Index c = 0; c < F; ++c) level_major[static_cast<size_t>((l * n + k) * F + c)] = d_features(l * F + c, k);
    }
  }
  return backwardLevelMajor(level_major.data());
}

template <typename T>
void HashGrid<T>::zeroGradients() {
  // Only touched entries carry gradient: clear those, not the whole table.
  const size_t F = static_cast<size_t>(config_.features);
#pragma omp parallel for schedule(static, 1)
  for (int l = 0; l < config_.levels; ++l) {
    for (size_t e = static_cast<size_t>(l) * entries_; e < static_cast<size_t>(l + 1) * entries_; ++e) {
      if (!touched_[e]) continue;
      std::fill(grad_.begin() + static_cast<std::ptrdiff_t>(e * F), grad_.begin() + static_cast<std::ptrdiff_t>((e + 1) * F), T(0));
      touched_[e] = 0;
    }
  }
}

template class HashGrid<float>;
template class HashGrid<double>;

}  // namespace evkit::nerf
