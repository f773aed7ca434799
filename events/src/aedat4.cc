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
#include "binary_file.h"
#include "codec.h"
#include "evkit/base/error.h"
#include "evkit/events/atomic_file.h"
#include "evkit/events/image_io.h"
#include "formats.h"

namespace evkit::detail {

namespace fb4 = evkit::aedat4;

namespace {

constexpr char kMagic[] = "#!AER-DAT4.0\r\n";
constexpr size_t kMagicBytes = 14;
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
    char magic[kMagicBytes];
    if (file_.read(magic, kMagicBytes) != kMagicBytes ||
        std::memcmp(magic, kMagic, kMagicBytes) != 0) {
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
    const auto* in = reinterpret_cast<const fb4::Event*>(events_->Data()) + first;  // verified size
    int64_t* out_t = ev.t.data() + base;
    uint16_t* out_x = ev.x.data() + base;
    uint16_t* out_y = ev.y.data() + base;
    int8_t* out_p = ev.p.data() + base;
    for (size_t i = 0; i < n; ++i) {
      const int64_t t = in[i].t();
      const int x = in[i].x(), y = in[i].y();
      bad |= (x < 0) | (y < 0) | (x >= w) | (y >= h) | (t < prev);
      prev = t;
      out_t[i] = t;
      out_x[i] = static_cast<uint16_t>(x);
      out_y[i] = static_cast<uint16_t>(y);
      out_p[i] = static_cast<int8_t>(2 * static_cast<int>(in[i].on()) -
                                     1);  // branch-free: polarity is random
    }
    if (bad) {
      for (size_t i = 0; i < n; ++i) {
        const fb4::Event* e = events_->Get(static_cast<flatbuffers::uoffset_t>(first + i));
        const std::string where = "event " + std::to_string(first + i) + " of the packet";
        if (e->x() < 0 || e->y() < 0 || e->x() >= w || e->y() >= h) {
          file_.failAt(packet_at_, where + ": (x, y) = (" + std::to_string(e->x()) + ", " +
                                       std::to_string(e->y()) + ") outside the " +
                                       std::to_string(w) + "x" + std::to_string(h) + " sensor");
        }
        if (e->t() < last_t_) {
          file_.failAt(packet_at_, where + ": timestamp " + std::to_string(e->t()) +
                                       " us goes back in time (previous " +
                                       std::to_string(last_t_) + " us)");
        }
        last_t_ = e->t();
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

// ---- Writer ----------------------------------------------------------------------------------

constexpr int32_t kEventStream = 0;
constexpr int32_t kFrameStream = 1;
constexpr size_t kEventsPerPacket = 32768;
// Written as the data table position, then patched at close.
constexpr int64_t kPlaceholder = 0x5ca1ab1e0ddba11LL;

class Aedat4Writer final : public EventWriter {
 public:
  Aedat4Writer(const std::string& path, SensorSize sensor, const WriterOptions& options)
      : out_(path), sensor_(sensor) {
    const Compression c = options.compression.value_or(Compression::kLz4);
    if (c != Compression::kLz4 && c != Compression::kZstd && c != Compression::kNone) {
      throwInFile(path, "AEDAT 4 compresses with lz4, zstd or none, not " + compressionName(c));
    }
    codec_ = c == Compression::kZstd   ? Codec::kZstd
             : c == Compression::kNone ? Codec::kNone
                                       : Codec::kLz4;
    level_ = codec_ == Codec::kZstd ? std::max(1, options.level) : 0;
    file_ = openFile(out_.temporaryPath(), "wb");
    if (!file_) throwInFile(path, "cannot open for writing");
    writeHeader();
  }

  void write(const EventSpan& events) override {
    validate(events, out_.finalPath(), written_, last_t_);
    if (!events.empty()) last_t_ = events.t.back();
    written_ += events.size();
    for (size_t i = 0; i < events.size(); ++i) {
      max_x_ = std::max<int>(max_x_, events.x[i]);
      max_y_ = std::max<int>(max_y_, events.y[i]);
      pending_.emplace_back(events.t[i], static_cast<int16_t>(events.x[i]),
                            static_cast<int16_t>(events.y[i]), events.p[i] > 0);
      if (pending_.size() == kEventsPerPacket) flushEvents();
    }
  }

  void writeFrame(const Frame& frame) override {
    flushEvents();  // keep packets in time order
    const cv::Mat& img = frame.image;
    if (img.empty() || (img.channels() != 1 && img.channels() != 3))
      throwInFile(out_.finalPath(), "frame must be grey or colour");
    const int bits = frame.bit_depth == 16 ? 16 : 8;
    cv::Mat q = quantize(img, bits);
    if (!q.isContinuous()) q = q.clone();
    fb4::FrameFormat format = img.channels() == 1
                                  ? (bits == 16 ? fb4::FrameFormat::GRAY16 : fb4::FrameFormat::GRAY)
                                  : (bits == 16 ? fb4::FrameFormat::BGR16 : fb4::FrameFormat::BGR);
    flatbuffers::FlatBufferBuilder fbb(q.total() * q.elemSize() + 256);
    const auto pixels = fbb.CreateVector(q.data, q.total() * q.elemSize());
    fb4::FrameBuilder b(fbb);
    b.add_t(frame.exposure_start_us);
    b.add_begin_t(frame.exposure_start_us);
    b.add_end_t(frame.exposure_end_us);
    b.add_exposure_begin_t(frame.exposure_start_us);
    b.add_exposure_end_t(frame.exposure_end_us);
    b.add_exposure(frame.exposure_end_us - frame.exposure_start_us);
    b.add_format(format);
    b.add_width(static_cast<int16_t>(img.cols));
    b.add_height(static_cast<int16_t>(img.rows));
    b.add_pixels(pixels);
    fbb.FinishSizePrefixed(b.Finish(), "FRME");
    writePacket(kFrameStream, fbb, 1, frame.exposure_start_us, frame.exposure_end_us);
  }

  void close() override {
    flushEvents();
    // File data table, then patch its position into the header.
    flatbuffers::FlatBufferBuilder fbb;
    std::vector<flatbuffers::Offset<fb4::FileDataDefinition>> defs;
    for (const Entry& e : table_) {
      const fb4::PacketHeader header(e.stream, e.size);
      defs.push_back(
          fb4::CreateFileDataDefinition(fbb, e.offset, &header, e.count, e.t_start, e.t_end));
    }
    fbb.FinishSizePrefixed(fb4::CreateFileDataTable(fbb, fbb.CreateVector(defs)), "FTAB");
    const int64_t table_at = offset_;
    compress(codec_, fbb.GetBufferPointer(), fbb.GetSize(), packed_, level_);
    put(packed_.data(), packed_.size());
    uint8_t le[8];
    for (int i = 0; i < 8; ++i)
      le[i] = static_cast<uint8_t>(static_cast<uint64_t>(table_at) >> (8 * i));
    bool ok = std::fseek(file_.get(), static_cast<long>(placeholder_at_), SEEK_SET) == 0 &&
              std::fwrite(le, 1, 8, file_.get()) == 8;
    // Unknown sensor: the bounding box of the events (sizeX, sizeY alternate in the XML).
    for (size_t i = 0; i < size_patches_.size(); ++i) {
      const std::string text = padded(i % 2 == 0 ? max_x_ + 1 : max_y_ + 1);
      ok = ok && std::fseek(file_.get(), static_cast<long>(size_patches_[i]), SEEK_SET) == 0 &&
           std::fwrite(text.data(), 1, 5, file_.get()) == 5;
    }
    if (!closeFile(file_) || !ok) throwInFile(out_.finalPath(), "write failed (disk full?)");
    out_.commit();
  }

 private:
  struct Entry {
    int64_t offset;  // of the packet data, after its 8-byte header
    int32_t stream, size;
    int64_t count, t_start, t_end;
  };

  // Sizes are written 5 characters wide (space-padded) so that an unknown sensor size can be
  // patched in place at close, once the events have shown it.
  static std::string padded(int v) {
    std::string text = std::to_string(v);
    return std::string(5 - std::min<size_t>(5, text.size()), ' ') + text;
  }

  void writeHeader() {
    const SensorSize s = sensor_;
    const char* compression = codec_ == Codec::kLz4    ? "LZ4"
                              : codec_ == Codec::kZstd ? "ZSTD"
                                                       : "NONE";
    std::ostringstream x;
    const auto stream = [&](int id, const char* type, const char* name, const char* description) {
      const std::string base = "/mainloop/Recorder/outInfo/" + std::to_string(id) + "/";
      x << "        <node name=\"" << id << "\" path=\"" << base << "\">\n"
        << "            <attr key=\"compression\" type=\"string\">" << compression << "</attr>\n"
        << "            <attr key=\"originalModuleName\" type=\"string\">evkit</attr>\n"
        << "            <attr key=\"originalOutputName\" type=\"string\">" << name << "</attr>\n"
        << "            <attr key=\"typeDescription\" type=\"string\">" << description
        << "</attr>\n"
        << "            <attr key=\"typeIdentifier\" type=\"string\">" << type << "</attr>\n"
        << "            <node name=\"info\" path=\"" << base << "info/\">\n"
        << "                <attr key=\"sizeX\" type=\"int\">" << padded(s.width) << "</attr>\n"
        << "                <attr key=\"sizeY\" type=\"int\">" << padded(s.height) << "</attr>\n"
        << "                <attr key=\"source\" type=\"string\">evkit</attr>\n"
        << "                <attr key=\"tsOffset\" type=\"long\">0</attr>\n"
        << "            </node>\n        </node>\n";
    };
    x << "<dv version=\"2.0\">\n    <node name=\"outInfo\" path=\"/mainloop/Recorder/outInfo/\">\n";
    stream(kEventStream, "EVTS", "events", "Array of events (polarity ON/OFF).");
    stream(kFrameStream, "FRME", "frames", "Standard frame (8-bit image).");
    x << "    </node>\n</dv>\n";
    const std::string xml = x.str();
    flatbuffers::FlatBufferBuilder fbb;
    fbb.ForceDefaults(true);
    const fb4::CompressionType type = codec_ == Codec::kLz4    ? fb4::CompressionType::LZ4
                                      : codec_ == Codec::kZstd ? fb4::CompressionType::ZSTD
                                                               : fb4::CompressionType::NONE;
    fbb.FinishSizePrefixed(fb4::CreateIOHeader(fbb, type, kPlaceholder, fbb.CreateString(xml)),
                           "IOHE");
    const uint8_t* buf = fbb.GetBufferPointer();
    const size_t len = fbb.GetSize();
    // Find the placeholder to patch the data table position at close.
    size_t found = len;
    for (size_t i = 0; i + 8 <= len; ++i) {
      if (static_cast<int64_t>(loadLe64(buf + i)) == kPlaceholder) {
        found = i;
        break;
      }
    }
    if (!sensor_.known()) {
      const std::string xml_head = xml.substr(0, 32);
      const uint8_t* xml_at = std::search(buf, buf + len, xml_head.begin(), xml_head.end());
      const std::string zero_size = ">    0</attr>";  // padded(0) between the tags
      for (size_t at = xml.find(zero_size); at != std::string::npos;
           at = xml.find(zero_size, at + 1)) {
        size_patches_.push_back(kMagicBytes + static_cast<int64_t>(xml_at - buf) +
                                static_cast<int64_t>(at) + 1);
      }
    }
    put(kMagic, kMagicBytes);  // then the size-prefixed header: its length field comes first
    placeholder_at_ = offset_ + static_cast<int64_t>(found);
    put(buf, len);
  }

  void flushEvents() {
    if (pending_.empty()) return;
    flatbuffers::FlatBufferBuilder fbb(pending_.size() * sizeof(fb4::Event) + 64);
    fbb.FinishSizePrefixed(fb4::CreateEventPacket(fbb, fbb.CreateVectorOfStructs(pending_)),
                           "EVTS");
    writePacket(kEventStream, fbb, static_cast<int64_t>(pending_.size()), pending_.front().t(),
                pending_.back().t());
    pending_.clear();
  }

  void writePacket(int32_t stream, const flatbuffers::FlatBufferBuilder& fbb, int64_t count,
                   int64_t t0, int64_t t1) {
    compress(codec_, fbb.GetBufferPointer(), fbb.GetSize(), packed_, level_);
    table_.push_back(
        Entry{offset_ + 8, stream, static_cast<int32_t>(packed_.size()), count, t0, t1});
    uint8_t h[8];
    for (int i = 0; i < 4; ++i) {
      h[i] = static_cast<uint8_t>(static_cast<uint32_t>(stream) >> (8 * i));
      h[4 + i] = static_cast<uint8_t>(static_cast<uint32_t>(packed_.size()) >> (8 * i));
    }
    put(h, 8);
    put(packed_.data(), packed_.size());
  }

  void put(const void* data, size_t n) {
    if (std::fwrite(data, 1, n, file_.get()) != n)
      throwInFile(out_.finalPath(), "write failed (disk full?)");
    offset_ += static_cast<int64_t>(n);
  }

  AtomicPath out_;
  SensorSize sensor_;
  Codec codec_ = Codec::kLz4;
  int level_ = 0;
  UniqueFile file_;
  int64_t offset_ = 0;
  int64_t placeholder_at_ = 0;
  std::vector<fb4::Event> pending_;
  std::vector<uint8_t> packed_;
  std::vector<Entry> table_;
  size_t written_ = 0;
  int64_t last_t_ = INT64_MIN;
  std::vector<int64_t> size_patches_;
  int max_x_ = -1, max_y_ = -1;
};

}  // namespace

std::unique_ptr<EventReader> openAedat4Reader(const std::string& path) {
  return std::make_unique<Aedat4Reader>(path);
}

std::unique_ptr<EventWriter> openAedat4Writer(const std::string& path, SensorSize sensor,
                                              const WriterOptions& options) {
  return std::make_unique<Aedat4Writer>(path, sensor, options);
}

}  // namespace evkit::detail
