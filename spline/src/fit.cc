#include "evkit/spline/fit.h"

#include <Eigen/Cholesky>
#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <numbers>
#include <stdexcept>

namespace evkit {

namespace {

constexpr double kRadToDeg = 180.0 / std::numbers::pi;

// Time of knot k's influence peak: cubic knots sit one spacing before their segment; linear ones at
// it.
int64_t knotTime(TrajectoryKind kind, int k, int knots, int64_t t_begin, int64_t t_end) {
  const int segments = knots - (kind == TrajectoryKind::kLinear ? 1 : 3);
  const int offset = kind == TrajectoryKind::kLinear ? 0 : 1;
  return t_begin + (t_end - t_begin) * (k - offset) / segments;
}

double weightedCost(const Trajectory& traj, const std::vector<StampedPose>& poses, double w_rot) {
  double cost = 0;
  for (const StampedPose& sp : poses) {
    Vector6 r =
        logSE3(traj.poseAt(std::clamp(sp.t_us, traj.beginUs(), traj.endUs())).inverse() * sp.pose);
    r.tail<3>() *= w_rot;
    cost += r.squaredNorm();
  }
  return cost;
}

}  // namespace

Trajectory fitTrajectory(TrajectoryKind kind, int knots, int64_t t_begin_us, int64_t t_end_us,
                         const std::vector<StampedPose>& poses, const FitOptions& options,
                         FitReport* report) {
  if (poses.empty()) throw std::invalid_argument("fitTrajectory: no poses");
  std::vector<SE3> init(static_cast<size_t>(std::max(knots, Trajectory::minimumKnots(kind))));
  for (size_t k = 0; k < init.size(); ++k) {
    const int64_t tk =
        knotTime(kind, static_cast<int>(k), static_cast<int>(init.size()), t_begin_us, t_end_us);
    const auto nearest = std::min_element(
        poses.begin(), poses.end(), [&](const StampedPose& a, const StampedPose& b) {
          return std::llabs(a.t_us - tk) < std::llabs(b.t_us - tk);
        });
    init[k] = nearest->pose;
  }
  Trajectory traj(kind, t_begin_us, t_end_us, std::move(init));
  const Eigen::Index dim = 6 * static_cast<Eigen::Index>(traj.knots().size());
  const double w = options.rotation_weight;
  double cost = weightedCost(traj, poses, w);
  const double initial_cost = cost;
  double lambda = options.initial_damping;
  int it = 0;
  for (; it < options.max_iterations; ++it) {
    Eigen::MatrixXd H = Eigen::MatrixXd::Zero(dim, dim);
    Eigen::VectorXd g = Eigen::VectorXd::Zero(dim);
    for (const StampedPose& sp : poses) {
      KnotJacobians J;
      const SE3 T = traj.poseAt(std::clamp(sp.t_us, t_begin_us, t_end_us), &J);
      Vector6 r = logSE3(T.inverse() * sp.pose);
      // r(eps) = log(exp(-eps) exp(r)) ~ r - J_l^-1(r) eps.
      Matrix6 dr = -leftJacobianInverseSE3(r);
      r.tail<3>() *= w;
      dr.bottomRows<3>() *= w;
      for (int a = 0; a < J.count; ++a) {
        const Matrix6 Ja = dr * J.d_pose_d_knot[a];
        const Eigen::Index ia = 6 * (J.first_knot + a);
        g.segment<6>(ia) += Ja.transpose() * r;
        for (int b = 0; b < J.count; ++b) {
          H.block<6, 6>(ia, 6 * (J.first_knot + b)) += Ja.transpose() * (dr * J.d_pose_d_knot[b]);
        }
      }
    }
    bool improved = false;
    for (int attempt = 0; attempt < 10 && !improved; ++attempt) {
      Eigen::MatrixXd A = H;
      A.diagonal().array() += lambda * (1.0 + H.diagonal().array());
      const Eigen::VectorXd step = A.ldlt().solve(-g);
      Trajectory candidate = traj;
      candidate.applyKnotSteps(step);
      const double c = weightedCost(candidate, poses, w);
      if (std::isfinite(c) && c < cost) {
        improved = true;
        const double gain = (cost - c) / std::max(cost, 1e-300);
        traj = candidate;
        cost = c;
        lambda = std::max(lambda * 0.3, 1e-12);
        if (gain < 1e-12) it = options.max_iterations;  // converged
      } else {
        lambda *= 10.0;
      }
    }
    if (!improved) break;
  }
  if (report) {
    report->iterations = it;
    report->initial_rms = std::sqrt(initial_cost / static_cast<double>(poses.size()));
    report->final_rms = std::sqrt(cost / static_cast<double>(poses.size()));
  }
  return traj;
}

KnotChoice knotsByLeaveOneOut(TrajectoryKind kind, int min_knots, int max_knots, int64_t t_begin_us,
                              int64_t t_end_us, const std::vector<StampedPose>& poses,
                              const HeldOutError& error, const FitOptions& options,
                              double rms_tolerance) {
  KnotChoice out;
  min_knots = std::max(min_knots, Trajectory::minimumKnots(kind));
  out.knots = min_knots;
  // Each count must still be determined with one pose left out: as many poses as knots.
  max_knots = std::min(max_knots, static_cast<int>(poses.size()) - 1);
  if (poses.size() < 3 || max_knots <= min_knots) return out;
  // Per count, the mean of the folds' squared errors and its standard error.
  std::vector<double> means, standard_errors;
  for (int knots = min_knots; knots <= max_knots; ++knots) {
    std::vector<double> folds;
    for (size_t left = 1; left + 1 < poses.size(); ++left) {
      std::vector<StampedPose> rest = poses;
      rest.erase(rest.begin() + static_cast<std::ptrdiff_t>(left));
      const Trajectory fit = fitTrajectory(kind, knots, t_begin_us, t_end_us, rest, options);
      const SE3 predicted = fit.poseAt(std::clamp(poses[left].t_us, t_begin_us, t_end_us));
      folds.push_back(error ? error(predicted, poses[left].pose)
                            : weightedCost(fit, {poses[left]}, options.rotation_weight));
    }
    const double n = static_cast<double>(folds.size());
    double mean = 0, spread = 0;
    for (const double e : folds) mean += e / n;
    for (const double e : folds) spread += (e - mean) * (e - mean) / (n - 1);
    means.push_back(mean);
    standard_errors.push_back(std::sqrt(spread / n));
    out.held_out_rms.push_back(std::sqrt(mean));
  }
  // The one-standard-error rule (Hastie, Tibshirani, Friedman, "The Elements of Statistical
  // Learning", 2nd ed., 2009, section 7.10): the fewest knots whose mean error is within one
  // standard error of the least, or with an RMS within rms_tolerance of the least's.
  const size_t least =
      static_cast<size_t>(std::min_element(means.begin(), means.end()) - means.begin());
  const double tolerated = std::pow(std::sqrt(means[least]) + rms_tolerance, 2);
  for (size_t i = 0; i < means.size(); ++i) {
    if (means[i] <= std::max(means[least] + standard_errors[least], tolerated)) {
      out.knots = min_knots + static_cast<int>(i);
      break;
    }
  }
  return out;
}

Similarity alignPositions(const std::vector<Vector3>& est, const std::vector<Vector3>& truth,
                          Alignment alignment) {
  Similarity sim;
  if (alignment == Alignment::kNone || est.empty()) return sim;
  const double n = static_cast<double>(est.size());
  Vector3 mu_e = Vector3::Zero(), mu_g = Vector3::Zero();
  for (size_t i = 0; i < est.size(); ++i) {
    mu_e += est[i];
    mu_g += truth[i];
  }
  mu_e /= n;
  mu_g /= n;
  Matrix3 sigma = Matrix3::Zero();
  double var_e = 0;
  for (size_t i = 0; i < est.size(); ++i) {
    sigma += (truth[i] - mu_g) * (est[i] - mu_e).transpose();
    var_e += (est[i] - mu_e).squaredNorm();
  }
  sigma /= n;
  var_e /= n;
  Matrix3 R = Matrix3::Identity();
  double s = 1.0;
  Eigen::JacobiSVD<Matrix3> svd(sigma, Eigen::ComputeFullU | Eigen::ComputeFullV);
  const Vector3 d = svd.singularValues();
  // A rotation is determined only if the positions span at least a plane.
  if (est.size() >= 3 && d(1) > 1e-12 * std::max(d(0), 1e-300)) {
    Matrix3 S = Matrix3::Identity();
    if (svd.matrixU().determinant() * svd.matrixV().determinant() < 0) S(2, 2) = -1;
    R = svd.matrixU() * S * svd.matrixV().transpose();
    if (alignment == Alignment::kSim3 && var_e > 0) s = (d.asDiagonal() * S).trace() / var_e;
  }
  sim.scale = s;
  sim.transform = SE3(R, mu_g - s * R * mu_e);
  return sim;
}

TrajectoryErrors compareTrajectories(const std::vector<SE3>& estimate,
                                     const std::vector<SE3>& truth, Alignment alignment) {
  if (estimate.size() != truth.size() || estimate.empty()) {
    throw std::invalid_argument("compareTrajectories: " + std::to_string(estimate.size()) +
                                " estimated poses against " + std::to_string(truth.size()) +
                                " true ones");
  }
  std::vector<Vector3> pe, pg;
  for (size_t i = 0; i < estimate.size(); ++i) {
    pe.push_back(estimate[i].translation());
    pg.push_back(truth[i].translation());
  }
  const Similarity sim = alignPositions(pe, pg, alignment);
  std::vector<SE3> aligned;
  for (const SE3& T : estimate) {
    aligned.emplace_back(
        sim.transform.rotation() * T.rotation(),
        sim.scale * (sim.transform.rotation() * T.translation()) + sim.transform.translation());
  }
  TrajectoryErrors e;
  e.count = static_cast<int>(estimate.size());
  e.scale = sim.scale;
  double ate = 0, rot = 0, rpe_t = 0, rpe_r = 0;
  for (size_t i = 0; i < aligned.size(); ++i) {
    ate += (aligned[i].translation() - truth[i].translation()).squaredNorm();
    const double angle = logSO3(truth[i].rotation().conjugate() * aligned[i].rotation()).norm();
    rot += angle * angle;
    if (i + 1 < aligned.size()) {
      const SE3 rel =
          (truth[i].inverse() * truth[i + 1]).inverse() * (aligned[i].inverse() * aligned[i + 1]);
      rpe_t += rel.translation().squaredNorm();
      const double a = logSO3(rel.rotation()).norm();
      rpe_r += a * a;
    }
  }
  const double n = static_cast<double>(aligned.size());
  e.ate_rmse = std::sqrt(ate / n);
  e.rotation_rmse_deg = std::sqrt(rot / n) * kRadToDeg;
  if (aligned.size() > 1) {
    e.rpe_translation_rmse = std::sqrt(rpe_t / (n - 1));
    e.rpe_rotation_rmse_deg = std::sqrt(rpe_r / (n - 1)) * kRadToDeg;
  }
  return e;
}

}  // namespace evkit
