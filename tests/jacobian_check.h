// expectJacobianNear: an analytic Jacobian against central differences, printing both on failure.
#pragma once

#include <gtest/gtest.h>

#include <Eigen/Core>
#include <functional>
#include <string>

namespace evkit::test {

// Central differences of f at x0 with step eps: column k = (f(x0 + eps e_k) - f(x0 - eps e_k)) /
// 2eps.
inline Eigen::MatrixXd centralDifferences(
    const std::function<Eigen::VectorXd(const Eigen::VectorXd&)>& f, const Eigen::VectorXd& x0,
    double eps) {
  const Eigen::VectorXd y0 = f(x0);
  Eigen::MatrixXd J(y0.size(), x0.size());
  for (Eigen::Index k = 0; k < x0.size(); ++k) {
    Eigen::VectorXd xp = x0, xm = x0;
    xp(k) += eps;
    xm(k) -= eps;
    J.col(k) = (f(xp) - f(xm)) / (2.0 * eps);
  }
  return J;
}

// Passes when |analytic - numeric| <= tol * max(1, |numeric|) entry-wise (max norm).
inline void expectJacobianNear(const std::string& name, const Eigen::MatrixXd& analytic,
                               const std::function<Eigen::VectorXd(const Eigen::VectorXd&)>& f,
                               const Eigen::VectorXd& x0, double eps, double tol) {
  const Eigen::MatrixXd numeric = centralDifferences(f, x0, eps);
  ASSERT_EQ(analytic.rows(), numeric.rows()) << name;
  ASSERT_EQ(analytic.cols(), numeric.cols()) << name;
  const double scale = std::max(1.0, numeric.cwiseAbs().maxCoeff());
  const double err = (analytic - numeric).cwiseAbs().maxCoeff();
  EXPECT_LE(err, tol * scale) << name << ": max |analytic - numeric| = " << err << "\nanalytic:\n"
                              << analytic << "\nnumeric:\n"
                              << numeric;
}

}  // namespace evkit::test
