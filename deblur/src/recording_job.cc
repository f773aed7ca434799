#include "evkit/deblur/recording_job.h"

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <map>
#include <opencv2/videoio.hpp>
#include <sstream>

#include "evkit/base/error.h"
#include "evkit/base/text.h"
#include "evkit/deblur/evaluate.h"
#include "evkit/events/atomic_file.h"
#include "evkit/events/calibration.h"
#include "evkit/events/image_io.h"
#include "evkit/events/io.h"

namespace evkit {

namespace fs = std::filesystem;

namespace {

constexpr const char* kCsvHeader =
    "index,exposure_start_us,exposure_end_us,events,method,wall_s,psnr_mid,ssim_mid,psnr_mean,"
    "brisque_mid,status,message";

size_t parseIndex(const std::string& text, const std::string& what) {
  size_t used = 0;
  unsigned long long v = 0;
  try {
    v = std::stoull(text, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (text.empty() || used != text.size() || text[0] == '-')
    throw Error(what + ": '" + text + "' is not a frame index");
  return static_cast<size_t>(v);
}

std::string settingsText(const MethodSettings& settings) {
  std::string s;
  for (const auto& [k, v] : settings) s += (s.empty() ? "" : ";") + k + "=" + v;
  return s;
}

// What identifies a job: the same for every worker of it, different for any other job.
std::string jobText(const RecordingJob& job, const std::vector<RecordedFrame>& chosen) {
  std::ostringstream s;
  s << "recording " << fs::absolute(job.recording).lexically_normal().string() << "\n"
    << "frames " << job.frames << "\nmethod " << job.method << "\nsettings "
    << settingsText(job.settings) << "\nseed " << job.seed << "\nlatent_per_exposure "
    << job.latent_per_exposure << "\nmargin_us " << job.margin_us << "\ncalib " << job.calib
    << "\nground_truth " << job.ground_truth << "\nnoise_filter ";
  if (job.noise_filter) {
    s << job.noise_filter->hot_pixels << ' ' << job.noise_filter->hot_ratio << ' '
      << job.noise_filter->hot_min_events << ' ' << job.noise_filter->refractory_us;
  } else {
    s << "off";
  }
  s << "\nchosen";
  for (const RecordedFrame& f : chosen) s << ' ' << f.index << ':' << f.start_us << ':' << f.end_us;
  s << "\n";
  return s.str();
}

std::string readText(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

// The chosen frames and latent count, as job.txt records them (for the merge).
struct JobRecord {
  std::vector<RecordedFrame> chosen;
  int latent_per_exposure = 10;
};

JobRecord readJob(const std::string& dir) {
  const std::string path = dir + "/job.txt";
  if (!fs::exists(path)) throwInFile(dir, "no job.txt: not a folder of `evkit deblur --recording`");
  std::istringstream in(readText(path));
  JobRecord job;
  std::string line;
  int line_no = 0;
  while (std::getline(in, line)) {
    ++line_no;
    std::istringstream fields(line);
    std::string key;
    fields >> key;
    if (key == "latent_per_exposure") {
      fields >> job.latent_per_exposure;
    } else if (key == "chosen") {
      std::string item;
      while (fields >> item) {
        RecordedFrame f;
        char c1 = 0, c2 = 0;
        std::istringstream is(item);
        if (!(is >> f.index >> c1 >> f.start_us >> c2 >> f.end_us) || c1 != ':' || c2 != ':')
          throwAtLine(path, line_no, "expected INDEX:START:END, found '" + item + "'");
        job.chosen.push_back(f);
      }
    }
  }
  if (job.latent_per_exposure < 1) throwInFile(path, "latent_per_exposure must be at least 1");
  return job;
}

std::string csvQuote(const std::string& s) {
  std::string q = "\"";
  for (char c : s) q += c == '"' ? std::string("\"\"") : std::string(1, c == '\n' ? ' ' : c);
  return q + "\"";
}

std::string manifestPath(const std::string& dir, size_t index) {
  return dir + "/manifest/" + std::to_string(index) + ".csv";
}

// The status field of a manifest row (the one before the quoted message), or "" without one.
std::string statusOf(const std::string& row) {
  const size_t quote = row.find(",\"");
  if (quote == std::string::npos) return "";
  const size_t comma = row.rfind(',', quote - 1);
  return comma == std::string::npos ? "" : row.substr(comma + 1, quote - comma - 1);
}

bool finished(const std::string& dir, size_t index) {
  return fs::exists(manifestPath(dir, index)) &&
         statusOf(readText(manifestPath(dir, index))) == "ok" &&
         fs::is_directory(dir + "/frames/" + std::to_string(index));
}

std::vector<int64_t> latentTimes(const RecordedFrame& f, int n) {
  std::vector<int64_t> times;
  if (n == 1) return {f.start_us + (f.end_us - f.start_us) / 2};
  for (int k = 0; k < n; ++k) times.push_back(f.start_us + (f.end_us - f.start_us) * k / (n - 1));
  return times;
}

// What every frame of a job shares, read once: the calibration file, where the ground truth's
// frames are (by time), and whether the method takes a seed.
struct JobInputs {
  std::optional<Calibration> calib;
  std::map<int64_t, std::string> ground_truth;  // t_us -> <t_us>.png
  bool seeded = false;
};

JobInputs readJobInputs(const RecordingJob& job) {
  JobInputs in;
  if (!job.calib.empty()) in.calib = readCalibration(job.calib);
  if (!job.ground_truth.empty()) {
    std::error_code ec;
    for (const auto& entry : fs::directory_iterator(job.ground_truth, ec)) {
      const std::string stem = entry.path().stem().string();
      if (entry.path().extension() == ".png" && !stem.empty() &&
          stem.find_first_not_of("0123456789") == std::string::npos)
        in.ground_truth[std::stoll(stem)] = entry.path().string();
    }
    if (ec) throwInFile(job.ground_truth, "cannot list the ground truth: " + ec.message());
  }
  in.seeded = ("\n" + deblurrerHelp(job.method)).find("\n  seed (") != std::string::npos;
  return in;
}

// Frame f of the recording with the events of its exposure (a time-window read), the camera, the
// ground truth inside the exposure, and the noise filter applied.
Observation frameObservation(const RecordingJob& job, const JobInputs& in, const RecordedFrame& f) {
  if (f.end_us <= f.start_us) {
    throwInFile(job.recording,
                "frame " + std::to_string(f.index) + " has no exposure interval (start " +
                    std::to_string(f.start_us) + " us, end " + std::to_string(f.end_us) + " us)");
  }
  Observation obs;
  obs.source = job.recording + " frame " + std::to_string(f.index);
  Recording rec = readRecording(job.recording, std::nullopt, f.start_us - job.margin_us,
                                f.end_us + job.margin_us + 1);
  const auto it = std::find_if(rec.frames.begin(), rec.frames.end(), [&](const Frame& fr) {
    return fr.exposure_start_us == f.start_us && fr.exposure_end_us == f.end_us;
  });
  if (it == rec.frames.end()) {
    throwInFile(job.recording, "frame " + std::to_string(f.index) + " (exposure " +
                                   std::to_string(f.start_us) + ".." + std::to_string(f.end_us) +
                                   ") is not where the first pass found it");
  }
  obs.blurry = std::move(*it);
  const SensorSize sensor{obs.blurry.image.cols, obs.blurry.image.rows};
  if (job.noise_filter) {
    rec.events.setSensor(sensor);
    obs.events = filterNoise(rec.events.view(), *job.noise_filter);
  } else {
    obs.events = std::move(rec.events);
  }
  obs.events.setSensor(sensor);
  obs.camera_assumed = !in.calib && !rec.info.calibration;
  obs.camera = (in.calib               ? *in.calib
                : rec.info.calibration ? *rec.info.calibration
                                       : Calibration::assumed(sensor.width, sensor.height))
                   .withSize(sensor.width, sensor.height);
  for (auto g = in.ground_truth.lower_bound(f.start_us);
       g != in.ground_truth.end() && g->first <= f.end_us; ++g) {
    Frame frame = readImageFile(g->second);
    frame.exposure_start_us = frame.exposure_end_us = g->first;
    obs.gt_frames.push_back(std::move(frame));
  }
  return obs;
}

FrameOutcome runFrame(const RecordingJob& job, const JobInputs& in, const RecordedFrame& f,
                      const std::string& dir) {
  FrameOutcome outcome;
  outcome.frame = f;
  const auto start = std::chrono::steady_clock::now();
  std::string row_tail;
  int64_t events = 0;
  try {
    MethodSettings settings = job.settings;
    if (in.seeded) settings["seed"] = std::to_string(job.seed + f.index);
    const Method method = makeMethod(job.method, settings);
    const Observation obs = frameObservation(job, in, f);
    events = static_cast<int64_t>(obs.events.size());
    DeblurRequest request;
    request.times_us = latentTimes(f, job.latent_per_exposure);
    const MethodReport report = evaluateMethod(obs, method, completeRequest(obs, request));
    writeMethodOutputs(dir + "/frames/" + std::to_string(f.index), obs, method, report);
    outcome.ok = true;
    row_tail = jsonNumber(report.psnr_mid) + "," + jsonNumber(report.ssim_mid) + "," +
               jsonNumber(report.psnr_mean) + "," + jsonNumber(report.brisque_mid) + ",ok,\"\"";
  } catch (const std::exception& e) {
    outcome.message = e.what();
    row_tail = "null,null,null,null,failed," + csvQuote(outcome.message);
  }
  outcome.wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  char wall[32];
  std::snprintf(wall, sizeof(wall), "%.3f", outcome.wall_s);
  const std::string row = std::to_string(f.index) + "," + std::to_string(f.start_us) + "," +
                          std::to_string(f.end_us) + "," + std::to_string(events) + "," +
                          job.method + "," + wall + "," + row_tail + "\n";
  writeFileAtomically(manifestPath(dir, f.index), row);
  return outcome;
}

cv::VideoWriter openVideo(const std::string& path, const std::string& name, double fps,
                          cv::Size size, bool colour) {
  const std::string ext = fs::path(name).extension().string();
  int fourcc;
  if (ext == ".avi")
    fourcc = cv::VideoWriter::fourcc('M', 'J', 'P', 'G');
  else if (ext == ".mp4")
    fourcc = cv::VideoWriter::fourcc('m', 'p', '4', 'v');
  else
    throw Error(name + ": the video must be .avi or .mp4");
  cv::VideoWriter video(path, fourcc, fps, size, colour);
  if (!video.isOpened()) throwInFile(name, "OpenCV cannot write this video here");
  return video;
}

}  // namespace

std::vector<RecordedFrame> listFrames(const std::string& path) {
  auto reader = openReader(path);
  std::vector<RecordedFrame> frames;
  Chunk chunk;
  while (reader->next(chunk, size_t{1} << 20)) {
    for (const Frame& f : chunk.frames)
      frames.push_back({frames.size(), f.exposure_start_us, f.exposure_end_us});
  }
  return frames;
}

std::vector<size_t> parseFrameSelection(const std::string& spec, size_t count) {
  std::vector<size_t> out;
  const std::string what = "--frames " + spec;
  if (spec == "all") {
    for (size_t i = 0; i < count; ++i) out.push_back(i);
    return out;
  }
  const size_t colon = spec.find(':');
  if (colon != std::string::npos) {
    const std::string a = spec.substr(0, colon), b = spec.substr(colon + 1);
    const size_t from = a.empty() ? 0 : parseIndex(a, what);
    const size_t to = b.empty() ? count : parseIndex(b, what);
    if (to > count || from >= to) {
      throw Error(what + ": the recording has " + std::to_string(count) +
                  " frames; A:B needs 0 <= A < B <= " + std::to_string(count));
    }
    for (size_t i = from; i < to; ++i) out.push_back(i);
    return out;
  }
  std::istringstream in(spec);
  std::string item;
  while (std::getline(in, item, ',')) {
    const size_t i = parseIndex(item, what);
    if (i >= count) {
      throw Error(what + ": frame " + item + " does not exist (the recording has " +
                  std::to_string(count) + " frames)");
    }
    out.push_back(i);
  }
  if (out.empty()) throw Error(what + ": no frame chosen (all, A:B or A,B,C)");
  std::sort(out.begin(), out.end());
  out.erase(std::unique(out.begin(), out.end()), out.end());
  return out;
}

Shard parseShard(const std::string& spec) {
  const size_t slash = spec.find('/');
  if (slash == std::string::npos) throw Error("--shard " + spec + ": expected I/N");
  const size_t i = parseIndex(spec.substr(0, slash), "--shard " + spec);
  const size_t n = parseIndex(spec.substr(slash + 1), "--shard " + spec);
  if (n < 1 || i >= n || n > 1'000'000)
    throw Error("--shard " + spec + ": expected I/N with 0 <= I < N");
  return {static_cast<int>(i), static_cast<int>(n)};
}

JobSummary runRecordingJob(const RecordingJob& job, const std::string& dir, Shard shard,
                           const VideoOptions& video,
                           const std::function<void(size_t, size_t, const FrameOutcome&)>& progress,
                           bool merge_when_complete) {
  if (job.latent_per_exposure < 1) throw Error("latent frames per exposure must be at least 1");
  makeMethod(job.method, job.settings);  // a bad method or setting fails before any work
  const std::vector<RecordedFrame> all = listFrames(job.recording);
  if (all.empty()) throwInFile(job.recording, "has no frames to deblur");
  std::vector<RecordedFrame> chosen;
  for (size_t i : parseFrameSelection(job.frames, all.size())) chosen.push_back(all[i]);

  fs::create_directories(dir + "/manifest");
  fs::create_directories(dir + "/frames");
  const std::string text = jobText(job, chosen);
  const std::string job_path = dir + "/job.txt";
  if (fs::exists(job_path)) {
    if (readText(job_path) != text)
      throwInFile(job_path,
                  "this folder holds another job (different recording, frames, method "
                  "or settings); use a new --out");
  } else {
    writeFileAtomically(job_path, text);
  }

  const JobInputs inputs = readJobInputs(job);
  JobSummary summary;
  summary.chosen = chosen.size();
  std::vector<RecordedFrame> mine;
  for (size_t k = 0; k < chosen.size(); ++k) {
    if (static_cast<int>(k % static_cast<size_t>(shard.count)) == shard.index)
      mine.push_back(chosen[k]);
  }
  summary.assigned = mine.size();
  size_t handled = 0;
  for (const RecordedFrame& f : mine) {
    FrameOutcome outcome;
    outcome.frame = f;
    if (finished(dir, f.index)) {
      outcome.ok = outcome.skipped = true;
      ++summary.skipped;
    } else {
      outcome = runFrame(job, inputs, f, dir);
      ++(outcome.ok ? summary.done : summary.failed);
    }
    if (progress) progress(++handled, mine.size(), outcome);
  }
  if (merge_when_complete) {
    const bool complete = std::all_of(chosen.begin(), chosen.end(), [&](const RecordedFrame& f) {
      return fs::exists(manifestPath(dir, f.index));
    });
    if (complete) {
      mergeRecordingJob(dir, video);
      summary.merged = true;
    }
  }
  return summary;
}

MergeSummary mergeRecordingJob(const std::string& dir, const VideoOptions& video) {
  if (!(video.fps > 0)) throw Error("--video-fps must be positive");
  const JobRecord job = readJob(dir);
  MergeSummary summary;
  std::string csv = std::string(kCsvHeader) + "\n";
  const std::string video_path = dir + "/" + video.file;
  const std::string video_tmp = dir + "/.tmp-" + std::to_string(getpid()) + "-" + video.file;
  std::optional<AtomicPath> png_dir;
  if (video.png) {
    png_dir.emplace(dir + "/video");
    fs::create_directories(png_dir->temporaryPath());
  }
  cv::VideoWriter writer;
  try {
    for (const RecordedFrame& f : job.chosen) {
      const std::string row_path = manifestPath(dir, f.index);
      if (!fs::exists(row_path)) {
        ++summary.missing;
        csv += std::to_string(f.index) + "," + std::to_string(f.start_us) + "," +
               std::to_string(f.end_us) + ",null,null,null,null,null,null,null,missing,\"\"\n";
        continue;
      }
      const std::string row = readText(row_path);
      csv += row;
      ++summary.rows;
      if (statusOf(row) != "ok") {
        ++summary.failed;
        continue;
      }
      ++summary.ok;
      for (int64_t t : latentTimes(f, job.latent_per_exposure)) {
        const std::string png = dir + "/frames/" + std::to_string(f.index) + "/" + frameName(t);
        const cv::Mat frame = encodeSrgb8(readImageFile(png).image);
        if (!writer.isOpened()) {
          writer = openVideo(video_tmp, video.file, video.fps, frame.size(), frame.channels() == 3);
        }
        writer.write(frame);
        if (png_dir) {
          char name[32];
          std::snprintf(name, sizeof(name), "/%06zu.png", summary.video_frames);
          cv::Mat unit;
          frame.convertTo(unit, CV_32F, 1.0 / 255);
          writeImageFile(png_dir->temporaryPath() + name, unit, 8);
        }
        ++summary.video_frames;
      }
    }
    if (writer.isOpened()) {
      writer.release();
      fs::rename(video_tmp, video_path);
    }
  } catch (...) {
    writer.release();
    std::error_code ec;
    fs::remove(video_tmp, ec);
    throw;
  }
  writeFileAtomically(dir + "/frames.csv", csv);
  if (png_dir) png_dir->commit();
  if (summary.missing == 0) {
    // Every frame has its row, so no worker writes any more: what a killed worker left half
    // written (a frame's temporary folder, a row's temporary file) can go.
    for (const char* sub : {"/frames", "/manifest"}) {
      std::error_code ec;
      for (const auto& e : fs::directory_iterator(dir + sub, ec)) {
        if (e.path().filename().string().find(".tmp-") != std::string::npos)
          fs::remove_all(e.path(), ec);
      }
    }
  }
  return summary;
}

}  // namespace evkit
