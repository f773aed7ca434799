// evkit accumulate IN --repr R (--window D | --count N) --out DIR
// Streams the recording and writes, per window, a PNG for people and the float data as .npy, plus
// windows.csv (index, t_begin_us, t_end_us, events). The folder appears only when complete.

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <opencv2/imgcodecs.hpp>

#include "common.h"
#include "evkit/base/error.h"
#include "evkit/events/accumulate.h"
#include "evkit/events/atomic_file.h"
#include "evkit/events/npy.h"
#include "evkit/events/slicer.h"

namespace evkit::cli {

namespace fs = std::filesystem;

namespace {

enum class Repr { kFrame, kCounts, kNormalized, kTimeSurface, kVoxel };

Repr parseRepr(const std::string& name) {
  if (name == "frame") return Repr::kFrame;
  if (name == "counts") return Repr::kCounts;
  if (name == "normalized") return Repr::kNormalized;
  if (name == "timesurface") return Repr::kTimeSurface;
  if (name == "voxel") return Repr::kVoxel;
  throw UsageError("--repr: unknown representation '" + name +
                   "' (known: frame, counts, normalized, timesurface, voxel)");
}

struct AccumulateSettings {
  Repr repr = Repr::kFrame;
  float c_on = 1, c_off = 1;
  int bins = 5;
  double tau_us = 10000;
  bool npy = true;
};

// Computes one window's representation and writes <index>.png and <index>.npy into dir.
void writeWindow(const std::string& dir, size_t index, const EventSpan& events, int64_t t_begin,
                 int64_t t_end, const AccumulateSettings& s) {
  char stem[32];
  std::snprintf(stem, sizeof(stem), "%06zu", index);
  const std::string base = dir + "/" + stem;
  std::vector<cv::Mat> planes;
  cv::Mat png;
  switch (s.repr) {
    case Repr::kFrame:
      planes = {accumulateSigned(events, s.c_on, s.c_off)};
      png = renderPolarity(planes[0]);
      break;
    case Repr::kCounts: {
      const PolarityCounts counts = accumulateCounts(events);
      planes = {counts.on, counts.off};
      png = renderPolarity(counts);
      break;
    }
    case Repr::kNormalized:
      planes = {accumulateNormalized(events)};
      png = renderPolarity(planes[0]);
      break;
    case Repr::kTimeSurface: {
      const TimeSurface ts = timeSurface(events, t_end - 1, s.tau_us);
      planes = {ts.on, ts.off};
      png = renderColormap(cv::max(ts.on, ts.off));
      break;
    }
    case Repr::kVoxel: {
      planes = voxelGrid(events, s.bins, t_begin, t_end - 1);
      std::vector<cv::Mat> tiles;
      for (const cv::Mat& p : planes) tiles.push_back(renderPolarity(p));
      cv::hconcat(tiles, png);
      break;
    }
  }
  if (!cv::imwrite(base + ".png", png)) throwInFile(base + ".png", "cannot write image");
  if (s.npy) {
    if (planes.size() == 1) {
      writeNpy(base + ".npy", planes[0].ptr<float>(),
               {static_cast<size_t>(planes[0].rows), static_cast<size_t>(planes[0].cols)});
    } else {
      writeNpy(base + ".npy", planes);
    }
  }
}

}  // namespace

int runAccumulate(const Args& args) {
  po::options_description opts("options");
  opts.add_options()("input", po::value<std::string>()->required(), "input recording")(
      "out", po::value<std::string>()->required(), "output folder")(
      "repr", po::value<std::string>()->default_value("frame"),
      "frame (signed sum, x C with --contrast), counts (ON, OFF), normalized (L2, BeNeRF), "
      "timesurface (ON, OFF), voxel (bins x H x W)")(
      "window", po::value<std::string>(), "window length: 10ms, 250us, 0.5s (default 10ms)")(
      "count", po::value<size_t>(), "window of N events instead of a duration")(
      "start", po::value<std::string>(),
      "first window starts here (µs, 1.5s, or +10ms from the first event)")(
      "end", po::value<std::string>(), "ignore events from here on")(
      "max-windows", po::value<size_t>()->default_value(1000), "stop after this many windows")(
      "bins", po::value<int>()->default_value(5), "voxel: temporal bins")(
      "tau", po::value<std::string>()->default_value("10ms"), "timesurface: decay constant")(
      "contrast", po::value<std::string>(), "frame: C_on,C_off multipliers (e.g. 0.2,0.25)")(
      "no-npy", po::bool_switch(), "write only the PNGs")("format", po::value<std::string>(),
                                                          "input format; default: from the name");
  po::positional_options_description pos;
  pos.add("input", 1);
  po::variables_map vm;
  if (!parseArgs(args, "usage: evkit accumulate IN --out DIR [--repr R] [--window D | --count N]",
                 opts, pos, vm)) {
    return kExitOk;
  }
  AccumulateSettings s;
  s.repr = parseRepr(vm["repr"].as<std::string>());
  s.bins = vm["bins"].as<int>();
  if (s.bins < 1 || s.bins > 1000) throw UsageError("--bins: expected 1..1000");
  s.tau_us = static_cast<double>(parseDuration(vm["tau"].as<std::string>(), "tau"));
  s.npy = !vm["no-npy"].as<bool>();
  if (vm.count("contrast")) {
    const auto [on, off] = parseNumberPair(vm["contrast"].as<std::string>(), "contrast");
    s.c_on = static_cast<float>(on);
    s.c_off = static_cast<float>(off);
    if (!(s.c_on > 0) || !(s.c_off > 0))
      throw UsageError("--contrast: thresholds must be positive");
  }
  if (vm.count("window") && vm.count("count"))
    throw UsageError("give --window or --count, not both");
  const bool by_count = vm.count("count") > 0;
  const size_t count = by_count ? vm["count"].as<size_t>() : 0;
  if (by_count && count == 0) throw UsageError("--count: expected a positive number");
  const int64_t window =
      by_count
          ? 0
          : parseDuration(vm.count("window") ? vm["window"].as<std::string>() : "10ms", "window");
  const size_t max_windows = vm["max-windows"].as<size_t>();

  const std::string in = vm["input"].as<std::string>();
  const std::optional<Format> format = optionalFormat(vm, "format");
  auto reader = openReader(in, format);
  std::optional<TimeValue> start, end;
  if (vm.count("start")) start = parseTimeValue(vm["start"].as<std::string>(), "start");
  if (vm.count("end")) end = parseTimeValue(vm["end"].as<std::string>(), "end");

  SensorSize sensor = reader->info().sensor;
  if (!sensor.known()) {
    // Text without a header: the size comes from the data, which takes one streaming pass.
    auto scan = openReader(in, format);
    Chunk chunk;
    while (scan->next(chunk, size_t{1} << 20)) {
      const SensorSize box = boundingSensor(chunk.events.view());
      sensor = SensorSize{std::max(sensor.width, box.width), std::max(sensor.height, box.height)};
    }
    if (!sensor.known()) throwInFile(in, "no events, nothing to accumulate");
  }

  const std::string out = vm["out"].as<std::string>();
  AtomicPath out_dir(out);
  fs::create_directories(out_dir.temporaryPath());
  std::ofstream csv(out_dir.temporaryPath() + "/windows.csv");
  csv << "index,t_begin_us,t_end_us,events\n";

  EventSlicer slicer =
      by_count ? EventSlicer::byCount(count, sensor) : EventSlicer::byTime(window, sensor);
  const auto write = [&](const EventSlicer::Window& w) {
    writeWindow(out_dir.temporaryPath(), w.index, w.events, w.t_begin, w.t_end, s);
    csv << w.index << ',' << w.t_begin << ',' << w.t_end << ',' << w.events.size() << '\n';
    return w.index + 1 < max_windows;
  };
  Progress progress("accumulate", reader->info().event_count);
  int64_t read = 0;
  bool started = false;
  Chunk chunk;
  while (reader->next(chunk, size_t{1} << 20)) {
    const EventStore& ev = chunk.events;
    if (!ev.empty() && !started) {
      // --start and --end may be relative to the first event.
      const auto resolve = [&](const TimeValue& v) {
        return v.relative ? ev.t.front() + v.us : v.us;
      };
      if (start) slicer.setOrigin(resolve(*start));
      if (end) slicer.setEnd(resolve(*end));
      started = true;
    }
    read += static_cast<int64_t>(ev.size());
    progress.update(read);
    if (!slicer.accept(ev.view(), write)) break;
  }
  const bool stopped = slicer.stopped();
  slicer.finish(write);
  const size_t windows = slicer.windows();
  progress.finish();
  if (windows == 0) throwInFile(in, "no events in the requested range, nothing written");
  csv.close();
  if (!csv) throwInFile(out, "cannot write windows.csv");
  out_dir.commit();
  std::cerr << "wrote " << windows << " window" << (windows == 1 ? "" : "s") << " to " << out << "/"
            << (stopped ? " (stopped at --max-windows)" : "") << "\n";
  return kExitOk;
}

}  // namespace evkit::cli
