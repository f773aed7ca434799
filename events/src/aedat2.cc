// jAER AEDAT 2.0 (DAVIS cameras).
//
// File: '#' header lines (CRLF; "#!AER-DAT2.0" first; "# AEChip: ...DAVIS240C" names the camera;
// an XML preferences dump), then records of a big-endian int32 address and a big-endian int32
// timestamp (µs). Address layout of jAER's DAVIS chips:
//   bit 31 = 0  DVS event: y = bits 30..22, x = bits 21..12, polarity = bit 11 (1 = ON);
//               bit 10 set marks an external-input (special) event instead
//   bit 31 = 1  APS read or IMU sample: readout type = bits 11..10 (0 reset read, 1 signal read,
//               3 IMU: address & 0x80000C00 == 0x80000C00), y = bits 30..22, x = bits 21..12,
//               ADC value = bits 9..0
// jAER's origin is bottom-left and its DVS x is mirrored, so (DESIGN.md §2, top-left origin):
//   DVS: x = W-1 - x_raw, y = H-1 - y_raw;   APS: x = x_raw, y = H-1 - y_raw.
// A frame is a global-shutter pass: reset reads of every pixel, then signal reads; its value is
// reset - signal clamped to [0, 1023], its exposure runs from the last reset read to the first
// signal read. Timestamps are 32-bit and wrap; a wrap is a backward jump of more than 2^31 µs.

#include <algorithm>
#include <cstring>

#include "binary_file.h"
#include "evkit/base/error.h"
#include "formats.h"

namespace evkit::detail {

namespace {

constexpr size_t kRecordBytes = 8;
constexpr size_t kBlockRecords = size_t{1} << 17;
constexpr uint32_t kApsOrImuBit = 0x80000000u;
constexpr uint32_t kImuMask = 0x80000C00u;
constexpr uint32_t kExternalInputBit = 0x400u;
constexpr int kAdcMax = 1023;

class Aedat2Reader final : public EventReader {
 public:
  explicit Aedat2Reader(const std::string& path) : file_(path) {
    info_.format = Format::kAedat2;
    info_.layout = "aedat2";
    readHeader();
    block_.resize(std::min<size_t>(
        kBlockRecords * kRecordBytes,
        static_cast<size_t>(file_.remaining()) / kRecordBytes * kRecordBytes + kRecordBytes));
    for (const char* key : {"dvs_events", "aps_words", "imu_words", "special_words", "frames"}) {
      info_.counters[key] = 0;
    }
  }

 protected:
  bool readChunk(Chunk& chunk, size_t max_events) override {
    EventStore& ev = chunk.events;
    ev.setSensor(info_.sensor);
    const size_t start_events = ev.size(), start_frames = chunk.frames.size();
    while (ev.size() - start_events < max_events) {
      if (pos_ == len_ && !refill()) break;
      const uint8_t* rec = block_.data() + pos_ * kRecordBytes;
      const uint32_t addr = loadBe32(rec);
      const int64_t t = unwrap(loadBe32(rec + 4));
      ++pos_;
      if ((addr & kApsOrImuBit) == 0) {
        if (addr & kExternalInputBit) {
          ++special_;
          continue;
        }
        const int x_raw = static_cast<int>((addr >> 12) & 0x3FF);
        const int y_raw = static_cast<int>((addr >> 22) & 0x1FF);
        if (x_raw >= width_ || y_raw >= height_) {
          file_.failAt(recordOffset(), "DVS event (x, y) = (" + std::to_string(x_raw) + ", " +
                                           std::to_string(y_raw) + ") outside the " +
                                           std::to_string(width_) + "x" + std::to_string(height_) +
                                           " sensor of the AEChip");
        }
        if (t < last_dvs_t_) {
          file_.failAt(recordOffset(), "DVS timestamp " + std::to_string(t) +
                                           " us goes back in time (previous " +
                                           std::to_string(last_dvs_t_) + " us)");
        }
        last_dvs_t_ = t;
        ev.push_back(t, static_cast<uint16_t>(width_ - 1 - x_raw),
                     static_cast<uint16_t>(height_ - 1 - y_raw), (addr >> 11) & 1 ? 1 : -1);
        ++dvs_;
      } else if ((addr & kImuMask) == kImuMask) {
        ++imu_;
      } else {
        ++aps_;
        apsRead(addr, t, chunk);
      }
    }
    info_.counters["dvs_events"] = dvs_;
    info_.counters["aps_words"] = aps_;
    info_.counters["imu_words"] = imu_;
    info_.counters["special_words"] = special_;
    info_.counters["frames"] = frames_;
    return ev.size() > start_events || chunk.frames.size() > start_frames;
  }

 private:
  void readHeader() {
    std::string line;
    if (!file_.readLine(line, 4096) || line.rfind("#!AER-DAT", 0) != 0) {
      file_.failAt(0, "not an AEDAT file (expected '#!AER-DAT2.0' on the first line)");
    }
    if (line.rfind("#!AER-DAT2", 0) != 0) {
      file_.failAt(0, "'" + line.substr(0, 20) + "' is not AEDAT 2.0 (wrong --format?)");
    }
    std::string chip;
    while (file_.peek() == '#') {
      file_.readLine(line);
      const size_t at = line.find("AEChip:");
      if (at != std::string::npos && line.rfind("#", 0) == 0 && chip.empty()) {
        chip = line.substr(at + 7);
        chip.erase(0, chip.find_first_not_of(' '));
        chip = chip.substr(
            chip.find_last_of('.') == std::string::npos ? 0 : chip.find_last_of('.') + 1);
      }
    }
    data_start_ = file_.offset();
    info_.counters["header_bytes"] = data_start_;
    info_.camera = chip;
    const SensorSizeGuess size = sensorSizeForCamera(chip);
    if (size.width == 0) {
      file_.failAt(0, chip.empty() ? "no '# AEChip:' header line, so the sensor size is unknown"
                                   : "AEChip '" + chip + "' is not a DAVIS240/346/640 camera");
    }
    width_ = size.width;
    height_ = size.height;
    info_.sensor = SensorSize{width_, height_};
    const int64_t data_bytes = file_.size() - data_start_;
    info_.counters["records"] = data_bytes / static_cast<int64_t>(kRecordBytes);
    if (data_bytes % static_cast<int64_t>(kRecordBytes) != 0) {
      info_.warnings.push_back(file_.path() + ": the last record is cut off (" +
                               std::to_string(data_bytes % static_cast<int64_t>(kRecordBytes)) +
                               " bytes ignored)");
    }
  }

  bool refill() {
    const size_t got = file_.read(block_.data(), block_.size());
    block_offset_ = file_.offset() - static_cast<int64_t>(got);
    len_ = got / kRecordBytes;
    pos_ = 0;
    return len_ > 0;
  }

  int64_t recordOffset() const {
    return block_offset_ + static_cast<int64_t>((pos_ - 1) * kRecordBytes);
  }

  int64_t unwrap(uint32_t raw) {
    if (have_t_ && raw < last_raw_ && last_raw_ - raw > 0x80000000u) wrap_ += int64_t{1} << 32;
    have_t_ = true;
    last_raw_ = raw;
    return wrap_ + raw;
  }

  void apsRead(uint32_t addr, int64_t t, Chunk& chunk) {
    const int type = static_cast<int>((addr >> 10) & 3);
    const int x = static_cast<int>((addr >> 12) & 0x3FF);
    const int y_raw = static_cast<int>((addr >> 22) & 0x1FF);
    if (type > 1) return;  // other readouts (e.g. colour "C" reads) are not frames
    if (x >= width_ || y_raw >= height_) {
      file_.failAt(recordOffset(), "APS read (x, y) = (" + std::to_string(x) + ", " +
                                       std::to_string(y_raw) + ") outside the sensor");
    }
    const size_t pixels = static_cast<size_t>(width_) * static_cast<size_t>(height_);
    if (reset_.empty()) {
      reset_.assign(pixels, 0);
      signal_.assign(pixels, 0);
    }
    const size_t index = static_cast<size_t>(height_ - 1 - y_raw) * static_cast<size_t>(width_) +
                         static_cast<size_t>(x);
    const int value = static_cast<int>(addr & 0x3FF);
    if (type == 0) {
      if (signals_ > 0) {
        // A new reset pass before the previous frame was complete: drop the partial frame.
        signals_ = 0;
        resets_ = 0;
      }
      reset_[index] = value;
      ++resets_;
      last_reset_t_ = t;
    } else {
      if (resets_ == 0) return;  // signal reads of a frame whose resets preceded the file
      if (signals_ == 0) first_signal_t_ = t;
      signal_[index] = value;
      if (++signals_ == pixels) {
        Frame frame;
        frame.image.create(height_, width_, CV_32F);
        float* out = frame.image.ptr<float>();
        for (size_t i = 0; i < pixels; ++i) {
          out[i] = static_cast<float>(std::clamp(reset_[i] - signal_[i], 0, kAdcMax)) / kAdcMax;
        }
        frame.exposure_start_us = last_reset_t_;
        frame.exposure_end_us = first_signal_t_;
        frame.bit_depth = 16;  // 10-bit ADC: kept at 16 bits when written out
        chunk.frames.push_back(std::move(frame));
        ++frames_;
        signals_ = 0;
        resets_ = 0;
      }
    }
  }

  BinaryFile file_;
  int width_ = 0, height_ = 0;
  int64_t data_start_ = 0;
  std::vector<uint8_t> block_;
  size_t pos_ = 0, len_ = 0;
  int64_t block_offset_ = 0;
  bool have_t_ = false;
  uint32_t last_raw_ = 0;
  int64_t wrap_ = 0;
  int64_t last_dvs_t_ = INT64_MIN;
  int64_t dvs_ = 0, aps_ = 0, imu_ = 0, special_ = 0, frames_ = 0;
  // Frame assembly.
  std::vector<int> reset_, signal_;
  size_t resets_ = 0, signals_ = 0;
  int64_t last_reset_t_ = 0, first_signal_t_ = 0;
};

}  // namespace

std::unique_ptr<EventReader> openAedat2Reader(const std::string& path) {
  return std::make_unique<Aedat2Reader>(path);
}

}  // namespace evkit::detail
