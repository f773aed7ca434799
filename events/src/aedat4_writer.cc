// The AEDAT 4.0 writer (aedat4.cc describes the format and reads it).

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
        size_patches_.push_back(kAedat4MagicBytes + static_cast<int64_t>(xml_at - buf) +
                                static_cast<int64_t>(at) + 1);
      }
    }
    put(kAedat4Magic,
        kAedat4MagicBytes);  // then the size-prefixed header: its length field comes first
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

std::unique_ptr<EventWriter> openAedat4Writer(const std::string& path, SensorSize sensor,
                                              const WriterOptions& options) {
  return std::make_unique<Aedat4Writer>(path, sensor, options);
}

}  // namespace evkit::detail
