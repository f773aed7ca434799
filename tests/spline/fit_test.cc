#include "evkit/spline/fit.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "evkit/base/error.h"
#include "evkit/spline/tum.h"
#include "test_util.h"

namespace evkit {
namespace {

constexpr int64_t kT0 = 1605537493718345;
constexpr int64_t kT1 = kT0 + 200000;

std::vector<SE3> wobblyKnots(int n) {
  std::vector<SE3> knots;
  for (int k = 0; k < n; ++k) {
    knots.emplace_back(expSO3(Vector3(0.05 * std::sin(k), 0.08 * k, -0.03 * k * k)),
                       Vector3(0.1 * k, 0.02 * k * k, std::cos(k)));
  }
  return knots;
}

std::vector<StampedPose> sample(const Trajectory& traj, int count) {
  std::vector<int64_t> times;
  for (int i = 0; i < count; ++i) times.push_back(kT0 + (kT1 - kT0) * i / (count - 1));
  return sampleTrajectory(traj, times);
}

TEST(Fit, RecoversASplineFromItsOwnSamples) {
  for (TrajectoryKind kind :
       {TrajectoryKind::kCubicSE3, TrajectoryKind::kCubicSplit, TrajectoryKind::kLinear}) {
    const Trajectory truth(kind, kT0, kT1, wobblyKnots(6));
    FitReport report;
    const Trajectory fit = fitTrajectory(kind, 6, kT0, kT1, sample(truth, 61), {}, &report);
    EXPECT_LT(report.final_rms, 1e-9) << trajectoryKindName(kind);
    EXPECT_LT(report.final_rms, report.initial_rms);
    for (double s : {0.0, 0.33, 0.5, 0.9, 1.0}) {
      EXPECT_LT((fit.evaluate(s).matrix() - truth.evaluate(s).matrix()).cwiseAbs().maxCoeff(), 1e-8)
          << trajectoryKindName(kind);
    }
  }
}

TEST(Fit, ApproximatesAMotionOfAnotherFamily) {
  // A circular arc with a constant rotation rate: a 4-knot cubic follows it closely.
  std::vector<StampedPose> poses;
  for (int i = 0; i <= 40; ++i) {
    const double a = 0.5 * i / 40.0;
    poses.push_back({kT0 + (kT1 - kT0) * i / 40,
                     SE3(expSO3(Vector3(0, a, 0)), Vector3(std::sin(a), 0, 1 - std::cos(a)))});
  }
  FitReport report;
  const Trajectory fit = fitTrajectory(TrajectoryKind::kCubicSE3, 4, kT0, kT1, poses, {}, &report);
  EXPECT_LT(report.final_rms, 1e-3);
  std::vector<SE3> est, truth;
  for (const auto& p : poses) {
    est.push_back(fit.poseAt(p.t_us));
    truth.push_back(p.pose);
  }
  EXPECT_LT(compareTrajectories(est, truth, Alignment::kNone).ate_rmse, 1e-3);
}

// n knots that rise slowly, alternating by `turn` about the rise: each pair of knots turns the
// motion once (turn 0: one smooth drift).
std::vector<SE3> turningKnots(int n, double turn) {
  std::vector<SE3> out;
  for (int k = 0; k < n; ++k) {
    const double a = 0.01 * k + turn * ((k % 2) ? 1 : -1);
    out.emplace_back(expSO3(Vector3(0.3 * a, a, 0.1 * a)), Vector3(0.5 * a, -0.2 * a, 0));
  }
  return out;
}

// Nine noisy poses over the interval, as the pixel grid registers them: from one smooth cubic
// segment (4 knots) the count chosen is 4 on every draw; from a motion that turns twice (6 knots)
// it is 6, where 4 knots predict the poses left out several times worse. A given error measure
// (here the rotation's angle alone) is the one used.
TEST(Fit, LeaveOneOutTakesTheKnotsAMotionThatTurnsNeeds) {
  std::mt19937 rng(3);
  std::normal_distribution<double> noise(0.0, 3e-4);
  const auto noisy = [&](const Trajectory& truth) {
    std::vector<StampedPose> poses = sample(truth, 9);
    for (StampedPose& p : poses) {
      p.pose = p.pose * SE3(expSO3(Vector3(noise(rng), noise(rng), noise(rng))),
                            Vector3(noise(rng), noise(rng), noise(rng)));
    }
    return poses;
  };
  const TrajectoryKind cubic = TrajectoryKind::kCubicSE3;
  for (int draw = 0; draw < 5; ++draw) {
    const KnotChoice smooth = knotsByLeaveOneOut(
        cubic, 4, 7, kT0, kT1, noisy(Trajectory(cubic, kT0, kT1, turningKnots(4, 0))));
    EXPECT_EQ(smooth.knots, 4) << "draw " << draw;
    ASSERT_EQ(smooth.held_out_rms.size(), 4u);
    const KnotChoice turning = knotsByLeaveOneOut(
        cubic, 4, 7, kT0, kT1, noisy(Trajectory(cubic, kT0, kT1, turningKnots(6, 0.02))));
    EXPECT_EQ(turning.knots, 6) << "draw " << draw;
    EXPECT_GT(turning.held_out_rms[0], 3 * turning.held_out_rms[2]) << "draw " << draw;
  }
  // The rotation's angle as the error: the same choice, and the figures are angles.
  const auto angle = [](const SE3& a, const SE3& b) {
    return logSO3(a.rotation().conjugate() * b.rotation()).squaredNorm();
  };
  const KnotChoice by_angle = knotsByLeaveOneOut(
      cubic, 4, 7, kT0, kT1, noisy(Trajectory(cubic, kT0, kT1, turningKnots(6, 0.02))), angle);
  EXPECT_EQ(by_angle.knots, 6);
  EXPECT_LT(by_angle.held_out_rms[2], 2e-3);
  // Fewer than three poses, or no room above the fewest knots: the fewest.
  EXPECT_EQ(knotsByLeaveOneOut(cubic, 4, 7, kT0, kT1,
                               sample(Trajectory(cubic, kT0, kT1, turningKnots(6, 0.02)), 5))
                .knots,
            4);
}

// Seventeen poses whose errors are correlated between neighbours (a random walk outwards from the
// middle, as chained flows give): the folds' neighbours carry the left-out pose's error, the
// standard error understates the spread and the one-standard-error rule takes more knots than a
// smooth segment needs. A tolerance on the held-out RMS takes the fewest within it: 4 there, and
// still 8 for a motion that turns four times, whose counts differ by far more.
TEST(Fit, ATolerancePutsBackTheFewestKnotsWhereTheFoldsAreCorrelated) {
  std::mt19937 rng(5);
  std::normal_distribution<double> noise(0.0, 4e-4);
  const auto walked = [&](const Trajectory& truth) {
    std::vector<StampedPose> poses = sample(truth, 17);
    const size_t mid = poses.size() / 2;
    for (const int step : {-1, 1}) {
      SE3 drift;
      for (size_t k = mid + step; k < poses.size(); k += step) {
        drift = drift * SE3(expSO3(Vector3(noise(rng), noise(rng), noise(rng))),
                            Vector3(noise(rng), noise(rng), noise(rng)));
        poses[k].pose = poses[k].pose * drift;
        if (k == 0) break;
      }
    }
    return poses;
  };
  const TrajectoryKind cubic = TrajectoryKind::kCubicSE3;
  int more_without = 0;
  for (int draw = 0; draw < 5; ++draw) {
    const std::vector<StampedPose> smooth = walked(Trajectory(cubic, kT0, kT1, turningKnots(4, 0)));
    more_without += knotsByLeaveOneOut(cubic, 4, 15, kT0, kT1, smooth).knots > 4 ? 1 : 0;
    EXPECT_EQ(knotsByLeaveOneOut(cubic, 4, 15, kT0, kT1, smooth, {}, {}, 2e-3).knots, 4)
        << "draw " << draw;
    const std::vector<StampedPose> turning =
        walked(Trajectory(cubic, kT0, kT1, turningKnots(8, 0.02)));
    EXPECT_EQ(knotsByLeaveOneOut(cubic, 4, 15, kT0, kT1, turning, {}, {}, 2e-3).knots, 8)
        << "draw " << draw;
  }
  EXPECT_GE(more_without, 2) << "the correlated folds without the tolerance";
}

TEST(Metrics, AlignmentRemovesSimilaritiesAndReportsWhatRemains) {
  const Trajectory truth_traj(TrajectoryKind::kCubicSE3, kT0, kT1, wobblyKnots(6));
  std::vector<SE3> truth, est;
  for (const auto& p : sample(truth_traj, 30)) truth.push_back(p.pose);
  const SE3 G(expSO3(Vector3(0.3, -1.0, 0.5)), Vector3(4, -2, 1));
  const double scale = 2.5;
  // est = G^-1 applied with scale 1/scale: aligning must undo it.
  for (const SE3& T : truth) {
    const SE3 moved = G.inverse() * T;
    est.emplace_back(moved.rotation(), moved.translation() / scale);
  }
  const TrajectoryErrors sim = compareTrajectories(est, truth, Alignment::kSim3);
  EXPECT_NEAR(sim.scale, scale, 1e-9);
  EXPECT_LT(sim.ate_rmse, 1e-9);
  EXPECT_LT(sim.rotation_rmse_deg, 1e-7);
  EXPECT_LT(sim.rpe_translation_rmse, 1e-9);
  const TrajectoryErrors se3 = compareTrajectories(est, truth, Alignment::kSE3);
  EXPECT_GT(se3.ate_rmse, 0.1);  // scale is not removed
  EXPECT_EQ(se3.scale, 1.0);
  // A known offset: every position 3 cm off along x, no alignment.
  std::vector<SE3> off;
  for (const SE3& T : truth) off.emplace_back(T.rotation(), T.translation() + Vector3(0.03, 0, 0));
  EXPECT_NEAR(compareTrajectories(off, truth, Alignment::kNone).ate_rmse, 0.03, 1e-12);
  EXPECT_NEAR(compareTrajectories(off, truth, Alignment::kSE3).ate_rmse, 0.0, 1e-9);
  // A rotation error of 2 degrees on every pose, no alignment.
  std::vector<SE3> rot;
  for (const SE3& T : truth)
    rot.emplace_back(T.rotation() * expSO3(Vector3(0, 0, 2.0 * M_PI / 180)), T.translation());
  EXPECT_NEAR(compareTrajectories(rot, truth, Alignment::kNone).rotation_rmse_deg, 2.0, 1e-9);
  EXPECT_THROW(compareTrajectories(rot, {}, Alignment::kNone), std::invalid_argument);
}

TEST(Tum, RoundTripIsExactInTimeAndToTheLastDigitInPose) {
  test::ScratchDir dir;
  const Trajectory traj(TrajectoryKind::kCubicSE3, kT0, kT1, wobblyKnots(5));
  const std::vector<StampedPose> poses = sample(traj, 17);
  writeTum(dir / "traj.txt", poses);
  const std::vector<StampedPose> back = readTum(dir / "traj.txt");
  ASSERT_EQ(back.size(), poses.size());
  for (size_t i = 0; i < poses.size(); ++i) {
    EXPECT_EQ(back[i].t_us, poses[i].t_us);
    EXPECT_EQ(back[i].pose.translation(), poses[i].pose.translation());
    EXPECT_LT((back[i].pose.rotation().coeffs() - poses[i].pose.rotation().coeffs()).norm(), 3e-16);
  }
  EXPECT_NE(test::readText(dir / "traj.txt").find("1605537493.718345 "), std::string::npos);
}

TEST(Tum, BadLinesNameTheFileAndLine) {
  test::ScratchDir dir;
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"1.0 0 0 0 0 0 0\n", "line 1: expected 8 fields"},
      {"# c\n1.0 0 0 0 0 0 0 1\nx 0 0 0 0 0 0 1\n", "line 3: cannot read the time 'x'"},
      {"1.0 0 0 0 0 0 0 2\n", "line 1: quaternion (qx qy qz qw) has norm 2"},
      {"1.0 0 nan 0 0 0 0 1\n", "line 1: field 3 'nan' is not a finite number"},
      {"2.0 0 0 0 0 0 0 1\n1.0 0 0 0 0 0 0 1\n", "line 2: time goes back"},
  };
  for (const auto& [text, expected] : cases) {
    test::writeText(dir / "bad.txt", text);
    try {
      readTum(dir / "bad.txt");
      FAIL() << expected;
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(expected), std::string::npos) << e.what();
    }
  }
}

}  // namespace
}  // namespace evkit
