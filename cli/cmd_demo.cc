// evkit demo: the built-in default job of the README's first command. It generates the default
// scene (a blurry frame, its events with a DAVIS-like sensor's noise, and the ground truth),
// deblurs it with blurry, EDI and BeNeRF, prints the comparison table, and writes each method's
// frames, latent video and trajectory, a side-by-side image, results.csv/md and the
// speed-against-error plot. `--formats` runs the event-file tour instead (random recording -> HDF5
// -> text -> info -> PNG).

#include <filesystem>
#include <iostream>
#include <opencv2/imgcodecs.hpp>
#include <tuple>

#include "common.h"
#include "deblur_runner.h"
#include "evkit/base/error.h"
#include "evkit/deblur/observation.h"
#include "evkit/events/accumulate.h"
#include "evkit/events/random_events.h"
#include "evkit/harness/speed_error.h"
#include "evkit/synth/generator.h"

namespace evkit::cli {

namespace fs = std::filesystem;

namespace {

int formatsTour(const fs::path& dir, size_t count, uint64_t seed) {
  fs::create_directories(dir);
  RandomEventOptions random;
  random.count = count;
  random.seed = seed;
  Recording rec;
  rec.events = randomEvents(random);
  const std::string txt = (dir / "random.txt").string();
  const std::string h5 = (dir / "random.h5").string();
  const std::string back = (dir / "roundtrip.txt").string();
  writeRecording(txt, rec);
  std::cout << "1. wrote " << withThousands(static_cast<int64_t>(rec.events.size()))
            << " random events to " << txt << "\n";

  convertFile(txt, std::nullopt, h5, std::nullopt, {}, std::nullopt, std::nullopt);
  convertFile(h5, std::nullopt, back, std::nullopt, {}, std::nullopt, std::nullopt);
  const Recording again = readRecording(back);
  const bool exact = again.events.t == rec.events.t && again.events.x == rec.events.x &&
                     again.events.y == rec.events.y && again.events.p == rec.events.p;
  std::cout << "2. converted text -> " << h5 << " -> " << back << ": round trip "
            << (exact ? "exact" : "DIFFERS") << "\n";
  if (!exact) throw Error("round trip through HDF5 changed the events");

  std::cout << "3. evkit info " << h5 << "\n\n";
  printInfo(h5, std::nullopt);

  const int64_t t0 = rec.events.t.front();
  const EventSpan window = rec.events.sliceTime(t0, t0 + 50000);
  const std::string png = (dir / "accumulated.png").string();
  if (!cv::imwrite(png, renderPolarity(accumulateSigned(window))))
    throwInFile(png, "cannot write image");
  std::cout << "\n4. accumulated the first 50 ms ("
            << withThousands(static_cast<int64_t>(window.size())) << " events) into " << png
            << " (ON red, OFF blue)\n";
  return kExitOk;
}

}  // namespace

int runDemo(const Args& args) {
  po::options_description opts("options");
  opts.add_options()("out", po::value<std::string>()->default_value("evkit-demo"), "output folder")(
      "preset", po::value<std::string>()->default_value("planes"),
      "scene: planes, box, rgbd, ground, text or plain")(
      "size", po::value<std::string>()->default_value("346x260"),
      "image size WxH (a DAVIS346 by default)")("blur-px", po::value<double>()->default_value(40),
                                                "blur length of the camera shake (px)")(
      "clean-events", po::bool_switch(),
      "noiseless events with exactly known thresholds (default: a DAVIS-like sensor's noise)")(
      "budget", po::value<std::string>()->default_value("fast"),
      "BeNeRF budget: fast, balanced, quality or seconds")(
      "threads", po::value<int>(), "BeNeRF threads (default: the cores other programs leave idle)")(
      "seed", po::value<uint64_t>()->default_value(1),
      "seed of the scene, the shake and the training")(
      "formats", po::bool_switch(),
      "instead: the event-file tour (random recording -> HDF5 -> text -> info -> PNG)")(
      "events", po::value<size_t>()->default_value(500000),
      "with --formats: number of random events");
  po::positional_options_description pos;
  po::variables_map vm;
  if (!parseArgs(args, "usage: evkit demo [--out DIR] [--preset NAME] [--budget fast] [--formats]",
                 opts, pos, vm))
    return kExitOk;
  const fs::path dir = vm["out"].as<std::string>();
  const uint64_t seed = vm["seed"].as<uint64_t>();
  if (vm["formats"].as<bool>()) return formatsTour(dir, vm["events"].as<size_t>(), seed);

  synth::SynthOptions o;
  std::tie(o.width, o.height) = parseImageSize(vm["size"].as<std::string>(), "size", 16, 4096);
  o.shake.blur_px = vm["blur-px"].as<double>();
  if (!(o.shake.blur_px > 0)) throw UsageError("--blur-px must be positive");
  o.shake.seed = o.simulator.seed = seed;
  if (!vm["clean-events"].as<bool>()) {
    // A DAVIS-like pixel array: thresholds vary by 0.03 around C = 0.2 (contrast.txt keeps the
    // nominal value), background activity of 1 Hz shot noise and 0.1 Hz leak per pixel.
    o.simulator.sigma = 0.03;
    o.simulator.shot_noise_rate_hz = 1.0;
    o.simulator.leak_rate_hz = 0.1;
  }
  synth::Scene scene;
  synth::SceneOptions so;
  so.seed = seed;
  try {
    scene = synth::makePreset(vm["preset"].as<std::string>(), so);
  } catch (const Error& e) {
    throw UsageError(std::string("--preset: ") + e.what());
  }
  MethodSettings benerf = {{"budget", vm["budget"].as<std::string>()},
                           {"seed", std::to_string(seed)}};
  if (vm.count("threads")) benerf["threads"] = std::to_string(vm["threads"].as<int>());
  const std::vector<BenchRun> runs = {
      {"blurry", "-", makeMethod("blurry", {})},
      {"edi", "-", makeMethod("edi", {})},
      {"benerf", vm["budget"].as<std::string>(), makeMethod("benerf", benerf)}};

  const std::string obs_dir = (dir / "observation").string();
  std::cout << "1. generating the " << vm["preset"].as<std::string>() << " scene at " << o.width
            << "x" << o.height << ", blur " << o.shake.blur_px << " px, "
            << (vm["clean-events"].as<bool>() ? "noiseless events" : "a DAVIS-like sensor's noise")
            << " -> " << obs_dir << std::endl;
  fs::create_directories(dir);
  const synth::SynthReport made = synth::writeObservation(scene, o, obs_dir);
  const Observation obs = loadObservation(obs_dir);
  std::cout << "   " << withThousands(made.events) << " events in the "
            << (obs.blurry.exposure_end_us - obs.blurry.exposure_start_us) / 1000
            << " ms exposure\n2. deblurring with blurry, edi and benerf (budget "
            << vm["budget"].as<std::string>() << ")" << std::endl;

  std::vector<BenchRow> rows;
  std::vector<MethodReport> reports;
  for (const BenchRun& run : runs) {
    MethodReport report;
    TrainingProgress progress(run.method + " training");
    BenchRow row = evkit::runBench(obs, "demo", vm["preset"].as<std::string>(), "", run,
                                   (dir / run.method).string(), &report, progress.callback());
    progress.finish();
    if (!row.ok())
      std::cerr << "evkit demo: " << run.method << " " << row.status
                << " (the other results are kept)\n";
    rows.push_back(row);
    if (row.ok()) reports.push_back(std::move(report));
  }
  std::printf("\n%-8s %10s %8s %9s %14s %11s\n", "method", "PSNR (dB)", "SSIM", "BRISQUE",
              "rot. err (°)", "wall (s)");
  for (const BenchRow& r : rows) {
    if (!r.ok()) {
      std::printf("%-8s failed\n", r.method.c_str());
      continue;
    }
    std::printf("%-8s %10s %8s %9s %14s %11s\n", r.method.c_str(), fixedOrDash(r.psnr, 2).c_str(),
                fixedOrDash(r.ssim, 4).c_str(), fixedOrDash(r.brisque, 1).c_str(),
                fixedOrDash(r.rotation_error_deg, 2).c_str(), fixedOrDash(r.wall_s, 3).c_str());
  }
  writeSideBySide((dir / "side_by_side.png").string(), obs, reports);
  writeBenchResults(
      dir.string(), rows,
      "evkit demo: " + vm["preset"].as<std::string>() + " at " + vm["size"].as<std::string>());
  std::cout << "\n3. wrote " << (dir / "side_by_side.png").string()
            << " (blurry | edi | benerf | ground truth), " << (dir / "speed_vs_error.png").string()
            << ", results.md, and per method <method>/: frames (<t_us>.png), latent.avi, "
               "summary.json (benerf also trajectory.txt, disparity.png)\n";
  return std::all_of(rows.begin(), rows.end(), [](const BenchRow& r) { return r.ok(); })
             ? kExitOk
             : kExitInputError;
}

}  // namespace evkit::cli
