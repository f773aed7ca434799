// cAER/libcaer AEDAT 3.1.
//
// File: text header lines from "#!AER-DAT3.1" to "#!END-HEADER", then packets, little-endian. A
// packet is a 28-byte header (int16 eventType, int16 eventSource, int32 eventSize, int32
// eventTSOffset, int32 eventTSOverflow, int32 eventCapacity, int32 eventNumber, int32 eventValid)
// followed by eventCapacity * eventSize bytes. Event timestamps are 31-bit; the 64-bit time is
// (eventTSOverflow << 31) | timestamp. Bit 0 of every event's first word marks it valid.
//   type 1, polarity (8 bytes): uint32 data (bit 1 polarity, bits 2..16 y, bits 17..31 x), int32 t
//   type 2, frame: uint32 info (bits 1..3 channels, bits 4..7 colour filter, bits 8..14 ROI id),
//     int32 start of frame, end of frame, start of exposure, end of exposure, int32 lengthX,
//     lengthY, positionX, positionY, then lengthX*lengthY*channels uint16 pixels (16-bit scale,
//     row-major, top-left origin, RGB(A) order)
// Other packet types (special, IMU, ...) are counted and skipped.

#include <algorithm>
#include <opencv2/imgproc.hpp>

#include "binary_file.h"
#include "evkit/base/error.h"
#include "formats.h"

namespace evkit::detail {

namespace {

constexpr int kHeaderBytes = 28;
constexpr int kPolarityType = 1;
constexpr int kFrameType = 2;
constexpr int kFrameHeaderBytes = 36;
constexpr int64_t kMaxPacketBytes = int64_t{1} << 30;

int32_t loadI32(const uint8_t* p) { return static_cast<int32_t>(loadLe32(p)); }

class Aedat31Reader final : public EventReader {
 public:
  explicit Aedat31Reader(const std::string& path) : file_(path) {
    info_.format = Format::kAedat31;
    info_.layout = "aedat3.1";
    readHeader();
  }

 protected:
  bool readChunk(Chunk& chunk, size_t max_events) override {
    EventStore& ev = chunk.events;
    ev.setSensor(info_.sensor);
    const size_t start_events = ev.size(), start_frames = chunk.frames.size();
    while (ev.size() - start_events < max_events) {
      if (next_event_ == packet_events_) {
        if (!nextPacket()) break;
        continue;  // the packet may hold no events
      }
      if (type_ == kPolarityType) {
        const uint8_t* e = payload_.data() + next_event_ * static_cast<size_t>(event_size_);
        ++next_event_;
        const uint32_t data = loadLe32(e);
        if ((data & 1) == 0) continue;
        const int64_t t = time(loadLe32(e + 4));
        const uint16_t x = static_cast<uint16_t>((data >> 17) & 0x7FFF);
        const uint16_t y = static_cast<uint16_t>((data >> 2) & 0x7FFF);
        const int64_t at =
            packet_offset_ + kHeaderBytes +
            static_cast<int64_t>((next_event_ - 1) * static_cast<size_t>(event_size_));
        if (info_.sensor.known() && !info_.sensor.contains(x, y)) {
          file_.failAt(at, "polarity event (x, y) = (" + std::to_string(x) + ", " +
                               std::to_string(y) + ") outside the " +
                               std::to_string(info_.sensor.width) + "x" +
                               std::to_string(info_.sensor.height) + " sensor");
        }
        if (t < last_t_) {
          file_.failAt(at, "timestamp " + std::to_string(t) + " us goes back in time (previous " +
                               std::to_string(last_t_) + " us)");
        }
        last_t_ = t;
        ev.push_back(t, x, y, (data >> 1) & 1 ? 1 : -1);
      } else {
        const size_t i = next_event_++;
        frame(payload_.data() + i * static_cast<size_t>(event_size_), chunk,
              packet_offset_ + kHeaderBytes +
                  static_cast<int64_t>(i * static_cast<size_t>(event_size_)));
      }
    }
    return ev.size() > start_events || chunk.frames.size() > start_frames;
  }

 private:
  void readHeader() {
    std::string line;
    if (!file_.readLine(line, 4096) || line.rfind("#!AER-DAT3", 0) != 0) {
      file_.failAt(0, "not an AEDAT 3.x file (expected '#!AER-DAT3.1' on the first line)");
    }
    bool ended = false;
    while (file_.peek() == '#') {
      file_.readLine(line, 1 << 16);
      if (line.rfind("#!END-HEADER", 0) == 0) {
        ended = true;
        break;
      }
      // "#Source 1: DAVIS346B" names the camera.
      if (line.rfind("#Source", 0) == 0 && info_.camera.empty()) {
        const size_t colon = line.find(':');
        if (colon != std::string::npos) {
          info_.camera = line.substr(line.find_first_not_of(' ', colon + 1) == std::string::npos
                                         ? line.size()
                                         : line.find_first_not_of(' ', colon + 1));
        }
      }
    }
    if (!ended) file_.fail("no '#!END-HEADER' line ending the header");
    const SensorSizeGuess size = sensorSizeForCamera(info_.camera);
    if (size.width > 0) info_.sensor = SensorSize{size.width, size.height};
  }

  bool nextPacket() {
    while (true) {
      packet_offset_ = file_.offset();
      uint8_t h[kHeaderBytes];
      const size_t got = file_.read(h, kHeaderBytes);
      if (got == 0) return false;
      if (got < static_cast<size_t>(kHeaderBytes))
        file_.failAt(packet_offset_, "truncated packet header (28 bytes expected)");
      const int type = static_cast<int16_t>(loadLe16(h));
      event_size_ = loadI32(h + 4);
      const int32_t ts_offset = loadI32(h + 8);
      overflow_ = loadI32(h + 12);
      const int32_t capacity = loadI32(h + 16);
      const int32_t number = loadI32(h + 20);
      if (event_size_ <= 0 || capacity < 0 || number < 0 || number > capacity || overflow_ < 0 ||
          ts_offset < 0 || int64_t{ts_offset} + 4 > event_size_) {
        file_.failAt(packet_offset_, "invalid packet header (event size " +
                                         std::to_string(event_size_) + ", capacity " +
                                         std::to_string(capacity) + ", number " +
                                         std::to_string(number) + ")");
      }
      const int64_t bytes = int64_t{capacity} * event_size_;
      if (bytes > file_.remaining() || bytes > kMaxPacketBytes) {
        file_.failAt(packet_offset_, "packet of " + std::to_string(bytes) +
                                         " bytes runs past the end of the file (truncated?)");
      }
      ++info_.counters["packets.type" + std::to_string(type)];
      if (type != kPolarityType && type != kFrameType) {
        file_.seek(file_.offset() + bytes);
        continue;
      }
      if (type == kPolarityType && (event_size_ != 8 || ts_offset != 4)) {
        file_.failAt(packet_offset_, "polarity packet with event size " +
                                         std::to_string(event_size_) + " (expected 8)");
      }
      if (type == kFrameType && event_size_ < kFrameHeaderBytes) {
        file_.failAt(packet_offset_, "frame packet with event size " + std::to_string(event_size_) +
                                         " (expected >= 36)");
      }
      payload_.resize(static_cast<size_t>(bytes));
      file_.readExact(payload_.data(), payload_.size(), "packet payload");
      type_ = type;
      packet_events_ = static_cast<size_t>(number);
      next_event_ = 0;
      return true;
    }
  }

  int64_t time(uint32_t ts) const { return (int64_t{overflow_} << 31) | (ts & 0x7FFFFFFFu); }

  void frame(const uint8_t* e, Chunk& chunk, int64_t at) {
    const uint32_t info = loadLe32(e);
    if ((info & 1) == 0) return;
    const int channels = static_cast<int>((info >> 1) & 7);
    const int32_t lx = loadI32(e + 20), ly = loadI32(e + 24), px = loadI32(e + 28),
                  py = loadI32(e + 32);
    if (channels != 1 && channels != 3 && channels != 4)
      file_.failAt(at, "frame with " + std::to_string(channels) + " channels (1, 3 or 4 expected)");
    if (lx <= 0 || ly <= 0 || lx > 65535 || ly > 65535 || px < 0 || py < 0 ||
        kFrameHeaderBytes + int64_t{2} * lx * ly * channels > event_size_) {
      file_.failAt(at, "frame of " + std::to_string(lx) + "x" + std::to_string(ly) + "x" +
                           std::to_string(channels) + " pixels does not fit its " +
                           std::to_string(event_size_) + "-byte event");
    }
    cv::Mat raw(ly, lx, CV_16UC(channels));
    const uint8_t* pixels = e + kFrameHeaderBytes;
    uint16_t* out = raw.ptr<uint16_t>();
    for (size_t i = 0;
         i < static_cast<size_t>(lx) * static_cast<size_t>(ly) * static_cast<size_t>(channels);
         ++i) {
      out[i] = loadLe16(pixels + 2 * i);
    }
    if (channels == 3) cv::cvtColor(raw, raw, cv::COLOR_RGB2BGR);
    if (channels == 4) cv::cvtColor(raw, raw, cv::COLOR_RGBA2BGR);
    Frame frame;
    frame.bit_depth = 16;
    cv::Mat image;
    raw.convertTo(image, CV_32F, 1.0 / 65535.0);
    const SensorSize s = info_.sensor;
    if (s.known() && px + lx <= s.width && py + ly <= s.height &&
        (lx != s.width || ly != s.height)) {
      frame.image = cv::Mat::zeros(s.height, s.width, image.type());
      image.copyTo(frame.image(cv::Rect(px, py, lx, ly)));
    } else {
      frame.image = image;
    }
    frame.exposure_start_us = time(loadLe32(e + 12));
    frame.exposure_end_us = time(loadLe32(e + 16));
    if (frame.exposure_end_us < frame.exposure_start_us)
      file_.failAt(at, "frame exposure ends before it starts");
    chunk.frames.push_back(std::move(frame));
    ++info_.counters["frames"];
  }

  BinaryFile file_;
  std::vector<uint8_t> payload_;
  int64_t packet_offset_ = 0;
  int type_ = 0;
  int32_t event_size_ = 0;
  int32_t overflow_ = 0;
  size_t packet_events_ = 0, next_event_ = 0;
  int64_t last_t_ = INT64_MIN;
};

}  // namespace

std::unique_ptr<EventReader> openAedat31Reader(const std::string& path) {
  return std::make_unique<Aedat31Reader>(path);
}

}  // namespace evkit::detail
