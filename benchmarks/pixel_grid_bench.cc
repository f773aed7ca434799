// The pixel grid's construction, its loss and gradient (PixelGridProblem::evaluate), the cost of
// each L-BFGS step of BeNeRF's default field, ten steps, and three steps of the motion's
// refinement, at 346x260 in colour with `fast`'s 32 views, two cells per pixel, the events against
// the sensor's reference level, the short windows and the robust penalty: a camera that turns 2
// degrees and slides over the exposure, 300k events, over two depths (the layer behind where the
// near half uncovers the far one; each benchmark's last argument 0: without,
// PixelGridOptions::occlusion off).
//
//   ./build/benchmarks/evkit_pixel_grid_bench

#include <benchmark/benchmark.h>
#include <omp.h>

#include <vector>

#include "evkit/deblur/benerf.h"
#include "evkit/deblur/pixel_grid.h"
#include "evkit/events/random_events.h"
#include "evkit/spline/fit.h"

namespace evkit {
namespace {

constexpr int kWidth = 346, kHeight = 260;

PixelGridOptions fastOptions() {
  const BenerfOptions b;
  PixelGridOptions o;
  o.min_views = o.max_views = 32;
  o.subdivision = b.cells;
  o.hysteresis = b.hysteresis;
  o.event_window = b.alpha;
  o.event_robust = b.mid_robust;
  o.chroma_smoothness = b.chroma_smooth;
  return o;
}

// An image of uniform noise in [0.05, 0.95]: the blurry frame, and where the unknowns start.
cv::Mat randomImage() {
  cv::Mat image(kHeight, kWidth, CV_32FC3);
  cv::randu(image, cv::Scalar::all(0.05), cv::Scalar::all(0.95));
  return image;
}

// What a problem is built from: the observation, the camera, the motion and the depths.
struct Inputs {
  Observation obs;
  PinholeCamera camera;
  Trajectory motion;
  cv::Mat inverse_depth;
};

Inputs makeInputs() {
  RandomEventOptions e;
  e.count = 300'000;
  e.rate_hz = 3e6;  // 300k events in 100 ms
  Observation obs;
  obs.events = randomEvents(e);
  const int64_t t0 = obs.events.t.front(), t1 = t0 + 100'000;
  obs.blurry.image = randomImage();
  obs.blurry.exposure_start_us = t0;
  obs.blurry.exposure_end_us = t1;
  const PinholeCamera camera = PinholeCamera::assumed(kWidth, kHeight).withSize(kWidth, kHeight);
  obs.camera = camera;
  std::vector<StampedPose> poses;
  for (int k = 0; k <= 8; ++k) {
    const double s = k / 8.0 - 0.5;
    poses.push_back({t0 + (t1 - t0) * k / 8,
                     SE3(expSO3(Vector3(0.02, -0.025, 0.005) * s), Vector3(0.03, 0.01, 0) * s)});
  }
  cv::Mat inverse_depth(kHeight, kWidth, CV_32F);
  for (int y = 0; y < kHeight; ++y) {
    for (int x = 0; x < kWidth; ++x)
      inverse_depth.at<float>(y, x) = x < kWidth / 2 ? 0.3f : 0.8f;  // two depths
  }
  return {std::move(obs), camera, fitTrajectory(TrajectoryKind::kCubicSE3, 4, t0, t1, poses),
          inverse_depth};
}

const Inputs& inputs() {
  static const Inputs in = makeInputs();
  return in;
}

PixelGridProblem makeProblem(bool occlusion) {
  const Inputs& in = inputs();
  PixelGridOptions o = fastOptions();
  o.occlusion = occlusion;
  return PixelGridProblem(in.obs, in.camera, in.motion, in.inverse_depth, Contrast{0.2, 0.2}, o);
}

const PixelGridProblem& problem(bool occlusion) {
  static const PixelGridProblem with = makeProblem(true), without = makeProblem(false);
  return occlusion ? with : without;
}

// The problem's construction: the views' stencils and each pixel's event changes at each view
// (BeNeRF builds one for each c that its search for c tries, and one to solve). range(0): threads;
// range(1): the layer behind.
void BM_PixelGridBuild(benchmark::State& state) {
  omp_set_num_threads(static_cast<int>(state.range(0)));
  inputs();  // the events and the motion made before the timed loop
  for (auto _ : state) benchmark::DoNotOptimize(makeProblem(state.range(1) != 0));
}

// range(0): threads; range(1): 1 with the gradient, 0 the loss alone (the line search's trials
// take both, the final terms the loss alone).
void BM_PixelGridEvaluate(benchmark::State& state) {
  omp_set_num_threads(static_cast<int>(state.range(0)));
  const PixelGridProblem& p = problem(state.range(2) != 0);
  const std::vector<double> x = p.start(randomImage());
  std::vector<double> gradient;
  for (auto _ : state)
    benchmark::DoNotOptimize(p.evaluate(x, state.range(1) ? &gradient : nullptr));
  state.counters["cells"] = static_cast<double>(x.size());
}

// Ten L-BFGS steps from the frame (BeNeRF's search for c takes ten for each c it tries).
void BM_PixelGridSolve10(benchmark::State& state) {
  omp_set_num_threads(static_cast<int>(state.range(0)));
  const PixelGridProblem& p = problem(state.range(1) != 0);
  const std::vector<double> start = p.start(randomImage());
  for (auto _ : state) {
    std::vector<double> x = start;
    benchmark::DoNotOptimize(p.solve(x, 10));
  }
}

// Three Levenberg-Marquardt steps on the motion with the image fixed (BeNeRF's second refinement):
// each step's normal equations, and each trial motion's stencils and loss.
void BM_PixelGridRefineMotion3(benchmark::State& state) {
  omp_set_num_threads(static_cast<int>(state.range(0)));
  const cv::Mat frame = randomImage();
  for (auto _ : state) {
    state.PauseTiming();
    PixelGridProblem p = problem(state.range(1) != 0);
    const std::vector<double> x = p.start(frame);
    state.ResumeTiming();
    benchmark::DoNotOptimize(p.refineMotion(x, 3));
  }
}

BENCHMARK(BM_PixelGridBuild)
    ->Args({2, 1})
    ->Args({2, 0})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK(BM_PixelGridEvaluate)
    ->Args({1, 1, 1})
    ->Args({2, 1, 1})
    ->Args({2, 0, 1})
    ->Args({2, 1, 0})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK(BM_PixelGridSolve10)
    ->Args({2, 1})
    ->Args({2, 0})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK(BM_PixelGridRefineMotion3)
    ->Args({2, 1})
    ->Args({2, 0})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

}  // namespace
}  // namespace evkit

BENCHMARK_MAIN();
