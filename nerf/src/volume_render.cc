#include "evkit/nerf/volume_render.h"

#include <algorithm>
#include <cmath>

namespace evkit::nerf {

namespace {
template <typename T>
T opticalDepth(T sigma, T delta) {
  const T tau = sigma * delta;
  if (!(tau > T(0))) return T(0);  // negative, zero or NaN
  return std::min(tau, T(80));
}
template <typename T>
T finite(T v) {
  return std::isfinite(v) ? v : T(0);
}
}  // namespace

template <typename T>
RayRender<T> renderRay(const T* sigma, const T* colours, const T* delta, const T* t, size_t n,
                       int channels, const RenderSettings& settings) {
  RayRender<T> out;
  T transmittance = 1;
  size_t j = 0;
  for (; j < n && transmittance >= T(settings.early_stop); ++j) {
    const T alpha = T(1) - std::exp(-opticalDepth(sigma[j], delta[j]));
    const T w = transmittance * alpha;
    for (int c = 0; c < channels; ++c)
      out.colour[c] +=
          w * finite(colours[j * static_cast<size_t>(channels) + static_cast<size_t>(c)]);
    out.opacity += w;
    if (t) out.depth += w * t[j];
    transmittance *= T(1) - alpha;
  }
  out.used = j;
  for (int c = 0; c < channels; ++c) out.colour[c] += (T(1) - out.opacity) * T(settings.background);
  return out;
}

template <typename T>
void renderRayBackward(const T* sigma, const T* colours, const T* delta, size_t n, int channels,
                       const RenderSettings& /*settings*/, const RayRender<T>& forward,
                       const T* d_colour, T* d_sigma, T* d_colours) {
  std::fill(d_sigma, d_sigma + n, T(0));
  std::fill(d_colours, d_colours + n * static_cast<size_t>(channels), T(0));
  // S (colour behind the current sample) starts as the full colour and loses each sample's share.
  T behind[3];
  for (int c = 0; c < channels; ++c) behind[c] = forward.colour[c];
  T transmittance = 1;
  for (size_t j = 0; j < forward.used; ++j) {
    const T tau = opticalDepth(sigma[j], delta[j]);
    const T alpha = T(1) - std::exp(-tau);
    const T w = transmittance * alpha;
    const T next = transmittance * (T(1) - alpha);
    T dot = 0;
    for (int c = 0; c < channels; ++c) {
      const T cj = finite(colours[j * static_cast<size_t>(channels) + static_cast<size_t>(c)]);
      behind[c] -= w * cj;  // now S_j: everything after sample j, background included
      d_colours[j * static_cast<size_t>(channels) + static_cast<size_t>(c)] = w * d_colour[c];
      dot += d_colour[c] * (next * cj - behind[c]);
    }
    // d tau / d sigma = delta inside the clamp, 0 outside it.
    const T tau_raw = sigma[j] * delta[j];
    d_sigma[j] = (tau_raw > T(0) && tau_raw < T(80)) ? delta[j] * dot : T(0);
    transmittance = next;
  }
}

template RayRender<float> renderRay(const float*, const float*, const float*, const float*, size_t,
                                    int, const RenderSettings&);
template RayRender<double> renderRay(const double*, const double*, const double*, const double*,
                                     size_t, int, const RenderSettings&);
template void renderRayBackward(const float*, const float*, const float*, size_t, int,
                                const RenderSettings&, const RayRender<float>&, const float*,
                                float*, float*);
template void renderRayBackward(const double*, const double*, const double*, size_t, int,
                                const RenderSettings&, const RayRender<double>&, const double*,
                                double*, double*);

}  // namespace evkit::nerf
