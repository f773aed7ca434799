#include "evkit/nerf/hash_grid.h"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <stdexcept>

namespace evkit::nerf {

template <typename T>
HashGrid<T>::HashGrid(const HashGridConfig& config, uint64_t seed) : config_(config) {
  if (config.levels < 1 || config.features < 1 || config.features > 16 || config.log2_table < 1 ||
      config.log2_table > 30 || config.base_resolution < 1 || !(config.per_level_scale >= 1.0)) {
    throw std::invalid_argument(
        "hash grid: needs levels >= 1, features 1..16, log2_table 1..30, base_resolution >= 1, "
        "per_level_scale >= 1");
  }
  entries_ = size_t{1} << config.log2_table;
  for (int l = 0; l < config.levels; ++l) {
    const int res =
        static_cast<int>(std::floor(config.base_resolution * std::pow(config.per_level_scale, l)));
    const uint64_t side = static_cast<uint64_t>(res) + 1;
    resolution_.push_back(res);
    dense_.push_back(side * side * side <= entries_ ? 1 : 0);
  }
  const size_t n =
      static_cast<size_t>(config.levels) * entries_ * static_cast<size_t>(config.features);
  table_.resize(n);
  grad_.assign(n, T(0));
  touched_.assign(static_cast<size_t>(config.levels) * entries_, 0);
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-1e-4, 1e-4);  // as instant-ngp
  for (T& v : table_) v = static_cast<T>(u(rng));
}

namespace {

constexpr int kChunk =
    64;  // samples whose corners and weights are computed together (SIMD over samples)

// One level's geometry: the corner entries (offsets within the level's slice) and trilinear
// weights of a chunk of samples, in structure-of-arrays form so that the compiler vectorises over
// samples. Bit a of a corner's number = the upper vertex along axis a.
template <typename T>
struct LevelChunk {
  uint32_t idx[8][kChunk];
  T w[8][kChunk];  // trilinear weights
  T f[3][kChunk];  // fractional position in the cell

  void compute(const T* px, const T* py, const T* pz, int count, int res, bool dense,
               uint32_t mask) {
    const T scale = T(res);
    const int last = res - 1;
    const T* p[3] = {px, py, pz};
    uint32_t cell[3][kChunk];
    // Separate simple loops over samples, each vectorised.
    for (int a = 0; a < 3; ++a) {
      const T* pa = p[a];
      T* fa = f[a];
      uint32_t* ca = cell[a];
      for (int k = 0; k < count; ++k) {
        const T q = pa[k] * scale;  // p is clamped to [0, 1]
        const int i = std::min(static_cast<int>(q), last);
        fa[k] = q - static_cast<T>(i);
        ca[k] = static_cast<uint32_t>(i);
      }
    }
    for (int k = 0; k < count; ++k) {
      const T fx = f[0][k], fy = f[1][k], fz = f[2][k];
      const T wx[2] = {T(1) - fx, fx}, wy[2] = {T(1) - fy, fy}, wz[2] = {T(1) - fz, fz};
      for (int c = 0; c < 8; ++c) w[c][k] = wx[c & 1] * wy[(c >> 1) & 1] * wz[c >> 2];
    }
    if (dense) {
      const uint32_t side = static_cast<uint32_t>(res) + 1;
      for (int k = 0; k < count; ++k) {
        const uint32_t x = cell[0][k], y = cell[1][k] * side, z = cell[2][k] * side * side;
        const uint32_t hx[2] = {x, x + 1}, hy[2] = {y, y + side}, hz[2] = {z, z + side * side};
        for (int c = 0; c < 8; ++c) idx[c][k] = hx[c & 1] + hy[(c >> 1) & 1] + hz[c >> 2];
      }
    } else {
      // The spatial hash; its low bits are those of 32-bit products.
      for (int k = 0; k < count; ++k) {
        const uint32_t x = cell[0][k], y = cell[1][k] * 2654435761u, z = cell[2][k] * 805459861u;
        const uint32_t hx[2] = {x, x + 1}, hy[2] = {y, y + 2654435761u},
                       hz[2] = {z, z + 805459861u};
        for (int c = 0; c < 8; ++c) idx[c][k] = (hx[c & 1] ^ hy[(c >> 1) & 1] ^ hz[c >> 2]) & mask;
      }
    }
  }
};

// Encodes one level of n samples: out[k stride + j]. F > 0 is a compile-time feature count
// (unrolled and vectorised), F = 0 takes it from `features`.
template <int F, typename T>
void encodeLevel(const T* const* p, Eigen::Index n, int res, bool dense, uint32_t mask,
                 const T* slice, int features, T* out, Eigen::Index stride) {
  const int nf = F > 0 ? F : features;
  LevelChunk<T> chunk;
  for (Eigen::Index begin = 0; begin < n; begin += kChunk) {
    const int count = static_cast<int>(std::min<Eigen::Index>(kChunk, n - begin));
    chunk.compute(p[0] + begin, p[1] + begin, p[2] + begin, count, res, dense, mask);
    for (int k = 0; k < count; ++k) {
      T acc[F > 0 ? F : 16] = {};
      for (int c = 0; c < 8; ++c) {
        const T w = chunk.w[c][k];
        const T* feat = slice + static_cast<size_t>(chunk.idx[c][k]) * static_cast<size_t>(nf);
        for (int j = 0; j < nf; ++j) acc[j] += w * feat[j];
      }
      T* dst = out + (begin + k) * stride;
      for (int j = 0; j < nf; ++j) dst[j] = acc[j];
    }
  }
}

// Backward of one level: scatters g (k F + j) into the level's gradient slice, marks touched
// entries, and writes d(sum g . features)/d(position) (in grid units times res) into dp (n x 3, one
// array per axis, zero where `inside` says the sample was clamped along that axis).
template <int F, typename T>
void encodeLevelBackward(const T* const* p, Eigen::Index n, int res, bool dense, uint32_t mask,
                         const T* slice, int features, const T* g, T* grad, uint8_t* touched,
                         const uint8_t* inside, T* dp) {
  const int nf = F > 0 ? F : features;
  const T scale = T(res);
  LevelChunk<T> chunk;
  T dot[8][kChunk];  // g . features of each corner
  for (Eigen::Index begin = 0; begin < n; begin += kChunk) {
    const int count = static_cast<int>(std::min<Eigen::Index>(kChunk, n - begin));
    chunk.compute(p[0] + begin, p[1] + begin, p[2] + begin, count, res, dense, mask);
    // The scatter: a read-modify-write per corner (entries repeat, so it stays scalar over
    // samples).
    for (int k = 0; k < count; ++k) {
      const T* gk = g + (begin + k) * nf;
      for (int c = 0; c < 8; ++c) {
        const T w = chunk.w[c][k];
        const uint32_t e = chunk.idx[c][k];
        const T* feat = slice + static_cast<size_t>(e) * static_cast<size_t>(nf);
        T* ge = grad + static_cast<size_t>(e) * static_cast<size_t>(nf);
        if constexpr (F > 0) {
          using Vec = Eigen::Array<T, F, 1>;
          const Eigen::Map<const Vec> gv(gk);
          dot[c][k] = (gv * Eigen::Map<const Vec>(feat)).sum();
          Eigen::Map<Vec>(ge) += w * gv;
        } else {
          T d = 0;
          for (int j = 0; j < nf; ++j) {
            d += gk[j] * feat[j];
            ge[j] += w * gk[j];
          }
          dot[c][k] = d;
        }
        touched[e] = 1;
      }
    }
    // d/df of the trilinear sum: differences of the dots along each axis, weighted by the other
    // two, then written into dp where the sample is inside along that axis (0 elsewhere). Two
    // loops, each vectorised over samples: with the multiplication under the condition (as one
    // loop, GCC moves it there), GCC does not convert the branch, as a multiplication might trap,
    // and the loop stayed scalar.
    T ddf[3][kChunk];
    const uint8_t* in = inside + begin;
    for (int k = 0; k < count; ++k) {
      const T gx = chunk.f[0][k], hx = T(1) - gx, gy = chunk.f[1][k], hy = T(1) - gy,
              gz = chunk.f[2][k], hz = T(1) - gz;
      const T d0 = dot[0][k], d1 = dot[1][k], d2 = dot[2][k], d3 = dot[3][k], d4 = dot[4][k],
              d5 = dot[5][k], d6 = dot[6][k], d7 = dot[7][k];
      const T ddx =
          hy * hz * (d1 - d0) + gy * hz * (d3 - d2) + hy * gz * (d5 - d4) + gy * gz * (d7 - d6);
      const T ddy =
          hx * hz * (d2 - d0) + gx * hz * (d3 - d1) + hx * gz * (d6 - d4) + gx * gz * (d7 - d5);
      const T ddz =
          hx * hy * (d4 - d0) + gx * hy * (d5 - d1) + hx * gy * (d6 - d2) + gx * gy * (d7 - d3);
      ddf[0][k] = ddx * scale;
      ddf[1][k] = ddy * scale;
      ddf[2][k] = ddz * scale;
    }
    for (int a = 0; a < 3; ++a) {
      T* d = dp + a * n + begin;
      const uint8_t bit = static_cast<uint8_t>(1 << a);
      for (int k = 0; k < count; ++k) d[k] = (in[k] & bit) ? ddf[a][k] : T(0);
    }
  }
}

}  // namespace

template <typename T>
void HashGrid<T>::setPositions(const Matrix& positions) {
  const Eigen::Index n = positions.cols();
  positions_ = positions.transpose();  // structure of arrays: one column per axis
  inside_.assign(static_cast<size_t>(n), 0);
  uint8_t* inside = inside_.data();
  for (int a = 0; a < 3; ++a) {  // one axis at a time: vectorised over samples
    T* p = positions_.col(a).data();
    const uint8_t bit = static_cast<uint8_t>(1 << a);
    for (Eigen::Index k = 0; k < n; ++k) {
      const T v = p[k];
      inside[k] |= (v > T(0) && v < T(1)) ? bit : uint8_t(0);
      p[k] = v < T(0) ? T(0) : (v > T(1) ? T(1) : v);
    }
  }
}

template <typename T>
void HashGrid<T>::encode(Eigen::Index begin, Eigen::Index count, T* out,
                         Eigen::Index stride) const {
  const int F = config_.features;
  const T* p[3] = {positions_.col(0).data() + begin, positions_.col(1).data() + begin,
                   positions_.col(2).data() + begin};
  const uint32_t mask = static_cast<uint32_t>(entries_ - 1);
  for (int l = 0; l < config_.levels; ++l) {
    const int res = resolution_[static_cast<size_t>(l)];
    const bool dense = dense_[static_cast<size_t>(l)];
    const T* slice = table_.data() + static_cast<size_t>(l) * entries_ * static_cast<size_t>(F);
    T* o = out + l * F;
    switch (F) {
      case 2:
        encodeLevel<2>(p, count, res, dense, mask, slice, F, o, stride);
        break;
      case 4:
        encodeLevel<4>(p, count, res, dense, mask, slice, F, o, stride);
        break;
      case 8:
        encodeLevel<8>(p, count, res, dense, mask, slice, F, o, stride);
        break;
      default:
        encodeLevel<0>(p, count, res, dense, mask, slice, F, o, stride);
        break;
    }
  }
}

template <typename T>
typename HashGrid<T>::Matrix HashGrid<T>::backwardLevelMajor(const T* d_features) {
  const Eigen::Index n = positions_.rows();
  const int F = config_.features;
  const T* p[3] = {positions_.col(0).data(), positions_.col(1).data(), positions_.col(2).data()};
  const uint32_t mask = static_cast<uint32_t>(entries_ - 1);
  // Each level is one thread's at a time (its table slice: no atomics) with its own position
  // sums, added in level order afterwards: the same sums whatever the number of threads. The levels
  // go to whichever thread is free, finest (hashed, the costliest) first: dealt in turn, one of
  // two threads got the finer half of each pair and the other waited for it.
  std::vector<Matrix>& partial = level_positions_;
  partial.resize(static_cast<size_t>(config_.levels));
  Matrix d_positions(3, n);
#pragma omp parallel
  {
#pragma omp for schedule(dynamic, 1)
    for (int finest = 0; finest < config_.levels; ++finest) {
      const int l = config_.levels - 1 - finest;
      Matrix& local = partial[static_cast<size_t>(l)];
      local.resize(n, 3);  // one array per axis, every element written; keeps its allocation
      const int res = resolution_[static_cast<size_t>(l)];
      const bool dense = dense_[static_cast<size_t>(l)];
      const size_t offset = static_cast<size_t>(l) * entries_;
      const T* slice = table_.data() + offset * static_cast<size_t>(F);
      T* grad = grad_.data() + offset * static_cast<size_t>(F);
      uint8_t* touched = touched_.data() + offset;
      const T* g =
          d_features + static_cast<size_t>(l) * static_cast<size_t>(n) * static_cast<size_t>(F);
      switch (F) {
        case 2:
          encodeLevelBackward<2>(p, n, res, dense, mask, slice, F, g, grad, touched, inside_.data(),
                                 local.data());
          break;
        case 4:
          encodeLevelBackward<4>(p, n, res, dense, mask, slice, F, g, grad, touched, inside_.data(),
                                 local.data());
          break;
        case 8:
          encodeLevelBackward<8>(p, n, res, dense, mask, slice, F, g, grad, touched, inside_.data(),
                                 local.data());
          break;
        default:
          encodeLevelBackward<0>(p, n, res, dense, mask, slice, F, g, grad, touched, inside_.data(),
                                 local.data());
          break;
      }
    }
    // The levels' sums in level order, threads over runs of samples, each axis's sums over a run
    // vectorised (summed sample by sample over the levels' arrays, the loop was scalar).
    constexpr Eigen::Index kRun = 512;
#pragma omp for schedule(static)
    for (Eigen::Index begin = 0; begin < n; begin += kRun) {
      const Eigen::Index count = std::min(kRun, n - begin);
      T sum[3][kRun];
      for (int a = 0; a < 3; ++a) {
        T* s = sum[a];
        std::fill(s, s + count, T(0));
        for (const Matrix& local : partial) {
          const T* level = local.col(a).data() + begin;
          for (Eigen::Index k = 0; k < count; ++k) s[k] += level[k];
        }
      }
      for (Eigen::Index k = 0; k < count; ++k) {
        for (int a = 0; a < 3; ++a) d_positions(a, begin + k) = sum[a][k];
      }
    }
  }
  return d_positions;
}

template <typename T>
typename HashGrid<T>::Matrix HashGrid<T>::forward(const Matrix& positions) {
  const Eigen::Index n = positions.cols();
  setPositions(positions);
  Matrix out(outputSize(), n);
  constexpr Eigen::Index kBlock = 256;  // samples per thread's block
#pragma omp parallel for schedule(dynamic, 4)
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
      for (Eigen::Index c = 0; c < F; ++c)
        level_major[static_cast<size_t>((l * n + k) * F + c)] = d_features(l * F + c, k);
    }
  }
  return backwardLevelMajor(level_major.data());
}

template <typename T>
void HashGrid<T>::zeroGradients() {
  // Only touched entries carry gradient: clear those, not the whole table (a level that was mostly
  // touched is cleared whole, which streams instead of skipping).
  const size_t F = static_cast<size_t>(config_.features);
#pragma omp parallel for schedule(static, 1)
  for (int l = 0; l < config_.levels; ++l) {
    const size_t first = static_cast<size_t>(l) * entries_;
    uint8_t* touched = touched_.data() + first;
    T* grad = grad_.data() + first * F;
    size_t count = 0;
    for (size_t e = 0; e < entries_; ++e) count += touched[e];
    if (count * 2 > entries_) {
      std::fill(grad, grad + entries_ * F, T(0));
    } else if (count > 0) {
      for (size_t e = 0; e < entries_; ++e) {
        if (touched[e]) std::fill(grad + e * F, grad + (e + 1) * F, T(0));
      }
    }
    std::fill(touched, touched + entries_, uint8_t(0));
  }
}

template class HashGrid<float>;
template class HashGrid<double>;

}  // namespace evkit::nerf
