// evkit synth: synthetic observation folders with ground truth (one scene, or a named suite).

#include <chrono>
#include <cstdio>
#include <iostream>
#include <tuple>

#include "common.h"
#include "evkit/base/error.h"
#include "evkit/events/calibration.h"
#include "evkit/synth/generator.h"

namespace evkit::cli {

using namespace evkit::synth;

int runSynth(const Args& args) {
  po::options_description opts("options");
  opts.add_options()(
      "preset", po::value<std::string>(),
      "planes, box, rgbd, ground, text, plain, or a natural scene (see --suite natural)")(
      "scene", po::value<std::string>(), "scene description file (YAML or JSON; see the README)")(
      "suite", po::value<std::string>(),
      "a named suite into OUT/<name>: standard (5 scenes x blur 15 and 40 px, noiseless events), "
      "noisy (the same with DAVIS-like event noise), hard (9 hard cases), natural (12 scenes from "
      "real photographs at several depths, 24 observations), all")(
      "out", po::value<std::string>()->required(), "output folder")(
      "size", po::value<std::string>()->default_value("346x260"), "image size WxH")(
      "blur-px", po::value<double>()->default_value(30),
      "blur length: the longest image path of a point (px)")(
      "exposure-us", po::value<int64_t>()->default_value(100000), "exposure time (µs)")(
      "start-us", po::value<int64_t>()->default_value(1'600'000'000'000'000),
      "exposure start (absolute µs)")("seed", po::value<uint64_t>()->default_value(1),
                                      "seed of the camera shake and textures")(
      "colour", po::bool_switch(), "colour scene and frames")(
      "contrast", po::value<std::string>()->default_value("0.2"),
      "event thresholds C or C_on,C_off (log units)")(
      "sigma", po::value<double>()->default_value(0.0), "threshold mismatch")(
      "shot-noise-hz", po::value<double>()->default_value(0.0),
      "shot noise events per pixel per second")("leak-hz", po::value<double>()->default_value(0.0),
                                                "leak events per pixel per second")(
      "gain", po::value<double>()->default_value(1.0),
      "radiance scale (< 1 dark, > 1 saturated highlights; frames clip at 1)")(
      "drop-events", po::bool_switch(), "write no events (an exposure whose events were lost)")(
      "rotation-share", po::value<double>()->default_value(0.7),
      "share of the shake that is rotation (the rest translation), 0..1")(
      "shake-knots", po::value<int>()->default_value(4),
      "knots of the shake's cubic B-spline over the exposure (4: one smooth segment; each more "
      "adds a turn)")(
      "share-of-image-motion", po::bool_switch(),
      "--rotation-share as a share of the image motion (the rotation alone moves the image by "
      "that share of --blur-px)")(
      "preroll-us", po::value<int64_t>()->default_value(0),
      "simulate events from this long before the exposure (real reference levels)")(
      "photos", po::value<std::string>(), "natural scenes: folder of the photographs")(
      "calib", po::value<std::string>(),
      "the camera to render with, lens distortion included (calib.txt: fx fy cx cy [k1 k2 p1 "
      "p2 [k3]]); else fx = 0.9 width at the centre")(
      "recording", po::bool_switch(),
      "a recording instead of one observation: OUT/recording.aedat4 and .h5 with several blurry "
      "frames and the continuous events between them, calib.txt, contrast.txt, gt/")(
      "frames", po::value<int>()->default_value(3), "with --recording: blurry frames")(
      "frame-interval-us", po::value<int64_t>()->default_value(150000),
      "with --recording: exposure start to exposure start (µs)")(
      "drop-frame-events", po::value<int>()->default_value(-1),
      "with --recording: this frame's exposure has no events")(
      "supersample", po::value<int>()->default_value(2), "rays per pixel per side (anti-aliasing)")(
      "image", po::value<std::string>(), "rgbd preset: colour image")(
      "depth", po::value<std::string>(), "rgbd preset: depth map (16-bit PNG)")(
      "depth-scale", po::value<double>()->default_value(0.001),
      "rgbd preset: depth file units to metres");
  po::positional_options_description pos;
  po::variables_map vm;
  if (!parseArgs(args,
                 "usage: evkit synth (--preset NAME | --scene FILE | --suite NAME) --out DIR "
                 "[--blur-px PX] [--size WxH]",
                 opts, pos, vm)) {
    return kExitOk;
  }
  const int sources = static_cast<int>(vm.count("preset") + vm.count("scene") + vm.count("suite"));
  if (sources != 1) throw UsageError("give exactly one of --preset, --scene, --suite");
  SynthOptions o;
  std::tie(o.width, o.height) = parseImageSize(vm["size"].as<std::string>(), "size", 8, 8192);
  o.shake.blur_px = vm["blur-px"].as<double>();
  o.exposure_us = vm["exposure-us"].as<int64_t>();
  o.t_begin_us = vm["start-us"].as<int64_t>();
  o.shake.seed = vm["seed"].as<uint64_t>();
  std::tie(o.simulator.contrast_pos, o.simulator.contrast_neg) =
      parseNumberPair(vm["contrast"].as<std::string>(), "contrast");
  o.simulator.sigma = vm["sigma"].as<double>();
  o.simulator.shot_noise_rate_hz = vm["shot-noise-hz"].as<double>();
  o.simulator.leak_rate_hz = vm["leak-hz"].as<double>();
  o.gain = vm["gain"].as<double>();
  o.drop_events = vm["drop-events"].as<bool>();
  o.simulator.seed = o.shake.seed;
  o.supersample = vm["supersample"].as<int>();
  o.shake.rotation_share = vm["rotation-share"].as<double>();
  o.preroll_us = vm["preroll-us"].as<int64_t>();
  o.shake.share_of_image_motion = vm["share-of-image-motion"].as<bool>();
  o.shake.knots = vm["shake-knots"].as<int>();
  if (o.shake.knots < 4 || o.shake.knots > 64) throw UsageError("--shake-knots must be in [4, 64]");
  if (!(o.shake.rotation_share >= 0 && o.shake.rotation_share <= 1) || o.preroll_us < 0)
    throw UsageError("--rotation-share must be in [0, 1] and --preroll-us not negative");
  if (!(o.shake.blur_px > 0) || o.exposure_us <= 0 || !(o.simulator.contrast_pos > 0) ||
      !(o.simulator.contrast_neg > 0) ||
      o.supersample < 1 || !(o.gain > 0)) {
    throw UsageError(
        "--blur-px, --exposure-us, --contrast, --gain and --supersample must be positive");
  }
  if (!(o.simulator.sigma >= 0) || !(o.simulator.shot_noise_rate_hz >= 0) ||
      !(o.simulator.leak_rate_hz >= 0)) {
    throw UsageError("--sigma, --shot-noise-hz and --leak-hz must not be negative");
  }
  if (vm.count("calib")) o.camera = readCalibration(vm["calib"].as<std::string>());
  SceneOptions so;
  so.colour = vm["colour"].as<bool>();
  so.seed = o.shake.seed;
  if (vm.count("image")) so.rgbd_image = vm["image"].as<std::string>();
  if (vm.count("depth")) so.rgbd_depth = vm["depth"].as<std::string>();
  so.rgbd_depth_scale = vm["depth-scale"].as<double>();
  if (vm.count("photos")) so.photo_dir = vm["photos"].as<std::string>();
  const std::string out = vm["out"].as<std::string>();
  if (vm["recording"].as<bool>()) {
    if (vm.count("suite")) throw UsageError("--recording takes --preset or --scene, not --suite");
    RecordingOptions r;
    r.frames = vm["frames"].as<int>();
    r.frame_interval_us = vm["frame-interval-us"].as<int64_t>();
    r.drop_frame_events = vm["drop-frame-events"].as<int>();
    if (r.frames < 1 || r.frame_interval_us <= o.exposure_us)
      throw UsageError("--frames must be at least 1 and --frame-interval-us above --exposure-us");
    const std::string name = vm.count("preset") ? vm["preset"].as<std::string>() : "scene";
    const Scene scene =
        vm.count("preset") ? makePreset(name, so) : loadScene(vm["scene"].as<std::string>(), so);
    const auto start = std::chrono::steady_clock::now();
    const RecordingReport rep = writeSyntheticRecording(scene, o, r, out);
    std::fprintf(stderr, "%s: %d frames, %s events, %lld renders, %.1f s -> %s\n", name.c_str(),
                 rep.frames, withThousands(rep.events).c_str(), static_cast<long long>(rep.renders),
                 std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count(),
                 out.c_str());
    return kExitOk;
  }

  const auto one = [](const Scene& scene, const SynthOptions& options, const std::string& dir,
                      const std::string& name) {
    const auto start = std::chrono::steady_clock::now();
    const SynthReport r = writeObservation(scene, options, dir);
    const double s =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    std::fprintf(stderr, "%-18s blur %5.1f px  %9s events  %5lld renders  %5.1f s  -> %s\n",
                 name.c_str(), r.blur_px, withThousands(r.events).c_str(),
                 static_cast<long long>(r.renders), s, dir.c_str());
  };
  if (vm.count("suite")) {
    std::vector<SuiteEntry> entries;
    try {
      entries = suiteEntries(vm["suite"].as<std::string>());
    } catch (const Error& e) {
      throw UsageError(std::string("--suite: ") + e.what());
    }
    for (const SuiteEntry& e : entries) {
      SynthOptions entry = o;
      e.apply(entry);
      one(makePreset(e.scene, so), entry, out + "/" + e.name, e.name);
    }
    return kExitOk;
  }
  if (vm.count("preset")) {
    Scene scene;
    try {
      scene = makePreset(vm["preset"].as<std::string>(), so);
    } catch (const Error& e) {
      if (std::string(e.what()).rfind("unknown preset", 0) == 0)
        throw UsageError(std::string("--preset: ") + e.what());
      throw;
    }
    one(scene, o, out, vm["preset"].as<std::string>());
  } else {
    one(loadScene(vm["scene"].as<std::string>(), so), o, out, "scene");
  }
  return kExitOk;
}

}  // namespace evkit::cli
