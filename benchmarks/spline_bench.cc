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
  for (int k = 0; k < 4; ++k)
    knots.push_back(
        expSE3((Vector6() << 0.01 * k, 0.002 * k, 0, 0.003 * k, -0.002 * k, 0.001).finished()));
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

// The reference: the same 4 knot Jacobians by central differences (48 evaluations), what one
// would do without the analytic derivation.
void BM_CentralDifferenceJacobians(benchmark::State& state) {
  const Trajectory traj = makeTrajectory(TrajectoryKind::kCubicSE3);
  double s = 0;
  for (auto _ : state) {
    s += 0.0137;
    if (s > 1) s -= 1;
    const SE3 P = traj.evaluate(s);
    const SE3 P_inv = P.inverse();
    KnotJacobians J;
    for (int k = 0; k < 4; ++k) {
      for (int c = 0; c < 6; ++c) {
        Vector6 d = Vector6::Zero();
        d(c) = 1e-6;
        Trajectory plus = traj, minus = traj;
        plus.knots()[static_cast<size_t>(k)] = plus.knots()[static_cast<size_t>(k)] * expSE3(d);
        minus.knots()[static_cast<size_t>(k)] = minus.knots()[static_cast<size_t>(k)] * expSE3(-d);
        J.d_pose_d_knot[static_cast<size_t>(k)].col(c) =
            (logSE3(P_inv * plus.evaluate(s)) - logSE3(P_inv * minus.evaluate(s))) / 2e-6;
      }
    }
    benchmark::DoNotOptimize(J);
  }
  state.SetItemsProcessed(state.iterations());
}

BENCHMARK(BM_Evaluate)->ArgsProduct({{0, 1, 2}, {0, 1}});
BENCHMARK(BM_CentralDifferenceJacobians);

}  // namespace
}  // namespace evkit

BENCHMARK_MAIN();
