#include "evkit/nerf/mlp.h"

#include <cassert>
#include <cmath>
#include <numbers>

namespace evkit::nerf {

template <typename T>
Mlp<T>::Mlp(std::vector<int> widths, int skip_layer, uint64_t seed)
    : widths_(std::move(widths)), skip_(skip_layer) {
  assert(widths_.size() >= 2);
  std::mt19937_64 rng(seed);
  const size_t layers = widths_.size() - 1;
  for (size_t l = 0; l < layers; ++l) {
    const int in = widths_[l] + (static_cast<int>(l) == skip_ ? widths_[0] : 0);
    const int out = widths_[l + 1];
    // He uniform for ReLU layers: U(-sqrt(6/in), sqrt(6/in)).
    std::uniform_real_distribution<double> u(-std::sqrt(6.0 / in), std::sqrt(6.0 / in));
    Matrix w(out, in);
    for (Eigen::Index i = 0; i < w.size(); ++i) w.data()[i] = static_cast<T>(u(rng));
    w_.push_back(w);
    b_.push_back(Vector::Zero(out));
    dw_.push_back(Matrix::Zero(out, in));
    db_.push_back(Vector::Zero(out));
  }
}

template <typename T>
size_t Mlp<T>::parameterCount() const {
  size_t n = 0;
  for (size_t l = 0; l < w_.size(); ++l) n += static_cast<size_t>(w_[l].size() + b_[l].size());
  return n;
}

template <typename T>
typename Mlp<T>::Matrix Mlp<T>::forward(const Matrix& x) {
  assert(x.rows() == widths_[0]);
  inputs_.resize(w_.size());
  pre_.resize(w_.size());
  Matrix h = x;
  for (size_t l = 0; l < w_.size(); ++l) {
    if (static_cast<int>(l) == skip_) {
      Matrix cat(h.rows() + x.rows(), h.cols());
      cat << h, x;
      h = std::move(cat);
    }
    inputs_[l] = h;
    pre_[l] = (w_[l] * h).colwise() + b_[l];
    h = l + 1 < w_.size() ? Matrix(pre_[l].cwiseMax(T(0))) : pre_[l];
  }
  return h;
}

template <typename T>
typename Mlp<T>::Matrix Mlp<T>::backward(const Matrix& dy) {
  Matrix d = dy;
  Matrix d_input = Matrix::Zero(widths_[0], dy.cols());
  for (size_t l = w_.size(); l-- > 0;) {
    if (l + 1 < w_.size())
      d = d.cwiseProduct((pre_[l].array() > T(0)).template cast<T>().matrix());  // ReLU
    dw_[l].noalias() += d * inputs_[l].transpose();
    db_[l] += d.rowwise().sum();
    Matrix dh = w_[l].transpose() * d;
    if (static_cast<int>(l) == skip_) {
      d_input += dh.bottomRows(widths_[0]);
      dh = Matrix(dh.topRows(dh.rows() - widths_[0]));
    }
    d = std::move(dh);
  }
  d_input += d;
  return d_input;
}

template <typename T>
void Mlp<T>::getParameters(T* out) const {
  for (size_t l = 0; l < w_.size(); ++l) {
    out = std::copy(w_[l].data(), w_[l].data() + w_[l].size(), out);
    out = std::copy(b_[l].data(), b_[l].data() + b_[l].size(), out);
  }
}

template <typename T>
void Mlp<T>::setParameters(const T* in) {
  for (size_t l = 0; l < w_.size(); ++l) {
    std::copy(in, in + w_[l].size(), w_[l].data());
    in += w_[l].size();
    std::copy(in, in + b_[l].size(), b_[l].data());
    in += b_[l].size();
  }
}

template <typename T>
void Mlp<T>::getGradients(T* out) const {
  for (size_t l = 0; l < w_.size(); ++l) {
    out = std::copy(dw_[l].data(), dw_[l].data() + dw_[l].size(), out);
    out = std::copy(db_[l].data(), db_[l].data() + db_[l].size(), out);
  }
}

template <typename T>
void Mlp<T>::zeroGradients() {
  for (size_t l = 0; l < w_.size(); ++l) {
    dw_[l].setZero();
    db_[l].setZero();
  }
}

template <typename T>
Eigen::Matrix<T, Eigen::Dynamic, Eigen::Dynamic> positionalEncoding(
    const Eigen::Matrix<T, Eigen::Dynamic, Eigen::Dynamic>& p, int frequencies) {
  const Eigen::Index d = p.rows();
  Eigen::Matrix<T, Eigen::Dynamic, Eigen::Dynamic> out(d * (1 + 2 * frequencies), p.cols());
  out.topRows(d) = p;
  for (int k = 0; k < frequencies; ++k) {
    const T scale = static_cast<T>(std::ldexp(std::numbers::pi, k));  // 2^k pi
    out.middleRows(d * (1 + 2 * k), d) = (p * scale).array().sin().matrix();
    out.middleRows(d * (2 + 2 * k), d) = (p * scale).array().cos().matrix();
  }
  return out;
}

template <typename T>
Eigen::Matrix<T, Eigen::Dynamic, Eigen::Dynamic> positionalEncodingBackward(
    const Eigen::Matrix<T, Eigen::Dynamic, Eigen::Dynamic>& p, int frequencies,
    const Eigen::Matrix<T, Eigen::Dynamic, Eigen::Dynamic>& de) {
  const Eigen::Index d = p.rows();
  Eigen::Matrix<T, Eigen::Dynamic, Eigen::Dynamic> dp = de.topRows(d);
  for (int k = 0; k < frequencies; ++k) {
    const T scale = static_cast<T>(std::ldexp(std::numbers::pi, k));
    dp.array() += scale * (de.middleRows(d * (1 + 2 * k), d).array() * (p * scale).array().cos() -
                           de.middleRows(d * (2 + 2 * k), d).array() * (p * scale).array().sin());
  }
  return dp;
}

template class Mlp<float>;
template class Mlp<double>;
template Eigen::MatrixXf positionalEncoding(const Eigen::MatrixXf&, int);
template Eigen::MatrixXd positionalEncoding(const Eigen::MatrixXd&, int);
template Eigen::MatrixXf positionalEncodingBackward(const Eigen::MatrixXf&, int,
                                                    const Eigen::MatrixXf&);
template Eigen::MatrixXd positionalEncodingBackward(const Eigen::MatrixXd&, int,
                                                    const Eigen::MatrixXd&);

}  // namespace evkit::nerf
