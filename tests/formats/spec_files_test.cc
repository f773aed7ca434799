// Files written here byte by byte from the format specifications (no public recording with APS
// frames exists), read back through evkit's readers.

#include <flatbuffers/flatbuffers.h>
#include <gtest/gtest.h>

#include <cstring>

#include "aedat4/events_generated.h"
#include "aedat4/frame_generated.h"
#include "aedat4/ioheader_generated.h"
#include "evkit/base/error.h"
#include "evkit/events/io.h"
#include "evkit/events/random_events.h"
#include "test_util.h"

namespace evkit {
namespace {

using test::ScratchDir;

struct Bytes {
  std::string data;
  Bytes& str(const std::string& s) {
    data += s;
    return *this;
  }
  Bytes& be32(uint32_t v) {
    for (int i = 3; i >= 0; --i) data += static_cast<char>(v >> (8 * i));
    return *this;
  }
  Bytes& le16(uint16_t v) {
    for (int i = 0; i < 2; ++i) data += static_cast<char>(v >> (8 * i));
    return *this;
  }
  Bytes& le32(uint32_t v) {
    for (int i = 0; i < 4; ++i) data += static_cast<char>(v >> (8 * i));
    return *this;
  }
  Bytes& raw(const void* p, size_t n) {
    data.append(static_cast<const char*>(p), n);
    return *this;
  }
  void save(const std::string& path) const { test::writeText(path, data); }
};

// ---- AEDAT 2.0 (jAER, DAVIS240C: 240 x 180) ---------------------------------------------------
constexpr int kW240 = 240, kH240 = 180;

uint32_t davisDvs(int x, int y, bool on) {  // top-left coordinates -> jAER raw address
  return (uint32_t(kH240 - 1 - y) << 22) | (uint32_t(kW240 - 1 - x) << 12) | (uint32_t(on) << 11);
}
uint32_t davisAps(int x, int y, int type, int value) {  // APS x is not mirrored
  return 0x80000000u | (uint32_t(kH240 - 1 - y) << 22) | (uint32_t(x) << 12) |
         (uint32_t(type) << 10) | uint32_t(value);
}

TEST(Aedat2Spec, DvsEventsApsFrameAndImuWords) {
  ScratchDir dir;
  Bytes b;
  b.str(
      "#!AER-DAT2.0\r\n# This is a raw AE data file\r\n# AEChip: "
      "eu.seebetter.ini.chips.davis.DAVIS240C\r\n");
  b.be32(davisDvs(0, 0, true)).be32(100);
  b.be32(davisDvs(239, 179, false)).be32(150);
  b.be32(0x80000C00u | 0x1234).be32(160);  // IMU word: skipped
  // One global-shutter frame: reset reads at t = 1000 + i, then signal reads from t = 60000.
  int64_t t = 1000;
  for (int y = 0; y < kH240; ++y) {
    for (int x = 0; x < kW240; ++x)
      b.be32(davisAps(x, y, 0, 1000)).be32(static_cast<uint32_t>(t++));
  }
  const int64_t last_reset = t - 1;
  b.be32(davisDvs(5, 6, true)).be32(50000);  // DVS events interleave with the readout
  t = 60000;
  for (int y = 0; y < kH240; ++y) {
    for (int x = 0; x < kW240; ++x) {
      const int signal = 1000 - (x + 2 * y);  // reset - signal = x + 2y (clamped to 1023)
      b.be32(davisAps(x, y, 1, std::max(signal, 0))).be32(static_cast<uint32_t>(t++));
    }
  }
  b.be32(davisDvs(7, 8, false)).be32(200000);
  b.str("abc");  // a cut-off last record
  b.save(dir / "f.aedat");

  const Recording rec = readRecording(dir / "f.aedat");
  EXPECT_EQ(rec.info.sensor, (SensorSize{240, 180}));
  ASSERT_EQ(rec.events.size(), 4u);
  EXPECT_EQ(rec.events.t, (std::vector<int64_t>{100, 150, 50000, 200000}));
  EXPECT_EQ(rec.events.x, (std::vector<uint16_t>{0, 239, 5, 7}));
  EXPECT_EQ(rec.events.y, (std::vector<uint16_t>{0, 179, 6, 8}));
  EXPECT_EQ(rec.events.p, (std::vector<int8_t>{1, -1, 1, -1}));
  EXPECT_EQ(rec.info.counters.at("imu_words"), 1);
  ASSERT_EQ(rec.frames.size(), 1u);
  const Frame& f = rec.frames[0];
  EXPECT_EQ(f.exposure_start_us, last_reset);
  EXPECT_EQ(f.exposure_end_us, 60000);
  ASSERT_EQ(f.image.size(), cv::Size(240, 180));
  EXPECT_FLOAT_EQ(f.image.at<float>(0, 0), 0.0f);
  EXPECT_FLOAT_EQ(f.image.at<float>(3, 10), 16.0f / 1023);
  EXPECT_FLOAT_EQ(f.image.at<float>(179, 239), (239.0f + 358.0f) / 1023);
  ASSERT_EQ(rec.info.warnings.size(), 1u);
  EXPECT_NE(rec.info.warnings[0].find("last record is cut off (3 bytes ignored)"),
            std::string::npos);
}

TEST(Aedat2Spec, TimestampWrapAndOutOfOrderEvents) {
  ScratchDir dir;
  Bytes b;
  b.str("#!AER-DAT2.0\r\n# AEChip: eu.seebetter.ini.chips.davis.DAVIS240C\r\n");
  b.be32(davisDvs(1, 1, true)).be32(0xFFFFFF00u);
  b.be32(davisDvs(1, 1, true)).be32(0x00000010u);  // wrapped: 2^32 + 16
  b.save(dir / "wrap.aedat");
  const Recording rec = readRecording(dir / "wrap.aedat");
  EXPECT_EQ(rec.events.t, (std::vector<int64_t>{0xFFFFFF00LL, (int64_t{1} << 32) + 16}));

  Bytes back;
  back.str("#!AER-DAT2.0\r\n# AEChip: eu.seebetter.ini.chips.davis.DAVIS240C\r\n");
  back.be32(davisDvs(1, 1, true)).be32(5000);
  back.be32(davisDvs(1, 1, true)).be32(4000);
  back.save(dir / "back.aedat");
  try {
    readRecording(dir / "back.aedat");
    FAIL();
  } catch (const Error& e) {
    const std::string expected = "byte " + std::to_string(back.data.size() - 8) +
                                 ": DVS timestamp 4000 us goes back in time";
    EXPECT_NE(std::string(e.what()).find(expected), std::string::npos) << e.what();
  }
}

// ---- AEDAT 3.1 (libcaer) ------------------------------------------------------------------------
Bytes aedat31Header(const std::string& source) {
  Bytes b;
  b.str("#!AER-DAT3.1\r\n#Format: RAW\r\n#Source 1: " + source +
        "\r\n#Start-Time: 2024-01-01\r\n#!END-HEADER\r\n");
  return b;
}

void packetHeader(Bytes& b, int16_t type, int32_t size, int32_t ts_offset, int32_t overflow,
                  int32_t n) {
  b.le16(static_cast<uint16_t>(type))
      .le16(1)
      .le32(static_cast<uint32_t>(size))
      .le32(static_cast<uint32_t>(ts_offset));
  b.le32(static_cast<uint32_t>(overflow))
      .le32(static_cast<uint32_t>(n))
      .le32(static_cast<uint32_t>(n))
      .le32(static_cast<uint32_t>(n));
}

uint32_t polarity31(int x, int y, bool on, bool valid = true) {
  return (uint32_t(x) << 17) | (uint32_t(y) << 2) | (uint32_t(on) << 1) | uint32_t(valid);
}

TEST(Aedat31Spec, PolarityPacketsWithOverflowFramesWithRoiAndUnknownPackets) {
  ScratchDir dir;
  Bytes b = aedat31Header("DAVIS346B");
  packetHeader(b, 1, 8, 4, 0, 3);
  b.le32(polarity31(0, 0, true)).le32(10);
  b.le32(polarity31(9, 9, false, false)).le32(11);  // invalid: skipped
  b.le32(polarity31(345, 259, false)).le32(20);
  packetHeader(b, 3, 40, 4, 0, 2);  // IMU6 packet: skipped
  b.data.append(80, '\0');
  // A colour frame of 4 x 2 pixels at ROI position (10, 20), exposure 1000..1500 µs.
  const int w = 4, h = 2, c = 3;
  packetHeader(b, 2, 36 + 2 * w * h * c, 12, 0, 1);
  b.le32((uint32_t(c) << 1) | 1).le32(900).le32(1600).le32(1000).le32(1500);
  b.le32(w).le32(h).le32(10).le32(20);
  for (int i = 0; i < w * h; ++i)
    b.le16(static_cast<uint16_t>(1000 * i)).le16(65535).le16(0);  // R, G, B
  packetHeader(b, 1, 8, 4, 1, 1);                                 // overflow 1: t = 2^31 + 5
  b.le32(polarity31(1, 2, true)).le32(5);
  b.save(dir / "f.aedat");

  const Recording rec = readRecording(dir / "f.aedat");
  EXPECT_EQ(rec.info.camera, "DAVIS346B");
  EXPECT_EQ(rec.info.sensor, (SensorSize{346, 260}));
  EXPECT_EQ(rec.events.t, (std::vector<int64_t>{10, 20, (int64_t{1} << 31) + 5}));
  EXPECT_EQ(rec.events.x, (std::vector<uint16_t>{0, 345, 1}));
  EXPECT_EQ(rec.events.p, (std::vector<int8_t>{1, -1, 1}));
  EXPECT_EQ(rec.info.counters.at("packets.type3"), 1);
  ASSERT_EQ(rec.frames.size(), 1u);
  const Frame& f = rec.frames[0];
  EXPECT_EQ(f.exposure_start_us, 1000);
  EXPECT_EQ(f.exposure_end_us, 1500);
  EXPECT_EQ(f.bit_depth, 16);
  ASSERT_EQ(f.image.size(), cv::Size(346, 260));       // the ROI placed in the sensor
  const cv::Vec3f px = f.image.at<cv::Vec3f>(21, 13);  // pixel i = 7 of the ROI, BGR in memory
  EXPECT_FLOAT_EQ(px[0], 0.0f);
  EXPECT_FLOAT_EQ(px[1], 1.0f);
  EXPECT_NEAR(px[2], 7000.0f / 65535, 1e-6);
  EXPECT_EQ(f.image.at<cv::Vec3f>(0, 0), cv::Vec3f(0, 0, 0));
}

TEST(Aedat31Spec, PacketClaimingMoreThanTheFileIsAnErrorNotAnAllocation) {
  ScratchDir dir;
  Bytes b = aedat31Header("DAVIS240C");
  packetHeader(b, 1, 8, 4, 0, 0x7FFFFFFF);  // 2^31 events of 8 bytes: 16 GiB claimed
  b.save(dir / "huge.aedat");
  try {
    readRecording(dir / "huge.aedat");
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("runs past the end of the file"), std::string::npos)
        << e.what();
  }
}

// ---- AEDAT 4.0
// ------------------------------------------------------------------------------------
Recording recordingWithFrames(int channels, int bits) {
  RandomEventOptions o;
  o.count = 100000;
  o.t_start_us = 1605537493718345;
  Recording rec;
  rec.events = randomEvents(o);
  for (int i = 0; i < 3; ++i) {
    Frame f;
    f.image = cv::Mat(260, 346, CV_32FC(channels));
    cv::randu(f.image, 0.0, 1.0);
    f.exposure_start_us = o.t_start_us + 20000 * i;
    f.exposure_end_us = f.exposure_start_us + 5000 + i;
    f.bit_depth = bits;
    rec.frames.push_back(f);
  }
  return rec;
}

TEST(Aedat4, WrittenFilesReadBackIdenticallyForEveryCompressionAndFrameFormat) {
  ScratchDir dir;
  for (Compression c : {Compression::kLz4, Compression::kZstd, Compression::kNone}) {
    for (const auto& [channels, bits] :
         std::vector<std::pair<int, int>>{{1, 8}, {1, 16}, {3, 8}, {3, 16}}) {
      const Recording rec = recordingWithFrames(channels, bits);
      WriterOptions options;
      options.compression = c;
      const std::string path = dir / ("r_" + compressionName(c) + std::to_string(channels) +
                                      std::to_string(bits) + ".aedat4");
      writeRecording(path, rec, std::nullopt, options);
      const Recording back = readRecording(path);
      EXPECT_EQ(back.info.sensor, (SensorSize{346, 260}));
      EXPECT_TRUE(back.events.t == rec.events.t && back.events.x == rec.events.x &&
                  back.events.y == rec.events.y && back.events.p == rec.events.p);
      ASSERT_EQ(back.frames.size(), 3u);
      for (size_t i = 0; i < 3; ++i) {
        EXPECT_EQ(back.frames[i].exposure_start_us, rec.frames[i].exposure_start_us);
        EXPECT_EQ(back.frames[i].exposure_end_us, rec.frames[i].exposure_end_us);
        EXPECT_EQ(back.frames[i].bit_depth, bits);
        cv::Mat diff;
        cv::absdiff(back.frames[i].image, rec.frames[i].image, diff);
        EXPECT_LE(cv::norm(diff.reshape(1), cv::NORM_INF), 0.5 / (bits == 16 ? 65535 : 255) + 1e-6);
      }
    }
  }
}

TEST(Aedat4, UnknownSensorSizeIsPatchedFromTheEvents) {
  ScratchDir dir;
  test::writeText(dir / "a.txt", "0.000001 12 7 1\n0.000002 3 30 0\n");
  auto reader = openReader(dir / "a.txt");
  auto writer = openWriter(dir / "a.aedat4", Format::kAedat4, reader->info().sensor);
  Chunk chunk;
  while (reader->next(chunk, 100)) writer->write(chunk.events.view());
  writer->close();
  EXPECT_EQ(readRecording(dir / "a.aedat4").info.sensor, (SensorSize{13, 31}));
}

// A frame packet as other recorders write it: exposure begin/end unset, timestamp + exposure.
TEST(Aedat4, FrameWithoutExposureFieldsUsesTimestampPlusExposure) {
  ScratchDir dir;
  const std::string xml =
      "<dv version=\"2.0\"><node name=\"outInfo\" path=\"/mainloop/Recorder/outInfo/\">"
      "<node name=\"3\" path=\"/mainloop/Recorder/outInfo/3/\"><attr key=\"typeIdentifier\" "
      "type=\"string\">FRME</attr>"
      "<node name=\"info\" path=\"/mainloop/Recorder/outInfo/3/info/\"><attr key=\"sizeX\" "
      "type=\"int\">4</attr>"
      "<attr key=\"sizeY\" type=\"int\">2</attr></node></node></node></dv>";
  flatbuffers::FlatBufferBuilder header;
  header.FinishSizePrefixed(
      aedat4::CreateIOHeader(header, aedat4::CompressionType::NONE, -1, header.CreateString(xml)),
      "IOHE");
  flatbuffers::FlatBufferBuilder frame;
  const std::vector<uint8_t> pixels = {0, 51, 102, 153, 204, 255, 0, 0};
  const auto px = frame.CreateVector(pixels);
  aedat4::FrameBuilder fb(frame);
  fb.add_t(5000);
  fb.add_exposure(1234);
  fb.add_width(4);
  fb.add_height(2);
  fb.add_pixels(px);
  frame.FinishSizePrefixed(fb.Finish(), "FRME");
  Bytes b;
  b.str("#!AER-DAT4.0\r\n").raw(header.GetBufferPointer(), header.GetSize());
  b.le32(3).le32(frame.GetSize()).raw(frame.GetBufferPointer(), frame.GetSize());
  b.save(dir / "f.aedat4");
  const Recording rec = readRecording(dir / "f.aedat4");
  ASSERT_EQ(rec.frames.size(), 1u);
  EXPECT_EQ(rec.frames[0].exposure_start_us, 5000);
  EXPECT_EQ(rec.frames[0].exposure_end_us, 6234);
  EXPECT_FLOAT_EQ(rec.frames[0].image.at<float>(1, 1), 1.0f);
  // A packet of an undeclared stream is an error naming its byte offset.
  b.le32(7).le32(0);
  b.save(dir / "g.aedat4");
  EXPECT_THROW(readRecording(dir / "g.aedat4"), Error);
}

// FlatBuffers' verifier checks a vector's 4-byte length field, not the 8-byte alignment of its
// structs: a valid EVTS packet may hold its events 4 bytes off that alignment (as the fuzzer
// found), and they must still be read, not read in place as misaligned 8-byte structs.
TEST(Aedat4, EventsFourBytesOffTheirAlignmentAreRead) {
  ScratchDir dir;
  const std::string xml =
      "<dv version=\"2.0\"><node name=\"outInfo\" path=\"/mainloop/Recorder/outInfo/\">"
      "<node name=\"0\" path=\"/mainloop/Recorder/outInfo/0/\"><attr key=\"typeIdentifier\" "
      "type=\"string\">EVTS</attr>"
      "<node name=\"info\" path=\"/mainloop/Recorder/outInfo/0/info/\"><attr key=\"sizeX\" "
      "type=\"int\">8</attr>"
      "<attr key=\"sizeY\" type=\"int\">6</attr></node></node></node></dv>";
  flatbuffers::FlatBufferBuilder header;
  header.FinishSizePrefixed(
      aedat4::CreateIOHeader(header, aedat4::CompressionType::NONE, -1, header.CreateString(xml)),
      "IOHE");
  const std::vector<aedat4::Event> events = {
      {100, 1, 2, true}, {250, 7, 5, false}, {251, 0, 0, true}};
  flatbuffers::FlatBufferBuilder fbb;
  fbb.FinishSizePrefixed(aedat4::CreateEventPacket(fbb, fbb.CreateVectorOfStructs(events)), "EVTS");
  std::string packet(reinterpret_cast<const char*>(fbb.GetBufferPointer()), fbb.GetSize());
  const auto* root = flatbuffers::GetSizePrefixedRoot<aedat4::EventPacket>(packet.data());
  const size_t length_at =
      reinterpret_cast<const char*>(root->elements()->Data()) - packet.data() - 4;
  ASSERT_EQ(length_at % 8, 4u);  // as the builder aligns it: the structs at a multiple of 8
  // Four bytes before the length field, and the table's offset to it (the one 4-byte word
  // before it that points there) and the size prefix grown by four.
  size_t field_at = 0;
  for (size_t at = 8; at < length_at; at += 4) {
    uint32_t offset = 0;
    std::memcpy(&offset, packet.data() + at, 4);
    if (at + offset == length_at) field_at = at;
  }
  ASSERT_GT(field_at, 0u);
  packet.insert(length_at, 4, '\0');
  for (const size_t at : {size_t{0}, field_at}) {
    uint32_t value = 0;
    std::memcpy(&value, packet.data() + at, 4);
    value += 4;
    std::memcpy(packet.data() + at, &value, 4);
  }
  Bytes b;
  b.str("#!AER-DAT4.0\r\n").raw(header.GetBufferPointer(), header.GetSize());
  b.le32(0).le32(static_cast<uint32_t>(packet.size())).raw(packet.data(), packet.size());
  b.save(dir / "e.aedat4");
  const Recording rec = readRecording(dir / "e.aedat4");
  ASSERT_EQ(rec.events.size(), 3u);
  EXPECT_EQ(rec.events.t, (std::vector<int64_t>{100, 250, 251}));
  EXPECT_EQ(rec.events.x, (std::vector<uint16_t>{1, 7, 0}));
  EXPECT_EQ(rec.events.y, (std::vector<uint16_t>{2, 5, 0}));
  EXPECT_EQ(rec.events.p, (std::vector<int8_t>{1, -1, 1}));
}

// ---- Prophesee
// ------------------------------------------------------------------------------------
TEST(Prophesee, Evt3VectorsAndTimeWords) {
  ScratchDir dir;
  Bytes b;
  b.str("% evt 3.0\n% format EVT3;height=720;width=1280\n% end\n");
  b.le16(0x8000 | 1);          // TIME_HIGH = 1
  b.le16(0x6000 | 5);          // TIME_LOW = 5 -> t = 4096 + 5
  b.le16(0x0000 | 10);         // ADDR_Y = 10
  b.le16(0x2000 | 0x800 | 3);  // ADDR_X = 3, ON
  b.le16(0x3000 | 100);        // VECT_BASE_X = 100, OFF
  b.le16(0x4000 | 0x005);      // VECT_12: bits 0, 2 -> x 100, 102; base -> 112
  b.le16(0x5000 | 0x80);       // VECT_8: bit 7 -> x 119; base -> 120
  b.le16(0x6000 | 9);          // TIME_LOW = 9
  b.le16(0x2000 | 1279);       // ADDR_X = 1279, OFF
  b.save(dir / "a.raw");
  const Recording rec = readRecording(dir / "a.raw");
  EXPECT_EQ(rec.info.format, Format::kEvt3);
  EXPECT_EQ(rec.info.sensor, (SensorSize{1280, 720}));
  EXPECT_EQ(rec.events.t, (std::vector<int64_t>{4101, 4101, 4101, 4101, 4105}));
  EXPECT_EQ(rec.events.x, (std::vector<uint16_t>{3, 100, 102, 119, 1279}));
  EXPECT_EQ(rec.events.y, (std::vector<uint16_t>{10, 10, 10, 10, 10}));
  EXPECT_EQ(rec.events.p, (std::vector<int8_t>{1, -1, -1, -1, -1}));
}

TEST(Prophesee, Evt2TimeHighAndDatRecords) {
  ScratchDir dir;
  Bytes e;
  e.str("% evt 2.0\n% geometry 640x480\n% end\n");
  e.le32(0x10000000u | (7u << 11) | 9u);                   // CD ON before any time base: dropped
  e.le32(0x80000000u | 10u);                               // TIME_HIGH 10
  e.le32(0x10000000u | (5u << 22) | (7u << 11) | 9u);      // ON, t = 10 << 6 | 5
  e.le32(0x00000000u | (6u << 22) | (639u << 11) | 479u);  // OFF at the far corner
  e.save(dir / "b.raw");
  const Recording evt2 = readRecording(dir / "b.raw");
  EXPECT_EQ(evt2.events.t, (std::vector<int64_t>{645, 646}));
  EXPECT_EQ(evt2.events.x, (std::vector<uint16_t>{7, 639}));
  EXPECT_EQ(evt2.events.p, (std::vector<int8_t>{1, -1}));
  EXPECT_EQ(evt2.info.counters.at("events_before_first_time_high"), 1);

  Bytes d;
  d.str("% Data file containing CD events.\n% Version 2\n% Width 304\n% Height 240\n");
  d.data += '\x0c';
  d.data += '\x08';
  d.le32(100).le32((1u << 28) | (17u << 14) | 300u);
  d.le32(250).le32((0u << 28) | (239u << 14) | 0u);
  d.save(dir / "c.dat");
  const Recording dat = readRecording(dir / "c.dat");
  EXPECT_EQ(dat.info.sensor, (SensorSize{304, 240}));
  EXPECT_EQ(dat.events.t, (std::vector<int64_t>{100, 250}));
  EXPECT_EQ(dat.events.x, (std::vector<uint16_t>{300, 0}));
  EXPECT_EQ(dat.events.y, (std::vector<uint16_t>{17, 239}));
  EXPECT_EQ(dat.events.p, (std::vector<int8_t>{1, -1}));
}

}  // namespace
}  // namespace evkit
