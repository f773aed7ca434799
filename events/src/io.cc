#include "evkit/events/io.h"

#include <algorithm>
#include <array>
#include <cstring>
#include <filesystem>
#include <fstream>

#include "evkit/base/error.h"
#include "formats.h"

namespace evkit {
namespace fs = std::filesystem;

namespace {

constexpr std::array<std::pair<Format, const char*>, 9> kFormatNames = {{
    {Format::kText, "text"},
    {Format::kHdf5, "hdf5"},
    {Format::kRpgFolder, "rpg"},
    {Format::kAedat2, "aedat2"},
    {Format::kAedat31, "aedat3"},
    {Format::kAedat4, "aedat4"},
    {Format::kEvt2, "evt2"},
    {Format::kEvt3, "evt3"},
    {Format::kDat, "dat"},
}};

std::string lowerExtension(const std::string& path) {
  std::string ext = fs::path(path).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return std::tolower(c); });
  return ext;
}

std::optional<Format> formatFromExtension(const std::string& path) {
  const std::string ext = lowerExtension(path);
  if (ext == ".txt" || ext == ".csv") return Format::kText;
  if (ext == ".h5" || ext == ".hdf5" || ext == ".hdf" || ext == ".he5") return Format::kHdf5;
  if (ext == ".aedat4") return Format::kAedat4;
  if (ext == ".aedat3") return Format::kAedat31;
  if (ext == ".aedat") return Format::kAedat2;  // refined by the first line
  if (ext == ".raw") return Format::kEvt2;      // refined by the header
  if (ext == ".dat") return Format::kDat;
  return std::nullopt;
}

// What the first bytes say, when they say something.
std::optional<Format> formatFromContent(const std::string& path) {
  std::ifstream file(path, std::ios::binary);
  char head[16] = {};
  file.read(head, sizeof(head));
  const std::string start(head, static_cast<size_t>(file.gcount()));
  if (start.rfind("#!AER-DAT2", 0) == 0) return Format::kAedat2;
  if (start.rfind("#!AER-DAT3", 0) == 0) return Format::kAedat31;
  if (start.rfind("#!AER-DAT4", 0) == 0) return Format::kAedat4;
  if (start.rfind("%", 0) == 0) {
    const std::string evt = detail::propheseeRawVersion(path);
    if (evt == "2.0") return Format::kEvt2;
    if (evt == "3.0") return Format::kEvt3;
    if (lowerExtension(path) == ".dat") return Format::kDat;
    return std::nullopt;
  }
  return std::nullopt;
}

bool hasHdf5Signature(const std::string& path) {
  // The superblock signature sits at byte 0, 512, 1024, ... (HDF5 file format spec, §2.1).
  static constexpr char kSignature[8] = {'\x89', 'H', 'D', 'F', '\r', '\n', '\x1a', '\n'};
  std::ifstream file(path, std::ios::binary);
  char head[8];
  for (std::streamoff offset = 0; offset <= 8192; offset = offset ? offset * 2 : 512) {
    file.seekg(offset);
    if (!file.read(head, 8)) return false;
    if (std::memcmp(head, kSignature, 8) == 0) return true;
  }
  return false;
}

}  // namespace

std::string formatName(Format format) {
  for (const auto& [f, name] : kFormatNames) {
    if (f == format) return name;
  }
  return "unknown";
}

Format parseFormat(const std::string& name) {
  for (const auto& [f, n] : kFormatNames) {
    if (name == n) return f;
  }
  std::string known;
  for (const auto& [f, n] : kFormatNames) known += std::string(known.empty() ? "" : ", ") + n;
  throw Error("unknown format '" + name + "' (known: " + known + ")");
}

Format detectFormat(const std::string& path) {
  std::error_code ec;
  if (fs::is_directory(path, ec)) {
    if (fs::exists(fs::path(path) / "events.txt")) return Format::kRpgFolder;
    throwInFile(path, "a folder without events.txt (expected an RPG dataset folder)");
  }
  if (!fs::exists(path, ec)) throwInFile(path, "no such file");
  if (!fs::is_regular_file(path, ec)) throwInFile(path, "not a regular file");
  const std::optional<Format> by_extension = formatFromExtension(path);
  const std::optional<Format> by_content =
      hasHdf5Signature(path) ? Format::kHdf5 : formatFromContent(path);
  if (by_content) {
    const bool aedat_family = by_extension == Format::kAedat2 &&
                              (*by_content == Format::kAedat31 || *by_content == Format::kAedat4);
    const bool raw_family = by_extension == Format::kEvt2 && *by_content == Format::kEvt3;
    if (by_extension && *by_extension != *by_content && !aedat_family && !raw_family) {
      throwAtByte(path, 0,
                  "a " + formatName(*by_content) + " file named like a " +
                      formatName(*by_extension) + " file; rename it or pass --format " +
                      formatName(*by_content));
    }
    return *by_content;
  }
  if (by_extension == Format::kHdf5)
    throwAtByte(path, 0, "no HDF5 signature (truncated, corrupt, or not an HDF5 file)");
  if (by_extension == Format::kAedat2 || by_extension == Format::kAedat31 ||
      by_extension == Format::kAedat4) {
    throwAtByte(path, 0, "no '#!AER-DAT' signature (not an AEDAT file, or its header is damaged)");
  }
  if (by_extension == Format::kEvt2) {
    throwAtByte(path, 0, "no '% evt 2.0' / '% evt 3.0' header line; pass --format evt2 or evt3");
  }
  if (by_extension) return *by_extension;
  throwInFile(path, "cannot tell the format from the name '" + fs::path(path).filename().string() +
                        "' (known: .txt .csv .h5 .hdf5 .aedat .aedat4 .raw .dat, or an RPG "
                        "folder); pass --format");
}

bool EventReader::next(Chunk& chunk, size_t max_events) {
  chunk.clear();
  return append(chunk, max_events);
}

bool EventReader::append(Chunk& chunk, size_t max_events) {
  const size_t start_events = chunk.events.size(), start_frames = chunk.frames.size();
  const size_t limit = start_events + max_events;
  const auto added = [&] {
    return chunk.events.size() > start_events || chunk.frames.size() > start_frames;
  };
  while (!past_window_) {
    const size_t before = chunk.events.size();
    const size_t before_frames = chunk.frames.size();
    if (!readChunk(chunk, limit - before)) break;
    if (chunk.events.size() == before && chunk.frames.size() == before_frames) break;
    // Trim to the window; events are sorted, so past the end means done.
    EventStore& ev = chunk.events;
    const auto t_begin = ev.t.begin() + static_cast<std::ptrdiff_t>(before);
    const size_t first =
        static_cast<size_t>(std::lower_bound(t_begin, ev.t.end(), window_begin_) - ev.t.begin());
    const size_t last =
        static_cast<size_t>(std::lower_bound(t_begin, ev.t.end(), window_end_) - ev.t.begin());
    if (last < ev.size()) past_window_ = true;
    if (first > before || last < ev.size()) {
      const auto erase_range = [&](auto& column) {
        column.erase(column.begin() + static_cast<std::ptrdiff_t>(last), column.end());
        column.erase(column.begin() + static_cast<std::ptrdiff_t>(before),
                     column.begin() + static_cast<std::ptrdiff_t>(first));
      };
      erase_range(ev.t);
      erase_range(ev.x);
      erase_range(ev.y);
      erase_range(ev.p);
    }
    const auto outside = [&](const Frame& f) {
      return f.exposure_start_us < window_begin_ || f.exposure_start_us >= window_end_;
    };
    chunk.frames.erase(
        std::remove_if(chunk.frames.begin() + static_cast<std::ptrdiff_t>(before_frames),
                       chunk.frames.end(), outside),
        chunk.frames.end());
    if (added()) return true;
  }
  return added();
}

void EventReader::setTimeWindow(int64_t t_begin, int64_t t_end) {
  window_begin_ = t_begin;
  window_end_ = t_end;
  past_window_ = t_end <= t_begin;
  if (t_begin != std::numeric_limits<int64_t>::min()) seek(t_begin);
}

std::unique_ptr<EventReader> openReader(const std::string& path, std::optional<Format> format) {
  const Format f = format ? *format : detectFormat(path);
  switch (f) {
    case Format::kText:
      return detail::openTextReader(path);
    case Format::kHdf5:
      return detail::openHdf5Reader(path);
    case Format::kRpgFolder:
      return detail::openRpgFolderReader(path);
    case Format::kAedat2:
      return detail::openAedat2Reader(path);
    case Format::kAedat31:
      return detail::openAedat31Reader(path);
    case Format::kAedat4:
      return detail::openAedat4Reader(path);
    case Format::kEvt2:
      return detail::openEvt2Reader(path);
    case Format::kEvt3:
      return detail::openEvt3Reader(path);
    case Format::kDat:
      return detail::openDatReader(path);
  }
  throwInFile(path, "no reader for format " + formatName(f));
}

std::string compressionName(Compression compression) {
  switch (compression) {
    case Compression::kNone:
      return "none";
    case Compression::kDeflate:
      return "deflate";
    case Compression::kBloscLz4:
      return "blosc-lz4";
    case Compression::kLz4:
      return "lz4";
    case Compression::kZstd:
      return "zstd";
  }
  return "unknown";
}

Compression parseCompression(const std::string& name) {
  for (Compression c : {Compression::kNone, Compression::kDeflate, Compression::kBloscLz4,
                        Compression::kLz4, Compression::kZstd}) {
    if (compressionName(c) == name) return c;
  }
  throw Error("unknown compression '" + name +
              "' (known: none, deflate, blosc-lz4 for HDF5; lz4, zstd for AEDAT 4)");
}

std::unique_ptr<EventWriter> openWriter(const std::string& path, Format format, SensorSize sensor,
                                        const WriterOptions& options) {
  switch (format) {
    case Format::kText:
      return detail::openTextWriter(path, sensor);
    case Format::kHdf5:
      return detail::openHdf5Writer(path, sensor, options);
    case Format::kAedat4:
      return detail::openAedat4Writer(path, sensor, options);
    default:
      break;
  }
  throwInFile(path, "format " + formatName(format) + " can be read but not written");
}

Format outputFormat(const std::string& path) {
  const std::string ext = lowerExtension(path);
  if (ext == ".aedat4" || ext == ".aedat") return Format::kAedat4;
  const auto f = formatFromExtension(path);
  if (f == Format::kText || f == Format::kHdf5) return *f;
  throwInFile(path,
              "cannot tell the output format from the extension (writable: .txt .h5 .aedat4); pass "
              "--out-format");
}

Recording readRecording(const std::string& path, std::optional<Format> format, int64_t t_begin,
                        int64_t t_end) {
  auto reader = openReader(path, format);
  reader->setTimeWindow(t_begin, t_end);
  // Read straight into the recording's columns (no intermediate chunk to copy from).
  Chunk all;
  if (reader->info().event_count)
    all.events.reserve(static_cast<size_t>(*reader->info().event_count));
  while (reader->append(all, size_t{1} << 20)) {
  }
  Recording rec;
  rec.events = std::move(all.events);
  rec.frames = std::move(all.frames);
  rec.info = reader->info();  // counters and warnings are complete only now
  SensorSize sensor = rec.info.sensor;
  if (!sensor.known()) {
    sensor = boundingSensor(rec.events.view());
    for (const Frame& f : rec.frames) {
      sensor.width = std::max(sensor.width, f.image.cols);
      sensor.height = std::max(sensor.height, f.image.rows);
    }
  }
  rec.events.setSensor(sensor);
  rec.info.sensor = sensor;
  return rec;
}

void writeRecording(const std::string& path, const Recording& recording,
                    std::optional<Format> format, const WriterOptions& options) {
  auto writer =
      openWriter(path, format ? *format : outputFormat(path), recording.events.sensor(), options);
  writer->write(recording.events.view());
  for (const Frame& f : recording.frames) writer->writeFrame(f);
  writer->close();
}

}  // namespace evkit
