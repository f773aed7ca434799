// Spline evaluations per second, with and without knot Jacobians, for each trajectory kind.
//
//   ./build/benchmarks/evkit_spline_bench

#include <benchmark/benchmark.h>

#include <random>

#include "evkit/spline/trajectory.h"

namespace evkit {
namespace {

Trajectory makeTrajectory(TrajectoryKind kind) {
  std::vector<SE3> knots;
  for (int k = 0; k < 4; ++k) knots.push_back(expSE3((Vector6() << 0.01 * k, 0.002 * k, 0, 0.003 * k, -0.002 * k, 0.001).finished()));
  return Trajectory(kind, 0, 100000, knots);
}

void BM_Evaluate(benchmark::State& state) {
  const Trajectory traj = makeTrajectory(static_cast<TrajectoryKind>(state.range(0)));
  const bool with_jacobians = state.range(1) != 0;
  KnotJacobians J;
  double s = 0;
  for (auto _ : state) {
    s += 0.0137;
    if (s > 1) s -= 1;
    benchmark::DoNotOptimize(traj.evaluate(s, with_jacobians ? &J : nullptr));
    benchmark::DoNotOptimize(J);
  }
  state.SetItemsProcessed(state.iterations());
  state.SetLabel(trajectoryKindName(traj.kind()) + (with_jacobians ? " + Jacobians" : ""));
}

BENCHMARK(BM_Evaluate)->ArgsProduct({{0, 1, 2}, {0, 1}});

}  // namespace
}  // namespace evkit

BENCHMARK_MAIN();
