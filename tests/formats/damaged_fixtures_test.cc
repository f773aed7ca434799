// Truncated and corrupted copies of each real recording: one clear error line naming the file and
// a byte position, a non-zero exit, no crash (through the evkit binary, as a user meets them).

#include <gtest/gtest.h>

#include <functional>

#include "test_util.h"

namespace evkit {
namespace {

using test::RunResult;
using test::ScratchDir;

struct Damage {
  std::string fixture;
  std::string name;
  std::function<std::string(const std::string&)> apply;
  std::string expected;  // part of the error line
};

std::string cut(const std::string& bytes, size_t n) {
  return bytes.substr(0, std::min(n, bytes.size()));
}

// The NCARS sample's header ends with its "% Date ..." line.
size_t datHeaderEnd(const std::string& bytes) {
  return bytes.find('\n', bytes.find("\n% Date") + 1) + 1;
}

std::string flip(std::string bytes, size_t at) {
  bytes[at] = static_cast<char>(bytes[at] ^ 0x5a);
  return bytes;
}

TEST(DamagedFixtures, OneErrorLineAndNonZeroExit) {
  const std::vector<Damage> damages = {
      {"dvxplorer_sample.aedat4", "cut in a packet",
       [](const std::string& b) { return cut(b, 300000); }, "runs past the end of the file"},
      {"dvxplorer_sample.aedat4", "cut in the header",
       [](const std::string& b) { return cut(b, 1000); },
       "byte 14: header length 2316 runs past the end of the file"},
      {"dvxplorer_sample.aedat4", "damaged magic", [](const std::string& b) { return flip(b, 3); },
       "no '#!AER-DAT' signature"},
      {"dvxplorer_sample.aedat4", "damaged IOHeader",
       [](const std::string& b) {
         std::string c = b;
         c.replace(18, 4, "\xff\xff\xff\x7f");
         return c;
       },
       "byte 18: corrupt IOHeader FlatBuffer"},
      {"dvxplorer_sample.aedat4", "damaged LZ4 data",
       [](const std::string& b) {
         std::string c = b;
         for (size_t i = 2400; i < 2500; ++i) c[i] = 0;
         return c;
       },
       "byte 2342: corrupt LZ4 data"},
      {"davis240c_translboxes.aedat", "cut in the header",
       [](const std::string& b) { return cut(b, 50000); }, "truncated inside the header"},
      {"davis240c_translboxes.aedat", "damaged magic",
       [](const std::string& b) { return flip(b, 1); }, "no '#!AER-DAT' signature"},
      {"davis240c_rotdisk.aedat", "damaged AEChip line",
       [](const std::string& b) {
         std::string c = b;
         const size_t at = c.find("AEChip:");
         c.replace(at, 7, "AEChap:");
         return c;
       },
       "no '# AEChip:' header line"},
      {"davis346red_header_only.aedat", "cut in the header",
       [](const std::string& b) { return cut(b, 300); }, "truncated inside the header"},
      {"prophesee_gen3_evt2.raw", "damaged header", [](const std::string& b) { return flip(b, 0); },
       "byte 0: no '% evt 2.0' / '% evt 3.0' header line"},
      {"prophesee_gen3_evt2.raw", "cut in the header",
       [](const std::string& b) { return cut(b, 60); }, "truncated inside the header"},
      {"atis_ncars_sample.dat", "cut after the header",
       [](const std::string& b) { return cut(b, datHeaderEnd(b)); },
       "truncated: expected the event type and size bytes"},
      {"atis_ncars_sample.dat", "wrong event size",
       [](const std::string& b) {
         std::string c = b;
         c[datHeaderEnd(b) + 1] = 9;
         return c;
       },
       "event size 9 (only 8-byte CD events are supported)"},
  };
  ScratchDir dir;
  int ran = 0;
  for (const Damage& d : damages) {
    const std::string source = test::fixture(d.fixture);
    if (source.empty()) continue;
    const std::string name =
        "damaged_" + std::to_string(ran++) + test::fs::path(d.fixture).extension().string();
    test::writeText(dir / name, d.apply(test::readText(source)));
    const RunResult r = test::runEvkit("info " + (dir / name), dir);
    EXPECT_EQ(r.exit_code, 1) << d.fixture << " / " << d.name << ": " << r.err;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1)
        << d.fixture << " / " << d.name << ": " << r.err;
    EXPECT_NE(r.err.find(dir / name), std::string::npos) << r.err;
    EXPECT_NE(r.err.find(d.expected), std::string::npos)
        << d.fixture << " / " << d.name << ": " << r.err;
  }
  if (ran == 0) GTEST_SKIP() << "../shared/fixtures/real is absent";
}

TEST(DamagedFixtures, DataCutMidRecordIsToleratedWithAWarning) {
  const std::string source = test::fixture("davis240c_translboxes.aedat");
  if (source.empty()) GTEST_SKIP() << "../shared/fixtures/real is absent";
  ScratchDir dir;
  const std::string bytes = test::readText(source);
  test::writeText(dir / "cut.aedat", cut(bytes, bytes.size() - 3));
  const RunResult r = test::runEvkit("info " + (dir / "cut.aedat"), dir);
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.err.find("warning: " + (dir / "cut.aedat") +
                       ": the last record is cut off (5 bytes ignored)"),
            std::string::npos)
      << r.err;
}

}  // namespace
}  // namespace evkit
