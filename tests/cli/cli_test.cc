// End-to-end tests of the evkit binary on small generated files.

#include <gtest/gtest.h>

#include <fstream>
#include <map>
#include <opencv2/imgcodecs.hpp>
#include <sstream>

#include "evkit/events/image_io.h"
#include "evkit/events/io.h"
#include "evkit/events/npy.h"
#include "evkit/events/random_events.h"
#include "test_util.h"

namespace evkit {
namespace {

using test::runEvkit;
using test::RunResult;
using test::ScratchDir;

int lineCount(const std::string& s) {
  return static_cast<int>(std::count(s.begin(), s.end(), '\n'));
}

std::string makeRecording(const ScratchDir& dir, const std::string& name, size_t count = 20000) {
  RandomEventOptions o;
  o.count = count;
  o.t_start_us = 1605537493718345;
  Recording rec;
  rec.events = randomEvents(o);
  writeRecording(dir / name, rec);
  return dir / name;
}

TEST(Cli, HelpVersionAndUnknownCommand) {
  ScratchDir dir;
  RunResult r = runEvkit("--help", dir);
  EXPECT_EQ(r.exit_code, 0);
  EXPECT_NE(r.out.find("accumulate"), std::string::npos);
  EXPECT_NE(r.out.find("exit codes"), std::string::npos);
  for (const char* cmd : {"info", "convert", "accumulate", "demo"}) {
    r = runEvkit(std::string(cmd) + " --help", dir);
    EXPECT_EQ(r.exit_code, 0) << cmd;
    EXPECT_NE(r.out.find("usage: evkit " + std::string(cmd)), std::string::npos) << cmd;
  }
  r = runEvkit("frobnicate", dir);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_EQ(lineCount(r.err), 1);
}

TEST(Cli, InfoReportsCountsSpanAndRate) {
  ScratchDir dir;
  const std::string txt = makeRecording(dir, "a.txt");
  const Recording rec = readRecording(txt);
  const RunResult r = runEvkit("info " + txt, dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("format:      text (rpg-text layout)"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("sensor:      346 x 260"), std::string::npos);
  const int64_t on = rec.events.countOn();
  const std::string on_text =
      std::to_string(on / 1000) + "," + std::to_string(on % 1000 + 1000).substr(1);
  EXPECT_NE(r.out.find("events:      20,000 (ON " + on_text + ", OFF "), std::string::npos)
      << r.out;
  EXPECT_NE(r.out.find("first:       1605537493718345 us"), std::string::npos) << r.out;
}

TEST(Cli, ConvertRoundTripAndRelativeWindow) {
  ScratchDir dir;
  const std::string txt = makeRecording(dir, "a.txt");
  RunResult r = runEvkit("convert " + txt + " " + (dir / "b.h5") + " --compression blosc-lz4", dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  r = runEvkit("convert " + (dir / "b.h5") + " " + (dir / "c.txt"), dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(test::readText(txt), test::readText(dir / "c.txt"));

  r = runEvkit("convert " + (dir / "b.h5") + " " + (dir / "w.txt") + " --start +1ms --end +5ms",
               dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const Recording all = readRecording(txt), part = readRecording(dir / "w.txt");
  const int64_t t0 = all.events.t.front();
  const EventSpan expected = all.events.sliceTime(t0 + 1000, t0 + 5000);
  ASSERT_EQ(part.events.size(), expected.size());
  EXPECT_EQ(part.events.t.front(), expected.t.front());
  EXPECT_EQ(part.events.t.back(), expected.t.back());
  // Absolute form of the same window.
  r = runEvkit("convert " + txt + " " + (dir / "w2.txt") + " --start " + std::to_string(t0 + 1000) +
                   " --end " + std::to_string(t0 + 5000),
               dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(test::readText(dir / "w.txt"), test::readText(dir / "w2.txt"));
}

TEST(Cli, AccumulateWritesPngNpyAndWindowTable) {
  ScratchDir dir;
  const std::string h5 = makeRecording(dir, "a.h5");
  RunResult r = runEvkit(
      "accumulate " + h5 + " --repr voxel --bins 3 --window 5ms --out " + (dir / "vox"), dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const std::string csv = test::readText(dir / "vox/windows.csv");
  const int windows = lineCount(csv) - 1;
  const Recording rec = readRecording(h5);
  EXPECT_EQ(windows, (rec.events.t.back() - rec.events.t.front()) / 5000 + 1);
  EXPECT_TRUE(test::fs::exists(dir / "vox/000000.png"));
  const NpyArray v = readNpy(dir / "vox/000000.npy");
  EXPECT_EQ(v.shape, (std::vector<size_t>{3, 260, 346}));

  r = runEvkit("accumulate " + h5 + " --repr counts --count 6000 --out " + (dir / "cnt"), dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(lineCount(test::readText(dir / "cnt/windows.csv")), 1 + 4);  // 6000, 6000, 6000, 2000
  const NpyArray c = readNpy(dir / "cnt/000003.npy");
  double total = 0;
  for (float x : c.data) total += x;
  EXPECT_DOUBLE_EQ(total, 2000.0);

  for (const char* repr : {"frame", "normalized", "timesurface"}) {
    r = runEvkit("accumulate " + h5 + " --repr " + repr + " --window 20ms --out " + (dir / repr),
                 dir);
    EXPECT_EQ(r.exit_code, 0) << repr << ": " << r.err;
    EXPECT_TRUE(test::fs::exists(dir / (std::string(repr) + "/000000.npy"))) << repr;
  }
}

TEST(Cli, BadInputGivesOneLineNonZeroExitAndNoPartialOutput) {
  ScratchDir dir;
  // Valid for the first 300k lines (more than one chunk gets written), then broken.
  std::string text = makeRecording(dir, "good.txt", 300000);
  std::string content = test::readText(text) + "1605537499.000000 1 2 7\n";
  test::writeText(dir / "bad.txt", content);
  for (const std::string out : {"out.h5", "out.txt"}) {
    const RunResult r = runEvkit("convert " + (dir / "bad.txt") + " " + (dir / out), dir);
    EXPECT_EQ(r.exit_code, 1);
    EXPECT_EQ(lineCount(r.err), 1) << r.err;
    EXPECT_NE(r.err.find("bad.txt: line 300002: expected 't x y p'; cannot read polarity"),
              std::string::npos)
        << r.err;
    EXPECT_FALSE(test::fs::exists(dir / out));
  }
  const RunResult acc =
      runEvkit("accumulate " + (dir / "bad.txt") + " --out " + (dir / "acc"), dir);
  EXPECT_EQ(acc.exit_code, 1);
  EXPECT_FALSE(test::fs::exists(dir / "acc"));
  EXPECT_EQ(test::countTemporaries(dir.path()), 0);

  const RunResult missing = runEvkit("info " + (dir / "nothing.h5"), dir);
  EXPECT_EQ(missing.exit_code, 1);
  EXPECT_EQ(missing.err, "evkit info: " + (dir / "nothing.h5") + ": no such file\n");
}

TEST(Cli, BadOptionsExitWithTwo) {
  ScratchDir dir;
  const std::string txt = makeRecording(dir, "a.txt", 100);
  for (const std::string& args : std::vector<std::string>{
           "convert " + txt, "convert " + txt + " b.h5 --compression zip",
           "accumulate " + txt + " --out x --repr nope",
           "accumulate " + txt + " --out x --window 5 parsecs", "info " + txt + " --format xyz",
           "accumulate " + txt + " --out x --window 1ms --count 5", std::string("info")}) {
    const RunResult r = runEvkit(args, dir);
    EXPECT_EQ(r.exit_code, 2) << args << ": " << r.err;
    EXPECT_EQ(lineCount(r.err), 1) << args << ": " << r.err;
  }
}

// A bar moving right over 20 frames, 1 ms apart, at absolute Unix-µs times.
void writeMovingBar(const ScratchDir& dir, bool missing_last = false) {
  std::string list;
  for (int f = 0; f < 20; ++f) {
    cv::Mat img(30, 40, CV_32F, cv::Scalar(0.1));
    img(cv::Rect(5 + f, 0, 4, 30)).setTo(0.8);
    const std::string name = "frame" + std::to_string(f) + ".png";
    if (!(missing_last && f == 19)) writeImageFile(dir / name, img, 16);
    list += std::to_string(1605537493000000 + 1000 * f) + " " + name + "\n";
  }
  test::writeText(dir / "timestamps.txt", list);
}

TEST(Cli, SimulateWritesEventsAndBlurryFrames) {
  ScratchDir dir;
  writeMovingBar(dir);
  for (const std::string out : {"sim.h5", "sim.aedat4", "sim.txt"}) {
    const RunResult r =
        runEvkit("simulate " + dir.path().string() + " --out " + (dir / out) +
                     " --exposure-every 5 --duty 0.6 --sigma 0.02 --refractory 50us",
                 dir);
    ASSERT_EQ(r.exit_code, 0) << r.err;
    EXPECT_NE(r.err.find("simulated 20 frames"), std::string::npos) << r.err;
    const Recording rec = readRecording(dir / out);
    EXPECT_GT(rec.events.size(), 500u);
    EXPECT_NO_THROW(validate(rec.events.view(), out));
    EXPECT_GE(rec.events.t.front(), 1605537493000000);
    ASSERT_EQ(rec.frames.size(), 4u) << out;  // exposures of 3 intervals from frames 0, 5, 10, 15
    EXPECT_EQ(rec.frames[1].exposure_start_us, 1605537493005000);
    EXPECT_EQ(rec.frames[1].exposure_end_us, 1605537493008000);
  }
  // The bar's edges jump from 0.1 to 0.8 between frames: far more than C for 5% of the pixels.
  const RunResult warn =
      runEvkit("simulate " + (dir / "timestamps.txt") + " --out " + (dir / "x.h5"), dir);
  ASSERT_EQ(warn.exit_code, 0) << warn.err;
  EXPECT_NE(warn.err.find("warning: 19 of 19 frame intervals change more than 1% of the pixels by "
                          "more than C (worst: 5%)"),
            std::string::npos)
      << warn.err;
}

TEST(Cli, SimulateReportsMissingFramesAndBadOptions) {
  ScratchDir dir;
  writeMovingBar(dir, true);
  RunResult r = runEvkit("simulate " + dir.path().string() + " --out " + (dir / "o.h5"), dir);
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_EQ(lineCount(r.err), 1) << r.err;
  EXPECT_NE(r.err.find("frame19.png: no such image file"), std::string::npos) << r.err;
  EXPECT_FALSE(test::fs::exists(dir / "o.h5"));
  r = runEvkit("simulate " + dir.path().string() + " --out " + (dir / "o.h5") + " --contrast -1",
               dir);
  EXPECT_EQ(r.exit_code, 2) << r.err;
  r = runEvkit("simulate " + dir.path().string() + " --out " + (dir / "o.h5") + " --exposure 5",
               dir);
  EXPECT_EQ(r.exit_code, 2) << r.err;
}

TEST(Cli, SynthWritesAnObservationFolder) {
  ScratchDir dir;
  RunResult r =
      runEvkit("synth --preset box --size 64x48 --blur-px 6 --exposure-us 20000 --seed 3 --out " +
                   (dir / "obs"),
               dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.err.find("blur   6.0 px"), std::string::npos) << r.err;
  for (const char* f : {"blurry.png", "events.h5", "calib.txt", "exposure.txt", "contrast.txt",
                        "gt/poses.txt", "gt/depth.npy"}) {
    EXPECT_TRUE(test::fs::exists(dir / (std::string("obs/") + f))) << f;
  }
  EXPECT_EQ(test::readText(dir / "obs/contrast.txt"), "0.2 0.2\n");
  r = runEvkit("synth --preset sphere --out " + (dir / "x"), dir);
  EXPECT_EQ(r.exit_code, 2) << r.err;
  EXPECT_NE(r.err.find("unknown preset 'sphere'"), std::string::npos) << r.err;
  r = runEvkit("synth --preset box --suite standard --out " + (dir / "x"), dir);
  EXPECT_EQ(r.exit_code, 2) << r.err;
  r = runEvkit("synth --scene " + (dir / "missing.yaml") + " --out " + (dir / "x"), dir);
  EXPECT_EQ(r.exit_code, 1) << r.err;
  EXPECT_FALSE(test::fs::exists(dir / "x"));
}

TEST(Cli, DeblurCompareAndMetricsOnASyntheticObservation) {
  ScratchDir dir;
  RunResult r = runEvkit(
      "synth --preset text --size 80x60 --blur-px 8 --exposure-us 20000 --out " + (dir / "obs"),
      dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  r = runEvkit("deblur " + (dir / "obs") + " --method edi --latent 3 --out " + (dir / "edi"), dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.err.find("edi: 3 frames"), std::string::npos)
      << r.err;  // start, middle, end (= gt times)
  const std::string summary = test::readText(dir / "edi/summary.json");
  EXPECT_NE(summary.find("\"method\": \"edi\""), std::string::npos) << summary;
  EXPECT_NE(summary.find("\"psnr_mid\": "), std::string::npos);
  EXPECT_EQ(summary.find("\"psnr_mid\": null"), std::string::npos) << summary;
  EXPECT_TRUE(test::fs::exists(dir / "edi/latent.avi"));
  EXPECT_TRUE(test::fs::exists(dir / "edi/1600000000010000.png"));
  r = runEvkit("compare " + (dir / "obs") + " --methods blurry,edi --out " + (dir / "cmp"), dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("blurry"), std::string::npos);
  EXPECT_NE(r.out.find("edi"), std::string::npos);
  EXPECT_TRUE(test::fs::exists(dir / "cmp/side_by_side.png"));
  r = runEvkit(
      "metrics " + (dir / "edi/1600000000010000.png") + " " + (dir / "obs/gt/1600000000010000.png"),
      dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("PSNR"), std::string::npos);
  EXPECT_NE(r.out.find("BRISQUE"), std::string::npos);
  // Mistakes: unknown method or setting (2), missing folder (1), times outside the exposure (2).
  EXPECT_EQ(
      runEvkit("deblur " + (dir / "obs") + " --method magic --out " + (dir / "x"), dir).exit_code,
      2);
  EXPECT_EQ(
      runEvkit("deblur " + (dir / "obs") + " --set speed=11 --out " + (dir / "x"), dir).exit_code,
      2);
  EXPECT_EQ(runEvkit("deblur " + (dir / "nothing") + " --out " + (dir / "x"), dir).exit_code, 1);
  EXPECT_EQ(runEvkit("deblur " + (dir / "obs") + " --times 5 --out " + (dir / "x"), dir).exit_code,
            2);
  EXPECT_FALSE(test::fs::exists(dir / "x"));
}

TEST(Cli, DeblurWithBenerfWritesFramesTrajectoryDisparityCurveAndCheckpoint) {
  ScratchDir dir;
  RunResult r = runEvkit(
      "synth --preset planes --size 48x36 --blur-px 6 --exposure-us 20000 --out " + (dir / "obs"),
      dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  r = runEvkit("deblur " + (dir / "obs") +
                   " --method benerf --set field=hash --set budget=fast --set iterations=30 --set "
                   "rays=128 " +
                   "--set samples=8 " + "--set checkpoint=" + (dir / "ckpt") +
                   " --latent 3 --out " + (dir / "nerf"),
               dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.err.find("benerf: 3 frames"), std::string::npos) << r.err;
  for (const char* file :
       {"1600000000000000.png", "1600000000010000.png", "1600000000020000.png", "latent.avi",
        "trajectory.txt", "disparity.npy", "disparity.png", "summary.json"}) {
    EXPECT_TRUE(test::fs::exists(dir / (std::string("nerf/") + file))) << file;
  }
  EXPECT_TRUE(test::fs::exists(dir / "ckpt"));
  const std::string summary = test::readText(dir / "nerf/summary.json");
  EXPECT_NE(summary.find("\"training_curve\": [[25, "), std::string::npos) << summary;
  EXPECT_NE(summary.find("\"training_psnr\": [["), std::string::npos) << summary;
  EXPECT_NE(summary.find("\"virtual_views\": "), std::string::npos) << summary;
  EXPECT_NE(summary.find("\"blur_fit_psnr\": "), std::string::npos) << summary;
  EXPECT_NE(summary.find("\"final_event_term\": "), std::string::npos) << summary;
  EXPECT_NE(summary.find("\"blur_weight\": 1"), std::string::npos) << summary;  // not a dim frame
  // Resuming from the finished checkpoint trains no further and gives the same frames.
  r = runEvkit("deblur " + (dir / "obs") +
                   " --method benerf --set field=hash --set budget=fast --set iterations=30 --set "
                   "rays=128 " +
                   "--set samples=8 " + "--set resume=" + (dir / "ckpt") + " --latent 3 --out " +
                   (dir / "again"),
               dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(test::readText(dir / "again/1600000000010000.png"),
            test::readText(dir / "nerf/1600000000010000.png"));
  // Mistakes: a bad budget or setting value is a usage error; a corrupt checkpoint one error line.
  EXPECT_EQ(runEvkit("deblur " + (dir / "obs") + " --method benerf --set budget=slow --out " +
                         (dir / "x"),
                     dir)
                .exit_code,
            2);
  EXPECT_EQ(
      runEvkit("deblur " + (dir / "obs") + " --method benerf --set alpha=2 --out " + (dir / "x"),
               dir)
          .exit_code,
      2);
  EXPECT_EQ(runEvkit("deblur " + (dir / "obs") + " --method benerf --set blur_rays=0 --out " +
                         (dir / "x"),
                     dir)
                .exit_code,
            2);
  EXPECT_EQ(runEvkit("deblur " + (dir / "obs") + " --method benerf --set event_rays=-1 --out " +
                         (dir / "x"),
                     dir)
                .exit_code,
            2);
  // A setting out of range: exit code 2 and a message naming it.
  const auto expectUsageError = [&](const std::string& setting, const std::string& message) {
    const auto u = runEvkit(
        "deblur " + (dir / "obs") + " --method benerf --set " + setting + " --out " + (dir / "x"),
        dir);
    EXPECT_EQ(u.exit_code, 2) << setting;
    EXPECT_NE(u.err.find(message), std::string::npos) << u.err;
  };
  expectUsageError("windows=0", "windows=0 must be an integer >= 1");
  expectUsageError("coarse_to_fine=1.5", "coarse_to_fine=1.5 must be in [0, 1]");
  expectUsageError("dim_frame=2", "dim_frame=2 must be in [0, 1]");
  expectUsageError("prefit=-5", "prefit=-5");
  std::ofstream(dir / "bad.ckpt") << "EVKBNRF1 not really";
  r = runEvkit("deblur " + (dir / "obs") + " --method benerf --set field=hash --set resume=" +
                   (dir / "bad.ckpt") + " --out " + (dir / "x"),
               dir);
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("bad.ckpt"), std::string::npos) << r.err;
  EXPECT_FALSE(test::fs::exists(dir / "x"));
}

TEST(Cli, DeblurStraightFromARecordingWithExtract) {
  ScratchDir dir;
  Recording rec;
  rec.events = randomEvents({});
  Frame f;
  f.image = cv::Mat(260, 346, CV_32F, cv::Scalar(0.4));
  f.exposure_start_us = rec.events.t[1000];
  f.exposure_end_us = rec.events.t[20000];
  rec.frames.push_back(f);
  writeRecording(dir / "rec.h5", rec);
  const RunResult r = runEvkit("deblur --recording " + (dir / "rec.h5") + " --frame 0 --extract " +
                                   (dir / "obs") + " --set contrast=0.2 --out " + (dir / "out"),
                               dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_TRUE(test::fs::exists(dir / "obs/events.h5"));
  EXPECT_EQ(readRecording(dir / "obs/events.h5").events.size(),
            rec.events.sliceTime(f.exposure_start_us, f.exposure_end_us + 1).size());
  EXPECT_EQ(
      runEvkit("deblur --recording " + (dir / "rec.h5") + " --frame 4 --out " + (dir / "o2"), dir)
          .exit_code,
      1);
}

TEST(Cli, BenchKeepsFinishedRunsWhenALaterOneFailsAndResumes) {
  ScratchDir dir;
  const std::string common =
      "bench --suite hard --scenes hard_blur2,hard_noevents --size 48x32 --budgets 12 --threads 1 "
      "--set benerf.field=hash --out " +
      (dir / "b");
  // BeNeRF cannot start (its checkpoint is missing): its rows fail, blurry's and EDI's are kept.
  RunResult r = runEvkit(
      common + " --methods blurry,edi,benerf --set benerf.resume=" + (dir / "missing.ckpt"), dir);
  EXPECT_EQ(r.exit_code, 1) << r.err;
  EXPECT_NE(r.err.find("2 runs failed"), std::string::npos) << r.err;
  std::string csv = test::readText(dir / "b/results.csv");
  EXPECT_EQ(lineCount(csv), 1 + 2 * 3) << csv;
  EXPECT_NE(csv.find("hard,hard_blur2,tiny blur: 2 px,edi,-,ok,"), std::string::npos) << csv;
  EXPECT_NE(csv.find("benerf,12 it,failed: "), std::string::npos) << csv;
  std::string md = test::readText(dir / "b/results.md");
  EXPECT_NE(md.find("| hard_noevents | no events in the exposure |"), std::string::npos) << md;
  EXPECT_NE(md.find("benerf 12 it: failed"), std::string::npos) << md;
  // Again without the bad setting: only BeNeRF runs (4 kept), and every row is healthy.
  r = runEvkit(common + " --methods blurry,edi,benerf", dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.err.find("2 to run, 4 kept"), std::string::npos) << r.err;
  csv = test::readText(dir / "b/results.csv");
  EXPECT_EQ(lineCount(csv), 1 + 2 * 3) << csv;
  EXPECT_EQ(csv.find("failed"), std::string::npos) << csv;
  md = test::readText(dir / "b/results.md");
  EXPECT_NE(md.find("| benerf | 12 it | "), std::string::npos) << md;
  EXPECT_NE(md.find("| hard_blur2 | tiny blur: 2 px | "), std::string::npos) << md;
  const cv::Mat plot = cv::imread(dir / "b/speed_vs_error.png");
  EXPECT_EQ(plot.cols, 960);
  EXPECT_TRUE(test::fs::exists(dir / "b/runs/hard_blur2/benerf_12it/trajectory.txt"));
  // The suite's thresholds (contrast.txt) reach both methods.
  EXPECT_NE(
      test::readText(dir / "b/runs/hard_blur2/edi/summary.json").find("\"contrast_searched\": 0"),
      std::string::npos);
  EXPECT_NE(test::readText(dir / "b/runs/hard_blur2/benerf_12it/summary.json")
                .find("\"events_normalised\": 0"),
            std::string::npos);
  EXPECT_TRUE(test::fs::exists(dir / "b/suite/hard_noevents/blurry.png"));
  // With no events EDI returns the blurry frame itself.
  EXPECT_EQ(test::readText(dir / "b/runs/hard_noevents/edi/1600000000050000.png"),
            test::readText(dir / "b/runs/hard_noevents/blurry/1600000000050000.png"));
  // Mistakes on the command line.
  EXPECT_EQ(runEvkit("bench --methods edi,magic --out " + (dir / "x"), dir).exit_code, 2);
  EXPECT_EQ(runEvkit("bench --budgets 10,slow --out " + (dir / "x"), dir).exit_code, 2);
  EXPECT_EQ(runEvkit("bench --suite hard --scenes nope --out " + (dir / "x"), dir).exit_code, 2);
  EXPECT_FALSE(test::fs::exists(dir / "x"));
}

TEST(Cli, BenchWithUnknownContrastHidesTheThresholdsFromEveryMethod) {
  ScratchDir dir;
  const std::string common =
      "bench --suite all --scenes hard_blur2,planes_blur15 --size 48x32 --methods edi,benerf "
      "--budgets 12 --threads 1 --set benerf.field=hash --data " +
      (dir / "suite");
  const RunResult r = runEvkit(common + " --unknown-contrast --out " + (dir / "unknown"), dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(test::readText(dir / "unknown/results.md").find("thresholds not given to the methods"),
            std::string::npos);
  const auto summary = [&](const std::string& run, const std::string& scene,
                           const std::string& method) {
    return test::readText(dir / (run + "/runs/" + scene + "/" + method + "/summary.json"));
  };
  for (const std::string scene : {"hard_blur2", "planes_blur15"}) {
    // The observations have contrast.txt (C = 0.2; without the flag both methods use it, as the
    // bench test above checks), yet EDI searches c.
    EXPECT_EQ(test::readText(dir / ("suite/" + scene + "/contrast.txt")), "0.2 0.2\n");
    EXPECT_NE(summary("unknown", scene, "edi").find("\"contrast_searched\": 1"), std::string::npos);
    EXPECT_NE(summary("unknown", scene, "edi").find(" by the sharpness search\""),
              std::string::npos);
  }
  // hard_blur2 (2 px of blur at 48 x 32): EDI's search runs to the end of its range, so BeNeRF
  // normalises its events, with the real-data weight (the paper's 2 at 1,024 event pixels, 4 at
  // fast's 2,048).
  EXPECT_NE(summary("unknown", "hard_blur2", "edi").find("\"contrast_on\": 0.5"),
            std::string::npos);
  const std::string normalised = summary("unknown", "hard_blur2", "benerf_12it");
  EXPECT_NE(normalised.find("\"events_normalised\": 1"), std::string::npos) << normalised;
  EXPECT_NE(normalised.find("\"beta\": 4"), std::string::npos) << normalised;
  EXPECT_EQ(normalised.find("contrast_estimated"), std::string::npos) << normalised;
  // planes_blur15: the search lands inside its range, and BeNeRF uses its c in the direct form.
  const std::string edi = summary("unknown", "planes_blur15", "edi");
  const size_t at = edi.find("\"contrast_on\": ");
  ASSERT_NE(at, std::string::npos) << edi;
  const double c = std::stod(edi.substr(at + 15));
  EXPECT_GT(c, 0.11);
  EXPECT_LT(c, 0.49);
  const std::string direct = summary("unknown", "planes_blur15", "benerf_12it");
  EXPECT_NE(direct.find("\"events_normalised\": 0"), std::string::npos) << direct;
  EXPECT_NE(direct.find("\"contrast_estimated\": " + edi.substr(at + 15, 6)), std::string::npos)
      << direct;
}

TEST(Cli, DemoDeblursTheDefaultSceneWithEveryMethod) {
  ScratchDir dir;
  const RunResult r =
      runEvkit("demo --size 64x48 --blur-px 6 --budget 3 --threads 1 --out " + (dir / "demo"), dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  for (const char* line : {"blurry ", "edi ", "benerf "})
    EXPECT_NE(r.out.find(line), std::string::npos) << r.out;
  for (const char* f : {"observation/blurry.png", "observation/events.h5", "side_by_side.png",
                        "speed_vs_error.png", "results.csv", "results.md", "edi/latent.avi",
                        "benerf/trajectory.txt", "benerf/disparity.png", "benerf/summary.json"}) {
    EXPECT_TRUE(test::fs::exists(dir / (std::string("demo/") + f))) << f;
  }
  // The side-by-side image: blurry, edi, benerf and the ground truth, each 64 wide.
  EXPECT_EQ(cv::imread(dir / "demo/side_by_side.png").cols, 4 * 64);
  const std::string csv = test::readText(dir / "demo/results.csv");
  EXPECT_EQ(lineCount(csv), 4) << csv;
  EXPECT_EQ(csv.find("failed"), std::string::npos) << csv;
  // EDI sharpens the blurry frame of the default scene even with the sensor's noise.
  std::map<std::string, double> psnr;
  std::istringstream lines(csv);
  for (std::string line; std::getline(lines, line);) {
    std::vector<std::string> f;
    std::istringstream fields(line);
    for (std::string v; std::getline(fields, v, ',');) f.push_back(v);
    if (f.size() > 7 && f[0] == "demo") psnr[f[3]] = std::stod(f[7]);
  }
  ASSERT_EQ(psnr.size(), 3u) << csv;
  EXPECT_GT(psnr["edi"], psnr["blurry"] + 3) << csv;
}

TEST(Cli, DemoFormatsTourRoundTripsARecording) {
  ScratchDir dir;
  const RunResult r = runEvkit("demo --formats --events 30000 --out " + (dir / "demo"), dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("round trip exact"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("events:      30,000"), std::string::npos) << r.out;
  for (const char* f : {"random.txt", "random.h5", "roundtrip.txt", "accumulated.png"}) {
    EXPECT_TRUE(test::fs::exists(dir / (std::string("demo/") + f))) << f;
  }
}

}  // namespace
}  // namespace evkit
