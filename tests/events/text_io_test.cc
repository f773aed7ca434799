#include <gtest/gtest.h>

#include "evkit/base/error.h"
#include "evkit/events/image_io.h"
#include "evkit/events/io.h"
#include "evkit/events/random_events.h"
#include "test_util.h"

namespace evkit {
namespace {

using test::ScratchDir;
using test::writeText;

TEST(TextIo, ReadsRpgLinesWithHeaderAndBothPolarityConventions) {
  ScratchDir dir;
  writeText(dir / "a.txt",
            "240 180\n0.000010 1 2 1\n0.000020 3 4 0\n0.5 239 179 -1\n1605537493.718345 0 0 +1\n");
  const Recording rec = readRecording(dir / "a.txt");
  EXPECT_EQ(rec.info.sensor, (SensorSize{240, 180}));
  EXPECT_EQ(rec.info.layout, "rpg-text");
  EXPECT_EQ(rec.events.t, (std::vector<int64_t>{10, 20, 500000, 1605537493718345}));
  EXPECT_EQ(rec.events.x, (std::vector<uint16_t>{1, 3, 239, 0}));
  EXPECT_EQ(rec.events.y, (std::vector<uint16_t>{2, 4, 179, 0}));
  EXPECT_EQ(rec.events.p, (std::vector<int8_t>{1, -1, -1, 1}));
}

TEST(TextIo, AcceptsTabsCommasCrlfCommentsBlankLinesAndNoFinalNewline) {
  ScratchDir dir;
  writeText(dir / "b.txt",
            "# t x y p\r\n\r\n1.0\t5\t6\t1\r\n2.0,7,8,0\r\n  # comment\n3.5e+0 9 10 1");
  const Recording rec = readRecording(dir / "b.txt");
  ASSERT_EQ(rec.events.size(), 3u);
  EXPECT_EQ(rec.events.t[0], 1000000);
  EXPECT_EQ(rec.events.t[2], 3500000);
  EXPECT_EQ(rec.events.x[1], 7);
  EXPECT_EQ(rec.events.p[1], -1);
  // Without a header the sensor is the bounding box of the events.
  EXPECT_EQ(rec.info.sensor, (SensorSize{10, 11}));
}

TEST(TextIo, WriterKeepsMicrosecondsAndHeader) {
  ScratchDir dir;
  Recording rec;
  rec.events.setSensor(SensorSize{346, 260});
  rec.events.push_back(1605537493718345, 345, 259, 1);
  rec.events.push_back(1605537493718346, 0, 0, -1);
  writeRecording(dir / "c.txt", rec);
  EXPECT_EQ(test::readText(dir / "c.txt"),
            "346 260\n1605537493.718345 345 259 1\n1605537493.718346 0 0 0\n");
}

TEST(TextIo, ChunkedReadingEqualsWholeReadingAcrossBufferBoundaries) {
  ScratchDir dir;
  RandomEventOptions o;
  o.count = 400000;  // ~11 MB of text: several 4 MiB buffer refills
  Recording rec;
  rec.events = randomEvents(o);
  writeRecording(dir / "r.txt", rec);
  auto reader = openReader(dir / "r.txt");
  EventStore all;
  Chunk chunk;
  size_t chunks = 0;
  while (reader->next(chunk, 9973)) {
    EXPECT_LE(chunk.events.size(), 9973u);
    all.append(chunk.events.view());
    ++chunks;
  }
  EXPECT_EQ(chunks, (o.count + 9972) / 9973);
  EXPECT_EQ(all.t, rec.events.t);
  EXPECT_EQ(all.x, rec.events.x);
  EXPECT_EQ(all.y, rec.events.y);
  EXPECT_EQ(all.p, rec.events.p);
}

TEST(TextIo, TimeWindowKeepsHalfOpenRange) {
  ScratchDir dir;
  writeText(dir / "w.txt", "10 10\n1.0 1 1 1\n2.0 2 2 1\n3.0 3 3 0\n4.0 4 4 1\n");
  const Recording rec = readRecording(dir / "w.txt", std::nullopt, 2000000, 4000000);
  EXPECT_EQ(rec.events.t, (std::vector<int64_t>{2000000, 3000000}));
  EXPECT_EQ(readRecording(dir / "w.txt", std::nullopt, 5000000, 6000000).events.size(), 0u);
}

TEST(TextIo, FramesTravelInAFolderBesideTheFile) {
  ScratchDir dir;
  Recording rec;
  rec.events.setSensor(SensorSize{8, 6});
  rec.events.push_back(100, 1, 1, 1);
  rec.events.push_back(300, 2, 2, -1);
  Frame f;
  f.image = cv::Mat(6, 8, CV_32F, cv::Scalar(0.5));
  f.image.at<float>(2, 3) = 1.0f;
  f.exposure_start_us = 150;
  f.exposure_end_us = 250;
  f.bit_depth = 16;
  rec.frames.push_back(f);
  writeRecording(dir / "f.txt", rec);
  ASSERT_TRUE(test::fs::exists(dir / "f_frames/frames.csv"));
  const Recording back = readRecording(dir / "f.txt");
  ASSERT_EQ(back.frames.size(), 1u);
  EXPECT_EQ(back.frames[0].exposure_start_us, 150);
  EXPECT_EQ(back.frames[0].exposure_end_us, 250);
  EXPECT_EQ(back.frames[0].bit_depth, 16);
  EXPECT_NEAR(back.frames[0].image.at<float>(0, 0), 0.5f, 1.0f / 65535);
  EXPECT_FLOAT_EQ(back.frames[0].image.at<float>(2, 3), 1.0f);
}

}  // namespace
}  // namespace evkit
