// The one mapping from linear intensity to log intensity, shared by the simulator, EDI and BeNeRF
// (DESIGN.md §2): a different eps in simulator and model is a silent error source.
//
//   log:     L = log(I + eps)            I linear in [0, 1]; eps = 1e-3 by default (as ESIM)
//   lin-log: v2e's mapping (Hu et al., CVPRW 2021), defined on x = 255 I as x ln(20)/20 below
//            x = 20 and ln(x) above; here shifted by -ln(255) so that L = ln(I) above 20/255.
#pragma once

#include <cmath>

namespace evkit {

struct LogMapping {
  double eps = 1e-3;
  bool lin_log = false;  // v2e's linear-below-threshold mapping instead of log(I + eps)
  static constexpr double kLinLogThreshold = 20.0 / 255.0;

  float toLog(float intensity) const {
    if (!lin_log) return std::log(intensity + static_cast<float>(eps));
    // v2e on x = 255 I: x ln(20)/20 below 20, ln(x) above; shifted by -ln(255) so that L = ln(I)
    // above the threshold.
    const float x = 255.0f * intensity;
    if (x >= 20.0f) return std::log(intensity);
    return x * (std::log(20.0f) / 20.0f) - std::log(255.0f);
  }
  // The same mapping in any precision, with its derivative dL/dI (for models trained through it).
  template <typename T>
  T logOf(T intensity) const {
    if (!lin_log) return std::log(intensity + static_cast<T>(eps));
    if (T(255) * intensity >= T(20)) return std::log(intensity);
    return T(255) * intensity * (std::log(T(20)) / T(20)) - std::log(T(255));
  }
  template <typename T>
  T logSlope(T intensity) const {
    if (!lin_log) return T(1) / (intensity + static_cast<T>(eps));
    if (T(255) * intensity >= T(20)) return T(1) / intensity;
    return T(255) * std::log(T(20)) / T(20);
  }
  float fromLog(float L) const {
    if (!lin_log) return std::exp(L) - static_cast<float>(eps);
    const float x_low = (L + std::log(255.0f)) * 20.0f / std::log(20.0f);
    if (x_low < 20.0f) return x_low / 255.0f;
    return std::exp(L);
  }
};

}  // namespace evkit
