// Prophesee recordings: EVT 2.0 and EVT 3.0 raw streams and the DAT format.
//
// All start with '%' header lines ("% evt 2.0", "% format EVT3;height=720;width=1280",
// "% geometry 640x480", "% Width 304", "% end", ...), then little-endian binary data.
//   EVT 2.0 (32-bit words, type = bits 31..28): 0x0 CD OFF / 0x1 CD ON with bits 27..22 the 6 low
//     bits of the time, bits 21..11 x, bits 10..0 y; 0x8 EV_TIME_HIGH with bits 27..0 the high
//     bits (t = high << 6 | low, 34 bits, wrapping); 0xA external trigger, 0xE other, 0xF
//     continued.
//   EVT 3.0 (16-bit words, type = bits 15..12): 0x0 EVT_ADDR_Y (y = bits 10..0), 0x2 EVT_ADDR_X
//     (x = bits 10..0, polarity bit 11: one event), 0x3 VECT_BASE_X (base x and polarity), 0x4
//     VECT_12 / 0x5 VECT_8 (a bit mask of events at base x, base x advances), 0x6 EVT_TIME_LOW
//     (bits 11..0), 0x8 EVT_TIME_HIGH (bits 23..12 of the 24-bit time, wrapping), 0xA trigger,
//     0xE other, 0xF continued.
//   DAT: after the header two bytes (event type, event size = 8), then records of uint32 t (µs)
//     and uint32 data with x = bits 13..0, y = bits 27..14, polarity = bits 31..28.
// Sensor size: from the header, else from the camera generation in "plugin_name" (gen3: 640x480,
// gen4/imx636: 1280x720), else unknown (the bounding box of the events).

#include <algorithm>
#include <cctype>

#include "binary_file.h"
#include "evkit/base/error.h"
#include "formats.h"

namespace evkit::detail {

namespace {

constexpr size_t kBlockBytes = size_t{1} << 20;

struct PropheseeHeader {
  std::string evt;  // "2.0", "3.0" or "" (DAT)
  SensorSize sensor;
  std::string camera;
};

int parseDimension(const std::string& text) {
  int v = 0, digits = 0;
  for (char c : text) {
    if (c < '0' || c > '9') break;
    v = v * 10 + (c - '0');
    if (++digits > 5) return 0;
  }
  return v;
}

PropheseeHeader readPropheseeHeader(BinaryFile& file) {
  PropheseeHeader h;
  std::string line;
  int width = 0, height = 0;
  while (file.peek() == '%') {
    file.readLine(line, 1 << 16);
    std::string lower = line;
    std::transform(lower.begin(), lower.end(), lower.begin(),
                   [](unsigned char c) { return std::tolower(c); });
    if (lower == "% end") break;
    const auto value_after = [&](const std::string& key) -> std::string {
      const size_t at = lower.find(key);
      return at == std::string::npos ? std::string() : lower.substr(at + key.size());
    };
    if (lower.rfind("% evt ", 0) == 0) h.evt = lower.substr(6);
    if (lower.rfind("% format ", 0) == 0) {
      if (lower.find("evt3") != std::string::npos) h.evt = "3.0";
      if (lower.find("evt2") != std::string::npos) h.evt = "2.0";
      if (const std::string w = value_after("width="); !w.empty()) width = parseDimension(w);
      if (const std::string hh = value_after("height="); !hh.empty()) height = parseDimension(hh);
    }
    if (lower.rfind("% geometry ", 0) == 0) {
      const std::string g = lower.substr(11);
      width = parseDimension(g);
      const size_t x = g.find('x');
      if (x != std::string::npos) height = parseDimension(g.substr(x + 1));
    }
    if (lower.rfind("% width ", 0) == 0) width = parseDimension(lower.substr(8));
    if (lower.rfind("% height ", 0) == 0) height = parseDimension(lower.substr(9));
    if (lower.rfind("% plugin_name ", 0) == 0) h.camera = line.substr(14);
  }
  if (width > 0 && height > 0) {
    h.sensor = SensorSize{width, height};
  } else {
    std::string c = h.camera;
    std::transform(c.begin(), c.end(), c.begin(),
                   [](unsigned char ch) { return std::tolower(ch); });
    if (c.find("gen3") != std::string::npos) h.sensor = SensorSize{640, 480};
    if (c.find("gen4") != std::string::npos || c.find("imx636") != std::string::npos)
      h.sensor = SensorSize{1280, 720};
  }
  return h;
}

// Shared machinery: block reading, event checks with byte offsets.
class PropheseeReader : public EventReader {
 protected:
  PropheseeReader(const std::string& path, Format format, const char* layout) : file_(path) {
    info_.format = format;
    info_.layout = layout;
    header_ = readPropheseeHeader(file_);
    info_.sensor = header_.sensor;
    info_.camera = header_.camera;
  }

  // Appends one event after checking it; `at` is its byte offset.
  void emit(EventStore& ev, int64_t t, int x, int y, bool on, int64_t at) {
    if (info_.sensor.known() && (x >= info_.sensor.width || y >= info_.sensor.height)) {
      file_.failAt(at, "event (x, y) = (" + std::to_string(x) + ", " + std::to_string(y) +
                           ") outside the " + std::to_string(info_.sensor.width) + "x" +
                           std::to_string(info_.sensor.height) + " sensor");
    }
    if (t < last_t_) {
      file_.failAt(at, "timestamp " + std::to_string(t) + " us goes back in time (previous " +
                           std::to_string(last_t_) + " us)");
    }
    last_t_ = t;
    ev.push_back(t, static_cast<uint16_t>(x), static_cast<uint16_t>(y), on ? 1 : -1);
  }

  // Refills block_ with whole words of `word_bytes`; false at the end. A cut-off last word is
  // tolerated with a warning.
  bool refill(size_t word_bytes) {
    block_.resize(
        std::min<size_t>(kBlockBytes, static_cast<size_t>(file_.remaining()) + word_bytes));
    const size_t got = file_.read(block_.data(), block_.size());
    block_offset_ = file_.offset() - static_cast<int64_t>(got);
    const size_t whole = got / word_bytes * word_bytes;
    if (whole < got) {
      info_.warnings.push_back(file_.path() + ": the last record is cut off (" +
                               std::to_string(got - whole) + " bytes ignored)");
    }
    block_.resize(whole);
    pos_ = 0;
    return whole > 0;
  }

  BinaryFile file_;
  PropheseeHeader header_;
  std::vector<uint8_t> block_;
  size_t pos_ = 0;
  int64_t block_offset_ = 0;
  int64_t last_t_ = INT64_MIN;
};

class Evt2Reader final : public PropheseeReader {
 public:
  explicit Evt2Reader(const std::string& path) : PropheseeReader(path, Format::kEvt2, "evt2") {}

 protected:
  bool readChunk(Chunk& chunk, size_t max_events) override {
    EventStore& ev = chunk.events;
    ev.setSensor(info_.sensor);
    const size_t start = ev.size();
    while (ev.size() - start < max_events) {
      if (pos_ == block_.size() && !refill(4)) break;
      const uint32_t w = loadLe32(block_.data() + pos_);
      const int64_t at = block_offset_ + static_cast<int64_t>(pos_);
      pos_ += 4;
      const uint32_t type = w >> 28;
      if (type == 0x8) {
        const int64_t high = w & 0x0FFFFFFF;
        if (have_high_ && high < high_ && high_ - high > (int64_t{1} << 27))
          wrap_ += int64_t{1} << 34;
        high_ = high;
        have_high_ = true;
      } else if (type <= 0x1) {
        if (!have_high_) {
          ++before_time_high_;  // no time base yet: cannot be timed
          continue;
        }
        const int64_t t = wrap_ + ((high_ << 6) | ((w >> 22) & 0x3F));
        emit(ev, t, static_cast<int>((w >> 11) & 0x7FF), static_cast<int>(w & 0x7FF), type == 0x1,
             at);
      } else if (type == 0xA) {
        ++triggers_;
      }
    }
    info_.counters["triggers"] = triggers_;
    info_.counters["events_before_first_time_high"] = before_time_high_;
    return ev.size() > start;
  }

 private:
  bool have_high_ = false;
  int64_t high_ = 0, wrap_ = 0;
  int64_t triggers_ = 0, before_time_high_ = 0;
};

class Evt3Reader final : public PropheseeReader {
 public:
  explicit Evt3Reader(const std::string& path) : PropheseeReader(path, Format::kEvt3, "evt3") {}

 protected:
  bool readChunk(Chunk& chunk, size_t max_events) override {
    EventStore& ev = chunk.events;
    ev.setSensor(info_.sensor);
    const size_t start = ev.size();
    // A vector word can add 12 events: stop early enough not to split one.
    while (ev.size() - start + 12 <= std::max<size_t>(max_events, 12)) {
      if (pos_ == block_.size() && !refill(2)) break;
      const uint16_t w = loadLe16(block_.data() + pos_);
      const int64_t at = block_offset_ + static_cast<int64_t>(pos_);
      pos_ += 2;
      switch (w >> 12) {
        case 0x0:
          y_ = w & 0x7FF;
          break;
        case 0x2:
          if (timed()) emit(ev, time(), w & 0x7FF, y_, (w >> 11) & 1, at);
          break;
        case 0x3:
          base_x_ = w & 0x7FF;
          base_on_ = (w >> 11) & 1;
          break;
        case 0x4:
        case 0x5: {
          const int bits = (w >> 12) == 0x4 ? 12 : 8;
          if (timed()) {
            for (int b = 0; b < bits; ++b) {
              if (w & (1u << b)) emit(ev, time(), base_x_ + b, y_, base_on_, at);
            }
          }
          base_x_ += bits;
          break;
        }
        case 0x6:
          low_ = w & 0xFFF;
          have_low_ = true;
          break;
        case 0x8: {
          const int64_t high = w & 0xFFF;
          if (have_high_ && high < high_ && high_ - high > 0x800) wrap_ += int64_t{1} << 24;
          high_ = high;
          have_high_ = true;
          break;
        }
        case 0xA:
          ++triggers_;
          break;
        default:
          break;
      }
    }
    info_.counters["triggers"] = triggers_;
    return ev.size() > start;
  }

 private:
  bool timed() const { return have_high_ && have_low_; }
  int64_t time() const { return wrap_ + ((high_ << 12) | low_); }

  int y_ = 0, base_x_ = 0;
  bool base_on_ = false;
  int64_t low_ = 0, high_ = 0, wrap_ = 0;
  bool have_low_ = false, have_high_ = false;
  int64_t triggers_ = 0;
};

class DatReader final : public PropheseeReader {
 public:
  explicit DatReader(const std::string& path) : PropheseeReader(path, Format::kDat, "dat") {
    uint8_t type_size[2];
    if (file_.read(type_size, 2) != 2)
      file_.fail("truncated: expected the event type and size bytes after the header");
    if (type_size[1] != 8) {
      file_.failAt(file_.offset() - 1, "event size " + std::to_string(type_size[1]) +
                                           " (only 8-byte CD events are supported)");
    }
    info_.counters["event_type"] = type_size[0];
  }

 protected:
  bool readChunk(Chunk& chunk, size_t max_events) override {
    EventStore& ev = chunk.events;
    ev.setSensor(info_.sensor);
    const size_t start = ev.size();
    while (ev.size() - start < max_events) {
      if (pos_ == block_.size() && !refill(8)) break;
      const uint32_t raw_t = loadLe32(block_.data() + pos_);
      const uint32_t data = loadLe32(block_.data() + pos_ + 4);
      const int64_t at = block_offset_ + static_cast<int64_t>(pos_);
      pos_ += 8;
      if (have_t_ && raw_t < last_raw_ && last_raw_ - raw_t > 0x80000000u)
        wrap_ += int64_t{1} << 32;
      have_t_ = true;
      last_raw_ = raw_t;
      emit(ev, wrap_ + raw_t, static_cast<int>(data & 0x3FFF),
           static_cast<int>((data >> 14) & 0x3FFF), (data >> 28) != 0, at);
    }
    return ev.size() > start;
  }

 private:
  bool have_t_ = false;
  uint32_t last_raw_ = 0;
  int64_t wrap_ = 0;
};

}  // namespace

std::unique_ptr<EventReader> openEvt2Reader(const std::string& path) {
  return std::make_unique<Evt2Reader>(path);
}
std::unique_ptr<EventReader> openEvt3Reader(const std::string& path) {
  return std::make_unique<Evt3Reader>(path);
}
std::unique_ptr<EventReader> openDatReader(const std::string& path) {
  return std::make_unique<DatReader>(path);
}

std::string propheseeRawVersion(const std::string& path) {
  BinaryFile file(path);
  return readPropheseeHeader(file).evt;
}

}  // namespace evkit::detail
