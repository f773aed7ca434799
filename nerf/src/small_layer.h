// Register-blocked kernels for the hash field's first MLP layer (inputs x hidden, both multiples of
// 16, float), on a block of samples that stays in the cache. They replace Eigen's general matrix
// product for these shapes: for a 64 x 32 weight and a few hundred samples, Eigen packs both
// operands on every call; here the weight columns stream from L1 while the accumulators stay in
// registers. Written with the generic vector type of GCC and Clang, for two targets:
// - AVX-512 (32 registers of 16 floats): products in tiles of 4 samples x 64 outputs, 16
//   accumulators;
// - AVX2 with FMA (16 registers of 8 floats): tiles of 2 samples x 32 outputs, 8 accumulators, the
//   4 weight vectors of a step pinned beside them.
// EVKIT_SMALL_LAYER is 1 where one of them is the target and 0 otherwise (Eigen's products are
// then used). Every output element is one sum over the inner index in increasing order, whatever
// the tiles: the results depend only on the inputs, not on the target's tiling. Each tiling has
// its own inline namespace, so that a unit built for another target (the tests build the AVX2
// tiling beside the AVX-512 one) does not share its symbols.
#pragma once

#if defined(__GNUC__) && (defined(__AVX512F__) || (defined(__AVX2__) && defined(__FMA__)))
#define EVKIT_SMALL_LAYER 1

#include <cstddef>
#include <cstring>

#if defined(__AVX512F__)
#define EVKIT_SMALL_LAYER_TILING avx512
#else
#define EVKIT_SMALL_LAYER_TILING avx2
#endif

// The loops over a tile's registers are unrolled whatever the optimisation level: left as loops (as
// GCC leaves them at -O2, CMake's RelWithDebInfo), the accumulators live in memory and the kernels
// run 3 to 6 times slower, and 40 times under AddressSanitizer.
#define EVKIT_UNROLL _Pragma("GCC unroll 16")

namespace evkit::nerf::small_layer {
inline namespace EVKIT_SMALL_LAYER_TILING {

#if defined(__AVX512F__)
constexpr int kWidth = 16;      // floats per register
constexpr int kRegisters = 32;  // vector registers
constexpr int kTileSamples = 4;
constexpr int kTileRows = 64;
#else
constexpr int kWidth = 8;
constexpr int kRegisters = 16;
constexpr int kTileSamples = 2;
constexpr int kTileRows = 32;
#endif

// One register of floats; loaded and stored through memcpy: no alignment needed.
using Vec = float __attribute__((vector_size(kWidth * sizeof(float))));

inline Vec load(const float* p) {
  Vec v;
  std::memcpy(&v, p, sizeof v);
  return v;
}
inline void store(float* p, Vec v) { std::memcpy(p, &v, sizeof v); }
// x - 0 is x for every x (x + 0 is not, for x = -0): the broadcast alone, with no zero register.
inline Vec splat(float x) { return x - Vec{}; }
// A loaded vector kept in a register: without it GCC folds the load into every FMA that uses it
// (a memory operand per FMA), and the kernels become bound by loads instead of FMAs. By value: a
// reference into an array makes GCC store the array to the stack on every step.
inline Vec pinned(Vec v) {
  asm("" : "+v"(v));
  return v;
}

// The rows of one tile: kTileRows, or all rows where there are fewer.
template <int kRows>
constexpr int tileRows() {
  static_assert(kRows % kWidth == 0, "rows must be whole vectors");
  return kRows < kTileRows ? kRows : kTileRows;
}

// A layer's matrix product, tile by tile: out(:, s) = A in(:, s) (+ bias, then max(0, .) when
// kRelu), A kRows x inner column-major, in inner x count and out kRows x count column-major; bias
// may be null (zero).
template <int kRows, bool kRelu>
void product(const float* A, const float* bias, int inner, const float* in, int count, float* out) {
  constexpr int kR = tileRows<kRows>(), kV = kR / kWidth, kS = kTileSamples;
  const auto finish = [](Vec a) { return kRelu ? (a > Vec{} ? a : Vec{}) : a; };
  int s = 0;
  for (; s + kS <= count; s += kS) {
    const float* in0 = in + static_cast<size_t>(s) * inner;
    for (int r = 0; r < kRows; r += kR) {
      Vec acc[kS][kV];
      EVKIT_UNROLL
      for (int v = 0; v < kV; ++v) {
        const Vec b = bias ? load(bias + r + kWidth * v) : Vec{};
        EVKIT_UNROLL
        for (int i = 0; i < kS; ++i) acc[i][v] = b;
      }
      for (int k = 0; k < inner; ++k) {
        Vec a[kV];
        EVKIT_UNROLL
        for (int v = 0; v < kV; ++v) {
          a[v] = pinned(load(A + static_cast<size_t>(k) * kRows + r + kWidth * v));
        }
        EVKIT_UNROLL
        for (int i = 0; i < kS; ++i) {
          const Vec xi = splat(in0[static_cast<size_t>(i) * inner + k]);
          EVKIT_UNROLL
          for (int v = 0; v < kV; ++v) acc[i][v] += a[v] * xi;
        }
      }
      EVKIT_UNROLL
      for (int i = 0; i < kS; ++i) {
        EVKIT_UNROLL
        for (int v = 0; v < kV; ++v)
          store(out + static_cast<size_t>(s + i) * kRows + r + kWidth * v, finish(acc[i][v]));
      }
    }
  }
  // The samples after the last whole tile, one at a time over every row.
  constexpr int kAll = kRows / kWidth;
  for (; s < count; ++s) {
    Vec acc[kAll];
    EVKIT_UNROLL
    for (int v = 0; v < kAll; ++v) acc[v] = bias ? load(bias + kWidth * v) : Vec{};
    for (int k = 0; k < inner; ++k) {
      const Vec xk = splat(in[static_cast<size_t>(s) * inner + k]);
      EVKIT_UNROLL
      for (int v = 0; v < kAll; ++v)
        acc[v] += load(A + static_cast<size_t>(k) * kRows + kWidth * v) * xk;
    }
    EVKIT_UNROLL
    for (int v = 0; v < kAll; ++v)
      store(out + static_cast<size_t>(s) * kRows + kWidth * v, finish(acc[v]));
  }
}

// Forward of a ReLU layer: h(:, s) = max(0, W x(:, s) + b), W hidden x inputs column-major.
template <int kHidden>
void forwardRelu(const float* W, const float* b, int inputs, const float* x, int count, float* h) {
  product<kHidden, true>(W, b, inputs, x, count, h);
}

// Weight gradient: dW += dh x^T (dW hidden x inputs column-major, dh hidden x count, x inputs x
// count), in tiles of kColumns input columns x the tile's rows, over chunks of 64 samples (their
// dh and x stay in L1 while every tile passes over them; the sums run over the samples in order).
// inputs must be a multiple of kColumns: the tiles have no tail (with a run-time tail GCC kept the
// accumulators in memory; the first layer's 32 features are whole tiles).
template <int kHidden, int kColumns = kTileSamples>
void weightGradient(const float* dh, const float* x, int inputs, int count, float* dW) {
  constexpr int kR = tileRows<kHidden>(), kV = kR / kWidth, kC = kColumns, kChunk = 64;
  for (int s0 = 0; s0 < count; s0 += kChunk) {
    const int s1 = count - s0 < kChunk ? count : s0 + kChunk;
    for (int k = 0; k < inputs; k += kC) {
      for (int r = 0; r < kHidden; r += kR) {
        Vec acc[kC][kV];
        EVKIT_UNROLL
        for (int j = 0; j < kC; ++j) {
          EVKIT_UNROLL
          for (int v = 0; v < kV; ++v)
            acc[j][v] = load(dW + static_cast<size_t>(k + j) * kHidden + r + kWidth * v);
        }
        for (int s = s0; s < s1; ++s) {
          Vec d[kV];
          EVKIT_UNROLL
          for (int v = 0; v < kV; ++v) {
            d[v] = pinned(load(dh + static_cast<size_t>(s) * kHidden + r + kWidth * v));
          }
          const float* xs = x + static_cast<size_t>(s) * inputs + k;
          EVKIT_UNROLL
          for (int j = 0; j < kC; ++j) {
            const Vec xj = splat(xs[j]);
            EVKIT_UNROLL
            for (int v = 0; v < kV; ++v) acc[j][v] += d[v] * xj;
          }
        }
        EVKIT_UNROLL
        for (int j = 0; j < kC; ++j) {
          EVKIT_UNROLL
          for (int v = 0; v < kV; ++v)
            store(dW + static_cast<size_t>(k + j) * kHidden + r + kWidth * v, acc[j][v]);
        }
      }
    }
  }
}

// Input gradient: dx(:, s) = W^T dh(:, s), with Wt = W^T (inputs x hidden column-major, i.e. W's
// rows contiguous).
template <int kIn>
void inputGradient(const float* Wt, int hidden, const float* dh, int count, float* dx) {
  product<kIn, false>(Wt, nullptr, hidden, dh, count, dx);
}

// The rows of one tile of outputLayerBackward: its kOut weight vectors, the bias sums and the
// gradient of a tile's rows stay in registers (kOut + 2 vectors per kWidth rows), with a few
// registers left for the splats and the loads.
template <int kHidden, int kOut>
constexpr int backwardTileRows() {
  int rows = tileRows<kHidden>();
  while (rows > kWidth && (kOut + 2) * (rows / kWidth) > kRegisters - 4) rows /= 2;
  return rows;
}

// Back through a linear output layer (kOut outputs) and the ReLU before it: with Wt = W^T
// (kHidden x kOut column-major) and h the ReLU's output, dh(:, s) = [h(:, s) > 0] (Wt dy(:, s));
// db += sum_s dh(:, s) (one pass over the samples per tile of rows); dWt += sum_s h(:, s)
// dy(:, s)^T (the output layer's weight gradient, transposed: weightGradient's product with
// (h, dy), in column tiles of at most kOut).
template <int kHidden, int kOut>
void outputLayerBackward(const float* Wt, const float* h, const float* dy, int count, float* dh,
                         float* db, float* dWt) {
  constexpr int kR = backwardTileRows<kHidden, kOut>(), kV = kR / kWidth;
  static_assert(kHidden % kR == 0, "hidden units must be whole tiles");
  for (int r = 0; r < kHidden; r += kR) {
    Vec w[kOut][kV], bias[kV];
    EVKIT_UNROLL
    for (int o = 0; o < kOut; ++o) {
      EVKIT_UNROLL
      for (int v = 0; v < kV; ++v) {
        w[o][v] = pinned(load(Wt + static_cast<size_t>(o) * kHidden + r + kWidth * v));
      }
    }
    EVKIT_UNROLL
    for (int v = 0; v < kV; ++v) bias[v] = load(db + r + kWidth * v);
    for (int s = 0; s < count; ++s) {
      const float* ys = dy + static_cast<size_t>(s) * kOut;
      Vec d[kV] = {};
      EVKIT_UNROLL
      for (int o = 0; o < kOut; ++o) {
        const Vec yo = splat(ys[o]);
        EVKIT_UNROLL
        for (int v = 0; v < kV; ++v) d[v] += w[o][v] * yo;
      }
      EVKIT_UNROLL
      for (int v = 0; v < kV; ++v) {
        const size_t at = static_cast<size_t>(s) * kHidden + r + kWidth * v;
        const Vec hv = load(h + at);
        const Vec masked = hv > Vec{} ? d[v] : Vec{};
        bias[v] += masked;
        store(dh + at, masked);
      }
    }
    EVKIT_UNROLL
    for (int v = 0; v < kV; ++v) store(db + r + kWidth * v, bias[v]);
  }
  constexpr int kColumns = kOut < kTileSamples ? kOut : kTileSamples;
  static_assert(kOut % kColumns == 0, "outputs must be whole column tiles");
  weightGradient<kHidden, kColumns>(h, dy, kOut, count, dWt);
}

}  // namespace EVKIT_SMALL_LAYER_TILING
}  // namespace evkit::nerf::small_layer

#else
#define EVKIT_SMALL_LAYER 0
#endif
