// evkit simulate INPUT --out FILE: events (and blurry frames) from a rendered image sequence or a
// video, with ESIM's model (see evkit/events/simulator.h).

#include <omp.h>

#include <iostream>

#include "common.h"
#include "evkit/base/error.h"
#include "evkit/events/frame_source.h"

namespace evkit::cli {

int runSimulate(const Args& args) {
  po::options_description opts("options");
  opts.add_options()("input", po::value<std::string>()->required(),
                     "image folder (timestamps.txt: 't_us path'; or RPG images.txt), a timestamps "
                     "file, or a video")(
      "out", po::value<std::string>()->required(),
      "output: .h5 / .aedat4 (events + blurry frames) or .txt (+ frames folder)")(
      "contrast", po::value<std::string>()->default_value("0.2"),
      "thresholds C or C_on,C_off (log units)")(
      "sigma", po::value<double>()->default_value(0.0),
      "per-pixel threshold mismatch (std. dev., log units)")(
      "refractory", po::value<std::string>()->default_value("0us"),
      "refractory period (e.g. 100us)")("shot-noise", po::value<double>()->default_value(0.0),
                                        "shot noise rate per pixel (Hz)")(
      "leak", po::value<double>()->default_value(0.0), "leak event rate per pixel (Hz)")(
      "exposure", po::value<std::vector<std::string>>()->composing(),
      "blurry frame over START:END (µs, repeatable)")(
      "exposure-every", po::value<int>()->default_value(0), "a blurry frame every N input frames")(
      "duty", po::value<double>()->default_value(0.5),
      "exposure length as a fraction of --exposure-every frames")(
      "fps", po::value<double>()->default_value(0.0), "video frame rate (default: from the file)")(
      "start-time", po::value<std::string>()->default_value("0"),
      "time of the first video frame (µs)")("srgb", po::bool_switch(),
                                            "input is sRGB-encoded: decode to linear first")(
      "bayer", po::bool_switch(), "colour input seen through an RGGB colour filter mosaic")(
      "log-eps", po::value<double>()->default_value(1e-3), "eps of L = log(I + eps)")(
      "lin-log", po::bool_switch(), "v2e's lin-log mapping instead of log(I + eps)")(
      "seed", po::value<uint64_t>()->default_value(1), "random seed")(
      "threads", po::value<int>()->default_value(0), "threads (0: all cores)")(
      "compression", po::value<std::string>()->default_value("auto"),
      "output compression (see evkit convert)");
  po::positional_options_description pos;
  pos.add("input", 1);
  po::variables_map vm;
  if (!parseArgs(args,
                 "usage: evkit simulate INPUT --out FILE [--contrast C] [--sigma S] [--exposure "
                 "START:END]",
                 opts, pos, vm)) {
    return kExitOk;
  }
  DriverOptions d;
  SimulatorOptions& s = d.simulator;
  std::tie(s.contrast_pos, s.contrast_neg) =
      parseNumberPair(vm["contrast"].as<std::string>(), "contrast");
  if (!(s.contrast_pos > 0) || !(s.contrast_neg > 0))
    throw UsageError("--contrast: thresholds must be positive");
  s.sigma = vm["sigma"].as<double>();
  s.refractory_us = parseTimeValue(vm["refractory"].as<std::string>(), "refractory").us;
  s.shot_noise_rate_hz = vm["shot-noise"].as<double>();
  s.leak_rate_hz = vm["leak"].as<double>();
  if (s.sigma < 0 || s.refractory_us < 0 || s.shot_noise_rate_hz < 0 || s.leak_rate_hz < 0) {
    throw UsageError("--sigma, --refractory, --shot-noise and --leak must not be negative");
  }
  s.log.eps = vm["log-eps"].as<double>();
  if (!(s.log.eps > 0)) throw UsageError("--log-eps must be positive");
  s.log.lin_log = vm["lin-log"].as<bool>();
  s.seed = vm["seed"].as<uint64_t>();
  d.bayer_rggb = vm["bayer"].as<bool>();
  d.exposure_every = vm["exposure-every"].as<int>();
  d.duty = vm["duty"].as<double>();
  if (d.exposure_every < 0 || !(d.duty > 0) || d.duty > 1)
    throw UsageError("--exposure-every >= 0 and 0 < --duty <= 1");
  if (vm.count("exposure")) {
    for (const std::string& e : vm["exposure"].as<std::vector<std::string>>()) {
      const size_t colon = e.find(':');
      if (colon == std::string::npos)
        throw UsageError("--exposure: expected START:END, got '" + e + "'");
      const int64_t a = parseTimeValue(e.substr(0, colon), "exposure").us,
                    b = parseTimeValue(e.substr(colon + 1), "exposure").us;
      if (b < a) throw UsageError("--exposure: END before START in '" + e + "'");
      d.exposures.push_back({a, b});
    }
  }
  if (vm["threads"].as<int>() > 0) omp_set_num_threads(vm["threads"].as<int>());
  SequenceOptions seq_options;
  seq_options.fps = vm["fps"].as<double>();
  seq_options.start_us = parseTimeValue(vm["start-time"].as<std::string>(), "start-time").us;
  seq_options.srgb = vm["srgb"].as<bool>();
  WriterOptions w;
  if (vm["compression"].as<std::string>() != "auto") {
    try {
      w.compression = parseCompression(vm["compression"].as<std::string>());
    } catch (const Error& e) {
      throw UsageError(std::string("--compression: ") + e.what());
    }
  }

  auto sequence = openFrameSequence(vm["input"].as<std::string>(), seq_options);
  const std::string out = vm["out"].as<std::string>();
  auto writer = openWriter(out, outputFormat(out), sequence->sensor(), w);
  Progress progress("simulate", static_cast<int64_t>(sequence->sizeHint()));
  int64_t frames = 0, blurry = 0;
  const SimulatorStats stats =
      simulateSequence(*sequence, d, [&](const EventStore& events, const std::vector<Frame>& done) {
        writer->write(events.view());
        for (const Frame& f : done) writer->writeFrame(f);
        blurry += static_cast<int64_t>(done.size());
        progress.update(++frames);
      });
  writer->close();
  progress.finish();
  std::cerr << "simulated " << stats.frames << " frames: " << withThousands(stats.events)
            << " events (" << withThousands(stats.noise_events) << " noise, "
            << withThousands(stats.refractory_dropped) << " dropped by the refractory period), "
            << blurry << " blurry frames -> " << out << "\n";
  if (stats.undersampled_intervals > 0) {
    std::cerr << "warning: " << stats.undersampled_intervals << " of " << stats.frames - 1
              << " frame intervals change more than " << 100 * s.undersampling_fraction
              << "% of the pixels by more than C (worst: " << 100 * stats.max_fraction_over_c
              << "%): the frame rate is too low for the motion, events between frames are "
                 "interpolated linearly\n";
  }
  return kExitOk;
}

}  // namespace evkit::cli
