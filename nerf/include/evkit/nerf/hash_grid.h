// Multiresolution hash encoding (Müller, Evans, Schied, Keller, "Instant Neural Graphics
// Primitives", SIGGRAPH 2022): L levels of F-feature grids with resolutions from N_min growing by
// a factor b per level; a level's vertices index a table of 2^log2_table entries directly while
// they fit, by the spatial hash (x * 1) ^ (y * 2654435761) ^ (z * 805459861) otherwise; features
// are trilinearly interpolated. Positions are in [0, 1]^3 (clamped).
//
// Forward runs over blocks of samples (threads own blocks; the tables are only read), level by
// level within a block, corners and weights computed for 64 samples at once (vectorised over
// samples). Backward runs level by level (threads own whole levels: each level's table slice, ~1
// MB, stays in its thread's cache, and the gradient scatter needs no atomics) on feature gradients
// stored level-major, [level][sample][feature], so that one level's pass reads contiguous memory;
// it recomputes the corners (cheaper than storing them) and marks the touched entries so that Adam
// can update only those.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <vector>

namespace evkit::nerf {

struct HashGridConfig {
  int levels = 8;
  int features = 4;     // 1..16
  int log2_table = 16;  // entries per level, 1..30
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

  // Sample-major: 3 x N -> (L F) x N, and back; backward accumulates the table gradients.
  Matrix forward(const Matrix& positions);
  Matrix backward(const Matrix& d_features);

  // The pieces, for callers that work in blocks of samples: setPositions keeps the positions
  // (3 x N) for encode and backward; encode writes samples [begin, begin + count) sample-major,
  // out[(k - begin) stride + l F + c] (thread-safe: reads only); backwardLevelMajor takes the
  // feature gradients level-major, d[(l N + k) F + c], and returns d positions (3 x N).
  void setPositions(const Matrix& positions);
  void encode(Eigen::Index begin, Eigen::Index count, T* out, Eigen::Index stride) const;
  Matrix backwardLevelMajor(const T* d_features);

  std::vector<T>& table() { return table_; }  // [level][entry][feature]
  std::vector<T>& gradients() { return grad_; }
  std::vector<uint8_t>& touched() { return touched_; }  // per [level][entry]
  void zeroGradients();

 private:
  HashGridConfig config_;
  size_t entries_;
  std::vector<int> resolution_;
  std::vector<uint8_t> dense_;  // per level: direct indexing (the grid fits the table)
  std::vector<T> table_, grad_;
  std::vector<uint8_t> touched_;
  Matrix positions_;  // forward's clamped positions (N x 3: one array per axis), for backward
  // backward's position gradients per level (N x 3 each), kept between steps: fresh buffers of
  // this size would cost more in page faults than the kernels take
  std::vector<Matrix> level_positions_;
  std::vector<uint8_t>
      inside_;  // per sample: axes strictly inside (0, 1): the clamp passes the gradient
};

}  // namespace evkit::nerf
