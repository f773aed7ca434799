// Radiance-field cost on this CPU: forward + backward per sample for the NeRF MLP (8 x 256, the
// reference) and for hash-grid fields of several sizes (the choice of the fast field), and a full
// training step (rays/s) for each.
//
//   ./build/benchmarks/evkit_nerf_bench --benchmark_repetitions=5
//   --benchmark_report_aggregates_only=true
//
// (the median of 5 repetitions: this shared machine drifts by +-20% between runs)

#include <benchmark/benchmark.h>

#include <random>

#include "evkit/nerf/adam.h"
#include "evkit/nerf/field.h"
#include "evkit/nerf/train.h"

namespace evkit::nerf {
namespace {

using MatrixF = Eigen::MatrixXf;

// Positions uniformly random in the volume (the worst case for the caches), or along rays as the
// renderer asks for them: rays through random pixels of a forward-facing view, 64 stratified
// samples over NDC depth [-1, 1] each.
MatrixF samplePositions(int batch, bool along_rays) {
  if (!along_rays) return MatrixF::Random(3, batch) * 0.9f;
  MatrixF p(3, batch);
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> u(-0.9f, 0.9f), jitter(0.0f, 1.0f);
  for (int r = 0; r < batch / 64; ++r) {
    const float x = u(rng), y = u(rng), dx = 0.05f * u(rng), dy = 0.05f * u(rng);
    for (int s = 0; s < 64; ++s) {
      const float t = (static_cast<float>(s) + jitter(rng)) / 64.0f;
      const int k = r * 64 + s;
      p(0, k) = x + t * dx, p(1, k) = y + t * dy, p(2, k) = -1.0f + 2.0f * t;
    }
  }
  return p;
}

void fieldStep(benchmark::State& state, RadianceField<float>& field, int batch,
               bool along_rays = false) {
  const MatrixF p = samplePositions(batch, along_rays);
  const MatrixF d = MatrixF::Random(1 + field.channels(), batch);
  for (auto _ : state) {
    field.zeroGradients();
    benchmark::DoNotOptimize(field.forward(p));
    benchmark::DoNotOptimize(field.backward(d));
  }
  state.SetItemsProcessed(state.iterations() * batch);  // samples
}

void BM_MlpField(benchmark::State& state) {
  auto field = makeMlpField<float>(MlpFieldConfig{}, 3, 1);
  fieldStep(state, *field, 4096);
}

// Args: levels, features, log2 table, samples along rays (1) or uniformly random (0), and
// optionally 0 to run the MLP through Eigen's products instead of the register-blocked kernels
// (small_layer.h; the reference for them).
void BM_HashField(benchmark::State& state) {
  HashFieldConfig c;
  c.grid.levels = static_cast<int>(state.range(0));
  c.grid.features = static_cast<int>(state.range(1));
  c.grid.log2_table = static_cast<int>(state.range(2));
  c.grid.per_level_scale = c.grid.levels >= 16 ? 1.38 : 1.5;
  c.kernels = state.range(4) != 0;
  auto field = makeHashField<float>(c, 3, 1);
  const bool rays = state.range(3) != 0;
  fieldStep(state, *field, 65536, rays);
  state.SetLabel(std::to_string(c.grid.levels) + "x" + std::to_string(c.grid.features) + ", 2^" +
                 std::to_string(c.grid.log2_table) + " entries, " +
                 std::to_string(c.grid.levels * (size_t{1} << c.grid.log2_table) * c.grid.features *
                                4 / 1000000) +
                 " MB, " + (rays ? "ray samples" : "random positions") +
                 (c.kernels ? "" : ", Eigen's products"));
}

// Adam's step over the `fast` field (8 x 4, 2^15, 1.05 M parameters) after the forward and backward
// of a BeNeRF step's samples (49,152 along rays): every fine level mostly touched, the coarse dense
// levels in part.
void BM_AdamStepHash(benchmark::State& state) {
  HashFieldConfig c;
  c.grid.log2_table = 15;
  auto field = makeHashField<float>(c, 1, 1);
  const int batch = 49152;
  const MatrixF p = samplePositions(batch, true);
  field->zeroGradients();
  field->forward(p);
  field->backward(MatrixF::Random(2, batch));
  Adam<float> adam(field->parameters(), AdamOptions{});
  for (auto _ : state) adam.step();
  state.SetItemsProcessed(state.iterations() * static_cast<int64_t>(field->parameters()[0].size));
}

void trainingSteps(benchmark::State& state, RadianceField<float>& field, int rays) {
  const PinholeCamera cam = PinholeCamera{58.0, 58.0, 31.5, 23.5, {}}.withSize(64, 48);
  std::vector<TrainingView> views = {{cv::Mat(48, 64, CV_32FC3, cv::Scalar(0.3, 0.5, 0.7)), SE3()}};
  FitOptions o;
  o.steps = 1;
  o.rays_per_step = rays;
  o.samples_per_ray = 64;
  for (auto _ : state) benchmark::DoNotOptimize(fitField(field, cam, views, o));
  state.SetItemsProcessed(state.iterations() * rays);  // rays
}

void BM_TrainStepHash(benchmark::State& state) {
  auto field = makeHashField<float>(HashFieldConfig{}, 3, 1);
  trainingSteps(state, *field, 1024);
}

void BM_TrainStepMlp(benchmark::State& state) {
  auto field = makeMlpField<float>(MlpFieldConfig{}, 3, 1);
  trainingSteps(state, *field, 64);
}

BENCHMARK(BM_MlpField)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_HashField)
    ->Args({16, 2, 19, 0, 1})
    ->Args({8, 4, 16, 0, 1})
    ->Args({8, 4, 16, 1, 1})
    ->Args({8, 4, 16, 1, 0})
    ->Args({8, 2, 16, 0, 1})
    ->Args({8, 2, 16, 1, 1})
    ->Args({12, 2, 16, 0, 1})
    ->Args({8, 4, 14, 0, 1})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK(BM_AdamStepHash)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_TrainStepHash)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_TrainStepMlp)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace
}  // namespace evkit::nerf

BENCHMARK_MAIN();
