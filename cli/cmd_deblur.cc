// evkit deblur / compare / metrics.

#include <cmath>
#include <cstdio>
#include <iostream>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "common.h"
#include "deblur_runner.h"
#include "evkit/base/error.h"
#include "evkit/deblur/metrics.h"
#include "evkit/deblur/observation.h"
#include "evkit/events/image_io.h"
#include "recording_job.h"

namespace evkit::cli {

namespace {

MethodSettings parseSettings(const po::variables_map& vm) {
  MethodSettings settings;
  if (!vm.count("set")) return settings;
  for (const std::string& kv : vm["set"].as<std::vector<std::string>>()) {
    const size_t eq = kv.find('=');
    if (eq == std::string::npos || eq == 0)
      throw UsageError("--set: expected KEY=VALUE, got '" + kv + "'");
    settings[kv.substr(0, eq)] = kv.substr(eq + 1);
  }
  return settings;
}

DeblurRequest parseTimes(const po::variables_map& vm, const Observation& obs) {
  if (!vm.count("times")) return defaultRequest(obs, vm["latent"].as<int>());
  DeblurRequest r;
  for (const std::string& t : vm["times"].as<std::vector<std::string>>()) {
    const TimeValue v = parseTimeValue(t, "times");
    const int64_t us = v.relative ? obs.blurry.exposure_start_us + v.us : v.us;
    if (us < obs.blurry.exposure_start_us || us > obs.blurry.exposure_end_us) {
      throw UsageError("--times: " + t + " lies outside the exposure [" +
                       std::to_string(obs.blurry.exposure_start_us) + ", " +
                       std::to_string(obs.blurry.exposure_end_us) + "]");
    }
    r.times_us.push_back(us);
  }
  return r;
}

Observation loadInput(const po::variables_map& vm) {
  if (vm.count("recording")) {
    if (vm.count("observation"))
      throw UsageError("give an observation folder or --recording, not both");
    if (!vm.count("frame")) throw UsageError("--recording needs --frame N (or --frames for many)");
    Observation obs =
        observationFromRecording(vm["recording"].as<std::string>(), vm["frame"].as<size_t>(),
                                 parseTimeValue(vm["margin"].as<std::string>(), "margin").us);
    if (vm.count("extract")) {
      saveObservation(obs, vm["extract"].as<std::string>());
      std::cerr << "extracted " << obs.source << " to " << vm["extract"].as<std::string>() << "\n";
    }
    return obs;
  }
  if (!vm.count("observation"))
    throw UsageError("give an observation folder, or --recording FILE --frame N");
  return loadObservation(vm["observation"].as<std::string>());
}

void addInputOptions(po::options_description& opts) {
  opts.add_options()("observation", po::value<std::string>(),
                     "observation folder (blurry.png, exposure.txt, events.*, calib.txt)")(
      "recording", po::value<std::string>(), "instead: a recording with frames")(
      "frame", po::value<size_t>(), "with --recording: the frame's index")(
      "margin", po::value<std::string>()->default_value("0us"),
      "with --recording: events this far beyond the exposure")(
      "extract", po::value<std::string>(),
      "with --recording: also write the observation folder here")(
      "times", po::value<std::vector<std::string>>()->multitoken(),
      "latent frame times (µs, or +offset into the exposure)")(
      "latent", po::value<int>()->default_value(5),
      "without --times: this many evenly spaced latent frames (+ the middle); with --recording "
      "--frames: per exposure, for the video (default 10)");
}

std::string fmt(double v, const char* format) {
  if (!std::isfinite(v)) return "-";
  char buf[32];
  std::snprintf(buf, sizeof(buf), format, v);
  return buf;
}

}  // namespace

int runDeblur(const Args& args) {
  po::options_description opts("options");
  addInputOptions(opts);
  opts.add_options()("method", po::value<std::string>()->default_value("edi"),
                     "blurry, edi or benerf")(
      "set", po::value<std::vector<std::string>>()->composing(),
      "method setting KEY=VALUE (repeatable; --settings lists them)")(
      "settings", "list the method's settings with their types, defaults and meaning, and exit")(
      "out", po::value<std::string>(), "output folder");
  addRecordingJobOptions(opts);
  po::positional_options_description pos;
  pos.add("observation", 1);
  po::variables_map vm;
  if (!parseArgs(args,
                 "usage: evkit deblur OBS --method M --out DIR  |  evkit deblur --recording FILE "
                 "--frame N --out DIR  |  evkit deblur --recording FILE --frames all|A:B|A,B,C "
                 "[--shard I/N] --out DIR",
                 opts, pos, vm)) {
    return kExitOk;
  }
  const std::string method = vm["method"].as<std::string>();
  if (vm.count("settings")) {
    try {
      std::cout << method << " settings (--set KEY=VALUE):\n" << deblurrerHelp(method);
    } catch (const Error& e) {
      throw UsageError(e.what());
    }
    return kExitOk;
  }
  if (!vm.count("out")) throw UsageError("the option '--out' is required but missing");
  if (vm.count("frames")) {
    if (!vm.count("recording")) throw UsageError("--frames needs --recording FILE");
    if (vm.count("frame")) throw UsageError("give --frame N or --frames, not both");
    return runRecordingDeblur(vm, method, parseSettings(vm));
  }
  const Method made = makeMethod(method, parseSettings(vm));
  const Observation obs = loadInput(vm);
  const DeblurRequest request = completeRequest(obs, parseTimes(vm, obs));
  const MethodReport r = runMethod(obs, made, request, vm["out"].as<std::string>());
  if (!r.result.account.empty()) std::cerr << method << ": " << r.result.account << "\n";
  std::cerr << method << ": " << r.result.frames.size() << " frames in " << fmt(r.wall_s, "%.3f")
            << " s; PSNR(mid) " << fmt(r.psnr_mid, "%.2f") << " dB, SSIM(mid) "
            << fmt(r.ssim_mid, "%.4f") << ", BRISQUE(mid) " << fmt(r.brisque_mid, "%.1f") << " -> "
            << vm["out"].as<std::string>() << "\n";
  return kExitOk;
}

int runCompare(const Args& args) {
  po::options_description opts("options");
  addInputOptions(opts);
  opts.add_options()("methods", po::value<std::string>()->default_value("blurry,edi"),
                     "comma-separated methods")(
      "set", po::value<std::vector<std::string>>()->composing(),
      "METHOD.KEY=VALUE settings (e.g. edi.contrast=0.2)")(
      "out", po::value<std::string>(), "folder for each method's output and side_by_side.png");
  po::positional_options_description pos;
  pos.add("observation", 1);
  po::variables_map vm;
  if (!parseArgs(args, "usage: evkit compare OBS [--methods blurry,edi] [--out DIR]", opts, pos,
                 vm))
    return kExitOk;
  const std::vector<std::string> methods = splitList(vm["methods"].as<std::string>());
  std::map<std::string, MethodSettings> settings;
  for (const auto& [key, value] : parseSettings(vm)) {
    const size_t dot = key.find('.');
    if (dot == std::string::npos)
      throw UsageError("--set: expected METHOD.KEY=VALUE, got '" + key + "'");
    settings[key.substr(0, dot)][key.substr(dot + 1)] = value;
  }
  std::vector<Method> made;
  for (const std::string& m : methods) made.push_back(makeMethod(m, settings[m]));
  const Observation obs = loadInput(vm);
  const DeblurRequest request = completeRequest(obs, parseTimes(vm, obs));
  const std::string out = vm.count("out") ? vm["out"].as<std::string>() : "";
  std::vector<MethodReport> reports;
  std::printf("%-10s %10s %8s %10s %11s\n", "method", "PSNR(mid)", "SSIM", "BRISQUE", "wall time");
  for (const Method& method : made) {
    const std::string& m = method.name;
    try {
      reports.push_back(runMethod(obs, method, request, out.empty() ? "" : out + "/" + m));
    } catch (const Error& e) {
      std::fprintf(stderr, "evkit compare: %s failed: %s (the other methods' results are kept)\n",
                   m.c_str(), e.what());
      continue;
    }
    const MethodReport& r = reports.back();
    std::printf("%-10s %10s %8s %10s %10ss\n", m.c_str(), fmt(r.psnr_mid, "%.2f").c_str(),
                fmt(r.ssim_mid, "%.4f").c_str(), fmt(r.brisque_mid, "%.1f").c_str(),
                fmt(r.wall_s, "%.3f").c_str());
    std::fflush(stdout);
  }
  if (!out.empty() && !reports.empty()) {
    writeSideBySide(out + "/side_by_side.png", obs, reports);
    std::cerr << "wrote " << out << "/side_by_side.png\n";
  }
  return reports.size() == methods.size() ? kExitOk : kExitInputError;
}

int runMetrics(const Args& args) {
  po::options_description opts("options");
  opts.add_options()("image", po::value<std::string>()->required(), "image to score")(
      "reference", po::value<std::string>(),
      "reference image (PSNR, SSIM); without it only BRISQUE");
  po::positional_options_description pos;
  pos.add("image", 1).add("reference", 1);
  po::variables_map vm;
  if (!parseArgs(args, "usage: evkit metrics IMAGE [REFERENCE]", opts, pos, vm)) return kExitOk;
  const Frame a = readImageFile(vm["image"].as<std::string>());
  if (vm.count("reference")) {
    const Frame b = readImageFile(vm["reference"].as<std::string>());
    if (a.image.size() != b.image.size() || a.image.channels() != b.image.channels()) {
      throw Error(vm["image"].as<std::string>() + ": size or channels differ from " +
                  vm["reference"].as<std::string>());
    }
    std::printf("PSNR    %.3f dB\nSSIM    %.5f\n", psnr(a.image, b.image), ssim(a.image, b.image));
  }
  std::printf("BRISQUE %.2f\n", brisque(a.image));
  return kExitOk;
}

}  // namespace evkit::cli
