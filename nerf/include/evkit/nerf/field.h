// Radiance fields behind one interface: positions (NDC, [-1, 1]^3) in, density and colour out,
// with a hand-written backward to the parameters and to the positions.
//  - MlpField: NeRF's MLP (Mildenhall et al. 2020): positional encoding with 10 frequencies,
//    8 x 256 ReLU layers with the input concatenated at the 5th, density head, and a 128-wide
//    colour head. The faithful reference (no view dependence here; the BeNeRF views of one
//    exposure differ by millimetres).
//  - HashField: the multiresolution hash grid (instant-ngp) and a tiny MLP (one 64-wide hidden
//    layer): the fast field. Sizes chosen by measurement (BENCHMARKS.md).
// Outputs: density = softplus(raw) (finite for any input), colour = sigmoid(raw), 1 (grey) or 3
// (colour) channels.
#pragma once

#include <Eigen/Core>
#include <memory>
#include <string>
#include <vector>

#include "evkit/nerf/hash_grid.h"
#include "evkit/nerf/mlp.h"

namespace evkit::nerf {

// A flat parameter array with its gradient; sparse blocks (hash tables) also list which rows
// (of row_size values) were touched since the last zeroGradients().
template <typename T>
struct ParameterBlock {
  T* values = nullptr;
  T* gradients = nullptr;
  size_t size = 0;
  const uint8_t* touched = nullptr;  // null: dense
  size_t row_size = 1;
};

template <typename T>
class RadianceField {
 public:
  using Matrix = Eigen::Matrix<T, Eigen::Dynamic, Eigen::Dynamic>;
  virtual ~RadianceField() = default;
  virtual std::string name() const = 0;
  virtual int channels() const = 0;
  // positions: 3 x N in NDC; returns (1 + channels) x N: density, then colour.
  virtual Matrix forward(const Matrix& positions) = 0;
  // d_outputs: (1 + channels) x N; accumulates parameter gradients; returns 3 x N.
  virtual Matrix backward(const Matrix& d_outputs) = 0;
  virtual std::vector<ParameterBlock<T>> parameters() = 0;
  virtual void zeroGradients() = 0;
  // Coarse to fine (BARF, Lin et al., ICCV 2021): the encoding's bands are weighted by a window
  // that opens with `bands` (0: the coarsest band only, >= the band count: all, the default);
  // between integers the next band fades in as (1 - cos(pi f)) / 2.
  virtual void setBandLimit(double bands) = 0;
  virtual int bands() const = 0;
};

struct MlpFieldConfig {
  int frequencies = 10;
  int depth = 8;  // hidden layers of the trunk
  int width = 256;
  int skip = 4;  // the input joins the 5th layer
  int colour_width = 128;
};

struct HashFieldConfig {
  HashGridConfig grid;
  int hidden = 64;
  // The MLP's register-blocked kernels where they apply (float, 32 features into 64 hidden units,
  // grey or colour, an AVX-512 or AVX2 + FMA target); false: Eigen's products everywhere (the
  // same maths, for comparison).
  bool kernels = true;
};

template <typename T>
std::unique_ptr<RadianceField<T>> makeMlpField(const MlpFieldConfig& config, int channels,
                                               uint64_t seed);
template <typename T>
std::unique_ptr<RadianceField<T>> makeHashField(const HashFieldConfig& config, int channels,
                                                uint64_t seed);

}  // namespace evkit::nerf
