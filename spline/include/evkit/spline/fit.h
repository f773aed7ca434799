// Fitting a trajectory to timed poses, and comparing trajectories.
#pragma once

#include <cstdint>
#include <functional>
#include <vector>

#include "evkit/spline/lie.h"
#include "evkit/spline/trajectory.h"

namespace evkit {

struct StampedPose {
  int64_t t_us = 0;
  SE3 pose;  // T_world_cam
};

struct FitOptions {
  int max_iterations = 50;
  // Weight of rotation residuals (rad) against translation residuals (scene units).
  double rotation_weight = 1.0;
  // Levenberg-Marquardt damping at the start; it adapts.
  double initial_damping = 1e-6;
};

struct FitReport {
  int iterations = 0;
  double initial_rms = 0;  // sqrt(mean |weighted log residual|^2)
  double final_rms = 0;
};

// Least-squares fit of a trajectory with `knots` knots over [t_begin, t_end] to the poses:
// minimises sum_i |W log(T(t_i)^-1 T_i)|^2 by Levenberg-Marquardt with the analytic knot Jacobians.
// Knots start from the poses nearest to their times. Poses outside the interval are clamped to it.
Trajectory fitTrajectory(TrajectoryKind kind, int knots, int64_t t_begin_us, int64_t t_end_us,
                         const std::vector<StampedPose>& poses, const FitOptions& options = {},
                         FitReport* report = nullptr);

// The knot count in [min_knots, max_knots] whose fit predicts the poses where they are not fitted:
// leave-one-out cross-validation over the interior poses (each left out in turn, the trajectory
// fitted to the rest and compared with it there), the fewest knots whose mean error is within one
// standard error (over the poses left out) of the least: the one-standard-error rule. A motion
// that turns within the interval needs more knots than one cubic segment; where it does not, more
// knots fit the poses' noise. `error`: the squared error of a prediction against the pose left out
// (none: the weighted log residual of the fit). Counts above poses - 1 are not tried.
// `rms_tolerance` (the error's square-root units, 0: none): a count whose held-out RMS is within
// this of the least's qualifies too, for differences too small to matter to the caller.
using HeldOutError = std::function<double(const SE3& predicted, const SE3& pose)>;
struct KnotChoice {
  int knots = 0;
  std::vector<double> held_out_rms;  // per count from min_knots: sqrt of the mean error
};
KnotChoice knotsByLeaveOneOut(TrajectoryKind kind, int min_knots, int max_knots, int64_t t_begin_us,
                              int64_t t_end_us, const std::vector<StampedPose>& poses,
                              const HeldOutError& error = {}, const FitOptions& options = {},
                              double rms_tolerance = 0);

enum class Alignment { kNone, kSE3, kSim3 };

struct TrajectoryErrors {
  int count = 0;
  double scale = 1.0;               // of the Sim(3) alignment (1 otherwise)
  double ate_rmse = 0;              // absolute trajectory error of positions after alignment
  double rotation_rmse_deg = 0;     // angle of R_truth^T R_aligned, RMS
  double rpe_translation_rmse = 0;  // relative pose error between consecutive poses
  double rpe_rotation_rmse_deg = 0;
};

// Compares an estimate with the truth, pose by pose (the same times, in order). Alignment by
// Umeyama's method (IEEE TPAMI 1991) on the positions: SE(3) (rotation + translation) or Sim(3)
// (with scale). With fewer than 3 poses, or positions that do not span a plane, only the mean
// translation is aligned. Throws std::invalid_argument when the sizes differ or are empty.
TrajectoryErrors compareTrajectories(const std::vector<SE3>& estimate,
                                     const std::vector<SE3>& truth, Alignment alignment);

// The aligning similarity: truth ~ s R estimate + t (s = 1 unless Sim(3)).
struct Similarity {
  double scale = 1.0;
  SE3 transform;
};
Similarity alignPositions(const std::vector<Vector3>& estimate, const std::vector<Vector3>& truth,
                          Alignment alignment);

}  // namespace evkit
