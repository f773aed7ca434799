// Camera trajectories over a time interval, from control knots: the uniform cumulative cubic
// B-spline on SE(3) of the BeNeRF paper, the split SO(3) x R^3 variant of the authors' public code,
// and linear interpolation (the paper's ablation), behind one interface.
//
// Cumulative cubic B-spline (Kim et al. 1995; Lovegrove et al. 2013; BeNeRF eq. 4-5): with knots
// T_0..T_{N-1} uniformly spaced, segment i in [0, N-4] and u in [0, 1),
//   T(u) = T_i * prod_{j=1..3} exp(B~_j(u) Omega_j),  Omega_j = log(T_{i+j-1}^-1 T_{i+j}),
//   B~(u) = M~ [1 u u^2 u^3]^T,  M~ = 1/6 [6 0 0 0; 5 3 -3 1; 1 3 3 -2; 0 0 0 1].
// The split variant runs the same cumulative spline on the rotations alone and an ordinary
// uniform cubic B-spline (the same basis, not cumulative) on the positions. Linear interpolation:
// T(u) = T_i exp(u log(T_i^-1 T_{i+1})) over N-1 segments.
//
// The normalised time s in [0, 1] spans [t_begin, t_end] (µs, int64; only differences become
// double). Jacobians are with respect to right perturbations of the pose and of each knot:
// T(s) exp(eps) with eps = sum_k J_k delta_k for knots T_k exp(delta_k); tangent order (rho, phi).
// Property: sum_k J_k Ad(T_k^-1) = Ad(T(s)^-1) (a common left motion of all knots moves the pose
// the same way).
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "evkit/spline/lie.h"

namespace evkit {

enum class TrajectoryKind { kCubicSE3, kCubicSplit, kLinear };
std::string trajectoryKindName(TrajectoryKind kind);
TrajectoryKind parseTrajectoryKind(const std::string& name);  // "cubic", "split", "linear"

// d pose / d knot for the (at most 4) knots that influence one time.
struct KnotJacobians {
  int first_knot = 0;
  int count = 0;  // 4 for the cubic kinds, 2 for linear
  std::array<Matrix6, 4> d_pose_d_knot;
};

class Trajectory {
 public:
  Trajectory(TrajectoryKind kind, int64_t t_begin_us, int64_t t_end_us, std::vector<SE3> knots);

  TrajectoryKind kind() const { return kind_; }
  int64_t beginUs() const { return t_begin_; }
  int64_t endUs() const { return t_end_; }
  const std::vector<SE3>& knots() const { return knots_; }
  std::vector<SE3>& knots() { return knots_; }
  // Minimal number of knots of the kind (4 cubic, 2 linear).
  static int minimumKnots(TrajectoryKind kind);

  // Pose at normalised time s in [0, 1] (clamped). Optional outputs: Jacobians with respect to the
  // knots, and the body velocity T^-1 dT/ds as a twist (rho, phi) per unit of s.
  SE3 evaluate(double s, KnotJacobians* jacobians = nullptr,
               Vector6* body_velocity = nullptr) const;
  // Pose at a time in µs (exact integer offset, then normalised).
  SE3 poseAt(int64_t t_us, KnotJacobians* jacobians = nullptr) const;
  double normalizedTime(int64_t t_us) const;

  // Applies right-perturbation steps: knot k <- knot k * exp(steps[6k .. 6k+5]).
  void applyKnotSteps(const Eigen::VectorXd& steps);

 private:
  SE3 evaluateCubic(int segment, double u, KnotJacobians* J, Vector6* velocity) const;
  SE3 evaluateSplit(int segment, double u, KnotJacobians* J, Vector6* velocity) const;
  SE3 evaluateLinear(int segment, double u, KnotJacobians* J, Vector6* velocity) const;

  TrajectoryKind kind_;
  int64_t t_begin_, t_end_;
  std::vector<SE3> knots_;
};

}  // namespace evkit
