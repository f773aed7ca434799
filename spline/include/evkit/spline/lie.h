// SO(3) and SE(3) in double: exp, log, hat/vee, adjoint, left and right Jacobians and their
// inverses.
//
// Conventions (DESIGN.md §2, Barfoot, "State Estimation for Robotics", 2017, ch. 7):
//  - A pose T = (R, t) is T_world_cam: it maps camera coordinates to world, x_world = R x_cam + t.
//    Stored as [tx ty tz qx qy qz qw] where it is written to text.
//  - Tangent vectors of SE(3) are xi = (rho, phi): translation part first, rotation second.
//    exp(xi) = [exp(phi^), J_l(phi) rho; 0 1].
//  - Right perturbation T exp(eps) unless a function says otherwise; J_r(xi) = J_l(-xi) and
//    exp(xi + d) ~ exp(xi) exp(J_r(xi) d).
//  - Adjoint: T exp(xi) T^-1 = exp(Ad(T) xi), Ad(T) = [R, t^ R; 0, R].
//
// Precision: every coefficient that the closed forms compute by cancellation (1 - cos, theta -
// sin, theta - sin - theta^3/6, ...) switches to its Taylor series below a threshold chosen so that
// both sides keep ~1e-15 relative accuracy; the angles 0, 1e-12, 1e-8, 1e-5 are exact to the last
// digits. log() goes through the quaternion with atan2, exact up to and at theta = pi.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace evkit {

using Vector3 = Eigen::Vector3d;
using Vector6 = Eigen::Matrix<double, 6, 1>;
using Matrix3 = Eigen::Matrix3d;
using Matrix6 = Eigen::Matrix<double, 6, 6>;
using Quaternion = Eigen::Quaterniond;

// ---- SO(3) ----------------------------------------------------------------------------------
Matrix3 hat(const Vector3& v);
Vector3 vee(const Matrix3& m);  // of a skew-symmetric matrix

Quaternion expSO3(const Vector3& phi);
// The rotation vector of minimal norm (theta in [0, pi]); at theta = pi either of the two
// opposite vectors.
Vector3 logSO3(const Quaternion& q);
Vector3 logSO3(const Matrix3& R);

Matrix3 leftJacobianSO3(const Vector3& phi);
Matrix3 leftJacobianInverseSO3(const Vector3& phi);  // singular at theta = 2 pi only
Matrix3 rightJacobianSO3(const Vector3& phi);
Matrix3 rightJacobianInverseSO3(const Vector3& phi);

// ---- SE(3) ----------------------------------------------------------------------------------
class SE3 {
 public:
  SE3() : q_(Quaternion::Identity()), t_(Vector3::Zero()) {}
  SE3(const Quaternion& q, const Vector3& t) : q_(q.normalized()), t_(t) {}
  SE3(const Matrix3& R, const Vector3& t) : q_(Quaternion(R).normalized()), t_(t) {}

  static SE3 identity() { return SE3(); }

  const Quaternion& rotation() const { return q_; }
  Matrix3 rotationMatrix() const { return q_.toRotationMatrix(); }
  const Vector3& translation() const { return t_; }
  Eigen::Matrix4d matrix() const;

  SE3 inverse() const;
  SE3 operator*(const SE3& other) const { return SE3(q_ * other.q_, t_ + q_ * other.t_); }
  Vector3 operator*(const Vector3& p) const { return q_ * p + t_; }

 private:
  Quaternion q_;  // unit
  Vector3 t_;
};

// The twist (rho, phi): translation part first, rotation part last. Written by halves: GCC 12 at
// -O2 and above with AVX (and without AVX-512) flags the comma initializer `xi << rho, phi` as
// reading past a 3-vector temporary (a false -Warray-bounds inside Eigen's packet loads).
inline Vector6 twist(const Vector3& rho, const Vector3& phi) {
  Vector6 xi;
  xi.head<3>() = rho;
  xi.tail<3>() = phi;
  return xi;
}

Eigen::Matrix4d hatSE3(const Vector6& xi);
Vector6 veeSE3(const Eigen::Matrix4d& m);

SE3 expSE3(const Vector6& xi);
Vector6 logSE3(const SE3& T);
Matrix6 adjoint(const SE3& T);

// The Q block of the SE(3) left Jacobian (Barfoot eq. 7.86), with series below 1 rad.
Matrix3 jacobianQ(const Vector3& rho, const Vector3& phi);
Matrix6 leftJacobianSE3(const Vector6& xi);
Matrix6 leftJacobianInverseSE3(const Vector6& xi);
Matrix6 rightJacobianSE3(const Vector6& xi);
Matrix6 rightJacobianInverseSE3(const Vector6& xi);

}  // namespace evkit
