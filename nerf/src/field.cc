#include "evkit/nerf/field.h"

#include <cmath>

namespace evkit::nerf {

namespace {

// Applies density = softplus(raw_0), colour = sigmoid(raw_c) in place; keeps the raw values.
template <typename T>
void activate(Eigen::Matrix<T, Eigen::Dynamic, Eigen::Dynamic>& raw_to_out) {
  for (Eigen::Index k = 0; k < raw_to_out.cols(); ++k) {
    const T r = raw_to_out(0, k);
    raw_to_out(0, k) = std::max(r, T(0)) + std::log1p(std::exp(-std::abs(r)));
    for (Eigen::Index c = 1; c < raw_to_out.rows(); ++c) raw_to_out(c, k) = T(1) / (T(1) + std::exp(-raw_to_out(c, k)));
  }
}

// d raw from d out, given the activated outputs: softplus' = sigmoid(raw) = 1 - exp(-density);
// sigmoid' = s (1 - s).
template <typename T>
Eigen::Matrix<T, Eigen::Dynamic, Eigen::Dynamic> activationBackward(const Eigen::Matrix<T, Eigen::Dynamic, Eigen::Dynamic>& out,
                                                                    const Eigen::Matrix<T, Eigen::Dynamic, Eigen::Dynamic>& d_out) {
  Eigen::Matrix<T, Eigen::Dynamic, Eigen::Dynamic> d_raw(d_out.rows(), d_out.cols());
  for (Eigen::Index k = 0; k < out.cols(); ++k) {
    d_raw(0, k) = d_out(0, k) * (T(1) - std::exp(-out(0, k)));
    for (Eigen::Index c = 1; c < out.rows(); ++c) d_raw(c, k) = d_out(c, k) * out(c, k) * (T(1) - out(c, k));
  }
  return d_raw;
}

template <typename T>
void appendMlp(Mlp<T>& mlp, std::vector<ParameterBlock<T>>& blocks) {
  for (size_t l = 0; l < mlp.weights().size(); ++l) {
    blocks.push_back({mlp.weights()[l].data(), mlp.weightGradients()[l].data(), static_cast<size_t>(mlp.weights()[l].size()), nullptr, 1});
    blocks.push_back({mlp.biases()[l].data(), mlp.biasGradients()[l].data(), static_cast<size_t>(mlp.biases()[l].size()), nullptr, 1});
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
    const Matrix features = trunk_.forward(positionalEncoding(positions, config_.frequencies));  // (1 + width) x N
    Matrix out(1 + channels_, positions.cols());
    out.row(0) = features.row(0);
    out.bottomRows(channels_) = head_.forward(features.bottomRows(config_.width));
    activate(out);
    out_ = out;
    return out;
  }

  Matrix backward(const Matrix& d_outputs) override {
    const Matrix d_raw = activationBackward(out_, d_outputs);
    Matrix d_features(1 + config_.width, d_raw.cols());
    d_features.row(0) = d_raw.row(0);
    d_features.bottomRows(config_.width) = head_.backward(d_raw.bottomRows(channels_));
    return positionalEncodingBackward(positions_, config_.frequencies, trunk_.backward(d_features));
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

 private:
  static std::vector<int> trunkWidths(const MlpFieldConfig& c) {
    std::vector<int> w = {3 * (1 + 2 * c.frequencies)};
    for (int l = 0; l < c.depth; ++l) w.push_back(c.width);
    w.push_back(1 + c.width);  // density + features for the colour head
    return w;
  }
  MlpFieldConfig config_;
  int channels_;
  Mlp<T> trunk_, head_;
  Matrix positions_, out_;
};

template <typename T>
class HashField final : public RadianceField<T> {
 public:
  using Matrix = typename RadianceField<T>::Matrix;
  HashField(const HashFieldConfig& c, int channels, uint64_t seed)
      : channels_(channels), grid_(c.grid, seed), mlp_({grid_.outputSize(), c.hidden, 1 + channels}, -1, seed + 1) {}

  std::string name() const override { return "hash"; }
  int channels() const override { return channels_; }

  Matrix forward(const Matrix& positions) override {
    // NDC [-1, 1] -> grid [0, 1].
    Matrix out = mlp_.forward(grid_.forward((positions.array() + T(1)) * T(0.5)));
    activate(out);
    out_ = out;
    return out;
  }
  Matrix backward(const Matrix& d_outputs) override {
    return grid_.backward(mlp_.backward(activationBackward(out_, d_outputs))) * T(0.5);
  }
  std::vector<ParameterBlock<T>> parameters() override {
    std::vector<ParameterBlock<T>> blocks;
    blocks.push_back({grid_.table().data(), grid_.gradients().data(), grid_.table().size(), grid_.touched().data(),
                      static_cast<size_t>(grid_.config().features)});
    appendMlp(mlp_, blocks);
    return blocks;
  }
  void zeroGradients() override {
    grid_.zeroGradients();
    mlp_.zeroGradients();
  }

 private:
  int channels_;
  HashGrid<T> grid_;
  Mlp<T> mlp_;
  Matrix out_;
};

}  // namespace

template <typename T>
std::unique_ptr<RadianceField<T>> makeMlpField(const MlpFieldConfig& config, int channels, uint64_t seed) {
  return std::make_unique<MlpField<T>>(config, channels, seed);
}
template <typename T>
std::unique_ptr<RadianceField<T>> makeHashField(const HashFieldConfig& config, int channels, uint64_t seed) {
  return std::make_unique<HashField<T>>(config, channels, seed);
}

template std::unique_ptr<RadianceField<float>> makeMlpField(const MlpFieldConfig&, int, uint64_t);
template std::unique_ptr<RadianceField<double>> makeMlpField(const MlpFieldConfig&, int, uint64_t);
template std::unique_ptr<RadianceField<float>> makeHashField(const HashFieldConfig&, int, uint64_t);
template std::unique_ptr<RadianceField<double>> makeHashField(const HashFieldConfig&, int, uint64_t);

}  // namespace evkit::nerf
