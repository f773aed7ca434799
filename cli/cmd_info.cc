// evkit info FILE: a summary computed in one streaming pass (bounded memory).

#include <algorithm>
#include <cstdio>
#include <iostream>

#include "common.h"

namespace evkit::cli {

void printInfo(const std::string& path, std::optional<Format> format) {
  auto reader = openReader(path, format);
  const ReaderInfo& info = reader->info();
  Progress progress("info", info.event_count);
  int64_t count = 0, on = 0;
  int64_t t_first = 0, t_last = 0;
  int max_x = -1, max_y = -1;
  int64_t frames = 0, exposure_sum = 0, exposure_min = INT64_MAX, exposure_max = INT64_MIN;
  int frame_w = 0, frame_h = 0, frame_c = 0, frame_bits = 0;
  Chunk chunk;
  while (reader->next(chunk, size_t{1} << 20)) {
    const EventStore& ev = chunk.events;
    if (!ev.empty()) {
      if (count == 0) t_first = ev.t.front();
      t_last = ev.t.back();
      on += ev.countOn();
      max_x = std::max<int>(max_x, *std::max_element(ev.x.begin(), ev.x.end()));
      max_y = std::max<int>(max_y, *std::max_element(ev.y.begin(), ev.y.end()));
      count += static_cast<int64_t>(ev.size());
    }
    for (const Frame& f : chunk.frames) {
      const int64_t exposure = f.exposure_end_us - f.exposure_start_us;
      exposure_sum += exposure;
      exposure_min = std::min(exposure_min, exposure);
      exposure_max = std::max(exposure_max, exposure);
      frame_w = f.image.cols;
      frame_h = f.image.rows;
      frame_c = f.image.channels();
      frame_bits = f.bit_depth;
      ++frames;
    }
    progress.update(count);
  }
  progress.finish();

  std::printf("file:        %s\n", path.c_str());
  std::printf("format:      %s (%s layout)\n", formatName(info.format).c_str(),
              info.layout.c_str());
  if (!info.camera.empty()) std::printf("camera:      %s\n", info.camera.c_str());
  if (info.sensor.known()) {
    std::printf("sensor:      %d x %d\n", info.sensor.width, info.sensor.height);
  } else {
    std::printf("sensor:      not stated; events span %d x %d\n", max_x + 1, max_y + 1);
  }
  std::printf("events:      %s (ON %s, OFF %s)\n", withThousands(count).c_str(),
              withThousands(on).c_str(), withThousands(count - on).c_str());
  if (count > 0) {
    const int64_t span = t_last - t_first;
    std::printf("first:       %lld us (%s)\n", static_cast<long long>(t_first),
                formatSeconds(t_first).c_str());
    std::printf("last:        %lld us (%s)\n", static_cast<long long>(t_last),
                formatSeconds(t_last).c_str());
    std::printf("duration:    %s\n", formatSeconds(span).c_str());
    if (span > 0) {
      std::printf("mean rate:   %.3f Mev/s\n",
                  static_cast<double>(count) / static_cast<double>(span));
    }
  }
  std::printf("frames:      %s", withThousands(frames).c_str());
  if (frames > 0) {
    std::printf(" (%d x %d, %s, %d-bit), exposure mean %.3f ms, min %.3f ms, max %.3f ms", frame_w,
                frame_h, frame_c == 3 ? "colour" : "grey", frame_bits,
                static_cast<double>(exposure_sum) / static_cast<double>(frames) / 1e3,
                static_cast<double>(exposure_min) / 1e3, static_cast<double>(exposure_max) / 1e3);
  }
  std::printf("\n");
  if (info.calibration) {
    const Calibration& c = *info.calibration;
    std::printf("intrinsics:  fx %.3f fy %.3f cx %.3f cy %.3f, %zu distortion coefficients\n", c.fx,
                c.fy, c.cx, c.cy, c.distortion.size());
  }
  for (const auto& [key, value] : info.counters)
    std::printf("  %-28s %s\n", key.c_str(), withThousands(value).c_str());
  std::fflush(stdout);
  for (const std::string& w : info.warnings) std::fprintf(stderr, "warning: %s\n", w.c_str());
}

int runInfo(const Args& args) {
  po::options_description opts("options");
  opts.add_options()("input", po::value<std::string>()->required(),
                     "recording (file or RPG folder)")(
      "format", po::value<std::string>(),
      "input format (text, hdf5, rpg, aedat2, aedat3, aedat4, evt2, evt3, dat); default: from the "
      "name");
  po::positional_options_description pos;
  pos.add("input", 1);
  po::variables_map vm;
  if (!parseArgs(args, "usage: evkit info FILE [--format NAME]", opts, pos, vm)) return kExitOk;
  printInfo(vm["input"].as<std::string>(), optionalFormat(vm, "format"));
  return kExitOk;
}

}  // namespace evkit::cli
