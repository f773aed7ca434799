// A fully connected network with ReLU hidden layers and an optional skip connection (the input
// concatenated to one hidden layer's input, as NeRF's 5th layer), on batches stored as columns.
// Forward keeps what backward needs; backward accumulates parameter gradients and returns the
// gradient with respect to the input. Templated on the scalar: float for training, double for the
// finite-difference checks.
#pragma once

#include <Eigen/Core>
#include <random>
#include <vector>

namespace evkit::nerf {

template <typename T>
class Mlp {
 public:
  using Matrix = Eigen::Matrix<T, Eigen::Dynamic, Eigen::Dynamic>;
  using Vector = Eigen::Matrix<T, Eigen::Dynamic, 1>;

  // widths = {input, hidden..., output}; skip_layer: index of the layer whose input also gets the
  // network input appended (-1: none). He-uniform initialisation from the seed.
  Mlp(std::vector<int> widths, int skip_layer, uint64_t seed);

  int inputSize() const { return widths_.front(); }
  int outputSize() const { return widths_.back(); }
  size_t parameterCount() const;

  // x: input x N; returns output x N (linear output layer).
  Matrix forward(const Matrix& x);
  // dy: output x N gradient; accumulates into the gradient buffers; returns input x N.
  Matrix backward(const Matrix& dy);

  // Parameters and gradients, flattened in a fixed order (W0, b0, W1, b1, ...).
  void getParameters(T* out) const;
  void setParameters(const T* in);
  void getGradients(T* out) const;
  void zeroGradients();

  std::vector<Matrix>& weights() { return w_; }
  std::vector<Vector>& biases() { return b_; }
  std::vector<Matrix>& weightGradients() { return dw_; }
  std::vector<Vector>& biasGradients() { return db_; }

 private:
  std::vector<int> widths_;
  int skip_;
  std::vector<Matrix> w_, dw_;
  std::vector<Vector> b_, db_;
  std::vector<Matrix> inputs_;  // per layer, its (concatenated) input
  std::vector<Matrix> pre_;     // per layer, W x + b before the activation
};

// NeRF's positional encoding: gamma(p) = (p, sin(2^k pi p), cos(2^k pi p))_{k<L} per coordinate
// (Mildenhall et al. 2020, eq. 4, with the raw input kept as in their code): dims 3 (1 + 2L).
template <typename T>
Eigen::Matrix<T, Eigen::Dynamic, Eigen::Dynamic> positionalEncoding(
    const Eigen::Matrix<T, Eigen::Dynamic, Eigen::Dynamic>& p, int frequencies);
// Gradient with respect to p of <d_encoded, gamma(p)>.
template <typename T>
Eigen::Matrix<T, Eigen::Dynamic, Eigen::Dynamic> positionalEncodingBackward(
    const Eigen::Matrix<T, Eigen::Dynamic, Eigen::Dynamic>& p, int frequencies,
    const Eigen::Matrix<T, Eigen::Dynamic, Eigen::Dynamic>& d_encoded);

}  // namespace evkit::nerf
