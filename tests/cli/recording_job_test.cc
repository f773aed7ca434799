// A whole recording deblurred by `evkit deblur --recording FILE --frames ...`: shards merge into
// the single run's output, a killed run resumes without redoing finished frames, a frame without
// events is deblurred, a corrupt frame is one line and exit code 1 while the others are done.
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/stat.h>
#include <unistd.h>

#include <chrono>
#include <thread>

#include "evkit/events/io.h"
#include "test_util.h"

namespace evkit::test {
namespace {

// A small synthetic recording made once for the suite: 4 frames of 48x36, frame 2's exposure
// without events.
class RecordingJobTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    root_ = new fs::path(fs::temp_directory_path() /
                         ("evkit_recording_job_" + std::to_string(::getpid())));
    fs::remove_all(*root_);
    fs::create_directories(*root_);
    const std::string cmd = std::string(EVKIT_BINARY) +
                            " synth --recording --preset planes --size 48x36 --blur-px 5 "
                            "--exposure-us 40000 --frames 4 --frame-interval-us 50000 "
                            "--drop-frame-events 2 --supersample 1 --out " +
                            (*root_ / "rec").string() + " 2>/dev/null";
    ASSERT_EQ(std::system(cmd.c_str()), 0);
  }
  static void TearDownTestSuite() {
    fs::remove_all(*root_);
    delete root_;
  }
  static std::string rec(const std::string& name) { return (*root_ / "rec" / name).string(); }
  static fs::path* root_;
};
fs::path* RecordingJobTest::root_ = nullptr;

// frames.csv without the wall-time column (the only field that differs between runs).
std::string csvWithoutWallTime(const std::string& path) {
  std::istringstream in(readText(path));
  std::string line, out;
  while (std::getline(in, line)) {
    std::vector<std::string> f;
    std::stringstream fields(line);
    std::string field;
    for (int k = 0; k < 6 && std::getline(fields, field, ','); ++k) f.push_back(field);
    std::string rest;
    std::getline(fields, rest);
    out += f[0] + "," + f[1] + "," + f[2] + "," + f[3] + "," + f[4] + "," + rest + "\n";
  }
  return out;
}

std::vector<std::string> csvRows(const std::string& path) {
  std::istringstream in(readText(path));
  std::vector<std::string> rows;
  std::string line;
  std::getline(in, line);  // header
  while (std::getline(in, line)) rows.push_back(line);
  return rows;
}

TEST_F(RecordingJobTest, SyntheticRecordingHoldsItsFramesInBothFormats) {
  const Recording a = readRecording(rec("recording.aedat4"));
  const Recording h = readRecording(rec("recording.h5"));
  ASSERT_EQ(a.frames.size(), 4u);
  ASSERT_EQ(h.frames.size(), 4u);
  for (size_t k = 0; k < 4; ++k) {
    const int64_t start = 1'600'000'000'000'000 + 50'000 * static_cast<int64_t>(k);
    EXPECT_EQ(a.frames[k].exposure_start_us, start);
    EXPECT_EQ(a.frames[k].exposure_end_us, start + 40'000);
    EXPECT_EQ(h.frames[k].exposure_start_us, start);
    EXPECT_EQ(a.frames[k].image.size(), cv::Size(48, 36));
    EXPECT_EQ(cv::norm(a.frames[k].image, h.frames[k].image, cv::NORM_INF), 0.0);
    // Ground truth at the exposure's start, middle and end.
    for (int64_t t : {start, start + 20'000, start + 40'000})
      EXPECT_TRUE(fs::exists(rec("gt/" + std::to_string(t) + ".png"))) << t;
  }
  EXPECT_EQ(a.events.t, h.events.t);
  EXPECT_EQ(a.events.p, h.events.p);
  // Continuous events between the exposures, none in frame 2's (its events were dropped).
  const auto in = [&](int64_t t0, int64_t t1) { return a.events.sliceTime(t0, t1).size(); };
  const int64_t t0 = 1'600'000'000'000'000;
  EXPECT_GT(in(t0 + 40'001, t0 + 50'000), 100u);
  EXPECT_EQ(in(t0 + 100'000, t0 + 140'001), 0u);
  EXPECT_GT(in(t0 + 150'000, t0 + 190'001), 1000u);
}

TEST_F(RecordingJobTest, ThreeShardsMergedEqualOneRun) {
  ScratchDir dir;
  const std::string common = "deblur --recording " + rec("recording.h5") +
                             " --frames all --method edi --calib " + rec("calib.txt") +
                             " --ground-truth " + rec("gt") + " --latent 4";
  RunResult r = runEvkit(common + " --out " + (dir / "one"), dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.err.find("4 done, 0 already finished, 0 failed"), std::string::npos) << r.err;
  for (int i = 0; i < 3; ++i) {
    r = runEvkit(
        common + " --shard " + std::to_string(i) + "/3 --no-merge --out " + (dir / "three"), dir);
    ASSERT_EQ(r.exit_code, 0) << r.err;
  }
  EXPECT_FALSE(fs::exists(dir / "three/frames.csv"));  // --no-merge
  r = runEvkit("video " + (dir / "three"), dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.err.find("merged 4 of 4 frames (0 failed, 0 missing)"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("(16 latent frames)"), std::string::npos) << r.err;  // 4 per exposure

  EXPECT_EQ(csvWithoutWallTime(dir / "one/frames.csv"),
            csvWithoutWallTime(dir / "three/frames.csv"));
  int compared = 0;
  for (const auto& e : fs::recursive_directory_iterator(dir / "one/frames")) {
    if (e.path().extension() != ".png" && e.path().filename() != "trajectory.txt") continue;
    const fs::path other = fs::path(dir / "three") / fs::relative(e.path(), dir / "one");
    EXPECT_EQ(readText(e.path().string()), readText(other.string())) << other;
    ++compared;
  }
  EXPECT_GE(compared, 4 * 5);  // 4 latent frames + the middle per exposure
  EXPECT_EQ(readText(dir / "one/latent.avi"), readText(dir / "three/latent.avi"));
  // The same merge as MPEG-4 with the video's frames as PNG.
  r = runEvkit("video " + (dir / "three") + " --video latent.mp4 --video-png", dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_GT(fs::file_size(dir / "three/latent.mp4"), 1000u);
  EXPECT_TRUE(fs::exists(dir / "three/video/000015.png"));
  EXPECT_FALSE(fs::exists(dir / "three/video/000016.png"));
  // Ground truth where it exists: every frame has its PSNR.
  for (const std::string& row : csvRows(dir / "one/frames.csv"))
    EXPECT_EQ(row.find("null"), std::string::npos) << row;
}

TEST_F(RecordingJobTest, FrameWithoutEventsIsDeblurred) {
  ScratchDir dir;
  const RunResult r = runEvkit("deblur --recording " + rec("recording.aedat4") +
                                   " --frames 2 --method edi --calib " + rec("calib.txt") +
                                   " --out " + (dir / "job"),
                               dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const auto rows = csvRows(dir / "job/frames.csv");
  ASSERT_EQ(rows.size(), 1u);
  EXPECT_EQ(rows[0].rfind("2,1600000000100000,1600000000140000,0,edi,", 0), 0u) << rows[0];
  EXPECT_NE(rows[0].find(",ok,"), std::string::npos);
  EXPECT_TRUE(fs::exists(dir / "job/frames/2/1600000000120000.png"));
}

TEST_F(RecordingJobTest, KilledRunResumesWithoutRedoingFinishedFrames) {
  ScratchDir dir;
  const std::string out = dir / "job";
  const std::string args = "deblur --recording " + rec("recording.h5") +
                           " --frames all --method benerf --set iterations=300 --set table=10 "
                           "--set levels=2 --set rays=256 --set threads=1 --latent 2 --calib " +
                           rec("calib.txt") + " --out " + out;
  // Started, then killed (SIGKILL: no clean-up) once the first frame is finished.
  const pid_t pid = fork();
  ASSERT_GE(pid, 0);
  if (pid == 0) {
    const std::string cmd = std::string(EVKIT_BINARY) + " " + args + " >/dev/null 2>&1";
    execl("/bin/sh", "sh", "-c", ("exec " + cmd).c_str(), static_cast<char*>(nullptr));
    _exit(127);
  }
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(300);
  while (!fs::exists(out + "/manifest/0.csv") && std::chrono::steady_clock::now() < deadline)
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  ::kill(pid, SIGKILL);
  int status = 0;
  ::waitpid(pid, &status, 0);
  ASSERT_TRUE(fs::exists(out + "/manifest/0.csv")) << "the first frame did not finish in 300 s";
  ASSERT_FALSE(fs::exists(out + "/frames.csv")) << "the run finished before it was killed";
  struct stat before {};
  ASSERT_EQ(::stat((out + "/frames/0/summary.json").c_str(), &before), 0);
  const std::string first_row = readText(out + "/manifest/0.csv");

  const RunResult r = runEvkit(args, dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.err.find("already finished"), std::string::npos) << r.err;
  struct stat after {};
  ASSERT_EQ(::stat((out + "/frames/0/summary.json").c_str(), &after), 0);
  EXPECT_EQ(before.st_ino, after.st_ino);  // frame 0's outputs were not written again
  EXPECT_EQ(before.st_mtim.tv_nsec, after.st_mtim.tv_nsec);
  EXPECT_EQ(readText(out + "/manifest/0.csv"), first_row);
  const auto rows = csvRows(out + "/frames.csv");
  ASSERT_EQ(rows.size(), 4u);
  for (const std::string& row : rows) EXPECT_NE(row.find(",ok,"), std::string::npos) << row;
  EXPECT_EQ(countTemporaries(out), 0);  // the killed run's half-written frame is gone
}

TEST_F(RecordingJobTest, CorruptFrameIsOneLineAndTheOthersAreDone) {
  ScratchDir dir;
  // Frames 0 and 2 from the synthetic recording, frame 1 with its exposure ending before it starts.
  Recording source = readRecording(rec("recording.h5"));
  ASSERT_GE(source.frames.size(), 3u);
  source.frames.resize(3);
  std::swap(source.frames[1].exposure_start_us, source.frames[1].exposure_end_us);
  const std::string path = dir / "corrupt.h5";
  writeRecording(path, source);
  const RunResult r = runEvkit(
      "deblur --recording " + path + " --frames all --method edi --out " + (dir / "job"), dir);
  EXPECT_EQ(r.exit_code, 1) << r.err;
  std::istringstream lines(r.err);
  std::string line, error;
  int errors = 0;
  while (std::getline(lines, line)) {
    if (line.rfind("evkit deblur: ", 0) == 0) ++errors, error = line;
  }
  EXPECT_EQ(errors, 1) << r.err;
  EXPECT_NE(error.find("corrupt.h5: frame 1 has no exposure interval"), std::string::npos) << error;
  const auto rows = csvRows(dir / "job/frames.csv");
  ASSERT_EQ(rows.size(), 3u);
  EXPECT_NE(rows[0].find(",ok,"), std::string::npos);
  EXPECT_NE(rows[1].find(",failed,\"" + path + ": frame 1 has no exposure interval"),
            std::string::npos)
      << rows[1];
  EXPECT_NE(rows[2].find(",ok,"), std::string::npos);
  EXPECT_TRUE(fs::exists(dir / "job/latent.avi"));
}

TEST_F(RecordingJobTest, RefusesBadSelectionsAndAnotherJobsFolder) {
  ScratchDir dir;
  const std::string base = "deblur --recording " + rec("recording.h5") + " --method edi";
  RunResult r = runEvkit(base + " --frames 7 --out " + (dir / "a"), dir);
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("frame 7 does not exist (the recording has 4 frames)"), std::string::npos)
      << r.err;
  r = runEvkit(base + " --frames 3:1 --out " + (dir / "a"), dir);
  EXPECT_NE(r.err.find("0 <= A < B <= 4"), std::string::npos) << r.err;
  r = runEvkit(base + " --frames all --shard 3/3 --out " + (dir / "a"), dir);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("0 <= I < N"), std::string::npos) << r.err;
  ASSERT_EQ(runEvkit(base + " --frames 0:2 --out " + (dir / "b"), dir).exit_code, 0);
  r = runEvkit(base + " --frames 0:3 --out " + (dir / "b"), dir);
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("holds another job"), std::string::npos) << r.err;
}

}  // namespace
}  // namespace evkit::test
