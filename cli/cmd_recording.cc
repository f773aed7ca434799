// evkit deblur --recording FILE --frames ... and evkit video DIR.

#include <cstdio>
#include <iostream>

#include "common.h"
#include "deblur_runner.h"
#include "evkit/base/error.h"
#include "evkit/deblur/recording_job.h"
#include "recording_job.h"

namespace evkit::cli {

namespace {

void addVideoOptions(po::options_description& opts) {
  opts.add_options()("video", po::value<std::string>()->default_value("latent.avi"),
                     "the latent video's file name in the job folder: .avi (Motion JPEG) or .mp4")(
      "video-fps", po::value<double>()->default_value(30), "the video's frame rate")(
      "video-png", po::bool_switch(), "also the video's frames as PNG (video/<n>.png)");
}

VideoOptions videoOptions(const po::variables_map& vm) {
  VideoOptions v;
  v.file = vm["video"].as<std::string>();
  v.fps = vm["video-fps"].as<double>();
  v.png = vm["video-png"].as<bool>();
  if (v.file.find('/') != std::string::npos)
    throw UsageError("--video: a file name inside the job folder, not a path");
  if (!(v.fps > 0)) throw UsageError("--video-fps must be positive");
  return v;
}

void printMerge(const MergeSummary& m, const std::string& dir, const VideoOptions& v) {
  std::fprintf(stderr,
               "merged %zu of %zu frames (%zu failed, %zu missing): %s/frames.csv, %s/%s (%zu "
               "latent frames)\n",
               m.ok, m.rows + m.missing, m.failed, m.missing, dir.c_str(), dir.c_str(),
               v.file.c_str(), m.video_frames);
}

}  // namespace

void addRecordingJobOptions(po::options_description& opts) {
  opts.add_options()("frames", po::value<std::string>(),
                     "with --recording: every chosen frame, all | A:B | A,B,C, into "
                     "OUT/frames/<index>/, OUT/frames.csv and one latent video")(
      "shard", po::value<std::string>()->default_value("0/1"),
      "with --frames: this worker's share I/N (a Slurm array task: $SLURM_ARRAY_TASK_ID/N)")(
      "no-merge", po::bool_switch(), "with --frames: leave the merge to `evkit video OUT`")(
      "calib", po::value<std::string>(), "with --frames: calib.txt (fx fy cx cy [k1 k2 p1 p2])")(
      "ground-truth", po::value<std::string>(),
      "with --frames: a folder of <t_us>.png sharp frames (PSNR / SSIM in frames.csv)")(
      "filter-hot-pixels", po::bool_switch(),
      "with --frames: remove hot pixels and refractory bursts before deblurring")(
      "refractory-us", po::value<int64_t>()->default_value(50),
      "with --filter-hot-pixels: the refractory period (0: off)")(
      "seed", po::value<uint64_t>()->default_value(1),
      "with --frames: frame i runs with seed + i (methods with a seed)");
  addVideoOptions(opts);
}

int runRecordingDeblur(const po::variables_map& vm, const std::string& method,
                       MethodSettings settings) {
  RecordingJob job;
  job.recording = vm["recording"].as<std::string>();
  job.frames = vm["frames"].as<std::string>();
  job.method = method;
  job.seed = vm["seed"].as<uint64_t>();
  if (settings.count("seed"))
    throw UsageError("--set seed: a recording's frames are seeded by --seed (frame i: seed + i)");
  job.settings = std::move(settings);
  job.latent_per_exposure = vm["latent"].defaulted() ? 10 : vm["latent"].as<int>();
  if (job.latent_per_exposure < 1) throw UsageError("--latent must be at least 1");
  job.margin_us = parseTimeValue(vm["margin"].as<std::string>(), "margin").us;
  if (vm.count("calib")) job.calib = vm["calib"].as<std::string>();
  if (vm.count("ground-truth")) job.ground_truth = vm["ground-truth"].as<std::string>();
  if (vm["filter-hot-pixels"].as<bool>()) {
    NoiseFilterOptions noise;
    noise.refractory_us = vm["refractory-us"].as<int64_t>();
    if (noise.refractory_us < 0) throw UsageError("--refractory-us must not be negative");
    job.noise_filter = noise;
  }
  Shard shard;
  try {
    shard = parseShard(vm["shard"].as<std::string>());
  } catch (const Error& e) {
    throw UsageError(e.what());
  }
  const VideoOptions video = videoOptions(vm);
  const std::string out = vm["out"].as<std::string>();
  makeMethod(method, job.settings);  // a bad name or setting: a usage error, before any work

  std::optional<Progress> bar;
  size_t failed = 0;
  const JobSummary s = evkit::runRecordingJob(
      job, out, shard, video,
      [&](size_t done, size_t total, const FrameOutcome& o) {
        if (!bar) bar.emplace("frames", static_cast<int64_t>(total));
        if (!o.ok) {
          ++failed;
          bar->finish();
          // One line naming the file and the frame (the reader's messages start with the file).
          if (o.message.rfind(job.recording + ": ", 0) == 0)
            std::fprintf(stderr, "evkit deblur: %s\n", o.message.c_str());
          else
            std::fprintf(stderr, "evkit deblur: %s: frame %zu: %s\n", job.recording.c_str(),
                         o.frame.index, o.message.c_str());
        }
        bar->update(static_cast<int64_t>(done),
                    std::to_string(failed) + " failed" + (o.skipped ? ", skipped finished" : ""));
      },
      !vm["no-merge"].as<bool>());
  if (bar) bar->finish();
  std::fprintf(
      stderr, "shard %d/%d: %zu of %zu chosen frames; %zu done, %zu already finished, %zu failed\n",
      shard.index, shard.count, s.assigned, s.chosen, s.done, s.skipped, s.failed);
  if (s.merged)
    std::fprintf(stderr, "merged: %s/frames.csv, %s/%s\n", out.c_str(), out.c_str(),
                 video.file.c_str());
  return s.failed > 0 ? kExitInputError : kExitOk;
}

int runVideo(const Args& args) {
  po::options_description opts("options");
  opts.add_options()("dir", po::value<std::string>()->required(),
                     "the job folder of `evkit deblur --recording FILE --frames ... --out DIR`");
  addVideoOptions(opts);
  po::positional_options_description pos;
  pos.add("dir", 1);
  po::variables_map vm;
  if (!parseArgs(args, "usage: evkit video DIR [--video latent.mp4] [--video-fps 30]", opts, pos,
                 vm))
    return kExitOk;
  const VideoOptions video = videoOptions(vm);
  const std::string dir = vm["dir"].as<std::string>();
  const MergeSummary m = mergeRecordingJob(dir, video);
  printMerge(m, dir, video);
  return m.failed + m.missing > 0 ? kExitInputError : kExitOk;
}

}  // namespace evkit::cli
