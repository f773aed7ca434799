#include "evkit/spline/lie.h"

#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <random>

#include "jacobian_check.h"

namespace evkit {
namespace {

constexpr double kPi = std::numbers::pi;
constexpr double kTightTol = 1e-14;
constexpr double kFdTol = 1e-8;  // central differences with eps 1e-6: O(eps^2) + rounding/eps
constexpr double kFdEps = 1e-6;

// The hard angles of the issue, and a few ordinary ones.
const std::vector<double> kAngles = {0.0, 1e-12, 1e-8, 1e-5, 1e-3, 1e-2,       0.1,
                                     0.5, 0.99,  1.01, 2.0,  3.0,  kPi - 1e-9, kPi};

Vector3 randomAxis(std::mt19937_64& rng) {
  std::normal_distribution<double> n;
  return Vector3(n(rng), n(rng), n(rng)).normalized();
}

SE3 randomPose(std::mt19937_64& rng, double max_angle = kPi) {
  std::uniform_real_distribution<double> u(-1, 1);
  const double angle = std::abs(u(rng)) * max_angle;
  return SE3(expSO3(randomAxis(rng) * angle), Vector3(u(rng), u(rng), u(rng)) * 3.0);
}

TEST(SO3, HatVeeAndExpOfHatMatchEigen) {
  const Vector3 v(0.3, -1.2, 2.5);
  EXPECT_TRUE(vee(hat(v)).isApprox(v));
  EXPECT_TRUE((hat(v) * Vector3(1, 2, 3)).isApprox(v.cross(Vector3(1, 2, 3))));
  for (double a : {1e-6, 0.4, 3.0}) {
    const Vector3 phi = a * Vector3(1, 2, -2).normalized();
    const Matrix3 eig = Eigen::AngleAxisd(a, phi.normalized()).toRotationMatrix();
    EXPECT_LT((expSO3(phi).toRotationMatrix() - eig).cwiseAbs().maxCoeff(), kTightTol);
  }
}

TEST(SO3, LogOfExpRecoversTheVectorAtHardAngles) {
  std::mt19937_64 rng(1);
  for (double theta : kAngles) {
    for (int draw = 0; draw < 20; ++draw) {
      const Vector3 phi = randomAxis(rng) * theta;
      const Vector3 back = logSO3(expSO3(phi));
      if (theta < kPi - 1e-6) {
        // Relative to theta: the small vectors keep all their digits.
        EXPECT_LE((back - phi).norm(), kTightTol * std::max(theta, 1e-300) + 1e-300)
            << "theta " << theta;
      } else {
        // At pi, phi and -phi are the same rotation; near it, atan2 keeps the angle exact.
        EXPECT_NEAR(back.norm(), theta, 1e-12) << "theta " << theta;
        EXPECT_LT((expSO3(back).toRotationMatrix() - expSO3(phi).toRotationMatrix())
                      .cwiseAbs()
                      .maxCoeff(),
                  1e-14);
        if (theta < kPi) {
          EXPECT_LT((back - phi).norm(), 1e-8) << "theta " << theta;
        }
      }
    }
  }
  // From a matrix exactly at pi (180 degrees about z).
  Matrix3 R = Matrix3::Identity();
  R(0, 0) = R(1, 1) = -1;
  EXPECT_NEAR(logSO3(R).norm(), kPi, 1e-15);
  EXPECT_NEAR(std::abs(logSO3(R).z()), kPi, 1e-15);
}

TEST(SO3, JacobianIdentitiesOverRandomDraws) {
  std::mt19937_64 rng(2);
  for (double theta : kAngles) {
    for (int draw = 0; draw < 10; ++draw) {
      const Vector3 phi = randomAxis(rng) * theta;
      const Matrix3 R = expSO3(phi).toRotationMatrix();
      // J_l = R J_r, J_l J_l^-1 = I, J_r J_r^-1 = I.
      EXPECT_LT((leftJacobianSO3(phi) - R * rightJacobianSO3(phi)).cwiseAbs().maxCoeff(), 1e-14);
      EXPECT_LT((leftJacobianSO3(phi) * leftJacobianInverseSO3(phi) - Matrix3::Identity())
                    .cwiseAbs()
                    .maxCoeff(),
                1e-13);
      EXPECT_LT((rightJacobianSO3(phi) * rightJacobianInverseSO3(phi) - Matrix3::Identity())
                    .cwiseAbs()
                    .maxCoeff(),
                1e-13);
    }
  }
}

TEST(SO3, RightJacobianAgainstCentralDifferences) {
  std::mt19937_64 rng(3);
  for (double theta : kAngles) {
    const Vector3 phi = randomAxis(rng) * theta;
    // J_r(phi) = d/dd log(exp(phi)^-1 exp(phi + d)) at d = 0.
    const auto f = [&](const Eigen::VectorXd& d) -> Eigen::VectorXd {
      return logSO3(expSO3(phi).conjugate() * expSO3(phi + Vector3(d)));
    };
    test::expectJacobianNear("J_r at theta " + std::to_string(theta), rightJacobianSO3(phi), f,
                             Vector3::Zero(), kFdEps, kFdTol);
    const auto g = [&](const Eigen::VectorXd& d) -> Eigen::VectorXd {
      return logSO3(expSO3(phi + Vector3(d)) * expSO3(phi).conjugate());
    };
    test::expectJacobianNear("J_l at theta " + std::to_string(theta), leftJacobianSO3(phi), g,
                             Vector3::Zero(), kFdEps, kFdTol);
  }
}

// The series branches against closed forms in long double where those are still accurate, and
// continuity across the thresholds.
TEST(SO3, SeriesAgreeWithLongDoubleClosedFormsAndAreContinuous) {
  for (double theta : {0.3, 0.5, 0.7, 0.9, 0.999}) {
    const long double t = theta;
    const long double a = (1.0L - std::cos(t)) / (t * t), b = (t - std::sin(t)) / (t * t * t);
    const Vector3 phi(theta, 0, 0), y(0, 1, 0);
    // J_l y for phi along x: y + a (phi x y) + b phi x (phi x y).
    const Vector3 expected = y + static_cast<double>(a) * phi.cross(y) +
                             static_cast<double>(b) * phi.cross(phi.cross(y));
    EXPECT_LT((leftJacobianSO3(phi) * y - expected).norm(), 5e-16) << theta;
  }
  // Across a threshold the value may change only as much as the function itself does over the
  // step (|dJ/dtheta| < 1 here): a wrong series term would jump by far more.
  for (double threshold : {0.2, 1.0}) {
    const Vector3 axis = Vector3(1, -2, 0.5).normalized();
    const double step = threshold * 1e-12;
    const Matrix6 below =
        leftJacobianInverseSE3(twist(Vector3(0.3, 0.1, -0.2), axis * (threshold - step)));
    const Matrix6 above =
        leftJacobianInverseSE3(twist(Vector3(0.3, 0.1, -0.2), axis * (threshold + step)));
    EXPECT_LT((below - above).cwiseAbs().maxCoeff(), 2.0 * 2 * step) << threshold;
  }
}

TEST(SE3, ExpLogAdjointAndInverse) {
  std::mt19937_64 rng(4);
  for (int draw = 0; draw < 100; ++draw) {
    const SE3 T = randomPose(rng);
    EXPECT_LT((T.inverse() * T).translation().norm(), 1e-14);
    EXPECT_LT(logSO3((T.inverse() * T).rotation()).norm(), 1e-14);
    const SE3 back = expSE3(logSE3(T));
    EXPECT_LT((back.matrix() - T.matrix()).cwiseAbs().maxCoeff(), 1e-13);
    std::uniform_real_distribution<double> u(-1, 1);
    const Vector6 xi = (Vector6() << u(rng), u(rng), u(rng), u(rng), u(rng), u(rng)).finished();
    // T exp(xi) T^-1 = exp(Ad(T) xi).
    EXPECT_LT(((T * expSE3(xi) * T.inverse()).matrix() - expSE3(adjoint(T) * xi).matrix())
                  .cwiseAbs()
                  .maxCoeff(),
              1e-13);
    EXPECT_LT((adjoint(T.inverse()) - adjoint(T).inverse()).cwiseAbs().maxCoeff(), 1e-12);
  }
  // The matrix exponential of the hat agrees with expSE3.
  const Vector6 xi = (Vector6() << 0.4, -0.3, 1.1, 0.2, 0.7, -0.5).finished();
  Eigen::Matrix4d series = Eigen::Matrix4d::Identity(), term = Eigen::Matrix4d::Identity();
  for (int k = 1; k < 30; ++k) {
    term = term * hatSE3(xi) / k;
    series += term;
  }
  EXPECT_LT((series - expSE3(xi).matrix()).cwiseAbs().maxCoeff(), 1e-14);
  EXPECT_TRUE(veeSE3(hatSE3(xi)).isApprox(xi));
}

TEST(SE3, JacobiansAgainstCentralDifferencesAtHardAngles) {
  std::mt19937_64 rng(5);
  for (double theta : kAngles) {
    for (double rho_scale : {0.0, 1e-3, 1.0, 5.0}) {
      const Vector3 rho = randomAxis(rng) * rho_scale;
      const Vector6 xi = twist(rho, randomAxis(rng) * theta);
      const std::string at =
          "theta " + std::to_string(theta) + " |rho| " + std::to_string(rho_scale);
      const auto fr = [&](const Eigen::VectorXd& d) -> Eigen::VectorXd {
        return logSE3(expSE3(xi).inverse() * expSE3(xi + Vector6(d)));
      };
      test::expectJacobianNear("SE3 J_r, " + at, rightJacobianSE3(xi), fr, Vector6::Zero(), kFdEps,
                               kFdTol);
      const auto fl = [&](const Eigen::VectorXd& d) -> Eigen::VectorXd {
        return logSE3(expSE3(xi + Vector6(d)) * expSE3(xi).inverse());
      };
      test::expectJacobianNear("SE3 J_l, " + at, leftJacobianSE3(xi), fl, Vector6::Zero(), kFdEps,
                               kFdTol);
      if (theta < kPi - 1e-3) {
        // d log(exp(xi) exp(d)) / dd = J_r^-1(xi).
        const auto fi = [&](const Eigen::VectorXd& d) -> Eigen::VectorXd {
          return logSE3(expSE3(xi) * expSE3(Vector6(d)));
        };
        test::expectJacobianNear("SE3 J_r^-1, " + at, rightJacobianInverseSE3(xi), fi,
                                 Vector6::Zero(), kFdEps, kFdTol * 10);
      }
      EXPECT_LT((leftJacobianSE3(xi) * leftJacobianInverseSE3(xi) - Matrix6::Identity())
                    .cwiseAbs()
                    .maxCoeff(),
                1e-12)
          << at;
    }
  }
}

TEST(SE3, TinyAnglesKeepTheQBlockExact) {
  // For theta -> 0, Q = 1/2 rho^ + 1/6 (phi^ rho^ + rho^ phi^) + O(theta^2 |rho|).
  const Vector3 rho(0.7, -0.2, 0.4);
  for (double theta : {1e-12, 1e-8, 1e-5}) {
    const Vector3 phi = theta * Vector3(0.6, 0.0, -0.8);
    const Matrix3 expected = 0.5 * hat(rho) + (hat(phi) * hat(rho) + hat(rho) * hat(phi)) / 6.0;
    EXPECT_LT((jacobianQ(rho, phi) - expected).cwiseAbs().maxCoeff(), 1e-16 + theta * theta)
        << theta;
  }
}

}  // namespace
}  // namespace evkit
