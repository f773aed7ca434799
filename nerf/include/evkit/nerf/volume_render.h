// Volume rendering of one ray (Max 1995; Mildenhall et al., NeRF, ECCV 2020), forward and an
// O(samples) backward.
//
// Samples j = 0..N-1 with densities sigma_j >= 0, colours c_j (C channels) and interval lengths
// delta_j: alpha_j = 1 - exp(-sigma_j delta_j), T_j = prod_{k<j} (1 - alpha_k), w_j = T_j alpha_j,
// C = sum_j w_j c_j (+ (1 - sum w) background). Backward without storing T per sample, with
// S_j = sum_{k>j} w_k c_k the colour accumulated behind sample j (DESIGN.md §5):
//   dL/dc_j     = w_j dL/dC
//   dL/dsigma_j = delta_j < dL/dC, T_{j+1} c_j - S_j >       (T_{j+1} = T_j (1 - alpha_j))
// (with a background b, S_j includes (1 - sum w) b, i.e. the background behind the ray).
// Safety: sigma delta is clamped to [0, 80] (exp(-80) ~ 2e-35), non-finite inputs count as 0, and
// the march stops once T < early_stop (the skipped samples get zero gradient).
#pragma once

#include <cstddef>

namespace evkit::nerf {

struct RenderSettings {
  float early_stop = 1e-4f;  // transmittance below which the remaining samples are skipped
  float background = 0.0f;
};

template <typename T>
struct RayRender {
  T colour[3] = {0, 0, 0};
  T opacity = 0;    // sum of weights
  T depth = 0;      // sum w_j t_j (expected distance, in the ray's parameter)
  size_t used = 0;  // samples visited before early termination
};

// colours: N x channels (row-major); t: sample positions along the ray (for depth), may be null.
template <typename T>
RayRender<T> renderRay(const T* sigma, const T* colours, const T* delta, const T* t, size_t n,
                       int channels, const RenderSettings& settings);

// Gradients of the ray's colour: given dL/dC (channels), writes dL/dsigma (n) and dL/dcolour
// (n x channels); entries past `used` are zero. Needs the forward's output.
template <typename T>
void renderRayBackward(const T* sigma, const T* colours, const T* delta, size_t n, int channels,
                       const RenderSettings& settings, const RayRender<T>& forward,
                       const T* d_colour, T* d_sigma, T* d_colours);

// The grey value of a colour (BGR) as the simulator and BeNeRF's code take it: 0.299 R + 0.587 G +
// 0.114 B, and the shared log mapping log(grey + eps) with its derivative 1 / (grey + eps).
template <typename T>
T greyOf(const T* colour, int channels) {
  return channels == 1 ? colour[0]
                       : T(0.114) * colour[0] + T(0.587) * colour[1] + T(0.299) * colour[2];
}
template <typename T>
void greyBackward(T d_grey, int channels, T* d_colour) {
  if (channels == 1) {
    d_colour[0] = d_grey;
    return;
  }
  d_colour[0] = T(0.114) * d_grey;
  d_colour[1] = T(0.587) * d_grey;
  d_colour[2] = T(0.299) * d_grey;
}

}  // namespace evkit::nerf
