#include "evkit/synth/generator.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>
#include <utility>

#include "evkit/base/error.h"
#include "evkit/events/atomic_file.h"
#include "evkit/events/image_io.h"
#include "evkit/events/io.h"
#include "evkit/events/npy.h"
#include "evkit/spline/tum.h"

namespace evkit::synth {

namespace fs = std::filesystem;

namespace {

// The scene rendered along a trajectory: the simulator's programmatic source.
class SceneSource final : public RenderSource {
 public:
  SceneSource(const Scene& scene, const Calibration& camera, int w, int h, const Trajectory& traj,
              int supersample, double gain)
      : scene_(scene), camera_(camera), w_(w), h_(h), traj_(traj), gain_(gain) {
    options_.supersample = supersample;
    // Through a distorting lens each sample's direction is an iteration: found once.
    if (!camera.distortion.empty()) {
      directions_ = sampleDirections(camera, w, h, supersample);
      options_.directions = &directions_;
    }
    // Before the trajectory's start (a pre-roll) the camera moves on at its speed there.
    const int64_t t0 = traj.beginUs(), dt = std::max<int64_t>(1, (traj.endUs() - t0) / 100);
    start_ = traj.poseAt(t0);
    velocity_per_us_ = logSE3(start_.inverse() * traj.poseAt(t0 + dt)) / static_cast<double>(dt);
  }
  SceneSource(const SceneSource&) = delete;  // options_ points into directions_
  SceneSource& operator=(const SceneSource&) = delete;
  SensorSize sensor() const override { return {w_, h_}; }
  SE3 pose(int64_t t_us) const {
    if (t_us >= traj_.beginUs()) return traj_.poseAt(t_us);
    return start_ * expSE3(velocity_per_us_ * static_cast<double>(t_us - traj_.beginUs()));
  }
  cv::Mat render(int64_t t_us) override {
    ++renders_;
    cv::Mat image = synth::render(scene_, camera_, w_, h_, pose(t_us), options_);
    if (gain_ != 1.0) image *= gain_;
    return image;
  }
  int64_t renders() const { return renders_; }
  // The ground truth at t: rendered as the events see it, clipped as a sensor's frame is not.
  cv::Mat sharp(int64_t t_us) const {
    cv::Mat image = synth::render(scene_, camera_, w_, h_, pose(t_us), options_);
    if (gain_ != 1.0) image *= gain_;
    return image;
  }

 private:
  const Scene& scene_;
  Calibration camera_;
  int w_, h_;
  const Trajectory& traj_;
  double gain_;
  RenderOptions options_;
  std::vector<Vector3> directions_;
  int64_t renders_ = 0;
  SE3 start_;
  Vector6 velocity_per_us_;
};

// Never rejecting, a fixed step: the image moves by at most max_motion_px between two renders
// when the camera's path over `duration_us` moves a point by `blur_px`; and a render at each of
// the ground truth's instants `sharp_times`, so that the events agree with it there.
AdaptiveOptions uniformSampling(int64_t duration_us, double blur_px, double max_motion_px,
                                std::vector<int64_t> sharp_times) {
  AdaptiveOptions uniform;
  uniform.sample_at = std::move(sharp_times);
  uniform.lambda = 1e30;
  uniform.min_step_us = uniform.max_step_us =
      std::clamp<int64_t>(static_cast<int64_t>(static_cast<double>(duration_us) * max_motion_px /
                                               std::max(blur_px, 1e-9)),
                          1, std::max<int64_t>(1, duration_us / 50));
  return uniform;
}

Trajectory scaled(const std::vector<Vector6>& xi, double s, int64_t t0, int64_t t1) {
  std::vector<SE3> knots;
  for (const Vector6& x : xi) knots.push_back(expSE3(s * x));
  Trajectory traj(TrajectoryKind::kCubicSE3, t0, t1, knots);
  // Re-centre so that the camera sits at the origin at mid-exposure: a left motion of all knots.
  const SE3 mid_inv = traj.evaluate(0.5).inverse();
  for (SE3& k : traj.knots()) k = mid_inv * k;
  return traj;
}

}  // namespace

double blurLengthPx(const Trajectory& trajectory, const Scene& scene, const Calibration& camera,
                    int width, int height) {
  const SE3 T_mid = trajectory.evaluate(0.5);
  cv::Mat depth;
  RenderOptions one;
  one.supersample = 1;
  render(scene, camera, width, height, T_mid, one, &depth);
  double longest = 0;
  constexpr int kSteps = 40;
  for (int gy = 0; gy < 6; ++gy) {
    for (int gx = 0; gx < 8; ++gx) {
      const int x = (gx + 1) * width / 9, y = (gy + 1) * height / 7;
      const float z = depth.at<float>(y, x);
      if (z <= 0) continue;
      const Vector3 X = T_mid * (z * cameraDirection(camera, x, y));
      double length = 0;
      Eigen::Vector2d prev;
      for (int k = 0; k <= kSteps; ++k) {
        const Vector3 p = trajectory.evaluate(static_cast<double>(k) / kSteps).inverse() * X;
        const std::array<double, 2> q = pixelOfNormalised(camera, p.x() / p.z(), p.y() / p.z());
        const Eigen::Vector2d uv(q[0], q[1]);
        if (k > 0) length += (uv - prev).norm();
        prev = uv;
      }
      longest = std::max(longest, length);
    }
  }
  return longest;
}

Trajectory makeShake(const Scene& scene, const Calibration& camera, int width, int height,
                     int64_t t_begin, int64_t t_end, const ShakeOptions& options) {
  std::mt19937_64 rng(options.seed * 0x9e3779b97f4a7c15ULL + 5);
  std::normal_distribution<double> n;
  // Knot tangents: rotation of ~0.01 rad, translation of ~1 cm, in random directions; the mix of
  // rotation and translation follows rotation_share, then one scale sets the blur length.
  std::vector<Vector6> xi;
  for (int k = 0; k < std::max(4, options.knots); ++k) {
    const Vector3 rho =
        Vector3(n(rng), n(rng), 0.3 * n(rng)) * 0.01 * (1.0 - options.rotation_share);
    const Vector3 phi = Vector3(n(rng), n(rng), 0.3 * n(rng)) * 0.01 * options.rotation_share;
    xi.push_back(twist(rho, phi));
  }
  // One scale s_r for the rotations and s_t for the translations, found on the blur length (it
  // grows monotonically with each): without share_of_image_motion one common scale, by fixed-point
  // steps (the blur is about proportional to it); with it the rotation alone to its share the same
  // way, then the translation for the rest by bisection.
  const auto with_scales = [&](double s_r, double s_t) {
    std::vector<Vector6> out = xi;
    for (Vector6& v : out) v.head<3>() *= s_t, v.tail<3>() *= s_r;
    return out;
  };
  const auto blur_of = [&](double s_r, double s_t) {
    const double blur = blurLengthPx(scaled(with_scales(s_r, s_t), 1.0, t_begin, t_end), scene,
                                     camera, width, height);
    if (blur <= 0) throw Error("the scene is empty: no blur can be measured");
    return blur;
  };
  const auto solve = [](double target, const auto& blur, double s) {
    for (int it = 0; it < 8; ++it) {
      const double ratio = target / blur(s);
      s *= ratio;
      if (std::abs(ratio - 1.0) < 1e-3) break;
    }
    return s;
  };
  double s_r = 1, s_t = 1;
  if (!options.share_of_image_motion) {
    s_r = s_t = solve(
        options.blur_px, [&](double s) { return blur_of(s, s); }, 1.0);
  } else {
    s_r = options.rotation_share > 0 ? solve(
                                           options.rotation_share * options.blur_px,
                                           [&](double s) { return blur_of(s, 0.0); }, 1.0)
                                     : 0.0;
    // The translation's part: from none (the rotation's blur) up, by bisection (the blur grows
    // with s_t, but not in proportion).
    s_t = 0;
    if (options.rotation_share < 1) {
      double lo = 0, hi = 1;
      while (blur_of(s_r, hi) < options.blur_px && hi < 1e6) lo = hi, hi *= 2;
      for (int it = 0; it < 40 && hi - lo > 1e-4 * hi; ++it) {
        const double mid = 0.5 * (lo + hi);
        (blur_of(s_r, mid) < options.blur_px ? lo : hi) = mid;
      }
      s_t = 0.5 * (lo + hi);
    }
  }
  return scaled(with_scales(s_r, s_t), 1.0, t_begin, t_end);
}

Calibration cameraOf(const SynthOptions& o) {
  return o.camera ? *o.camera : defaultCamera(o.width, o.height);
}

SynthReport writeObservation(const Scene& scene, const SynthOptions& o, const std::string& dir) {
  const Calibration camera = cameraOf(o);
  const int64_t t0 = o.t_begin_us, t1 = o.t_begin_us + o.exposure_us;
  const Trajectory traj = makeShake(scene, camera, o.width, o.height, t0, t1, o.shake);
  SynthReport report;
  report.blur_px = blurLengthPx(traj, scene, camera, o.width, o.height);

  AtomicPath out(dir);
  const std::string tmp = out.temporaryPath();
  fs::create_directories(tmp + "/gt");

  // Events and the blurry frame: adaptive sampling of the rendered scene over the exposure.
  SceneSource source(scene, camera, o.width, o.height, traj, o.supersample, o.gain);
  DriverOptions driver;
  driver.simulator = o.simulator;
  driver.exposures = {{t0, t1}};
  auto writer = openWriter(tmp + "/events.h5", Format::kHdf5, SensorSize{o.width, o.height});
  // The ground truth's instants: evenly over the exposure (start, ..., end) and mid-exposure.
  std::vector<int64_t> sharp_times;
  const int sharp = std::max(2, o.sharp_frames);
  for (int k = 0; k < sharp; ++k) sharp_times.push_back(t0 + (t1 - t0) * k / (sharp - 1));
  const int64_t mid = t0 + (t1 - t0) / 2;
  if (sharp % 2 == 0) sharp_times.insert(sharp_times.begin() + sharp / 2, mid);
  cv::Mat blurry;
  int64_t written = 0;
  const SimulatorStats stats =
      simulateAdaptive(source, t0 - o.preroll_us, t1, driver,
                       uniformSampling(t1 - t0, report.blur_px, o.max_motion_px, sharp_times),
                       [&](const EventStore& ev, const std::vector<Frame>& done) {
                         // The pre-roll's events only set each pixel's reference level.
                         const EventSpan kept = ev.sliceTime(t0, t1 + 1);
                         if (!o.drop_events) writer->write(kept);
                         written += static_cast<int64_t>(kept.size());
                         if (!done.empty()) blurry = done.front().image;
                       });
  writer->close();
  report.events = o.drop_events ? 0 : written;
  report.renders = source.renders();
  report.max_fraction_over_c = stats.max_fraction_over_c;
  writeImageFile(tmp + "/blurry.png", blurry, 16);

  std::ofstream(tmp + "/exposure.txt") << t0 << ' ' << t1 << '\n';
  std::ofstream(tmp + "/contrast.txt")
      << o.simulator.contrast_pos << ' ' << o.simulator.contrast_neg << '\n';
  writeCalibration(tmp + "/calib.txt", camera);

  // Ground truth: sharp frames, poses, knots, depth at mid-exposure.
  for (int64_t t : sharp_times)
    writeImageFile(tmp + "/gt/" + std::to_string(t) + ".png", source.sharp(t), 16);
  std::vector<int64_t> times;
  for (int k = 0; k < std::max(2, o.poses); ++k)
    times.push_back(t0 + (t1 - t0) * k / (std::max(2, o.poses) - 1));
  writeTum(tmp + "/gt/poses.txt", sampleTrajectory(traj, times));
  std::vector<StampedPose> knots;
  for (size_t k = 0; k < traj.knots().size(); ++k)
    knots.push_back({static_cast<int64_t>(k), traj.knots()[k]});
  writeTum(tmp + "/gt/knots.txt", knots);
  cv::Mat depth;
  RenderOptions single;
  single.supersample = 1;
  render(scene, camera, o.width, o.height, traj.poseAt(mid), single, &depth);
  writeNpy(tmp + "/gt/depth.npy", depth.ptr<float>(),
           {static_cast<size_t>(o.height), static_cast<size_t>(o.width)});
  std::ostringstream info;
  info << "blur_px " << report.blur_px << "\nevents " << report.events << "\nrenders "
       << report.renders << "\nmax_fraction_over_c " << report.max_fraction_over_c << "\ngain "
       << o.gain << "\ncontrast " << o.simulator.contrast_pos << "\ncontrast_off " << o.simulator.contrast_neg
       << "\nsigma " << o.simulator.sigma
       << "\nshot_noise_hz " << o.simulator.shot_noise_rate_hz << "\nleak_hz "
       << o.simulator.leak_rate_hz << "\ndrop_events " << o.drop_events << "\nseed " << o.shake.seed
       << "\nknots_kind cubic\n"
       << "knot_times " << t0 << ' ' << t1 << "\n";
  std::ofstream(tmp + "/gt/info.txt") << info.str();
  out.commit();
  return report;
}

}  // namespace evkit::synth

namespace evkit::synth {

RecordingReport writeSyntheticRecording(const Scene& scene, const SynthOptions& o,
                                        const RecordingOptions& r, const std::string& dir) {
  if (r.frames < 1 || r.frame_interval_us <= o.exposure_us)
    throw Error("a recording needs at least one frame, and frames further apart than the exposure");
  const Calibration camera = cameraOf(o);
  const int64_t t0 = o.t_begin_us;
  const int64_t t_end = t0 + (r.frames - 1) * r.frame_interval_us + o.exposure_us;
  // One shake through the whole recording, as smooth as a single observation's: one spline
  // segment (knot spacing) per exposure time, as makeShake's 4 knots give one observation; and
  // about blur_px of image motion per exposure (the path grows with the duration).
  ShakeOptions shake = o.shake;
  shake.knots = 3 + static_cast<int>((t_end - t0 + o.exposure_us - 1) / o.exposure_us);
  shake.blur_px = o.shake.blur_px * static_cast<double>(t_end - t0) / o.exposure_us;
  const Trajectory traj = makeShake(scene, camera, o.width, o.height, t0, t_end, shake);
  const double path_px = blurLengthPx(traj, scene, camera, o.width, o.height);

  AtomicPath out(dir);
  const std::string tmp = out.temporaryPath();
  fs::create_directories(tmp + "/gt");
  const SensorSize sensor{o.width, o.height};
  auto aedat4 = openWriter(tmp + "/recording.aedat4", Format::kAedat4, sensor);
  auto hdf5 = openWriter(tmp + "/recording.h5", Format::kHdf5, sensor);
  DriverOptions driver;
  driver.simulator = o.simulator;
  for (int k = 0; k < r.frames; ++k) {
    const int64_t start = t0 + k * r.frame_interval_us;
    driver.exposures.push_back({start, start + o.exposure_us});
  }
  const auto dropped = [&](int64_t t) {
    if (r.drop_frame_events < 0 || r.drop_frame_events >= r.frames) return false;
    const auto& e = driver.exposures[static_cast<size_t>(r.drop_frame_events)];
    return t >= e.start_us && t <= e.end_us;
  };
  SceneSource source(scene, camera, o.width, o.height, traj, o.supersample, o.gain);
  RecordingReport report;
  report.frames = r.frames;
  // The ground truth's instants: each exposure's start, middle and end.
  std::vector<int64_t> sharp_times;
  for (const auto& e : driver.exposures)
    for (int64_t t : {e.start_us, e.start_us + (e.end_us - e.start_us) / 2, e.end_us})
      sharp_times.push_back(t);
  simulateAdaptive(source, t0 - o.preroll_us, t_end, driver,
                   uniformSampling(t_end - t0, path_px, o.max_motion_px, sharp_times),
                   [&](const EventStore& ev, const std::vector<Frame>& done) {
                     EventStore kept(sensor);
                     const EventSpan recorded = ev.sliceTime(t0, t_end + 1);
                     for (size_t i = 0; i < recorded.size(); ++i) {
                       if (!dropped(recorded.t[i]))
                         kept.push_back(recorded.t[i], recorded.x[i], recorded.y[i], recorded.p[i]);
                     }
                     aedat4->write(kept.view());
                     hdf5->write(kept.view());
                     report.events += static_cast<int64_t>(kept.size());
                     for (Frame f : done) {
                       f.bit_depth = 16;
                       aedat4->writeFrame(f);
                       hdf5->writeFrame(f);
                     }
                   });
  aedat4->close();
  hdf5->close();
  report.renders = source.renders();

  std::ofstream(tmp + "/contrast.txt")
      << o.simulator.contrast_pos << ' ' << o.simulator.contrast_neg << '\n';
  writeCalibration(tmp + "/calib.txt", camera);
  for (int64_t t : sharp_times)
    writeImageFile(tmp + "/gt/" + std::to_string(t) + ".png", source.sharp(t), 16);
  std::vector<int64_t> times;
  for (const auto& e : driver.exposures)
    for (int k = 0; k <= 100; ++k) times.push_back(e.start_us + (e.end_us - e.start_us) * k / 100);
  writeTum(tmp + "/gt/poses.txt", sampleTrajectory(traj, times));
  out.commit();
  return report;
}

}  // namespace evkit::synth
