// A whole recording deblurred frame by frame into a sharp high-frame-rate video: `evkit deblur
// --recording FILE --frames all --out DIR` on one machine, or N workers each with `--shard I/N`
// (a Slurm job array), then one merge (`evkit video DIR`, or the last worker).
//
// The job folder:
//   job.txt                   what the job is (recording, frames, method, settings, latent times);
//                             every worker checks it, so two jobs never mix in one folder
//   frames/<index>/           one frame's outputs (writeMethodOutputs: latent PNGs, trajectory,
//                             summary.json), written atomically
//   manifest/<index>.csv      the frame's row of frames.csv, written after its folder: a frame
//                             with a row "ok" is finished and never redone
//   frames.csv, latent.avi    the merge: one row per chosen frame, one continuous latent video
//   video/<n>.png             with --video-png, the video's frames as PNG (sRGB, 8-bit)
//
// Deterministic: each frame's seed is the job's seed plus its index, so the result does not depend
// on how the frames were split between workers. Bounded memory: a worker holds one frame's events
// (a time-window read).
#pragma once

#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "evkit/deblur/deblurrer.h"
#include "evkit/events/filters.h"

namespace evkit {

// A frame of a recording: its index (in file order) and exposure.
struct RecordedFrame {
  size_t index = 0;
  int64_t start_us = 0, end_us = 0;
};

// Every frame of a recording, in one pass of bounded memory.
std::vector<RecordedFrame> listFrames(const std::string& path);

// "all", "A:B" (A to B-1; either end may be left out), or "A,B,C": indices into `count` frames,
// sorted and unique. Throws evkit::Error naming the bad part.
std::vector<size_t> parseFrameSelection(const std::string& spec, size_t count);

struct Shard {
  int index = 0, count = 1;  // this worker is `index` of `count` (0-based)
};
// "I/N" with 0 <= I < N.
Shard parseShard(const std::string& spec);

struct RecordingJob {
  std::string recording;
  std::string frames = "all";
  std::string method = "edi";
  MethodSettings settings;
  int latent_per_exposure = 10;  // latent frames from exposure start to end, for the video
  int64_t margin_us = 0;         // events this far beyond the exposure
  std::string calib;             // calib.txt; else the recording's, else fx = 0.9 width, centred
  std::string ground_truth;      // a folder of <t_us>.png sharp frames (PSNR / SSIM where present)
  std::optional<NoiseFilterOptions> noise_filter;  // hot pixels and refractory bursts
  uint64_t seed = 1;  // frame i runs with seed + i (methods with a seed)
};

struct VideoOptions {
  std::string file = "latent.avi";  // .avi (Motion JPEG) or .mp4 (MPEG-4 part 2)
  double fps = 30;
  bool png = false;  // also video/<n>.png
};

struct FrameOutcome {
  RecordedFrame frame;
  bool ok = false;
  bool skipped = false;  // finished before (its manifest row says ok)
  std::string message;   // the error line when not ok
  double wall_s = 0;
};

struct JobSummary {
  size_t chosen = 0;    // frames the job covers (all shards)
  size_t assigned = 0;  // this shard's share
  size_t done = 0, skipped = 0, failed = 0;
  bool merged = false;  // this worker wrote frames.csv and the video
};

// Runs this shard's share of the job into `dir` (frames i of the chosen list with i % count ==
// index), skipping finished frames. A frame's failure is reported and recorded, and the others go
// on. When every chosen frame has a row afterwards (this was the last worker), merges.
// `progress` is called after each frame with (frames handled, frames assigned, outcome).
JobSummary runRecordingJob(
    const RecordingJob& job, const std::string& dir, Shard shard, const VideoOptions& video,
    const std::function<void(size_t, size_t, const FrameOutcome&)>& progress = {},
    bool merge_when_complete = true);

struct MergeSummary {
  size_t rows = 0, ok = 0, failed = 0, missing = 0;
  size_t video_frames = 0;
};
// Writes frames.csv and the continuous latent video from what the workers finished in `dir`
// (atomically; missing frames are listed and left out of the video).
MergeSummary mergeRecordingJob(const std::string& dir, const VideoOptions& video);

}  // namespace evkit
