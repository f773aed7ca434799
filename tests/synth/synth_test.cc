#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <opencv2/imgproc.hpp>

#include "evkit/base/error.h"
#include "evkit/deblur/observation.h"
#include "evkit/events/image_io.h"
#include "evkit/events/io.h"
#include "evkit/spline/tum.h"
#include "evkit/synth/generator.h"
#include "test_util.h"

namespace evkit::synth {
namespace {

using test::ScratchDir;

// Each pixel's |log start + C (its events up to `until`) - log at|, with the frames' log mapping:
// at most C where the events agree with the frames (noiseless events, C = 0.2).
std::vector<double> levelResiduals(const Recording& rec, const cv::Mat& start, const cv::Mat& at,
                                   int64_t until) {
  cv::Mat sum = cv::Mat::zeros(start.size(), CV_32F);
  for (size_t e = 0; e < rec.events.size() && rec.events.t[e] <= until; ++e)
    sum.at<float>(rec.events.y[e], rec.events.x[e]) += 0.2f * rec.events.p[e];
  const LogMapping log;
  std::vector<double> r;
  for (int y = 0; y < start.rows; ++y) {
    for (int x = 0; x < start.cols; ++x)
      r.push_back(std::abs(log.toLog(start.at<float>(y, x)) + sum.at<float>(y, x) -
                           log.toLog(at.at<float>(y, x))));
  }
  return r;
}

// How many residuals exceed `limit`.
long countOver(const std::vector<double>& r, double limit) {
  return std::count_if(r.begin(), r.end(), [&](double v) { return v > limit; });
}

SynthOptions small(double blur_px) {
  SynthOptions o;
  o.width = 64;
  o.height = 48;
  o.exposure_us = 40000;
  o.shake.blur_px = blur_px;
  o.poses = 161;
  return o;
}

TEST(Synth, IdentityPoseFrontoParallelPlaneReproducesTheTexture) {
  const int w = 40, h = 30;
  const Calibration cam = defaultCamera(w, h);
  auto tex = std::make_shared<Texture>();
  tex->image = cv::Mat(h, w, CV_32F);
  cv::randu(tex->image, 0.0, 1.0);
  // A plane at depth z that exactly covers the field of view: texel (x, y) under pixel (x, y).
  const double z = 2.5;
  Scene scene;
  scene.rectangles.emplace_back(
      Vector3(z * ((w - 1) / 2.0 - cam.cx) / cam.fx, z * ((h - 1) / 2.0 - cam.cy) / cam.fy, z),
      Vector3::UnitX(), Vector3::UnitY(), z * w / cam.fx, z * h / cam.fy, tex);
  RenderOptions one;
  one.supersample = 1;
  cv::Mat depth;
  const cv::Mat img = render(scene, cam, w, h, SE3(), one, &depth);
  EXPECT_LT(cv::norm(img - tex->image, cv::NORM_INF), 1e-5);
  EXPECT_LT(cv::norm(depth - z, cv::NORM_INF), 1e-9 + 1e-6);
}

// Through a wide lens with barrel distortion (`evkit synth --calib`): every pixel's direction
// projects back onto it (the undistortion's fixed point inverts the distortion), the corners see
// further out than a pinhole would, and the directions found once render the image that the
// per-sample ones do.
TEST(Synth, RendersThroughALensWithDistortion) {
  const int w = 64, h = 48;
  const Calibration lens{0.72 * w, 0.72 * w, (w - 1) / 2.0, (h - 1) / 2.0, {-0.3, 0.08, 0, 0}};
  double worst = 0;
  for (int y = 0; y < h; y += 7) {
    for (int x = 0; x < w; x += 7) {
      const Vector3 d = cameraDirection(lens, x, y);
      const std::array<double, 2> q = pixelOfNormalised(lens, d.x(), d.y());
      worst = std::max(worst, std::hypot(q[0] - x, q[1] - y));
    }
  }
  EXPECT_LT(worst, 1e-4);  // pixels (measured 5e-6 at the corners, the iteration's slowest)
  const Vector3 corner = cameraDirection(lens, 0, 0);
  EXPECT_LT(corner.x(), -(lens.cx / lens.fx) * 1.05);  // barrel: the corner sees further out

  const Scene scene = makePreset("planes", {});
  RenderOptions plain;
  RenderOptions tabled;
  const std::vector<Vector3> directions = sampleDirections(lens, w, h, tabled.supersample);
  tabled.directions = &directions;
  const SE3 pose(expSO3(Vector3(0.01, -0.02, 0.005)), Vector3(0.02, 0, 0));
  const cv::Mat a = render(scene, lens, w, h, pose, plain);
  const cv::Mat b = render(scene, lens, w, h, pose, tabled);
  EXPECT_EQ(cv::norm(a - b, cv::NORM_INF), 0.0);
  EXPECT_GT(cv::norm(a - render(scene, defaultCamera(w, h), w, h, pose, plain), cv::NORM_INF),
            0.05);
}

TEST(Synth, ShakeHasTheRequestedBlurAndIsCentredAtMidExposure) {
  const Scene scene = makePreset("planes", {});
  const Calibration cam = defaultCamera(120, 90);
  for (double blur : {2.0, 15.0, 60.0}) {
    ShakeOptions s;
    s.blur_px = blur;
    const Trajectory traj = makeShake(scene, cam, 120, 90, 0, 100000, s);
    EXPECT_NEAR(blurLengthPx(traj, scene, cam, 120, 90), blur, 0.01 * blur);
    EXPECT_LT((traj.evaluate(0.5).matrix() - Eigen::Matrix4d::Identity()).cwiseAbs().maxCoeff(),
              1e-12);
  }
}

// A shake split by image motion: the rotation alone moves the image by its share of the blur, the
// translation adds the rest, so the near layer of a two-depth scene moves more than the far one.
TEST(Synth, ShakeSplitByImageMotion) {
  Scene scene;
  auto tex = std::make_shared<Texture>();
  tex->image = cv::Mat(8, 8, CV_32F, cv::Scalar(0.5));
  scene.rectangles.emplace_back(Vector3(0, 0, 6), Vector3::UnitX(), Vector3::UnitY(), 30, 30, tex);
  scene.rectangles.emplace_back(Vector3(0, 0, 1.2), Vector3::UnitX(), Vector3::UnitY(), 0.3, 0.3,
                                tex);
  const Calibration cam = defaultCamera(120, 90);
  ShakeOptions s;
  s.blur_px = 30;
  s.rotation_share = 0.7;
  s.share_of_image_motion = true;
  const Trajectory traj = makeShake(scene, cam, 120, 90, 0, 100000, s);
  EXPECT_NEAR(blurLengthPx(traj, scene, cam, 120, 90), 30, 0.3);
  Trajectory rotation_only = traj;
  for (SE3& k : rotation_only.knots()) k = SE3(k.rotation(), Vector3::Zero());
  EXPECT_NEAR(blurLengthPx(rotation_only, scene, cam, 120, 90), 21, 1.5);
}

// The observation folder: blurry frame = mean of dense sharp frames; events = the simulator's
// invariant between the ground-truth frames at the exposure's start and end; deterministic.
TEST(Synth, ObservationFolderIsConsistentWithItsGroundTruth) {
  ScratchDir dir;
  const Scene scene = makePreset("text", {});
  const SynthOptions o = small(8.0);
  const SynthReport report = writeObservation(scene, o, dir / "obs");
  EXPECT_NEAR(report.blur_px, 8.0, 0.1);
  for (const char* f : {"blurry.png", "exposure.txt", "events.h5", "calib.txt", "contrast.txt",
                        "gt/poses.txt", "gt/knots.txt", "gt/depth.npy", "gt/info.txt"}) {
    EXPECT_TRUE(test::fs::exists(dir / (std::string("obs/") + f))) << f;
  }
  const int64_t t0 = o.t_begin_us, t1 = t0 + o.exposure_us;
  EXPECT_EQ(test::readText(dir / "obs/exposure.txt"),
            std::to_string(t0) + " " + std::to_string(t1) + "\n");

  // Blurry frame against the trapezoidal mean of 161 renders at the true poses.
  const std::vector<StampedPose> poses = readTum(dir / "obs/gt/poses.txt");
  ASSERT_EQ(poses.size(), 161u);
  const Calibration cam = readCalibration(dir / "obs/calib.txt");
  cv::Mat mean = cv::Mat::zeros(o.height, o.width, CV_32F);
  for (size_t k = 0; k < poses.size(); ++k) {
    const double w = (k == 0 || k + 1 == poses.size()) ? 0.5 : 1.0;
    mean += w * render(scene, cam, o.width, o.height, poses[k].pose, RenderOptions{o.supersample});
  }
  mean /= static_cast<double>(poses.size() - 1);
  const Frame blurry = readImageFile(dir / "obs/blurry.png");
  EXPECT_EQ(blurry.bit_depth, 16);
  cv::Mat diff = cv::abs(blurry.image - mean);
  EXPECT_LT(cv::mean(diff)[0], 2e-3);
  EXPECT_LT(cv::norm(diff, cv::NORM_INF), 2e-2);

  // Events: |L(t0) + sum p C - L(t1)| <= C at every pixel (sigma = 0), with the frames' log.
  const Recording rec = readRecording(dir / "obs/events.h5");
  EXPECT_EQ(rec.events.size(), static_cast<size_t>(report.events));
  ASSERT_GT(rec.events.size(), 1000u);
  EXPECT_GE(rec.events.t.front(), t0);
  EXPECT_LE(rec.events.t.back(), t1);
  const cv::Mat start = readImageFile(dir / ("obs/gt/" + std::to_string(t0) + ".png")).image;
  const cv::Mat end = readImageFile(dir / ("obs/gt/" + std::to_string(t1) + ".png")).image;
  // 0.02: the 16-bit quantisation of the frames.
  EXPECT_EQ(countOver(levelResiduals(rec, start, end, t1), 0.2 + 0.02), 0);

  // Same seed, same bytes.
  writeObservation(scene, o, dir / "again");
  EXPECT_EQ(test::readText(dir / "obs/blurry.png"), test::readText(dir / "again/blurry.png"));
  const Recording again = readRecording(dir / "again/events.h5");
  EXPECT_TRUE(again.events.t == rec.events.t && again.events.x == rec.events.x &&
              again.events.p == rec.events.p);
}

// The events interpolate between renders; the ground truth is rendered at its own instants. Each
// instant is a sample, so the events' level there is the ground truth's to within a threshold
// (a render step between two samples straddling an instant put the events of an edge crossing it
// up to a step late: 0.4 log units at rgbd_blur15_noisy's bottom row at mid-exposure).
TEST(Synth, EventsAgreeWithTheGroundTruthAtEveryInstant) {
  ScratchDir dir;
  const Scene scene = makePreset("text", {});
  SynthOptions o = small(7.0);  // renders 571 us apart: not a divisor of the instants' spacing
  o.sharp_frames = 4;           // t0, a third, mid-exposure (added), two thirds, t1
  writeObservation(scene, o, dir / "obs");
  const Recording rec = readRecording(dir / "obs/events.h5");
  ASSERT_GT(rec.events.size(), 1000u);
  const int64_t t0 = o.t_begin_us, T = o.exposure_us;
  const cv::Mat start = readImageFile(dir / ("obs/gt/" + std::to_string(t0) + ".png")).image;
  for (const int64_t t : {t0 + T / 3, t0 + T / 2, t0 + 2 * T / 3, t0 + T}) {
    const std::string path = dir / ("obs/gt/" + std::to_string(t) + ".png");
    ASSERT_TRUE(test::fs::exists(path)) << path;
    const cv::Mat at = readImageFile(path).image;
    EXPECT_EQ(countOver(levelResiduals(rec, start, at, t), 0.2 + 0.02), 0)
        << "at t0 + " << t - t0 << " us";
  }
}

TEST(Synth, RgbdPresetAndSceneFiles) {
  ScratchDir dir;
  const Scene rgbd = makePreset("rgbd", {});
  ASSERT_TRUE(rgbd.height_field.has_value());
  const Calibration cam = defaultCamera(48, 36);
  cv::Mat depth;
  const cv::Mat img = render(rgbd, cam, 48, 36, SE3(), {}, &depth);
  EXPECT_TRUE(cv::checkRange(img));
  // At the identity pose the first hit lies on the height field: its depth at the same ray.
  const HeightField& hf = *rgbd.height_field;
  for (const auto& [x, y] : std::vector<std::pair<int, int>>{{24, 18}, {5, 30}, {40, 3}}) {
    // Pixel (x, y) looks along ((x - cx)/fx, (y - cy)/fy, 1): where that ray meets the source
    // image.
    const double u = hf.intrinsics.fx * (x - cam.cx) / cam.fx + hf.intrinsics.cx;
    const double v = hf.intrinsics.fy * (y - cam.cy) / cam.fy + hf.intrinsics.cy;
    cv::Mat patch;
    cv::getRectSubPix(hf.depth, cv::Size(1, 1),
                      cv::Point2f(static_cast<float>(u), static_cast<float>(v)), patch);
    EXPECT_NEAR(depth.at<float>(y, x), patch.at<float>(0, 0), 1e-3) << x << ", " << y;
  }

  test::writeText(dir / "scene.yaml",
                  "%YAML:1.0\nbackground: 0.2\nobjects:\n"
                  "  - { type: plane, center: [0, 0, 3], size: [6, 4], texture: { kind: checker, "
                  "scale: 0.25 } }\n"
                  "  - { type: box, center: [0, 0, 2], size: [0.4, 0.4, 0.4], rotation: [0, 0.3, "
                  "0], texture: { kind: stripes } }\n");
  const Scene scene = loadScene(dir / "scene.yaml", {});
  EXPECT_EQ(scene.rectangles.size(), 7u);
  EXPECT_DOUBLE_EQ(scene.background, 0.2);
  test::writeText(dir / "bad.yaml", "%YAML:1.0\nobjects:\n  - { type: cone, center: [0, 0, 3] }\n");
  try {
    loadScene(dir / "bad.yaml", {});
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("object 0: unknown type 'cone'"), std::string::npos)
        << e.what();
  }
  EXPECT_THROW(makePreset("nope", {}), Error);
  EXPECT_EQ(suiteEntries("standard").size(), 10u);
  EXPECT_EQ(suiteEntries("hard").size(), 9u);
  EXPECT_EQ(suiteEntries("all").size(), 29u + 2 * naturalSceneNames().size());
  const std::vector<SuiteEntry> noisy = suiteEntries("noisy");
  ASSERT_EQ(noisy.size(), 10u);
  EXPECT_EQ(noisy[0].name, "planes_blur15_noisy");
  SynthOptions o;
  noisy[0].apply(o);
  EXPECT_DOUBLE_EQ(o.simulator.sigma, 0.03);
  EXPECT_DOUBLE_EQ(o.simulator.shot_noise_rate_hz, 1.0);
  EXPECT_DOUBLE_EQ(o.simulator.leak_rate_hz, 0.1);
  EXPECT_DOUBLE_EQ(o.shake.blur_px, 15.0);
  EXPECT_THROW(suiteEntries("easy"), Error);
}

TEST(Synth, HardCasesSaturateDarkenAndDropEvents) {
  test::ScratchDir dir;
  const auto make = [&](const std::string& name) {
    for (const SuiteEntry& e : suiteEntries("hard")) {
      if (e.name != name) continue;
      SynthOptions o;
      o.width = 48;
      o.height = 32;
      o.exposure_us = 20000;
      e.apply(o);
      o.shake.blur_px = 6;  // small: few renders
      const SynthReport r = writeObservation(makePreset(e.scene, {}), o, dir / name);
      return std::make_pair(r, loadObservation(dir / name));
    }
    throw std::runtime_error("no entry " + name);
  };
  double lo, hi;
  // Saturated: the frames clip at 1 where the radiance (x3) exceeds it; the events do not.
  auto [sat, sat_obs] = make("hard_saturated");
  cv::minMaxLoc(sat_obs.blurry.image, &lo, &hi);
  EXPECT_EQ(hi, 1.0);
  EXPECT_GT(cv::countNonZero(sat_obs.blurry.image >= 1.0), 20);
  EXPECT_GT(sat.events, 0);
  // Dark: radiance x0.02.
  auto [dark, dark_obs] = make("hard_dark");
  cv::minMaxLoc(dark_obs.gt_frames.front().image, &lo, &hi);
  EXPECT_LT(hi, 0.03);
  EXPECT_GT(hi, 0.005);
  // No events: the folder loads with an empty event file and a blurred frame.
  auto [none, none_obs] = make("hard_noevents");
  EXPECT_EQ(none.events, 0);
  EXPECT_EQ(none_obs.events.size(), 0u);
  EXPECT_GT(none.blur_px, 5);
  // Noisy: the contrast file keeps the nominal C while the pixels' thresholds vary.
  auto [noisy, noisy_obs] = make("hard_noisy");
  ASSERT_TRUE(noisy_obs.contrast.has_value());
  EXPECT_DOUBLE_EQ(noisy_obs.contrast->on, 0.2);
  EXPECT_NE(test::readText(dir / "hard_noisy/gt/info.txt").find("shot_noise_hz 5"),
            std::string::npos);
}

// A plane with a matte lets what lies behind it through: front-to-back compositing, and the depth
// of the first surface at least half opaque.
TEST(Synth, MattesCompositeFrontToBack) {
  const int w = 24, h = 18;
  const Calibration cam = defaultCamera(w, h);
  const auto flat = [&](float value, float alpha) {
    auto tex = std::make_shared<Texture>();
    tex->image = cv::Mat(8, 8, CV_32F, cv::Scalar(value));
    if (alpha < 1) tex->alpha = cv::Mat(8, 8, CV_32F, cv::Scalar(alpha));
    return tex;
  };
  for (const float alpha : {0.25f, 0.75f}) {
    Scene scene;
    scene.rectangles.emplace_back(Vector3(0, 0, 4), Vector3::UnitX(), Vector3::UnitY(), 20, 20,
                                  flat(0.2f, 1));
    scene.rectangles.emplace_back(Vector3(0, 0, 2), Vector3::UnitX(), Vector3::UnitY(), 10, 10,
                                  flat(0.8f, alpha));
    cv::Mat depth;
    const cv::Mat img = render(scene, cam, w, h, SE3(), RenderOptions{1}, &depth);
    EXPECT_NEAR(img.at<float>(h / 2, w / 2), alpha * 0.8 + (1 - alpha) * 0.2, 1e-6) << alpha;
    EXPECT_NEAR(depth.at<float>(h / 2, w / 2), alpha < 0.5 ? 4.0 : 2.0, 1e-6) << alpha;
  }
}

// With a pre-roll the events of the exposure start from each pixel's last event before it, not
// from the exposure's first frame: the accumulated events still match the log change to within
// two thresholds (one at each end), and some pixels need more than one.
TEST(Synth, PrerollLeavesRealReferenceLevels) {
  ScratchDir dir;
  const Scene scene = makePreset("text", {});
  SynthOptions o = small(8.0);
  const auto residuals = [&](const std::string& name) {
    writeObservation(scene, o, dir / name);
    const Recording rec = readRecording(dir / (name + "/events.h5"));
    const int64_t t0 = o.t_begin_us, t1 = t0 + o.exposure_us;
    EXPECT_GE(rec.events.t.front(), t0);
    EXPECT_LE(rec.events.t.back(), t1);
    const cv::Mat start = readImageFile(dir / (name + "/gt/" + std::to_string(t0) + ".png")).image;
    const cv::Mat end = readImageFile(dir / (name + "/gt/" + std::to_string(t1) + ".png")).image;
    return levelResiduals(rec, start, end, t1);
  };
  const std::vector<double> reset = residuals("reset");
  o.preroll_us = 15000;
  const std::vector<double> real = residuals("preroll");
  EXPECT_EQ(countOver(reset, 0.2 + 0.02), 0);
  EXPECT_EQ(countOver(real, 0.4 + 0.02), 0);
  EXPECT_GT(countOver(real, 0.2 + 0.02), 20);
}

TEST(Synth, NaturalSuiteHasEachSceneTwiceAtEveryBlur) {
  const std::vector<SuiteEntry> entries = suiteEntries("natural");
  ASSERT_EQ(entries.size(), 2 * naturalSceneNames().size());
  std::map<double, int> blurs;
  std::map<std::string, int> scenes;
  for (const SuiteEntry& e : entries) {
    ++blurs[e.blur_px];
    ++scenes[e.scene];
    EXPECT_EQ(e.group, "natural");
    EXPECT_EQ(e.preroll_us, 30000);
    EXPECT_EQ(e.rotation_share, 0.7);
    EXPECT_TRUE(e.share_of_image_motion);
    EXPECT_EQ(e.sigma > 0, e.name.ends_with("_noisy")) << e.name;
  }
  EXPECT_EQ(blurs, (std::map<double, int>{{15, 8}, {30, 8}, {60, 8}}));
  for (const auto& [scene, n] : scenes) EXPECT_EQ(n, 2) << scene;
}

// The photographs come from Debian's python3-skimage (scripts/install-deps.sh installs it).
TEST(Synth, NaturalScenesFromPhotographs) {
  if (!test::fs::exists(test::fs::path(defaultPhotoDir()) / "astronaut.png"))
    GTEST_SKIP() << "no photographs in " << defaultPhotoDir()
                 << ": install python3-skimage (scripts/install-deps.sh) or set EVKIT_PHOTOS";
  const int w = 64, h = 48;
  const Calibration cam = defaultCamera(w, h);
  for (const std::string& name : naturalSceneNames()) {
    const Scene scene = makePreset(name, {});
    cv::Mat depth;
    const cv::Mat img = render(scene, cam, w, h, SE3(), RenderOptions{1}, &depth);
    double lo, hi;
    cv::minMaxLoc(img.reshape(1), &lo, &hi);
    EXPECT_GE(lo, 0.03 - 1e-6) << name;  // no pure black, nothing above the photographs' 0.88
    EXPECT_LE(hi, 0.88 + 1e-6) << name;
    EXPECT_GT(hi - lo, 0.2) << name;  // a photograph, not a flat wall
    cv::minMaxLoc(depth, &lo, &hi);
    EXPECT_GT(lo, 0.5) << name;  // every pixel sees a surface
    EXPECT_LT(hi, 12) << name;
    if (name == "coffee_astronaut") {
      EXPECT_EQ(img.channels(), 3);
      EXPECT_NEAR(lo, 1.2, 1e-6);  // the cut-out before the backdrop
      EXPECT_NEAR(hi, 4.5, 1e-6);
    }
    if (name == "coffee_plane") {
      EXPECT_NEAR(hi - lo, 0, 1e-9);
    }
    if (name == "motorcycle") {  // the Middlebury depth: about 0.7 m to 5 m
      EXPECT_GT(lo, 0.6);
      EXPECT_GT(hi - lo, 1.0);
    }
  }
  EXPECT_THROW(makePreset("no_such_scene", {}), Error);
  SceneOptions elsewhere;
  elsewhere.photo_dir = "/nonexistent";
  EXPECT_THROW(makeNaturalScene("coffee_plane", elsewhere), Error);
  // A damaged depth archive: one clear error naming it, for each way it can be damaged.
  ScratchDir dir;
  test::fs::copy_file(test::fs::path(defaultPhotoDir()) / "motorcycle_left.png",
                      dir.path() / "motorcycle_left.png");
  const std::string archive =
      test::readText((test::fs::path(defaultPhotoDir()) / "motorcycle_disp.npz").string());
  elsewhere.photo_dir = dir.path().string();
  for (const std::string& bad :
       {std::string(), archive.substr(0, 20), archive.substr(0, 2000), "PK\x03\x04" + archive,
        archive.substr(0, 30) + std::string(5000, '\x55')}) {
    test::writeText(dir / "motorcycle_disp.npz", bad);
    try {
      makeNaturalScene("motorcycle", elsewhere);
      ADD_FAILURE() << "a damaged archive of " << bad.size() << " bytes was read";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find("motorcycle_disp.npz"), std::string::npos) << e.what();
    }
  }
}

}  // namespace
}  // namespace evkit::synth
