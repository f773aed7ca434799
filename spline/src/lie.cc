#include "evkit/spline/lie.h"

#include <cmath>

namespace evkit {

namespace {

// Series thresholds: below them the closed forms lose digits to cancellation.
constexpr double kSeriesAngle = 1.0;         // for the coefficients of J_l, J_r and Q (10 terms)
constexpr double kInverseSeriesAngle = 0.2;  // for the coefficient of J^-1 (6 terms)
constexpr int kSeriesTerms = 10;

// sum_{k>=0} (-1)^k theta^(2k) / (2k + offset)!, the Taylor series of the Jacobian coefficients.
double alternatingSeries(double theta2, int offset) {
  double factorial = 1.0;
  for (int i = 2; i <= offset; ++i) factorial *= i;
  double term = 1.0 / factorial, sum = 0.0;
  for (int k = 0; k < kSeriesTerms; ++k) {
    sum += term;
    term *= -theta2 / ((2.0 * k + offset + 1) * (2.0 * k + offset + 2));
  }
  return sum;
}

// a(theta) = (1 - cos)/theta^2,  b(theta) = (theta - sin)/theta^3.
void jacobianCoefficients(double theta, double& a, double& b) {
  if (theta < kSeriesAngle) {
    a = alternatingSeries(theta * theta, 2);
    b = alternatingSeries(theta * theta, 3);
  } else {
    const double t2 = theta * theta;
    a = (1.0 - std::cos(theta)) / t2;
    b = (theta - std::sin(theta)) / (t2 * theta);
  }
}

// e(theta) = 1/theta^2 - cot(theta/2) / (2 theta): J_l^-1 = I - phi^/2 + e phi^ phi^.
double inverseCoefficient(double theta) {
  if (theta < kInverseSeriesAngle) {
    // Bernoulli series of 1/x^2 - cot(x/2)/(2x).
    const double t2 = theta * theta;
    return 1.0 / 12.0 +
           t2 * (1.0 / 720.0 + t2 * (1.0 / 30240.0 + t2 * (1.0 / 1209600.0 +
                                                           t2 * (1.0 / 47900160.0 +
                                                                 t2 * (691.0 / 1307674368000.0)))));
  }
  return 1.0 / (theta * theta) - std::cos(0.5 * theta) / (2.0 * theta * std::sin(0.5 * theta));
}

}  // namespace

Matrix3 hat(const Vector3& v) {
  Matrix3 m;
  m << 0, -v.z(), v.y(), v.z(), 0, -v.x(), -v.y(), v.x(), 0;
  return m;
}

Vector3 vee(const Matrix3& m) { return Vector3(m(2, 1), m(0, 2), m(1, 0)); }

Quaternion expSO3(const Vector3& phi) {
  const double theta = phi.norm();
  const double half = 0.5 * theta;
  // sin(theta/2)/theta, with its series near 0: 1/2 - theta^2/48 + theta^4/3840.
  const double s = theta < 1e-4
                       ? 0.5 - theta * theta / 48.0 + theta * theta * theta * theta / 3840.0
                       : std::sin(half) / theta;
  Quaternion q(std::cos(half), s * phi.x(), s * phi.y(), s * phi.z());
  return q.normalized();
}

Vector3 logSO3(const Quaternion& q_in) {
  Quaternion q = q_in.normalized();
  if (q.w() < 0) q.coeffs() = -q.coeffs();  // the same rotation, theta in [0, pi]
  const Vector3 v = q.vec();
  const double n = v.norm();
  const double w = q.w();
  // theta = 2 atan2(n, w); phi = theta v / n, whose factor 2 atan2(n, w)/n -> 2/w (1 - n^2/(3
  // w^2)).
  if (n < 1e-8 * std::max(w, 1e-300)) return (2.0 / w) * (1.0 - n * n / (3.0 * w * w)) * v;
  return (2.0 * std::atan2(n, w) / n) * v;
}

Vector3 logSO3(const Matrix3& R) { return logSO3(Quaternion(R)); }

Matrix3 leftJacobianSO3(const Vector3& phi) {
  double a, b;
  jacobianCoefficients(phi.norm(), a, b);
  const Matrix3 P = hat(phi);
  return Matrix3::Identity() + a * P + b * P * P;
}

Matrix3 leftJacobianInverseSO3(const Vector3& phi) {
  const Matrix3 P = hat(phi);
  return Matrix3::Identity() - 0.5 * P + inverseCoefficient(phi.norm()) * P * P;
}

Matrix3 rightJacobianSO3(const Vector3& phi) { return leftJacobianSO3(-phi); }
Matrix3 rightJacobianInverseSO3(const Vector3& phi) { return leftJacobianInverseSO3(-phi); }

Eigen::Matrix4d SE3::matrix() const {
  Eigen::Matrix4d m = Eigen::Matrix4d::Identity();
  m.topLeftCorner<3, 3>() = rotationMatrix();
  m.topRightCorner<3, 1>() = t_;
  return m;
}

SE3 SE3::inverse() const {
  const Quaternion qi = q_.conjugate();
  return SE3(qi, -(qi * t_));
}

Eigen::Matrix4d hatSE3(const Vector6& xi) {
  Eigen::Matrix4d m = Eigen::Matrix4d::Zero();
  m.topLeftCorner<3, 3>() = hat(xi.tail<3>());
  m.topRightCorner<3, 1>() = xi.head<3>();
  return m;
}

Vector6 veeSE3(const Eigen::Matrix4d& m) {
  return twist(m.topRightCorner<3, 1>(), vee(m.topLeftCorner<3, 3>()));
}

SE3 expSE3(const Vector6& xi) {
  const Vector3 rho = xi.head<3>(), phi = xi.tail<3>();
  return SE3(expSO3(phi), leftJacobianSO3(phi) * rho);
}

Vector6 logSE3(const SE3& T) {
  const Vector3 phi = logSO3(T.rotation());
  return twist(leftJacobianInverseSO3(phi) * T.translation(), phi);
}

Matrix6 adjoint(const SE3& T) {
  const Matrix3 R = T.rotationMatrix();
  Matrix6 ad = Matrix6::Zero();
  ad.topLeftCorner<3, 3>() = R;
  ad.topRightCorner<3, 3>() = hat(T.translation()) * R;
  ad.bottomRightCorner<3, 3>() = R;
  return ad;
}

// Q(rho, phi) = 1/2 rho^ + c1 (phi^ rho^ + rho^ phi^ + phi^ rho^ phi^)
//             + c2 (phi^ phi^ rho^ + rho^ phi^ phi^ - 3 phi^ rho^ phi^)
//             + c3 (phi^ rho^ phi^ phi^ + phi^ phi^ rho^ phi^)
// with c1 = (theta - sin)/theta^3, c2 = (theta^2 + 2 cos - 2)/(2 theta^4) and
// c3 = (2 theta - 3 sin + theta cos)/(2 theta^5)   (Barfoot, "State Estimation for Robotics",
// eq. 7.86). Series: c1 = sum (-1)^k theta^2k/(2k+3)!, c2 = sum (-1)^k theta^2k/(2k+4)!,
// c3 = sum (-1)^k (k+1) theta^2k/(2k+5)!   (from the Taylor series of sin and cos).
Matrix3 jacobianQ(const Vector3& rho, const Vector3& phi) {
  const double theta = phi.norm();
  double c1, c2, c3;
  if (theta < kSeriesAngle) {
    const double t2 = theta * theta;
    c1 = alternatingSeries(t2, 3);
    c2 = alternatingSeries(t2, 4);
    double term = 1.0 / 120.0;  // (-1)^k theta^2k / (2k+5)!
    c3 = 0.0;
    for (int k = 0; k < kSeriesTerms; ++k) {
      c3 += (k + 1) * term;
      term *= -t2 / ((2.0 * k + 6) * (2.0 * k + 7));
    }
  } else {
    const double t2 = theta * theta, s = std::sin(theta), c = std::cos(theta);
    c1 = (theta - s) / (t2 * theta);
    c2 = (t2 + 2.0 * c - 2.0) / (2.0 * t2 * t2);
    c3 = (2.0 * theta - 3.0 * s + theta * c) / (2.0 * t2 * t2 * theta);
  }
  const Matrix3 P = hat(phi), Rh = hat(rho);
  const Matrix3 PR = P * Rh, RP = Rh * P, PRP = PR * P;
  return 0.5 * Rh + c1 * (PR + RP + PRP) + c2 * (P * PR + RP * P - 3.0 * PRP) +
         c3 * (PRP * P + P * PRP);
}

Matrix6 leftJacobianSE3(const Vector6& xi) {
  const Matrix3 J = leftJacobianSO3(xi.tail<3>());
  Matrix6 out = Matrix6::Zero();
  out.topLeftCorner<3, 3>() = J;
  out.bottomRightCorner<3, 3>() = J;
  out.topRightCorner<3, 3>() = jacobianQ(xi.head<3>(), xi.tail<3>());
  return out;
}

Matrix6 leftJacobianInverseSE3(const Vector6& xi) {
  const Matrix3 Ji = leftJacobianInverseSO3(xi.tail<3>());
  Matrix6 out = Matrix6::Zero();
  out.topLeftCorner<3, 3>() = Ji;
  out.bottomRightCorner<3, 3>() = Ji;
  out.topRightCorner<3, 3>() = -Ji * jacobianQ(xi.head<3>(), xi.tail<3>()) * Ji;
  return out;
}

Matrix6 rightJacobianSE3(const Vector6& xi) { return leftJacobianSE3(-xi); }
Matrix6 rightJacobianInverseSE3(const Vector6& xi) { return leftJacobianInverseSE3(-xi); }

}  // namespace evkit
