// Register-blocked kernels for the hash field's first MLP layer (inputs x hidden, both multiples of
// 16, float), on a block of samples that stays in the cache. They replace Eigen's general matrix
// product for these shapes: for a 64 x 32 weight and a few hundred samples, Eigen packs both
// operands on every call; here the weight columns stream
// from L1 while 16 accumulators stay in registers (4 samples x 64 outputs, or 4 inputs x 64
// outputs). Written with the generic vector type of GCC and Clang. Built only for targets with
// AVX-512 (EVKIT_SMALL_LAYER is then 1): there a 16-float vector is one register; with narrower
// vectors 16 accumulators of 16 floats would not fit the register file, and Eigen's products are
// used instead. Sums run in a fixed order: the results depend only on the inputs.
#pragma once

#if defined(__AVX512F__) && defined(__GNUC__)
#define EVKIT_SMALL_LAYER 1

#include <cstring>

namespace evkit::nerf::small_layer {

using V16 =
    float __attribute__((vector_size(64)));  // loads and stores through memcpy: no alignment needed

inline V16 load(const float* p) {
  V16 v;
  std::memcpy(&v, p, sizeof v);
  return v;
}
inline void store(float* p, V16 v) { std::memcpy(p, &v, sizeof v); }
inline V16 splat(float x) { return V16{} + x; }
// Keeps a loaded vector in a register: without it GCC folds the load into every FMA that uses it
// (a memory operand per FMA), and the kernels become bound by loads instead of FMAs.
inline void pin(V16& v) { asm("" : "+v"(v)); }

// A layer's matrix product, four samples at a time: out(:, s) = A in(:, s) (+ bias, then max(0, .)
// when kRelu), A kRows x inner column-major, in inner x count and out kRows x count column-major;
// bias may be null (zero).
template <int kRows, bool kRelu>
void product(const float* A, const float* bias, int inner, const float* in, int count, float* out) {
  constexpr int kV = kRows / 16;
  V16 init[kV];
  for (int v = 0; v < kV; ++v) init[v] = bias ? load(bias + 16 * v) : V16{};
  const auto finish = [](V16 a) { return kRelu ? (a > V16{} ? a : V16{}) : a; };
  int s = 0;
  for (; s + 4 <= count; s += 4) {
    V16 acc[4][kV];
    for (int v = 0; v < kV; ++v) acc[0][v] = acc[1][v] = acc[2][v] = acc[3][v] = init[v];
    const float* in0 = in + static_cast<size_t>(s) * inner;
    for (int k = 0; k < inner; ++k) {
      V16 a[kV];
      for (int v = 0; v < kV; ++v) {
        a[v] = load(A + static_cast<size_t>(k) * kRows + 16 * v);
        pin(a[v]);
      }
      for (int i = 0; i < 4; ++i) {
        const V16 xi = splat(in0[static_cast<size_t>(i) * inner + k]);
        for (int v = 0; v < kV; ++v) acc[i][v] += a[v] * xi;
      }
    }
    for (int i = 0; i < 4; ++i) {
      for (int v = 0; v < kV; ++v)
        store(out + static_cast<size_t>(s + i) * kRows + 16 * v, finish(acc[i][v]));
    }
  }
  for (; s < count; ++s) {
    V16 acc[kV];
    for (int v = 0; v < kV; ++v) acc[v] = init[v];
    for (int k = 0; k < inner; ++k) {
      const V16 xk = splat(in[static_cast<size_t>(s) * inner + k]);
      for (int v = 0; v < kV; ++v) acc[v] += load(A + static_cast<size_t>(k) * kRows + 16 * v) * xk;
    }
    for (int v = 0; v < kV; ++v)
      store(out + static_cast<size_t>(s) * kRows + 16 * v, finish(acc[v]));
  }
}

// Forward of a ReLU layer: h(:, s) = max(0, W x(:, s) + b), W hidden x inputs column-major.
template <int kHidden>
void forwardRelu(const float* W, const float* b, int inputs, const float* x, int count, float* h) {
  product<kHidden, true>(W, b, inputs, x, count, h);
}

// Weight gradient: dW += dh x^T (dW hidden x inputs column-major, dh hidden x count, x inputs x
// count), four input columns at a time over all samples.
template <int kHidden>
void weightGradient(const float* dh, const float* x, int inputs, int count, float* dW) {
  constexpr int kV = kHidden / 16;
  for (int k = 0; k < inputs; k += 4) {
    const int kn = inputs - k < 4 ? inputs - k : 4;
    V16 acc[4][kV];
    for (int j = 0; j < kn; ++j) {
      for (int v = 0; v < kV; ++v)
        acc[j][v] = load(dW + static_cast<size_t>(k + j) * kHidden + 16 * v);
    }
    for (int s = 0; s < count; ++s) {
      V16 d[kV];
      for (int v = 0; v < kV; ++v) d[v] = load(dh + static_cast<size_t>(s) * kHidden + 16 * v);
      const float* xs = x + static_cast<size_t>(s) * inputs + k;
      for (int j = 0; j < kn; ++j) {
        const V16 xj = splat(xs[j]);
        for (int v = 0; v < kV; ++v) acc[j][v] += d[v] * xj;
      }
    }
    for (int j = 0; j < kn; ++j) {
      for (int v = 0; v < kV; ++v)
        store(dW + static_cast<size_t>(k + j) * kHidden + 16 * v, acc[j][v]);
    }
  }
}

// Input gradient: dx(:, s) = W^T dh(:, s), with Wt = W^T (inputs x hidden column-major, i.e. W's
// rows contiguous).
template <int kIn>
void inputGradient(const float* Wt, int hidden, const float* dh, int count, float* dx) {
  product<kIn, false>(Wt, nullptr, hidden, dh, count, dx);
}

// Back through a linear output layer (kOut outputs) and the ReLU before it: with Wt = W^T
// (kHidden x kOut column-major) and h the ReLU's output, dh(:, s) = [h(:, s) > 0] (Wt dy(:, s));
// db += sum_s dh(:, s); dWt += sum_s h(:, s) dy(:, s)^T (the output layer's weight gradient,
// transposed).
template <int kHidden, int kOut>
void outputLayerBackward(const float* Wt, const float* h, const float* dy, int count, float* dh,
                         float* db, float* dWt) {
  constexpr int kV = kHidden / 16;
  {
    V16 w[kOut][kV], bias[kV];
    for (int o = 0; o < kOut; ++o) {
      for (int v = 0; v < kV; ++v) {
        w[o][v] = load(Wt + static_cast<size_t>(o) * kHidden + 16 * v);
        pin(w[o][v]);
      }
    }
    for (int v = 0; v < kV; ++v) bias[v] = load(db + 16 * v);
    for (int s = 0; s < count; ++s) {
      const float* ys = dy + static_cast<size_t>(s) * kOut;
      V16 d[kV] = {};
      for (int o = 0; o < kOut; ++o) {
        const V16 yo = splat(ys[o]);
        for (int v = 0; v < kV; ++v) d[v] += w[o][v] * yo;
      }
      for (int v = 0; v < kV; ++v) {
        const V16 hv = load(h + static_cast<size_t>(s) * kHidden + 16 * v);
        const V16 masked = hv > V16{} ? d[v] : V16{};
        bias[v] += masked;
        store(dh + static_cast<size_t>(s) * kHidden + 16 * v, masked);
      }
    }
    for (int v = 0; v < kV; ++v) store(db + 16 * v, bias[v]);
  }
  V16 acc[kOut][kV];
  for (int o = 0; o < kOut; ++o) {
    for (int v = 0; v < kV; ++v) acc[o][v] = load(dWt + static_cast<size_t>(o) * kHidden + 16 * v);
  }
  for (int s = 0; s < count; ++s) {
    V16 hv[kV];
    for (int v = 0; v < kV; ++v) hv[v] = load(h + static_cast<size_t>(s) * kHidden + 16 * v);
    for (int o = 0; o < kOut; ++o) {
      const V16 yo = splat(dy[static_cast<size_t>(s) * kOut + o]);
      for (int v = 0; v < kV; ++v) acc[o][v] += hv[v] * yo;
    }
  }
  for (int o = 0; o < kOut; ++o) {
    for (int v = 0; v < kV; ++v) store(dWt + static_cast<size_t>(o) * kHidden + 16 * v, acc[o][v]);
  }
}

}  // namespace evkit::nerf::small_layer

#else
#define EVKIT_SMALL_LAYER 0
#endif
