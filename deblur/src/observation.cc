#include "evkit/deblur/observation.h"

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "evkit/base/error.h"
#include "evkit/events/atomic_file.h"
#include "evkit/events/decimal.h"
#include "evkit/events/image_io.h"
#include "evkit/events/io.h"
#include "evkit/events/npy.h"
#include "evkit/spline/tum.h"

namespace evkit {
namespace fs = std::filesystem;

namespace {

std::vector<double> readNumbers(const std::string& path, size_t min_count, size_t max_count,
                                const std::string& expected) {
  std::ifstream in(path);
  if (!in) throwInFile(path, "cannot open");
  std::vector<double> values;
  std::string token;
  while (in >> token) {
    try {
      size_t used = 0;
      values.push_back(std::stod(token, &used));
      if (used != token.size()) throw std::invalid_argument(token);
    } catch (const std::exception&) {
      throwAtLine(path, 1, "'" + token + "' is not a number (expected " + expected + ")");
    }
  }
  if (values.size() < min_count || values.size() > max_count)
    throwAtLine(path, 1, "expected " + expected);
  return values;
}

// gt/depth.npy: one float32 plane at the blurry frame's size, (H, W) or (1, H, W).
cv::Mat readDepth(const std::string& path, const Observation& obs) {
  NpyArray a = readNpy(path);
  const int h = obs.blurry.image.rows, w = obs.blurry.image.cols;
  const bool one_plane = a.shape.size() == 2 || (a.shape.size() == 3 && a.shape[0] == 1);
  if (!one_plane || a.shape[a.shape.size() - 2] != static_cast<size_t>(h) ||
      a.shape.back() != static_cast<size_t>(w))
    throwInFile(path, "expected one " + std::to_string(h) + " x " + std::to_string(w) +
                          " plane (the blurry frame's size)");
  return cv::Mat(h, w, CV_32F, a.data.data()).clone();
}

}  // namespace

Observation loadObservation(const std::string& dir) {
  if (!fs::is_directory(dir))
    throwInFile(
        dir,
        "not an observation folder (expected blurry.png, exposure.txt, events.*, [calib.txt])");
  Observation obs;
  obs.source = dir;
  obs.blurry = readImageFile((fs::path(dir) / "blurry.png").string());
  // exposure.txt holds integers (µs): read exactly, not through double.
  const std::string exposure_path = (fs::path(dir) / "exposure.txt").string();
  std::ifstream ex(exposure_path);
  if (!ex) throwInFile(exposure_path, "cannot open (expected 'exposure_start_us exposure_end_us')");
  std::string a, b;
  ex >> a >> b;
  const char* pa = a.data();
  const char* pb = b.data();
  int64_t t0 = 0, t1 = 0;
  if (!parseInt(pa, a.data() + a.size(), INT64_MIN, INT64_MAX, t0) || pa != a.data() + a.size() ||
      !parseInt(pb, b.data() + b.size(), INT64_MIN, INT64_MAX, t1) || pb != b.data() + b.size() ||
      t1 <= t0) {
    throwAtLine(exposure_path, 1,
                "expected 'exposure_start_us exposure_end_us' (integers, start < end)");
  }
  obs.blurry.exposure_start_us = t0;
  obs.blurry.exposure_end_us = t1;
  std::string events_path;
  for (const auto& entry : fs::directory_iterator(dir)) {
    if (entry.path().stem() == "events" && entry.is_regular_file())
      events_path = entry.path().string();
  }
  if (events_path.empty())
    throwInFile(dir, "no events file (events.h5, events.txt, events.aedat4, ...)");
  const Recording rec = readRecording(events_path);
  obs.events = rec.events;
  obs.events.setSensor(SensorSize{obs.blurry.image.cols, obs.blurry.image.rows});
  validate(obs.events.view(), events_path);
  const fs::path calib = fs::path(dir) / "calib.txt";
  if (fs::exists(calib)) {
    obs.camera = readCalibration(calib.string());
  } else {
    obs.camera = Calibration::assumed(obs.blurry.image.cols, obs.blurry.image.rows);
    obs.camera_assumed = true;
  }
  const fs::path contrast = fs::path(dir) / "contrast.txt";
  if (fs::exists(contrast)) {
    const std::vector<double> c = readNumbers(contrast.string(), 1, 2, "'C_on C_off' or 'C'");
    if (!(c.front() > 0) || !(c.back() > 0))
      throwAtLine(contrast.string(), 1, "thresholds must be positive");
    obs.contrast = Contrast{c.front(), c.back()};
  }
  const fs::path gt = fs::path(dir) / "gt";
  if (fs::is_directory(gt)) {
    for (const auto& entry : fs::directory_iterator(gt)) {
      const std::string stem = entry.path().stem().string();
      if (entry.path().extension() != ".png" || stem.empty() ||
          !std::all_of(stem.begin(), stem.end(), ::isdigit))
        continue;
      Frame f = readImageFile(entry.path().string());
      f.exposure_start_us = f.exposure_end_us = std::stoll(stem);
      obs.gt_frames.push_back(std::move(f));
    }
    std::sort(obs.gt_frames.begin(), obs.gt_frames.end(), [](const Frame& x, const Frame& y) {
      return x.exposure_start_us < y.exposure_start_us;
    });
    if (fs::exists(gt / "poses.txt")) obs.gt_poses = readTum((gt / "poses.txt").string());
    if (fs::exists(gt / "depth.npy")) obs.gt_depth = readDepth((gt / "depth.npy").string(), obs);
    std::ifstream info(gt / "info.txt");
    for (std::string line; std::getline(info, line);) {
      if (line.rfind("blur_px ", 0) == 0) obs.gt_blur_px = std::strtod(line.c_str() + 8, nullptr);
    }
  }
  return obs;
}

void saveObservation(const Observation& obs, const std::string& dir) {
  AtomicPath out(dir);
  const std::string tmp = out.temporaryPath();
  fs::create_directories(tmp);
  writeImageFile(tmp + "/blurry.png", obs.blurry.image, obs.blurry.bit_depth);
  std::ofstream(tmp + "/exposure.txt")
      << obs.blurry.exposure_start_us << ' ' << obs.blurry.exposure_end_us << '\n';
  Recording rec;
  rec.events = obs.events;
  writeRecording(tmp + "/events.h5", rec);
  if (!obs.camera_assumed) writeCalibration(tmp + "/calib.txt", obs.camera);
  if (obs.contrast)
    std::ofstream(tmp + "/contrast.txt") << obs.contrast->on << ' ' << obs.contrast->off << '\n';
  out.commit();
}

Observation observationFromRecording(const std::string& path, size_t index, int64_t margin_us) {
  // First pass: find the frame (frames arrive with the events around them).
  Observation obs;
  obs.source = path + " frame " + std::to_string(index);
  auto reader = openReader(path);
  Chunk chunk;
  size_t seen = 0;
  bool found = false;
  while (!found && reader->next(chunk, size_t{1} << 20)) {
    for (Frame& f : chunk.frames) {
      if (seen++ == index) {
        obs.blurry = std::move(f);
        found = true;
        break;
      }
    }
  }
  if (!found)
    throwInFile(path, "has " + std::to_string(seen) + " frames; frame " + std::to_string(index) +
                          " does not exist");
  if (obs.blurry.exposure_end_us <= obs.blurry.exposure_start_us) {
    throwInFile(path, "frame " + std::to_string(index) + " has no exposure interval (start " +
                          std::to_string(obs.blurry.exposure_start_us) + ", end " +
                          std::to_string(obs.blurry.exposure_end_us) + ")");
  }
  // Second pass: the events of the exposure (the time window uses the file's index if it has one).
  const Recording rec = readRecording(path, std::nullopt, obs.blurry.exposure_start_us - margin_us,
                                      obs.blurry.exposure_end_us + margin_us + 1);
  obs.events = rec.events;
  obs.events.setSensor(SensorSize{obs.blurry.image.cols, obs.blurry.image.rows});
  obs.camera_assumed = !rec.info.calibration;
  obs.camera = rec.info.calibration
                   ? *rec.info.calibration
                   : Calibration::assumed(obs.blurry.image.cols, obs.blurry.image.rows);
  return obs;
}

}  // namespace evkit
