// The register-blocked kernels of the hash field's MLP (nerf/src/small_layer.h) against plain sums
// in double, for the shapes the field uses: 32 encoded features into 64 hidden units, 2 or 4
// outputs. Included by two test units: one built for the target (AVX-512 or AVX2 tiles), one built
// without AVX-512 (AVX2 tiles), so that a machine with AVX-512 checks both tilings. The suite's
// name comes from SMALL_LAYER_SUITE. No Eigen here: it would be built for two targets as well.
#pragma once

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include "small_layer.h"

namespace evkit::nerf {
namespace {
// Unity builds put this beside nerf_test.cc's helpers: its own names apart.
namespace small_layer_cases {

#if EVKIT_SMALL_LAYER
constexpr int kIn = 32, kHidden = 64;

std::vector<float> randomValues(size_t n, std::mt19937& rng) {
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  std::vector<float> v(n);
  for (float& x : v) x = u(rng);
  return v;
}

// |got - want| within `tol` of the larger of 1 and |want|, element by element.
void expectClose(const std::vector<float>& got, const std::vector<double>& want, double tol,
                 const char* what) {
  ASSERT_EQ(got.size(), want.size()) << what;
  double worst = 0;
  size_t at = 0;
  for (size_t i = 0; i < got.size(); ++i) {
    const double e = std::abs(got[i] - want[i]) / std::max(1.0, std::abs(want[i]));
    if (e > worst) worst = e, at = i;
  }
  EXPECT_LT(worst, tol) << what << ": element " << at << " is " << got[at] << ", not " << want[at];
}
#endif

// 263 samples: four chunks of 64 for the weight gradient and a tail of 7, whole tiles of 2 and 4
// samples and a tail that is neither.
TEST(SMALL_LAYER_SUITE, KernelsMatchPlainSums) {
#if !EVKIT_SMALL_LAYER
  GTEST_SKIP() << "the target has neither AVX-512 nor AVX2 with FMA: Eigen's products run instead";
#else
  const int n = 263;
  std::mt19937 rng(3);
  const std::vector<float> W = randomValues(kHidden * kIn, rng), b = randomValues(kHidden, rng),
                           x = randomValues(static_cast<size_t>(kIn) * n, rng),
                           dh = randomValues(static_cast<size_t>(kHidden) * n, rng);
  // Forward: h = max(0, W x + b), W column-major.
  std::vector<float> h(static_cast<size_t>(kHidden) * n);
  small_layer::forwardRelu<kHidden>(W.data(), b.data(), kIn, x.data(), n, h.data());
  std::vector<double> want(h.size());
  for (int s = 0; s < n; ++s) {
    for (int r = 0; r < kHidden; ++r) {
      double sum = b[r];
      for (int k = 0; k < kIn; ++k) sum += double(W[k * kHidden + r]) * x[s * kIn + k];
      want[s * kHidden + r] = std::max(sum, 0.0);
    }
  }
  expectClose(h, want, 1e-5, "forwardRelu");
  const auto dead = std::count(h.begin(), h.end(), 0.0f);
  EXPECT_GT(dead, static_cast<long>(h.size() / 4)) << "the ReLU must cut some of the samples";
  // Weight gradient, added to what dW holds: dW += dh x^T.
  std::vector<float> dW = randomValues(kHidden * kIn, rng);
  std::vector<double> want_dW(dW.begin(), dW.end());
  small_layer::weightGradient<kHidden>(dh.data(), x.data(), kIn, n, dW.data());
  for (int k = 0; k < kIn; ++k) {
    for (int r = 0; r < kHidden; ++r) {
      for (int s = 0; s < n; ++s)
        want_dW[k * kHidden + r] += double(dh[s * kHidden + r]) * x[s * kIn + k];
    }
  }
  expectClose(dW, want_dW, 1e-5, "weightGradient");
  // Input gradient: dx = W^T dh, with W^T given column-major (W's rows contiguous).
  std::vector<float> Wt(W.size());
  for (int k = 0; k < kIn; ++k) {
    for (int r = 0; r < kHidden; ++r) Wt[r * kIn + k] = W[k * kHidden + r];
  }
  std::vector<float> dx(static_cast<size_t>(kIn) * n);
  small_layer::inputGradient<kIn>(Wt.data(), kHidden, dh.data(), n, dx.data());
  std::vector<double> want_dx(dx.size(), 0.0);
  for (int s = 0; s < n; ++s) {
    for (int k = 0; k < kIn; ++k) {
      for (int r = 0; r < kHidden; ++r)
        want_dx[s * kIn + k] += double(W[k * kHidden + r]) * dh[s * kHidden + r];
    }
  }
  expectClose(dx, want_dx, 1e-5, "inputGradient");
#endif
}

// Back through the output layer and the ReLU, grey (2 outputs) and colour (4): dh = [h > 0] W1^T
// dy; db and dW1^T add to what they hold.
TEST(SMALL_LAYER_SUITE, OutputLayerBackwardMatchesPlainSums) {
#if !EVKIT_SMALL_LAYER
  GTEST_SKIP() << "the target has neither AVX-512 nor AVX2 with FMA: Eigen's products run instead";
#else
  const int n = 263;
  for (const int outs : {2, 4}) {
    std::mt19937 rng(4 + outs);
    const std::vector<float> w1t = randomValues(static_cast<size_t>(kHidden) * outs, rng),
                             dy = randomValues(static_cast<size_t>(outs) * n, rng);
    std::vector<float> h = randomValues(static_cast<size_t>(kHidden) * n, rng);
    for (float& v : h) v = std::max(v, 0.0f);  // a ReLU's output: about half zero
    std::vector<float> dh(h.size()), db = randomValues(kHidden, rng),
                                     dw1t = randomValues(w1t.size(), rng);
    std::vector<double> want_dh(h.size()), want_db(db.begin(), db.end()),
        want_dw1t(dw1t.begin(), dw1t.end());
    for (int s = 0; s < n; ++s) {
      for (int r = 0; r < kHidden; ++r) {
        double d = 0;
        for (int o = 0; o < outs; ++o) {
          d += double(w1t[o * kHidden + r]) * dy[s * outs + o];
          want_dw1t[o * kHidden + r] += double(h[s * kHidden + r]) * dy[s * outs + o];
        }
        want_dh[s * kHidden + r] = h[s * kHidden + r] > 0 ? d : 0.0;
        want_db[r] += want_dh[s * kHidden + r];
      }
    }
    if (outs == 2) {
      small_layer::outputLayerBackward<kHidden, 2>(w1t.data(), h.data(), dy.data(), n, dh.data(),
                                                   db.data(), dw1t.data());
    } else {
      small_layer::outputLayerBackward<kHidden, 4>(w1t.data(), h.data(), dy.data(), n, dh.data(),
                                                   db.data(), dw1t.data());
    }
    expectClose(dh, want_dh, 1e-5, outs == 2 ? "dh, 2 outputs" : "dh, 4 outputs");
    expectClose(db, want_db, 1e-5, outs == 2 ? "db, 2 outputs" : "db, 4 outputs");
    expectClose(dw1t, want_dw1t, 1e-5, outs == 2 ? "dW1^T, 2 outputs" : "dW1^T, 4 outputs");
  }
#endif
}

}  // namespace small_layer_cases
}  // namespace
}  // namespace evkit::nerf
