#include "evkit/nerf/field.h"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <numbers>
#include <type_traits>

#include "small_layer.h"

namespace evkit::nerf {

namespace {

// Applies density = softplus(raw_0), colour = sigmoid(raw_c) in place (vectorised by Eigen).
template <typename Derived>
void activate(Eigen::MatrixBase<Derived>&& raw_to_out) {
  using T = typename Derived::Scalar;
  const auto r = raw_to_out.row(0).array();
  raw_to_out.row(0) = (r.max(T(0)) + (-r.abs()).exp().log1p()).matrix();
  raw_to_out.bottomRows(raw_to_out.rows() - 1) =
      raw_to_out.bottomRows(raw_to_out.rows() - 1).array().logistic().matrix();
}

// d raw from d out, given the activated outputs: softplus' = sigmoid(raw) = 1 - exp(-density);
// sigmoid' = s (1 - s).
template <typename A, typename B, typename C>
void activationBackward(const Eigen::MatrixBase<A>& out, const Eigen::MatrixBase<B>& d_out,
                        Eigen::MatrixBase<C>&& d_raw) {
  using T = typename A::Scalar;
  const Eigen::Index c = out.rows() - 1;
  d_raw.row(0) = (d_out.row(0).array() * (T(1) - (-out.row(0).array()).exp())).matrix();
  d_raw.bottomRows(c) =
      (d_out.bottomRows(c).array() * out.bottomRows(c).array() * (T(1) - out.bottomRows(c).array()))
          .matrix();
}

// BARF's window: band 0 always, band b at (1 - cos(pi f)) / 2 with f = clamp(bands - (b - 1), 0,
// 1); empty when every band is fully open (the fields then skip the weighting).
template <typename T>
std::vector<T> bandWeights(double bands, int count) {
  std::vector<T> w(static_cast<size_t>(count), T(1));
  for (int b = 1; b < count; ++b) {
    const double f = std::clamp(bands - (b - 1), 0.0, 1.0);
    w[static_cast<size_t>(b)] = static_cast<T>(0.5 * (1 - std::cos(std::numbers::pi * f)));
  }
  if (std::all_of(w.begin(), w.end(), [](T v) { return v == T(1); })) w.clear();
  return w;
}

template <typename T>
void appendMlp(Mlp<T>& mlp, std::vector<ParameterBlock<T>>& blocks) {
  for (size_t l = 0; l < mlp.weights().size(); ++l) {
    blocks.push_back({mlp.weights()[l].data(), mlp.weightGradients()[l].data(),
                      static_cast<size_t>(mlp.weights()[l].size()), nullptr, 1});
    blocks.push_back({mlp.biases()[l].data(), mlp.biasGradients()[l].data(),
                      static_cast<size_t>(mlp.biases()[l].size()), nullptr, 1});
  }
}

template <typename T>
class MlpField final : public RadianceField<T> {
 public:
  using Matrix = typename RadianceField<T>::Matrix;
  MlpField(const MlpFieldConfig& c, int channels, uint64_t seed)
      : config_(c),
        channels_(channels),
        trunk_(trunkWidths(c), c.skip, seed),
        head_({c.width, c.colour_width, channels}, -1, seed + 1) {}

  std::string name() const override { return "mlp"; }
  int channels() const override { return channels_; }

  Matrix forward(const Matrix& positions) override {
    positions_ = positions;
    Matrix encoded = positionalEncoding(positions, config_.frequencies);
    weightBands(encoded);
    const Matrix features = trunk_.forward(encoded);  // (1 + width) x N
    Matrix out(1 + channels_, positions.cols());
    out.row(0) = features.row(0);
    out.bottomRows(channels_) = head_.forward(features.bottomRows(config_.width));
    activate(out.leftCols(out.cols()));
    out_ = out;
    return out;
  }

  Matrix backward(const Matrix& d_outputs) override {
    Matrix d_raw(d_outputs.rows(), d_outputs.cols());
    activationBackward(out_, d_outputs, d_raw.leftCols(d_raw.cols()));
    Matrix d_features(1 + config_.width, d_raw.cols());
    d_features.row(0) = d_raw.row(0);
    d_features.bottomRows(config_.width) = head_.backward(d_raw.bottomRows(channels_));
    Matrix d_encoded = trunk_.backward(d_features);
    weightBands(d_encoded);
    return positionalEncodingBackward(positions_, config_.frequencies, d_encoded);
  }

  std::vector<ParameterBlock<T>> parameters() override {
    std::vector<ParameterBlock<T>> blocks;
    appendMlp(trunk_, blocks);
    appendMlp(head_, blocks);
    return blocks;
  }
  void zeroGradients() override {
    trunk_.zeroGradients();
    head_.zeroGradients();
  }
  // Band 0: the raw position; band k + 1: frequency 2^k pi.
  int bands() const override { return 1 + config_.frequencies; }
  void setBandLimit(double bands) override {
    band_weight_ = bandWeights<T>(bands, 1 + config_.frequencies);
  }

 private:
  static std::vector<int> trunkWidths(const MlpFieldConfig& c) {
    std::vector<int> w = {3 * (1 + 2 * c.frequencies)};
    for (int l = 0; l < c.depth; ++l) w.push_back(c.width);
    w.push_back(1 + c.width);  // density + features for the colour head
    return w;
  }
  // Scales the sine and cosine rows of each frequency by its band's weight (a no-op at full band).
  void weightBands(Matrix& encoded) const {
    if (band_weight_.empty()) return;
    const Eigen::Index d = positions_.rows();
    for (int k = 0; k < config_.frequencies; ++k)
      encoded.middleRows(d * (1 + 2 * k), 2 * d) *= band_weight_[static_cast<size_t>(k + 1)];
  }
  MlpFieldConfig config_;
  int channels_;
  std::vector<T> band_weight_;  // per band; empty: every band at weight 1
  Mlp<T> trunk_, head_;
  Matrix positions_, out_;
};

// The fast field: hash encoding, then one hidden ReLU layer, in blocks of samples that stay in the
// cache (the encoding's 32 features and the 64 hidden values of a block are a few tens of KB),
// threads over blocks (the grid's backward: threads over levels). Forward keeps the encoding and
// the hidden layer for backward (cheaper than recomputing the first layer).
template <typename T>
class HashField final : public RadianceField<T> {
 public:
  using Matrix = typename RadianceField<T>::Matrix;
  HashField(const HashFieldConfig& c, int channels, uint64_t seed)
      : channels_(channels),
        grid_(c.grid, seed),
        mlp_({grid_.outputSize(), c.hidden, 1 + channels}, -1, seed + 1),
        fast_layers_(EVKIT_SMALL_LAYER && c.kernels && std::is_same_v<T, float> &&
                     grid_.outputSize() == 32 && c.hidden == 64 &&
                     (channels == 1 || channels == 3)) {}

  std::string name() const override { return "hash"; }
  int channels() const override { return channels_; }

  Matrix forward(const Matrix& positions) override {
    const Eigen::Index n = positions.cols();
    grid_.setPositions((positions.array() + T(1)) * T(0.5));  // NDC [-1, 1] -> [0, 1]
    features_.resize(grid_.outputSize(), n);
    const Matrix& w0 = mlp_.weights()[0];
    const Matrix& w1 = mlp_.weights()[1];
    const auto& b0 = mlp_.biases()[0];
    const auto& b1 = mlp_.biases()[1];
    Matrix out(1 + channels_, n);
    hidden_.resize(w0.rows(), n);
    // Blocks go to whichever thread is free (each block's outputs are its own: the same result for
    // any split).
#pragma omp parallel for schedule(dynamic, 4)
    for (Eigen::Index begin = 0; begin < n; begin += kBlock) {
      const Eigen::Index count = std::min(kBlock, n - begin);
      auto x = features_.middleCols(begin, count);
      grid_.encode(begin, count, x.data(), x.rows());
      if (!level_weight_.empty()) {
        for (int l = 0; l < grid_.config().levels; ++l)
          x.middleRows(l * grid_.config().features, grid_.config().features) *=
              level_weight_[static_cast<size_t>(l)];
      }
      auto hidden = hidden_.middleCols(begin, count);
#if EVKIT_SMALL_LAYER
      if constexpr (std::is_same_v<T, float>) {
        if (fast_layers_)
          small_layer::forwardRelu<64>(w0.data(), b0.data(), 32, x.data(), static_cast<int>(count),
                                       hidden.data());
      }
#endif
      if (!fast_layers_) {
        hidden.noalias() = w0 * x;
        hidden = (hidden.colwise() + b0).cwiseMax(T(0));
      }
      out.middleCols(begin, count).noalias() = w1 * hidden;
      out.middleCols(begin, count).colwise() += b1;
      activate(out.middleCols(begin, count));
    }
    out_ = out;
    return out;
  }

  Matrix backward(const Matrix& d_outputs) override {
    const Eigen::Index n = d_outputs.cols();
    const Matrix& w0 = mlp_.weights()[0];
    const Matrix& w1 = mlp_.weights()[1];
    d_features_.resize(static_cast<size_t>(features_.size()));
    // Parameter gradients per lane (a fixed run of blocks), added in lane order: the same sums
    // whatever the number of threads, and whichever thread runs a lane (they go to the free one).
    // (The kernels accumulate the output weights' gradient transposed, in dw1t.)
    const Eigen::Index blocks = (n + kBlock - 1) / kBlock;
    std::vector<Matrix> dw0(kLanes), dw1(kLanes), dw1t(kLanes), db0(kLanes), db1(kLanes);
    const Matrix w0t = w0.transpose(), w1t = w1.transpose();
#pragma omp parallel for schedule(dynamic, 1)
    for (size_t t = 0; t < kLanes; ++t) {
      dw0[t] = Matrix::Zero(w0.rows(), w0.cols());
      dw1[t] = Matrix::Zero(w1.rows(), w1.cols());
      dw1t[t] = Matrix::Zero(w1.cols(), w1.rows());
      db0[t] = Matrix::Zero(w0.rows(), 1);
      db1[t] = Matrix::Zero(w1.rows(), 1);
      Matrix d_out, d_hidden, d_x;
      const Eigen::Index lane = static_cast<Eigen::Index>(t), lanes = kLanes;
      for (Eigen::Index b = blocks * lane / lanes; b < blocks * (lane + 1) / lanes; ++b) {
        const Eigen::Index begin = b * kBlock;
        const Eigen::Index count = std::min(kBlock, n - begin);
        const auto x = features_.middleCols(begin, count);
        const auto hidden = hidden_.middleCols(begin, count);
        d_out.resize(out_.rows(), count);
        activationBackward(out_.middleCols(begin, count), d_outputs.middleCols(begin, count),
                           d_out.leftCols(count));
        db1[t] += d_out.rowwise().sum();
#if EVKIT_SMALL_LAYER
        if constexpr (std::is_same_v<T, float>) {
          if (fast_layers_) {
            d_hidden.resize(w0.rows(), count);
            d_x.resize(x.rows(), count);
            const int c = static_cast<int>(count);
            if (channels_ == 1) {
              small_layer::outputLayerBackward<64, 2>(w1t.data(), hidden.data(), d_out.data(), c,
                                                      d_hidden.data(), db0[t].data(),
                                                      dw1t[t].data());
            } else {
              small_layer::outputLayerBackward<64, 4>(w1t.data(), hidden.data(), d_out.data(), c,
                                                      d_hidden.data(), db0[t].data(),
                                                      dw1t[t].data());
            }
            small_layer::weightGradient<64>(d_hidden.data(), x.data(), 32, c, dw0[t].data());
            small_layer::inputGradient<32>(w0t.data(), 64, d_hidden.data(), c, d_x.data());
          }
        }
#endif
        if (!fast_layers_) {
          dw1[t].noalias() += d_out * hidden.transpose();
          d_hidden.noalias() = w1t * d_out;
          d_hidden = (hidden.array() > T(0)).select(d_hidden, T(0));  // ReLU
          db0[t] += d_hidden.rowwise().sum();
          dw0[t].noalias() += d_hidden * x.transpose();
          d_x.noalias() = w0t * d_hidden;
        }
        scatter(begin, count, d_x);
      }
    }
    for (size_t t = 0; t < kLanes; ++t) {
      mlp_.weightGradients()[0] += dw0[t];
      mlp_.weightGradients()[1] += dw1[t] + dw1t[t].transpose();
      mlp_.biasGradients()[0] += db0[t];
      mlp_.biasGradients()[1] += db1[t];
    }
    return grid_.backwardLevelMajor(d_features_.data()) * T(0.5);
  }

  std::vector<ParameterBlock<T>> parameters() override {
    std::vector<ParameterBlock<T>> blocks;
    blocks.push_back({grid_.table().data(), grid_.gradients().data(), grid_.table().size(),
                      grid_.touched().data(), static_cast<size_t>(grid_.config().features)});
    appendMlp(mlp_, blocks);
    return blocks;
  }
  void zeroGradients() override {
    grid_.zeroGradients();
    mlp_.zeroGradients();
  }
  int bands() const override { return grid_.config().levels; }
  void setBandLimit(double bands) override {
    level_weight_ = bandWeights<T>(bands, grid_.config().levels);
  }

 private:
  static constexpr Eigen::Index kBlock = 256;
  static constexpr size_t kLanes = 16;  // fixed partial sums of the backward pass

  // d features of samples [begin, begin + count) into the level-major layout of the grid's
  // backward.
  void scatter(Eigen::Index begin, Eigen::Index count, const Matrix& d_x) {
    const Eigen::Index F = grid_.config().features, n = features_.cols();
    for (int l = 0; l < grid_.config().levels; ++l) {
      T* dst = d_features_.data() + (l * n + begin) * F;
      const T w = level_weight_.empty() ? T(1) : level_weight_[static_cast<size_t>(l)];
      for (Eigen::Index k = 0; k < count; ++k) {
        for (Eigen::Index c = 0; c < F; ++c) dst[k * F + c] = w * d_x(l * F + c, k);
      }
    }
  }

  int channels_;
  HashGrid<T> grid_;
  Mlp<T> mlp_;
  Matrix out_;
  Matrix features_, hidden_;   // the last forward's encoding and hidden layer (after the ReLU)
  std::vector<T> d_features_;  // level-major, for the grid's backward
  // The register-blocked kernels (small_layer.h; AVX-512 or AVX2 + FMA) for the common shape in
  // float: 32 encoded features (8 x 4, 16 x 2) into 64 hidden units, grey or colour; Eigen's
  // products otherwise.
  bool fast_layers_;
  std::vector<T> level_weight_;  // per level; empty: every level at weight 1
};

}  // namespace

template <typename T>
std::unique_ptr<RadianceField<T>> makeMlpField(const MlpFieldConfig& config, int channels,
                                               uint64_t seed) {
  return std::make_unique<MlpField<T>>(config, channels, seed);
}
template <typename T>
std::unique_ptr<RadianceField<T>> makeHashField(const HashFieldConfig& config, int channels,
                                                uint64_t seed) {
  return std::make_unique<HashField<T>>(config, channels, seed);
}

template std::unique_ptr<RadianceField<float>> makeMlpField(const MlpFieldConfig&, int, uint64_t);
template std::unique_ptr<RadianceField<double>> makeMlpField(const MlpFieldConfig&, int, uint64_t);
template std::unique_ptr<RadianceField<float>> makeHashField(const HashFieldConfig&, int, uint64_t);
template std::unique_ptr<RadianceField<double>> makeHashField(const HashFieldConfig&, int,
                                                              uint64_t);

}  // namespace evkit::nerf
