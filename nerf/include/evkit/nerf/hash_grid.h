// Multiresolution hash encoding (Müller, Evans, Schied, Keller, "Instant Neural Graphics
// Primitives", SIGGRAPH 2022): L levels of F-feature grids with resolutions from N_min growing by
// a factor b per level; a level's vertices index a table of 2^log2_table entries directly while
// they fit, by the spatial hash (x * 1) ^ (y * 2654435761) ^ (z * 805459861) otherwise; features
// are trilinearly interpolated. Positions are in [0, 1]^3 (clamped).
//
// Backward scatters the feature gradients into the table (each level's table slice owned by one
// thread: no atomics) and marks the touched entries, so that Adam can update only those.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <vector>

namespace evkit::nerf {

struct HashGridConfig {
  int levels = 8;
  int features = 4;
  int log2_table = 16;     // entries per level
  int base_resolution = 16;
  double per_level_scale = 1.5;
};

template <typename T>
class HashGrid {
 public:
  using Matrix = Eigen::Matrix<T, Eigen::Dynamic, Eigen::Dynamic>;
  HashGrid(const HashGridConfig& config, uint64_t seed);

  const HashGridConfig& config() const { return config_; }
  int outputSize() const { return config_.levels * config_.features; }
  int resolution(int level) const { return resolution_[static_cast<size_t>(level)]; }

  Matrix forward(const Matrix& positions);          // 3 x N -> (L F) x N
  Matrix backward(const Matrix& d_features);        // (L F) x N -> 3 x N; accumulates table grads

  std::vector<T>& table() { return table_; }        // [level][entry][feature]
  std::vector<T>& gradients() { return grad_; }
  std::vector<uint8_t>& touched() { return touched_; }  // per [level][entry]
  void zeroGradients();

 private:
  size_t index(int level, int x, int y, int z) const;

  HashGridConfig config_;
  size_t entries_;
  std::vector<int> resolution_;
  std::vector<T> table_, grad_;
  std::vector<uint8_t> touched_;
  // Forward's record for backward: corner entries, fractional positions, in-range axes.
  std::vector<uint32_t> corners_;
  std::vector<T> fractions_;
  std::vector<uint8_t> inside_;
};

}  // namespace evkit::nerf
