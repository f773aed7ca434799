// iniVation DV AEDAT 4.0, read and write.
//
// File: "#!AER-DAT4.0\r\n", a little-endian uint32 length, the IOHeader FlatBuffer (compression,
// data_table_position, an XML description of the output streams: id, typeIdentifier EVTS / FRME /
// IMUS / TRIG, sizeX, sizeY, source), then packets: int32 stream id, int32 byte size, and that many
// bytes holding one size-prefixed FlatBuffer, compressed as a whole (LZ4 frame or Zstandard) or
// not. An optional file data table (FTAB: per packet its offset, stream, element count and time
// range) sits at data_table_position, compressed the same way, up to the end of the file.
// Schemas: events/schema/*.fbs. Every FlatBuffer read from a file passes flatbuffers::Verifier
// before it is touched.

#include <algorithm>
#include <cstring>
#include <filesystem>
#include <map>
#include <opencv2/imgproc.hpp>
#include <sstream>

#include "aedat4/events_generated.h"
#include "aedat4/filedatatable_generated.h"
#include "aedat4/frame_generated.h"
#include "aedat4/imus_generated.h"
#include "aedat4/ioheader_generated.h"
#include "aedat4/triggers_generated.h"
#include "aedat4_format.h"
#include "binary_file.h"
#include "codec.h"
#include "evkit/base/error.h"
#include "evkit/events/atomic_file.h"
#include "evkit/events/image_io.h"
#include "formats.h"

namespace evkit::detail {

namespace fb4 = evkit::aedat4;

namespace {

constexpr uint32_t kMaxHeaderBytes = 16u << 20;
constexpr size_t kMaxDecompressedBytes = size_t{512}
                                         << 20;  // decompressed; a 4K BGRA16 frame is 64 MB

Codec codecFor(fb4::CompressionType c) {
  switch (c) {
    case fb4::CompressionType::NONE:
      return Codec::kNone;
    case fb4::CompressionType::LZ4:
    case fb4::CompressionType::LZ4_HIGH:
      return Codec::kLz4;
    case fb4::CompressionType::ZSTD:
    case fb4::CompressionType::ZSTD_HIGH:
      return Codec::kZstd;
  }
  return Codec::kNone;
}

struct StreamInfo {
  std::string type;  // EVTS, FRME, IMUS, TRIG, ...
  int width = 0, height = 0;
  std::string source;
};

// The text of <attr key="KEY" ...>TEXT</attr> inside xml[begin, end), or "".
std::string attrText(const std::string& xml, size_t begin, size_t end, const std::string& key) {
  const size_t at = xml.find("key=\"" + key + "\"", begin);
  if (at == std::string::npos || at >= end) return "";
  const size_t open = xml.find('>', at);
  const size_t close = xml.find("</attr>", at);
  if (open == std::string::npos || close == std::string::npos || close < open || close > end)
    return "";
  return xml.substr(open + 1, close - open - 1);
}

// Streams of the IOHeader's XML: the children <node name="ID" path=".../outInfo/ID/"> of outInfo.
std::map<int, StreamInfo> parseStreams(const std::string& xml) {
  std::map<int, StreamInfo> streams;
  std::vector<std::pair<int, size_t>> starts;
  for (size_t at = xml.find("outInfo/"); at != std::string::npos;
       at = xml.find("outInfo/", at + 8)) {
    // Only ".../outInfo/<digits>/\"" opens a stream node.
    size_t p = at + 8;
    int id = 0, digits = 0;
    while (p < xml.size() && xml[p] >= '0' && xml[p] <= '9' && digits < 9)
      id = id * 10 + (xml[p++] - '0'), ++digits;
    if (digits == 0 || p + 1 >= xml.size() || xml[p] != '/' || xml[p + 1] != '"') continue;
    starts.emplace_back(id, at);
  }
  for (size_t i = 0; i < starts.size(); ++i) {
    const size_t begin = starts[i].second;
    const size_t end = i + 1 < starts.size() ? starts[i + 1].second : xml.size();
    StreamInfo s;
    s.type = attrText(xml, begin, end, "typeIdentifier");
    s.source = attrText(xml, begin, end, "source");
    const auto number = [](const std::string& text) {
      int v = 0;
      for (char c : text) {
        if (c == ' ') continue;
        if (c < '0' || c > '9' || v > 100000) return 0;
        v = v * 10 + (c - '0');
      }
      return v;
    };
    s.width = number(attrText(xml, begin, end, "sizeX"));
    s.height = number(attrText(xml, begin, end, "sizeY"));
    if (!s.type.empty()) streams[starts[i].first] = s;
  }
  return streams;
}

template <typename T>
const T* verifiedSizePrefixedRoot(const std::vector<uint8_t>& buf, size_t size,
                                  const char* identifier) {
  flatbuffers::Verifier verifier(buf.data(), size, 64, 10'000'000);
  if (!verifier.VerifySizePrefixedBuffer<T>(identifier)) return nullptr;
  return flatbuffers::GetSizePrefixedRoot<T>(buf.data());
}

class Aedat4Reader final : public EventReader {
 public:
  explicit Aedat4Reader(const std::string& path) : file_(path) {
    info_.format = Format::kAedat4;
    readHeader();
  }

 protected:
  bool readChunk(Chunk& chunk, size_t max_events) override {
    EventStore& ev = chunk.events;
    ev.setSensor(info_.sensor);
    const size_t start_events = ev.size(), start_frames = chunk.frames.size();
    while (ev.size() - start_events < max_events) {
      if (events_ != nullptr && next_ < events_->size()) {
        const size_t n = std::min(events_->size() - next_, max_events - (ev.size() - start_events));
        appendEvents(ev, next_, n);
        next_ += n;
        continue;
      }
      events_ = nullptr;
      if (!nextPacket(chunk)) break;
    }
    return ev.size() > start_events || chunk.frames.size() > start_frames;
  }

  void seek(int64_t t_begin) override {
    // With a data table: jump to the first packet (of any stream) that ends at or after t_begin.
    if (data_table_ < 0) return;
    try {
      file_.seek(data_table_);
      std::vector<uint8_t> raw(static_cast<size_t>(file_.remaining()));
      file_.readExact(raw.data(), raw.size(), "file data table");
      std::string error;
      size_t table_size = 0;
      if (!decompress(codec_, raw.data(), raw.size(), table_buf_, table_size, kMaxDecompressedBytes,
                      error))
        throw Error(error);
      const auto* table =
          verifiedSizePrefixedRoot<fb4::FileDataTable>(table_buf_, table_size, "FTAB");
      if (table == nullptr || table->table() == nullptr) throw Error("invalid file data table");
      // byte_offset is where the packet's data starts, 8 bytes after its header (as DV writes it).
      int64_t target = -1;
      for (const fb4::FileDataDefinition* d : *table->table()) {
        const int64_t header_at = d->byte_offset() - 8;
        if (d->t_end() >= t_begin && header_at >= packets_start_ && header_at < data_table_) {
          target = target < 0 ? header_at : std::min(target, header_at);
        }
      }
      file_.seek(target < 0 ? data_table_ : target);
    } catch (const Error&) {
      // The table is an accelerator, never required: fall back to reading from the start.
      info_.warnings.push_back(file_.path() + ": unreadable file data table ignored");
      file_.seek(packets_start_);
    }
  }

 private:
  void readHeader() {
    char magic[kAedat4MagicBytes];
    if (file_.read(magic, kAedat4MagicBytes) != kAedat4MagicBytes ||
        std::memcmp(magic, kAedat4Magic, kAedat4MagicBytes) != 0) {
      file_.failAt(0, "not an AEDAT 4.0 file (expected '#!AER-DAT4.0' and CRLF)");
    }
    // The header is a size-prefixed FlatBuffer: its alignment counts from the length field, so the
    // length is read into the (8-aligned) buffer too.
    uint8_t len_bytes[4];
    file_.readExact(len_bytes, 4, "the header length");
    const uint32_t len = loadLe32(len_bytes);
    if (len > kMaxHeaderBytes || len > file_.remaining())
      file_.failAt(14, "header length " + std::to_string(len) + " runs past the end of the file");
    std::vector<uint8_t> header(size_t{len} + 4);
    std::memcpy(header.data(), len_bytes, 4);
    file_.readExact(header.data() + 4, len, "the IOHeader");
    flatbuffers::Verifier verifier(header.data(), header.size(), 64, 1000);
    if (!verifier.VerifySizePrefixedBuffer<fb4::IOHeader>(nullptr))
      file_.failAt(18, "corrupt IOHeader FlatBuffer");
    const fb4::IOHeader* h = flatbuffers::GetSizePrefixedRoot<fb4::IOHeader>(header.data());
    const int32_t compression = static_cast<int32_t>(h->compression());
    if (compression < 0 || compression > 4)
      file_.failAt(18, "unknown compression " + std::to_string(compression));
    codec_ = codecFor(h->compression());
    data_table_ = h->data_table_position();
    packets_start_ = file_.offset();
    if (data_table_ >= 0 && (data_table_ < packets_start_ || data_table_ > file_.size())) {
      info_.warnings.push_back(file_.path() + ": data table position outside the file ignored");
      data_table_ = -1;
    }
    static constexpr const char* kNames[] = {"none", "lz4", "lz4-high", "zstd", "zstd-high"};
    info_.layout = std::string("aedat4-") + kNames[compression];
    info_.counters["compression"] = compression;
    info_.counters["data_table_position"] = data_table_;
    streams_ = parseStreams(h->info_node() ? h->info_node()->str() : "");
    if (streams_.empty()) file_.failAt(18, "the header describes no output streams");
    for (const auto& [id, s] : streams_) {
      info_.counters["packets." + s.type] = 0;
      if (s.type == "EVTS" && !info_.sensor.known() && s.width > 0 && s.height > 0) {
        info_.sensor = SensorSize{s.width, s.height};
        info_.camera = s.source;
      }
    }
    for (const auto& [id, s] : streams_) {
      if (s.type == "FRME" && !info_.sensor.known() && s.width > 0)
        info_.sensor = SensorSize{s.width, s.height};
    }
  }

  // Reads the next packet; events are left in events_, frames appended to the chunk.
  bool nextPacket(Chunk& chunk) {
    while (true) {
      if (data_table_ >= 0 && file_.offset() >= data_table_) return false;
      const int64_t at = file_.offset();
      uint8_t h[8];
      const size_t got = file_.read(h, 8);
      if (got == 0) return false;
      if (got < 8) file_.failAt(at, "truncated packet header (8 bytes expected)");
      const int32_t stream = static_cast<int32_t>(loadLe32(h));
      const int32_t size = static_cast<int32_t>(loadLe32(h + 4));
      const int64_t limit = data_table_ >= 0 ? data_table_ : file_.size();
      if (size < 0 || size > limit - file_.offset()) {
        file_.failAt(at, "packet of " + std::to_string(size) +
                             " bytes runs past the end of the file (truncated?)");
      }
      raw_.resize(static_cast<size_t>(size));
      file_.readExact(raw_.data(), raw_.size(), "packet data");
      const auto it = streams_.find(stream);
      if (it == streams_.end())
        file_.failAt(at, "packet of stream " + std::to_string(stream) +
                             ", which the header does not declare");
      const std::string& type = it->second.type;
      ++info_.counters["packets." + type];
      if (type != "EVTS" && type != "FRME" && type != "IMUS" && type != "TRIG") continue;
      std::string error;
      size_t size_out = 0;
      if (!decompress(codec_, raw_.data(), raw_.size(), buf_, size_out, kMaxDecompressedBytes,
                      error))
        file_.failAt(at + 8, error);
      if (type == "EVTS") {
        const auto* packet = verifiedSizePrefixedRoot<fb4::EventPacket>(buf_, size_out, "EVTS");
        if (packet == nullptr)
          file_.failAt(at + 8, "corrupt EVTS packet (FlatBuffer verification failed)");
        if (packet->elements() == nullptr || packet->elements()->size() == 0) continue;
        events_ = packet->elements();
        next_ = 0;
        packet_at_ = at;
        return true;
      }
      if (type == "FRME") {
        const auto* frame = verifiedSizePrefixedRoot<fb4::Frame>(buf_, size_out, "FRME");
        if (frame == nullptr)
          file_.failAt(at + 8, "corrupt FRME packet (FlatBuffer verification failed)");
        chunk.frames.push_back(toFrame(*frame, it->second, at));
        ++info_.counters["frames"];
        return true;
      }
      if (type == "IMUS") {
        const auto* imu = verifiedSizePrefixedRoot<fb4::ImuPacket>(buf_, size_out, "IMUS");
        if (imu == nullptr)
          file_.failAt(at + 8, "corrupt IMUS packet (FlatBuffer verification failed)");
        info_.counters["imu_samples"] += imu->elements() ? imu->elements()->size() : 0;
      } else {
        const auto* trig = verifiedSizePrefixedRoot<fb4::TriggerPacket>(buf_, size_out, "TRIG");
        if (trig == nullptr)
          file_.failAt(at + 8, "corrupt TRIG packet (FlatBuffer verification failed)");
        info_.counters["triggers"] += trig->elements() ? trig->elements()->size() : 0;
      }
    }
  }

  static fb4::Event eventAt(const uint8_t* events, size_t i) {
    fb4::Event e;
    std::memcpy(static_cast<void*>(&e), events + i * sizeof(fb4::Event), sizeof(fb4::Event));
    return e;
  }

  void appendEvents(EventStore& ev, size_t first, size_t n) {
    const size_t base = ev.size();
    ev.t.resize(base + n);
    ev.x.resize(base + n);
    ev.y.resize(base + n);
    ev.p.resize(base + n);
    const int w = info_.sensor.known() ? info_.sensor.width : 65536;
    const int h = info_.sensor.known() ? info_.sensor.height : 65536;
    bool bad = false;
    int64_t prev = last_t_;
    // The verifier checks the vector's length field (4-byte aligned), not its 8-byte structs:
    // each event is copied out rather than read in place.
    const uint8_t* in = events_->Data() + first * sizeof(fb4::Event);  // verified size
    int64_t* out_t = ev.t.data() + base;
    uint16_t* out_x = ev.x.data() + base;
    uint16_t* out_y = ev.y.data() + base;
    int8_t* out_p = ev.p.data() + base;
    for (size_t i = 0; i < n; ++i) {
      const fb4::Event e = eventAt(in, i);
      const int64_t t = e.t();
      const int x = e.x(), y = e.y();
      bad |= (x < 0) | (y < 0) | (x >= w) | (y >= h) | (t < prev);
      prev = t;
      out_t[i] = t;
      out_x[i] = static_cast<uint16_t>(x);
      out_y[i] = static_cast<uint16_t>(y);
      out_p[i] = static_cast<int8_t>(2 * static_cast<int>(e.on()) - 1);  // branch-free
    }
    if (bad) {
      for (size_t i = 0; i < n; ++i) {
        const fb4::Event e = eventAt(in, i);
        const std::string where = "event " + std::to_string(first + i) + " of the packet";
        if (e.x() < 0 || e.y() < 0 || e.x() >= w || e.y() >= h) {
          file_.failAt(packet_at_, where + ": (x, y) = (" + std::to_string(e.x()) + ", " +
                                       std::to_string(e.y()) + ") outside the " +
                                       std::to_string(w) + "x" + std::to_string(h) + " sensor");
        }
        if (e.t() < last_t_) {
          file_.failAt(packet_at_, where + ": timestamp " + std::to_string(e.t()) +
                                       " us goes back in time (previous " +
                                       std::to_string(last_t_) + " us)");
        }
        last_t_ = e.t();
      }
    }
    last_t_ = prev;
  }

  Frame toFrame(const fb4::Frame& f, const StreamInfo& stream, int64_t at) {
    int channels = 1, depth = CV_8U;
    switch (f.format()) {
      case fb4::FrameFormat::GRAY:
        break;
      case fb4::FrameFormat::GRAY16:
        depth = CV_16U;
        break;
      case fb4::FrameFormat::BGR:
        channels = 3;
        break;
      case fb4::FrameFormat::BGR16:
        channels = 3;
        depth = CV_16U;
        break;
      case fb4::FrameFormat::BGRA:
        channels = 4;
        break;
      case fb4::FrameFormat::BGRA16:
        channels = 4;
        depth = CV_16U;
        break;
      default:
        file_.failAt(
            at, "frame with unknown pixel format " + std::to_string(static_cast<int>(f.format())));
    }
    const int w = f.width(), h = f.height();
    const size_t bytes_per = depth == CV_16U ? 2 : 1;
    if (w <= 0 || h <= 0 || f.pixels() == nullptr ||
        f.pixels()->size() != static_cast<size_t>(w) * static_cast<size_t>(h) *
                                  static_cast<size_t>(channels) * bytes_per) {
      file_.failAt(at, "frame of " + std::to_string(w) + "x" + std::to_string(h) +
                           " pixels does not match its pixel data");
    }
    cv::Mat raw(h, w, CV_MAKETYPE(depth, channels));
    std::memcpy(raw.data, f.pixels()->data(), f.pixels()->size());
    if (channels == 4) cv::cvtColor(raw, raw, cv::COLOR_BGRA2BGR);
    Frame frame;
    frame.bit_depth = depth == CV_16U ? 16 : 8;
    cv::Mat image;
    raw.convertTo(image, CV_32F, depth == CV_16U ? 1.0 / 65535.0 : 1.0 / 255.0);
    const int ox = f.offset_x(), oy = f.offset_y();
    const int sw = stream.width, sh = stream.height;
    if (sw > 0 && sh > 0 && ox >= 0 && oy >= 0 && ox + w <= sw && oy + h <= sh &&
        (w != sw || h != sh)) {
      frame.image = cv::Mat::zeros(sh, sw, image.type());
      image.copyTo(frame.image(cv::Rect(ox, oy, w, h)));
    } else {
      frame.image = image;
    }
    // Exposure: the start/end fields when set, else timestamp + exposure duration.
    if (f.exposure_end_t() > f.exposure_begin_t() ||
        (f.exposure_begin_t() != 0 && f.exposure_end_t() == f.exposure_begin_t())) {
      frame.exposure_start_us = f.exposure_begin_t();
      frame.exposure_end_us = f.exposure_end_t();
    } else {
      frame.exposure_start_us = f.t();
      frame.exposure_end_us = f.t() + std::max<int64_t>(f.exposure(), 0);
    }
    return frame;
  }

  BinaryFile file_;
  Codec codec_ = Codec::kNone;
  int64_t data_table_ = -1;
  int64_t packets_start_ = 0;
  std::map<int, StreamInfo> streams_;
  std::vector<uint8_t> raw_, buf_, table_buf_;
  const flatbuffers::Vector<const fb4::Event*>* events_ = nullptr;
  size_t next_ = 0;
  int64_t packet_at_ = 0;
  int64_t last_t_ = INT64_MIN;
};

}  // namespace

std::unique_ptr<EventReader> openAedat4Reader(const std::string& path) {
  return std::make_unique<Aedat4Reader>(path);
}

}  // namespace evkit::detail
