#include "evkit/nerf/adam.h"

#include <cmath>
#include <istream>
#include <ostream>

namespace evkit::nerf {

template <typename T>
Adam<T>::Adam(std::vector<ParameterBlock<T>> blocks, const AdamOptions& options)
    : blocks_(std::move(blocks)), options_(options) {
  for (const ParameterBlock<T>& b : blocks_) {
    m_.emplace_back(b.size, T(0));
    v_.emplace_back(b.size, T(0));
  }
}

template <typename T>
double Adam<T>::learningRate() const {
  return options_.learning_rate *
         std::pow(options_.decay_rate, static_cast<double>(t_) / options_.decay_steps);
}

template <typename T>
void Adam<T>::step() {
  const double lr = learningRate();
  ++t_;
  const double c1 = 1.0 - std::pow(options_.beta1, static_cast<double>(t_));
  const double c2 = 1.0 - std::pow(options_.beta2, static_cast<double>(t_));
  const T step = static_cast<T>(lr * std::sqrt(c2) / c1);
  const T b1 = static_cast<T>(options_.beta1), b2 = static_cast<T>(options_.beta2),
          eps = static_cast<T>(options_.epsilon);
  for (size_t k = 0; k < blocks_.size(); ++k) {
    const ParameterBlock<T>& b = blocks_[k];
    T* m = m_[k].data();
    T* v = v_[k].data();
    const auto update = [&](size_t i) {
      const T g = b.gradients[i];
      m[i] = b1 * m[i] + (T(1) - b1) * g;
      v[i] = b2 * v[i] + (T(1) - b2) * g * g;
      b.values[i] -= step * m[i] / (std::sqrt(v[i]) + eps);
    };
    if (b.touched == nullptr) {
      for (size_t i = 0; i < b.size; ++i) update(i);
    } else {
      // Runs of rows go to whichever thread is free: a split in halves gave one thread the coarse
      // levels (few rows touched) and left it waiting for the other.
      const size_t rows = b.size / b.row_size;
#pragma omp parallel for schedule(dynamic, 4096)
      for (size_t r = 0; r < rows; ++r) {
        if (!b.touched[r]) continue;
        for (size_t i = r * b.row_size; i < (r + 1) * b.row_size; ++i) update(i);
      }
    }
  }
}

template <typename T>
void Adam<T>::save(std::ostream& out) const {
  out.write(reinterpret_cast<const char*>(&t_), sizeof(t_));
  for (size_t k = 0; k < blocks_.size(); ++k) {
    out.write(reinterpret_cast<const char*>(m_[k].data()),
              static_cast<std::streamsize>(m_[k].size() * sizeof(T)));
    out.write(reinterpret_cast<const char*>(v_[k].data()),
              static_cast<std::streamsize>(v_[k].size() * sizeof(T)));
  }
}

template <typename T>
void Adam<T>::restore(std::istream& in) {
  in.read(reinterpret_cast<char*>(&t_), sizeof(t_));
  for (size_t k = 0; k < blocks_.size(); ++k) {
    in.read(reinterpret_cast<char*>(m_[k].data()),
            static_cast<std::streamsize>(m_[k].size() * sizeof(T)));
    in.read(reinterpret_cast<char*>(v_[k].data()),
            static_cast<std::streamsize>(v_[k].size() * sizeof(T)));
  }
}

template class Adam<float>;
template class Adam<double>;

}  // namespace evkit::nerf
