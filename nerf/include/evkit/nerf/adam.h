// Adam (Kingma and Ba, ICLR 2015) over parameter blocks, with an exponentially decaying learning
// rate lr_t = lr * decay_rate^(t / decay_steps) and, for sparse blocks (hash tables), updates of
// the touched rows only (their moments are left alone otherwise: "lazy" Adam).
#pragma once

#include <iosfwd>
#include <vector>

#include "evkit/nerf/field.h"

namespace evkit::nerf {

struct AdamOptions {
  double learning_rate = 1e-2;
  double beta1 = 0.9, beta2 = 0.99, epsilon = 1e-15;
  double decay_rate = 0.1;   // lr multiplier after decay_steps
  double decay_steps = 1e9;  // effectively constant unless set
};

template <typename T>
class Adam {
 public:
  Adam(std::vector<ParameterBlock<T>> blocks, const AdamOptions& options);
  void step();  // applies the blocks' gradients
  double learningRate() const;
  long steps() const { return t_; }
  AdamOptions& options() { return options_; }  // e.g. to set the decay once the step count is known
  // The optimiser's state (step count and moments), for checkpoints: restore needs the same blocks.
  void save(std::ostream& out) const;
  void restore(std::istream& in);

 private:
  std::vector<ParameterBlock<T>> blocks_;
  AdamOptions options_;
  std::vector<std::vector<T>> m_, v_;
  long t_ = 0;
};

}  // namespace evkit::nerf
