// The real recordings of ../shared/fixtures/real reproduce every fact of its README (read there
// with independent parsers). Each test skips, saying why, when the folder is absent.

#include <gtest/gtest.h>

#include "evkit/events/io.h"
#include "test_util.h"

namespace evkit {
namespace {

#define REQUIRE_FIXTURE(var, name)             \
  const std::string var = test::fixture(name); \
  if (var.empty())                             \
  GTEST_SKIP() << "fixture " << name << " not found (../shared/fixtures/real is absent)"

int64_t countOn(const EventStore& e) { return e.countOn(); }

TEST(Fixtures, DvxplorerAedat4) {
  REQUIRE_FIXTURE(path, "dvxplorer_sample.aedat4");
  const Recording rec = readRecording(path);
  EXPECT_EQ(detectFormat(path), Format::kAedat4);
  EXPECT_EQ(rec.info.counters.at("compression"), 1);  // LZ4
  EXPECT_EQ(rec.info.counters.at("data_table_position"), 945243);
  EXPECT_EQ(rec.info.sensor, (SensorSize{320, 240}));
  EXPECT_EQ(rec.info.camera, "DVXplorer_DXB00010");
  EXPECT_EQ(rec.info.counters.at("packets.EVTS"), 59);
  EXPECT_EQ(rec.info.counters.at("packets.IMUS"), 59);
  ASSERT_EQ(rec.events.size(), 111954u);
  EXPECT_EQ(countOn(rec.events), 55023);
  EXPECT_EQ(static_cast<int64_t>(rec.events.size()) - countOn(rec.events), 56931);
  EXPECT_EQ(*std::min_element(rec.events.x.begin(), rec.events.x.end()), 0);
  EXPECT_EQ(*std::max_element(rec.events.x.begin(), rec.events.x.end()), 319);
  EXPECT_EQ(*std::min_element(rec.events.y.begin(), rec.events.y.end()), 0);
  EXPECT_EQ(*std::max_element(rec.events.y.begin(), rec.events.y.end()), 239);
  EXPECT_EQ(rec.events.t.front(), 1605537493718345);
  EXPECT_EQ(rec.events.x.front(), 154);
  EXPECT_EQ(rec.events.y.front(), 204);
  EXPECT_EQ(rec.events.p.front(), -1);
  EXPECT_EQ(rec.events.t.back(), 1605537494308262);
}

TEST(Fixtures, Davis240TranslBoxesAedat2) {
  REQUIRE_FIXTURE(path, "davis240c_translboxes.aedat");
  const Recording rec = readRecording(path);
  EXPECT_EQ(detectFormat(path), Format::kAedat2);
  EXPECT_EQ(rec.info.sensor, (SensorSize{240, 180}));
  EXPECT_EQ(rec.info.camera, "DAVIS240C");
  EXPECT_EQ(rec.info.counters.at("header_bytes"), 175268);
  EXPECT_EQ(rec.info.counters.at("records"), 196608);
  EXPECT_EQ(rec.info.counters.at("dvs_events"), 162771);
  EXPECT_EQ(rec.info.counters.at("aps_words"), 0);
  EXPECT_EQ(rec.info.counters.at("imu_words"), 33837);
  ASSERT_EQ(rec.events.size(), 162771u);
  EXPECT_EQ(countOn(rec.events), 82944);
  EXPECT_EQ(static_cast<int64_t>(rec.events.size()) - countOn(rec.events), 79827);
  EXPECT_EQ(rec.events.t.front(), 294976755);
  EXPECT_EQ(rec.events.t.back(), 297049406);
  // Raw (x, y) = (156, 36), (205, 128), (169, 46) before jAER's flips: x' = 239 - x, y' = 179 - y.
  EXPECT_EQ(rec.events.x[0], 239 - 156);
  EXPECT_EQ(rec.events.y[0], 179 - 36);
  EXPECT_EQ(rec.events.p[0], -1);
  EXPECT_EQ(rec.events.t[1], 294976892);
  EXPECT_EQ(rec.events.x[1], 239 - 205);
  EXPECT_EQ(rec.events.y[1], 179 - 128);
  EXPECT_EQ(rec.events.p[1], -1);
  EXPECT_EQ(rec.events.t[2], 294976940);
  EXPECT_EQ(rec.events.x[2], 239 - 169);
  EXPECT_EQ(rec.events.y[2], 179 - 46);
  EXPECT_EQ(rec.events.p[2], 1);
  EXPECT_TRUE(rec.info.warnings.empty());
}

TEST(Fixtures, Davis240RotDiskAedat2) {
  REQUIRE_FIXTURE(path, "davis240c_rotdisk.aedat");
  const Recording rec = readRecording(path);
  EXPECT_EQ(rec.info.counters.at("header_bytes"), 175039);
  EXPECT_EQ(rec.info.counters.at("records"), 425984);
  EXPECT_EQ(rec.info.counters.at("aps_words"), 0);
  EXPECT_EQ(rec.info.counters.at("imu_words"), 51688);
  ASSERT_EQ(rec.events.size(), 374296u);
  EXPECT_EQ(countOn(rec.events), 163098);
  EXPECT_EQ(rec.events.t.front(), 341678);
  EXPECT_EQ(rec.events.t.back(), 3508437);
  EXPECT_EQ(rec.events.x[0], 239 - 11);
  EXPECT_EQ(rec.events.y[0], 179 - 15);
  EXPECT_EQ(rec.events.p[0], 1);
}

TEST(Fixtures, Davis346HeaderOnlyAedat2) {
  REQUIRE_FIXTURE(path, "davis346red_header_only.aedat");
  const Recording rec = readRecording(path);
  EXPECT_EQ(rec.info.camera, "Davis346red");
  EXPECT_EQ(rec.info.sensor, (SensorSize{346, 260}));
  EXPECT_EQ(rec.events.size(), 0u);
}

// Facts of the Prophesee fixtures, read here with an independent numpy decoder of the EVT 2.0 and
// DAT specifications (numpy.frombuffer over the words, by the bit layouts in
// events/src/prophesee.cc).
TEST(Fixtures, PropheseeGen3Evt2) {
  REQUIRE_FIXTURE(path, "prophesee_gen3_evt2.raw");
  const Recording rec = readRecording(path);
  EXPECT_EQ(detectFormat(path), Format::kEvt2);
  EXPECT_EQ(rec.info.sensor, (SensorSize{640, 480}));  // Gen3 from plugin_name
  ASSERT_EQ(rec.events.size(), 521252u);
  EXPECT_EQ(countOn(rec.events), 185861);
  EXPECT_EQ(rec.events.t.front(), 913716224);
  EXPECT_EQ(rec.events.t.back(), 913812095);
}

TEST(Fixtures, AtisNcarsDat) {
  REQUIRE_FIXTURE(path, "atis_ncars_sample.dat");
  const Recording rec = readRecording(path);
  EXPECT_EQ(detectFormat(path), Format::kDat);
  ASSERT_EQ(rec.events.size(), 2009u);
  EXPECT_EQ(countOn(rec.events), 1350);
  EXPECT_EQ(rec.events.t.front(), 0);
  EXPECT_EQ(rec.events.t[1], 35);
  EXPECT_EQ(rec.events.t.back(), 99952);
  EXPECT_EQ(*std::max_element(rec.events.x.begin(), rec.events.x.end()), 77);
  EXPECT_EQ(*std::max_element(rec.events.y.begin(), rec.events.y.end()), 41);
}

TEST(Fixtures, Aedat4TimeWindowThroughTheDataTableMatchesAFullRead) {
  REQUIRE_FIXTURE(path, "dvxplorer_sample.aedat4");
  const Recording all = readRecording(path);
  const int64_t t0 = all.events.t[40000], t1 = all.events.t[70000];
  const Recording part = readRecording(path, std::nullopt, t0, t1);
  const EventSpan expected = all.events.sliceTime(t0, t1);
  ASSERT_EQ(part.events.size(), expected.size());
  EXPECT_EQ(part.events.t.front(), expected.t.front());
  EXPECT_EQ(part.events.x.back(), expected.x.back());
}

}  // namespace
}  // namespace evkit
