#include "evkit/spline/trajectory.h"

#include <algorithm>
#include <cassert>
#include <cmath>
#include <stdexcept>

namespace evkit {

namespace {

// Cumulative basis B~_j(u), j = 0..3, and its derivative d/du.
std::array<double, 4> cumulativeBasis(double u) {
  const double u2 = u * u, u3 = u2 * u;
  return {1.0, (5.0 + 3.0 * u - 3.0 * u2 + u3) / 6.0, (1.0 + 3.0 * u + 3.0 * u2 - 2.0 * u3) / 6.0,
          u3 / 6.0};
}
std::array<double, 4> cumulativeBasisDerivative(double u) {
  const double u2 = u * u;
  return {0.0, (3.0 - 6.0 * u + 3.0 * u2) / 6.0, (3.0 + 6.0 * u - 6.0 * u2) / 6.0, 0.5 * u2};
}

}  // namespace

std::string trajectoryKindName(TrajectoryKind kind) {
  switch (kind) {
    case TrajectoryKind::kCubicSE3:
      return "cubic";
    case TrajectoryKind::kCubicSplit:
      return "split";
    case TrajectoryKind::kLinear:
      return "linear";
  }
  return "unknown";
}

TrajectoryKind parseTrajectoryKind(const std::string& name) {
  for (TrajectoryKind k :
       {TrajectoryKind::kCubicSE3, TrajectoryKind::kCubicSplit, TrajectoryKind::kLinear}) {
    if (trajectoryKindName(k) == name) return k;
  }
  throw std::invalid_argument("unknown trajectory kind '" + name +
                              "' (known: cubic, split, linear)");
}

int Trajectory::minimumKnots(TrajectoryKind kind) {
  return kind == TrajectoryKind::kLinear ? 2 : 4;
}

Trajectory::Trajectory(TrajectoryKind kind, int64_t t_begin_us, int64_t t_end_us,
                       std::vector<SE3> knots)
    : kind_(kind), t_begin_(t_begin_us), t_end_(t_end_us), knots_(std::move(knots)) {
  if (static_cast<int>(knots_.size()) < minimumKnots(kind)) {
    throw std::invalid_argument("a " + trajectoryKindName(kind) + " trajectory needs at least " +
                                std::to_string(minimumKnots(kind)) + " knots");
  }
  if (t_end_ <= t_begin_) throw std::invalid_argument("a trajectory needs t_end > t_begin");
}

double Trajectory::normalizedTime(int64_t t_us) const {
  return static_cast<double>(t_us - t_begin_) / static_cast<double>(t_end_ - t_begin_);
}

SE3 Trajectory::poseAt(int64_t t_us, KnotJacobians* jacobians) const {
  return evaluate(normalizedTime(t_us), jacobians);
}

SE3 Trajectory::evaluate(double s, KnotJacobians* J, Vector6* velocity) const {
  const int segments = static_cast<int>(knots_.size()) - (kind_ == TrajectoryKind::kLinear ? 1 : 3);
  const double x = std::clamp(s, 0.0, 1.0) * segments;
  const int segment = std::min(static_cast<int>(x), segments - 1);
  const double u = x - segment;
  SE3 pose;
  switch (kind_) {
    case TrajectoryKind::kCubicSE3:
      pose = evaluateCubic(segment, u, J, velocity);
      break;
    case TrajectoryKind::kCubicSplit:
      pose = evaluateSplit(segment, u, J, velocity);
      break;
    case TrajectoryKind::kLinear:
      pose = evaluateLinear(segment, u, J, velocity);
      break;
  }
  if (velocity) *velocity *= segments;  // d/du -> d/ds
  return pose;
}

// Right Jacobians of T(u) = T_i A_1 A_2 A_3, A_j = exp(b_j Omega_j):
//  - through T_i directly: Ad((A_1 A_2 A_3)^-1);
//  - through Omega_j: A_j' = A_j exp(b_j J_r(b_j Omega_j) dOmega_j), which reaches the end of the
//    product as D_j dOmega_j with D_j = Ad((A_{j+1}..A_3)^-1) b_j J_r(b_j Omega_j);
//  - Omega_j = log(T_{i+j-1}^-1 T_{i+j}): dOmega_j = J_r^-1(Omega_j) delta_{i+j}
//    - J_l^-1(Omega_j) delta_{i+j-1}.
// Hence J_i = Ad((A_1A_2A_3)^-1) - D_1 J_l^-1(Omega_1), J_{i+j} = D_j J_r^-1(Omega_j)
// - D_{j+1} J_l^-1(Omega_{j+1}) (j = 1, 2), J_{i+3} = D_3 J_r^-1(Omega_3)   (Sommer et al., CVPR
// 2020, derive the same in a recursive form). Body velocity: sum_j Ad((A_{j+1}..A_3)^-1) b'_j
// Omega_j.
SE3 Trajectory::evaluateCubic(int i, double u, KnotJacobians* J, Vector6* velocity) const {
  const auto b = cumulativeBasis(u);
  std::array<Vector6, 4> omega;
  std::array<SE3, 4> A;
  SE3 pose = knots_[static_cast<size_t>(i)];
  for (int j = 1; j <= 3; ++j) {
    omega[j] = logSE3(knots_[static_cast<size_t>(i + j - 1)].inverse() *
                      knots_[static_cast<size_t>(i + j)]);
    A[j] = expSE3(b[j] * omega[j]);
    pose = pose * A[j];
  }
  if (!J && !velocity) return pose;
  // tail[j] = A_{j+1} .. A_3 (tail[3] = identity), P_j = Ad(tail[j]^-1).
  std::array<SE3, 4> tail;
  tail[3] = SE3();
  for (int j = 2; j >= 0; --j) tail[j] = A[j + 1] * tail[j + 1];
  std::array<Matrix6, 4> P;
  for (int j = 0; j <= 3; ++j) P[j] = adjoint(tail[j].inverse());
  if (velocity) {
    const auto db = cumulativeBasisDerivative(u);
    velocity->setZero();
    for (int j = 1; j <= 3; ++j) *velocity += P[j] * (db[j] * omega[j]);
  }
  if (J) {
    J->first_knot = i;
    J->count = 4;
    std::array<Matrix6, 5> D;  // D[4] = 0 closes the recursion
    for (int j = 1; j <= 3; ++j) D[j] = P[j] * b[j] * rightJacobianSE3(b[j] * omega[j]);
    D[4].setZero();
    J->d_pose_d_knot[0] = P[0] - D[1] * leftJacobianInverseSE3(omega[1]);
    for (int j = 1; j <= 3; ++j) {
      J->d_pose_d_knot[j] = D[j] * rightJacobianInverseSE3(omega[j]);
      if (j < 3) J->d_pose_d_knot[j] -= D[j + 1] * leftJacobianInverseSE3(omega[j + 1]);
    }
  }
  return pose;
}

// Split: R(u) = R_i prod exp(b_j phi_j) on SO(3) (the same Jacobians in 3x3), and
// p(u) = sum_k B_k(u) p_{i+k} with the ordinary basis B_0 = 1 - b_1, B_k = b_k - b_{k+1},
// B_3 = b_3. In the SE(3) right-perturbation convention: a knot step (rho_k, phi_k) moves
// p_k by R_k rho_k and R_k by exp(phi_k); the pose step is (R(u)^T dp, dphi).
SE3 Trajectory::evaluateSplit(int i, double u, KnotJacobians* J, Vector6* velocity) const {
  const auto b = cumulativeBasis(u);
  const std::array<double, 4> B = {1.0 - b[1], b[1] - b[2], b[2] - b[3], b[3]};
  std::array<Vector3, 4> phi;
  std::array<Quaternion, 4> A;
  Quaternion R = knots_[static_cast<size_t>(i)].rotation();
  Vector3 p = Vector3::Zero();
  for (int k = 0; k <= 3; ++k) p += B[k] * knots_[static_cast<size_t>(i + k)].translation();
  for (int j = 1; j <= 3; ++j) {
    phi[j] = logSO3(knots_[static_cast<size_t>(i + j - 1)].rotation().conjugate() *
                    knots_[static_cast<size_t>(i + j)].rotation());
    A[j] = expSO3(b[j] * phi[j]);
    R = R * A[j];
  }
  const SE3 pose(R, p);
  if (!J && !velocity) return pose;
  std::array<Quaternion, 4> tail;
  tail[3] = Quaternion::Identity();
  for (int j = 2; j >= 0; --j) tail[j] = A[j + 1] * tail[j + 1];
  std::array<Matrix3, 4> P;
  for (int j = 0; j <= 3; ++j) P[j] = tail[j].conjugate().toRotationMatrix();
  const Matrix3 Rt = R.conjugate().toRotationMatrix();
  if (velocity) {
    const auto db = cumulativeBasisDerivative(u);
    const std::array<double, 4> dB = {-db[1], db[1] - db[2], db[2] - db[3], db[3]};
    Vector3 dp = Vector3::Zero(), w = Vector3::Zero();
    for (int k = 0; k <= 3; ++k) dp += dB[k] * knots_[static_cast<size_t>(i + k)].translation();
    for (int j = 1; j <= 3; ++j) w += P[j] * (db[j] * phi[j]);
    *velocity = twist(Rt * dp, w);
  }
  if (J) {
    J->first_knot = i;
    J->count = 4;
    std::array<Matrix3, 5> D;
    for (int j = 1; j <= 3; ++j) D[j] = P[j] * b[j] * rightJacobianSO3(b[j] * phi[j]);
    D[4].setZero();
    for (int k = 0; k <= 3; ++k) {
      Matrix3 rot = k == 0 ? Matrix3(P[0]) : Matrix3(D[k] * rightJacobianInverseSO3(phi[k]));
      if (k < 3) rot -= D[k + 1] * leftJacobianInverseSO3(phi[k + 1]);
      Matrix6& Jk = J->d_pose_d_knot[k];
      Jk.setZero();
      Jk.topLeftCorner<3, 3>() = B[k] * Rt * knots_[static_cast<size_t>(i + k)].rotationMatrix();
      Jk.bottomRightCorner<3, 3>() = rot;
    }
  }
  return pose;
}

// T(u) = T_i exp(u Omega): J_i = Ad(exp(-u Omega)) - u J_r(u Omega) J_l^-1(Omega),
// J_{i+1} = u J_r(u Omega) J_r^-1(Omega); body velocity Omega.
SE3 Trajectory::evaluateLinear(int i, double u, KnotJacobians* J, Vector6* velocity) const {
  const SE3& T0 = knots_[static_cast<size_t>(i)];
  const Vector6 omega = logSE3(T0.inverse() * knots_[static_cast<size_t>(i + 1)]);
  const SE3 step = expSE3(u * omega);
  if (velocity) *velocity = omega;
  if (J) {
    J->first_knot = i;
    J->count = 2;
    const Matrix6 Jr = u * rightJacobianSE3(u * omega);
    J->d_pose_d_knot[0] = adjoint(step.inverse()) - Jr * leftJacobianInverseSE3(omega);
    J->d_pose_d_knot[1] = Jr * rightJacobianInverseSE3(omega);
  }
  return T0 * step;
}

void Trajectory::applyKnotSteps(const Eigen::VectorXd& steps) {
  assert(steps.size() == 6 * static_cast<Eigen::Index>(knots_.size()));
  for (size_t k = 0; k < knots_.size(); ++k) {
    knots_[k] = knots_[k] * expSE3(steps.segment<6>(static_cast<Eigen::Index>(6 * k)));
  }
}

}  // namespace evkit
