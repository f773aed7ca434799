#include "evkit/spline/trajectory.h"

#include <gtest/gtest.h>

#include <random>

#include "jacobian_check.h"

namespace evkit {
namespace {

constexpr int64_t kBegin = 1605537493718345;  // absolute Unix µs
constexpr int64_t kEnd = kBegin + 100000;
const TrajectoryKind kKinds[] = {TrajectoryKind::kCubicSE3, TrajectoryKind::kCubicSplit,
                                 TrajectoryKind::kLinear};

// Knots that step by `step` (rad and scene units) from one to the next, in random directions.
std::vector<SE3> randomKnots(int n, double step, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> g;
  std::vector<SE3> knots{
      SE3(expSO3(Vector3(g(rng), g(rng), g(rng)) * 0.3), Vector3(g(rng), g(rng), g(rng)))};
  for (int k = 1; k < n; ++k) {
    const Vector3 rho = Vector3(g(rng), g(rng), g(rng)).normalized() * step;
    const Vector3 phi = Vector3(g(rng), g(rng), g(rng)).normalized() * step;
    knots.push_back(knots.back() * expSE3(twist(rho, phi)));
  }
  return knots;
}

TEST(Trajectory, ConstantKnotsGiveAConstantTrajectoryExactly) {
  const SE3 T(expSO3(Vector3(0.3, -0.2, 1.0)), Vector3(1.5, -2.0, 0.25));
  for (TrajectoryKind kind : kKinds) {
    const Trajectory traj(kind, kBegin, kEnd, std::vector<SE3>(6, T));
    for (double s : {0.0, 0.123, 0.5, 0.999, 1.0}) {
      const SE3 P = traj.evaluate(s);
      EXPECT_LT((P.matrix() - T.matrix()).cwiseAbs().maxCoeff(), 1e-15)
          << trajectoryKindName(kind) << " s " << s;
      Vector6 v;
      traj.evaluate(s, nullptr, &v);
      EXPECT_LT(v.norm(), 1e-15);
    }
  }
}

TEST(Trajectory, LinearInterpolatesItsKnotsAndCubicIsContinuousAcrossSegments) {
  const std::vector<SE3> knots = randomKnots(7, 0.3, 1);
  const Trajectory linear(TrajectoryKind::kLinear, kBegin, kEnd, knots);
  EXPECT_LT((linear.evaluate(0).matrix() - knots[0].matrix()).cwiseAbs().maxCoeff(), 1e-14);
  EXPECT_LT((linear.evaluate(1).matrix() - knots[6].matrix()).cwiseAbs().maxCoeff(), 1e-13);
  for (TrajectoryKind kind : {TrajectoryKind::kCubicSE3, TrajectoryKind::kCubicSplit}) {
    const Trajectory traj(kind, kBegin, kEnd, knots);
    for (int boundary = 1; boundary < 4; ++boundary) {
      const double s = boundary / 4.0;
      const SE3 left = traj.evaluate(s - 1e-12), right = traj.evaluate(s + 1e-12);
      EXPECT_LT((left.matrix() - right.matrix()).cwiseAbs().maxCoeff(), 1e-10)
          << trajectoryKindName(kind) << " " << s;
      Vector6 vl, vr;
      traj.evaluate(s - 1e-12, nullptr, &vl);
      traj.evaluate(s + 1e-12, nullptr, &vr);
      EXPECT_LT((vl - vr).norm(), 1e-9) << "velocity is continuous too (C2 spline)";
    }
  }
}

// Every knot Jacobian against central differences, at many times, for tiny and large knot steps,
// 4 and 7 knots, every kind.
TEST(Trajectory, KnotJacobiansAgainstCentralDifferences) {
  for (TrajectoryKind kind : kKinds) {
    for (int n : {4, 7}) {
      for (double step : {1e-4, 0.1, 1.0}) {
        const Trajectory traj(kind, kBegin, kEnd, randomKnots(n, step, 7 + n));
        for (double s : {0.0, 0.05, 0.21, 0.37, 0.5, 0.63, 0.88, 0.9999}) {
          KnotJacobians J;
          const SE3 P = traj.evaluate(s, &J);
          for (int a = 0; a < J.count; ++a) {
            const int k = J.first_knot + a;
            const auto f = [&](const Eigen::VectorXd& d) -> Eigen::VectorXd {
              Trajectory moved = traj;
              moved.knots()[static_cast<size_t>(k)] =
                  moved.knots()[static_cast<size_t>(k)] * expSE3(Vector6(d));
              return logSE3(P.inverse() * moved.evaluate(s));
            };
            test::expectJacobianNear(
                trajectoryKindName(kind) + " n=" + std::to_string(n) + " step=" +
                    std::to_string(step) + " s=" + std::to_string(s) + " knot " + std::to_string(k),
                J.d_pose_d_knot[static_cast<size_t>(a)], f, Vector6::Zero(), 1e-6, 1e-7);
          }
        }
      }
    }
  }
}

TEST(Trajectory, JacobiansSatisfyTheLeftInvarianceIdentity) {
  // sum_k J_k Ad(T_k^-1) = Ad(T(s)^-1).
  for (TrajectoryKind kind : kKinds) {
    const Trajectory traj(kind, kBegin, kEnd, randomKnots(5, 0.8, 3));
    for (double s : {0.0, 0.3, 0.71, 1.0}) {
      KnotJacobians J;
      const SE3 P = traj.evaluate(s, &J);
      Matrix6 sum = Matrix6::Zero();
      for (int a = 0; a < J.count; ++a) {
        sum += J.d_pose_d_knot[static_cast<size_t>(a)] *
               adjoint(traj.knots()[static_cast<size_t>(J.first_knot + a)].inverse());
      }
      EXPECT_LT((sum - adjoint(P.inverse())).cwiseAbs().maxCoeff(), 1e-12)
          << trajectoryKindName(kind) << " s " << s;
    }
  }
}

TEST(Trajectory, BodyVelocityIsTheDerivativeOfThePose) {
  for (TrajectoryKind kind : kKinds) {
    const Trajectory traj(kind, kBegin, kEnd, randomKnots(6, 0.4, 11));
    for (double s : {0.1, 0.45, 0.77}) {  // away from knots, where linear velocity jumps
      Vector6 v;
      const SE3 P = traj.evaluate(s, nullptr, &v);
      const double h = 1e-6;
      const Vector6 numeric = (logSE3(P.inverse() * traj.evaluate(s + h)) -
                               logSE3(P.inverse() * traj.evaluate(s - h))) /
                              (2 * h);
      EXPECT_LT((v - numeric).norm(), 1e-6 * std::max(1.0, numeric.norm()))
          << trajectoryKindName(kind) << " s " << s;
    }
  }
}

TEST(Trajectory, TimesAreExactIntegerMicroseconds) {
  const Trajectory traj(TrajectoryKind::kCubicSE3, kBegin, kEnd, randomKnots(4, 0.2, 5));
  EXPECT_EQ(traj.normalizedTime(kBegin), 0.0);
  EXPECT_EQ(traj.normalizedTime(kEnd), 1.0);
  EXPECT_EQ(traj.normalizedTime(kBegin + 25000), 0.25);
  EXPECT_LT(
      (traj.poseAt(kBegin + 50000).matrix() - traj.evaluate(0.5).matrix()).cwiseAbs().maxCoeff(),
      1e-15);
  EXPECT_THROW(Trajectory(TrajectoryKind::kCubicSE3, kBegin, kEnd, randomKnots(3, 0.1, 1)),
               std::invalid_argument);
  EXPECT_THROW(Trajectory(TrajectoryKind::kLinear, kEnd, kBegin, randomKnots(3, 0.1, 1)),
               std::invalid_argument);
  EXPECT_EQ(parseTrajectoryKind("split"), TrajectoryKind::kCubicSplit);
}

}  // namespace
}  // namespace evkit
