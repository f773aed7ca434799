// Thousands of bad files read in one process: every reader must release what it opened when it
// throws (file descriptors, HDF5 identifiers, codec contexts, memory). A reader that leaks shows
// here as a growing descriptor count; LeakSanitizer reports leaked memory in the sanitizer build.

#include <gtest/gtest.h>
#include <unistd.h>

#include <cstring>
#include <fstream>
#include <random>
#include <string>
#include <vector>

#include "evkit/base/error.h"
#include "evkit/events/io.h"
#include "evkit/events/random_events.h"
#include "open_descriptors.h"
#include "test_util.h"

namespace evkit {
namespace {

using test::kSanitized;
using test::openDescriptors;
using test::ScratchDir;

// Resident set size in kB (VmRSS of /proc/self/status); -1 when unknown.
long residentKb() {
  std::ifstream status("/proc/self/status");
  std::string line;
  while (std::getline(status, line)) {
    if (line.rfind("VmRSS:", 0) == 0) return std::stol(line.substr(6));
  }
  return -1;
}

std::string bytesOf(const std::string& path) { return test::readText(path); }

void writeBytes(const std::string& path, const std::string& bytes) {
  std::ofstream(path, std::ios::binary | std::ios::trunc)
      .write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

struct Seed {
  Format format;
  std::string extension;
  std::string bytes;
};

// One valid (or nearly valid) file per format: written by evkit where it can write the format,
// hand-made headers and records for the read-only ones.
std::vector<Seed> makeSeeds(const ScratchDir& dir) {
  Recording rec;
  rec.events = randomEvents({.count = 400, .sensor = {64, 48}, .seed = 3});
  Frame frame;
  frame.image = cv::Mat(48, 64, CV_32F, cv::Scalar(0.5));
  frame.exposure_start_us = rec.events.t.front();
  frame.exposure_end_us = rec.events.t.front() + 1000;
  rec.frames.push_back(frame);
  std::vector<Seed> seeds;
  for (const auto& [format, ext] : {std::pair{Format::kText, std::string(".txt")},
                                    {Format::kHdf5, ".h5"},
                                    {Format::kAedat4, ".aedat4"}}) {
    const std::string path = dir / ("seed" + ext);
    Recording written = rec;
    if (format == Format::kText)
      written.frames.clear();  // a text file keeps its frames in a folder
    writeRecording(path, written, format);
    seeds.push_back({format, ext, bytesOf(path)});
  }
  const auto raw = [](const char* s, size_t n) { return std::string(s, n); };
  seeds.push_back(
      {Format::kAedat2, ".aedat",
       "#!AER-DAT2.0\r\n# This is a raw AE data file created by the DAVIS240C\r\n" +
           raw("\x00\x01\x02\x00\x00\x00\x10\x00\x00\x21\x04\x00\x00\x00\x10\x08", 16)});
  seeds.push_back(
      {Format::kAedat31, ".aedat",
       "#!AER-DAT3.1\r\n#Source 1: DAVIS240C\r\n#!END-HEADER\r\n" +
           raw("\x01\x00\x01\x00\x08\x00\x00\x00\x04\x00\x00\x00\x00\x00\x00\x00\x01\x00\x00\x00"
               "\x01\x00\x00\x00\x01\x00\x00\x00\x07\x00\x02\x00\x10\x00\x00\x00",
               36)});
  seeds.push_back({Format::kEvt2, ".raw",
                   "% evt 2.0\n% geometry 640x480\n" + raw("\x0a\x00\x00\x80\x09\x38\x40\x11", 8)});
  seeds.push_back({Format::kEvt3, ".raw",
                   "% evt 3.0\n% format EVT3;height=720;width=1280\n% end\n" +
                       raw("\x01\x80\x05\x60\x0a\x00\x03\x2a\x64\x30\x05\x40\x80\x50", 14)});
  seeds.push_back({Format::kDat, ".dat",
                   "% Version 2\n% Width 304\n% Height 240\n" +
                       raw("\x0c\x08\x64\x00\x00\x00\x2c\x41\x04\x10", 10)});
  return seeds;
}

// The kinds of damage a user's files come with.
std::string damage(const std::string& good, int kind, std::mt19937& rng) {
  std::string s = good;
  const auto at = [&](size_t n) {
    return n == 0 ? size_t{0} : std::uniform_int_distribution<size_t>(0, n - 1)(rng);
  };
  switch (kind) {
    case 0:  // truncated
      s.resize(at(s.size()));
      break;
    case 1:  // empty
      s.clear();
      break;
    case 2: {  // binary data spliced in
      std::string junk(1 + at(64), '\0');
      for (char& c : junk) c = static_cast<char>(rng());
      s.insert(at(s.size()), junk);
      break;
    }
    case 3:  // wrong magic
      for (size_t i = 0; i < std::min<size_t>(8, s.size()); ++i) s[i] = static_cast<char>(rng());
      break;
    case 4: {  // a huge size field
      const size_t pos = at(s.size() >= 4 ? s.size() - 3 : 1);
      const char huge[4] = {'\xff', '\xff', '\xff', static_cast<char>(rng() % 2 ? '\x7f' : '\xff')};
      for (size_t i = 0; i < 4 && pos + i < s.size(); ++i) s[pos + i] = huge[i];
      break;
    }
    default:  // scattered bit flips
      for (int i = 0; i < 8 && !s.empty(); ++i)
        s[at(s.size())] ^= static_cast<char>(1 << (rng() % 8));
      break;
  }
  return s;
}

// Reads the file fully through the chunked reader and through readRecording; an evkit::Error is
// the expected outcome for most damaged files, anything else fails the test.
void readAll(const std::string& path, Format format) {
  const auto fail = [&](const char* what) {
    ADD_FAILURE() << formatName(format)
                  << " reader threw something other than evkit::Error: " << what;
  };
  try {
    auto reader = openReader(path, format);
    Chunk chunk;
    while (reader->next(chunk, 1 << 12)) {
    }
  } catch (const Error&) {
  } catch (const std::exception& e) {
    fail(e.what());
  }
  try {
    (void)readRecording(path, format);
  } catch (const Error&) {
  } catch (const std::exception& e) {
    fail(e.what());
  }
}

TEST(BadFiles, TwoThousandBadFilesPerFormatLeakNoDescriptorAndNoMemory) {
  ScratchDir dir;
  const std::vector<Seed> seeds = makeSeeds(dir);
  constexpr int kFilesPerFormat = 2000;
  constexpr int kWarmUp = 20;  // files per format read before the baseline is taken
  std::mt19937 rng(20261123);

  const auto pass = [&](int first, int last) {
    for (const Seed& seed : seeds) {
      const std::string path = dir / ("bad" + seed.extension);
      for (int i = first; i < last; ++i) {
        writeBytes(path, damage(seed.bytes, i % 6, rng));
        readAll(path, seed.format);
      }
    }
  };
  pass(0, kWarmUp);
  const int descriptors = openDescriptors();
  const long rss_kb = residentKb();
  ASSERT_GT(descriptors, 0);
  pass(kWarmUp, kFilesPerFormat);

  EXPECT_EQ(openDescriptors(), descriptors) << "descriptors left open by readers that threw";
  // AddressSanitizer keeps freed memory in quarantine, so the resident size only means something
  // without it; there LeakSanitizer checks the same at exit.
  if (!kSanitized) {
    EXPECT_LT(residentKb() - rss_kb, 4 * 1024) << "resident memory grew by more than 4 MB";
  }
}

TEST(BadFiles, FuzzFindingsStayFixed) {
  // tests/fuzz/regressions/<reader>/: inputs that once crashed, leaked or escaped as another
  // exception; each must now be read or refused with an evkit::Error, leaving nothing open.
  const std::filesystem::path root =
      std::filesystem::path(EVKIT_SOURCE_DIR) / "tests/fuzz/regressions";
  int inputs = 0;
  for (const auto& reader_dir : std::filesystem::directory_iterator(root)) {
    const Format format = parseFormat(reader_dir.path().filename().string());
    for (const auto& input : std::filesystem::directory_iterator(reader_dir.path())) {
      const int before = openDescriptors();
      readAll(input.path().string(), format);
      EXPECT_EQ(openDescriptors(), before) << input.path().filename() << " left a descriptor open";
      ++inputs;
    }
  }
  EXPECT_GE(inputs, 4);
}

TEST(BadFiles, TheDescriptorCountSeesALeak) {
  // The check above must be able to fail: an opened file that is not closed shows in the count.
  ScratchDir dir;
  const int before = openDescriptors();
  std::FILE* f = std::fopen((dir / "x").c_str(), "wb");
  ASSERT_NE(f, nullptr);
  EXPECT_EQ(openDescriptors(), before + 1);
  std::fclose(f);
  EXPECT_EQ(openDescriptors(), before);
}

}  // namespace
}  // namespace evkit
