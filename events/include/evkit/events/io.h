// Reading and writing recordings: events plus optional frames, in chunks with bounded memory.
//
//   auto reader = openReader("rec.h5");              // format from the extension (and magic bytes)
//   Chunk chunk;
//   while (reader->next(chunk, 1 << 20)) { ... }     // at most 2^20 events per chunk
//
//   Recording rec = readRecording("rec.txt");        // everything in memory
//   writeRecording("rec.h5", rec);                   // written to a temporary name, then renamed
//
// Every reader converts to the conventions of DESIGN.md §2 (int64 µs, ±1 polarity, top-left
// origin) and throws evkit::Error naming the file, the position and what was expected.
#pragma once

#include <cstdint>
#include <limits>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "evkit/events/calibration.h"
#include "evkit/events/event_store.h"
#include "evkit/events/frame.h"

namespace evkit {

enum class Format {
  kText,  // RPG: "t x y p" per line, t in seconds, p 0/1 or ±1; optional "width height" first line
  kHdf5,  // evkit's layout (read and write); DSEC and event_utils layouts (read)
  kRpgFolder,  // RPG dataset folder: events.txt, images.txt + images/, calib.txt (read)
  kAedat2,     // jAER AEDAT 2.0: DVS events, APS frames, IMU (read)
  kAedat31,    // cAER AEDAT 3.1: polarity and frame packets (read)
  kAedat4,     // DV AEDAT 4.0: events, frames, IMU, triggers; LZ4/ZSTD (read and write)
  kEvt2,       // Prophesee EVT 2.0 raw (read)
  kEvt3,       // Prophesee EVT 3.0 raw (read)
  kDat,        // Prophesee DAT, CD events (read)
};

// "text", "hdf5", "rpg"; parseFormat throws evkit::Error listing the known names.
std::string formatName(Format format);
Format parseFormat(const std::string& name);
// Decides from the path: a directory is an RPG folder; otherwise the extension, checked against the
// file's first bytes (an HDF5 signature in a ".txt" file is reported, not misread).
Format detectFormat(const std::string& path);
// The format to write for an output path, from its extension; throws when it cannot tell.
Format outputFormat(const std::string& path);

struct ReaderInfo {
  Format format = Format::kText;
  std::string layout;  // e.g. "rpg-text", "evkit", "dsec", "event_utils", "aedat4-lz4"
  std::string camera;  // as the file names it ("DAVIS240C", "DVXplorer_DXB00010"), when it does
  SensorSize sensor;   // unknown (0x0) when the file does not say; see readRecording
  std::optional<int64_t> event_count;  // when the format knows it without a full pass
  std::optional<Calibration> calibration;
  // Format-specific tallies, complete once the reader is exhausted ("aps_words", "imu_words",
  // "packets.EVTS", ...), and problems that were tolerated (a cut-off last record).
  std::map<std::string, int64_t> counters;
  std::vector<std::string> warnings;
};

struct Chunk {
  EventStore events;
  std::vector<Frame> frames;
  void clear() {
    events.clear();
    frames.clear();
  }
};

class EventReader {
 public:
  virtual ~EventReader() = default;
  const ReaderInfo& info() const { return info_; }

  // Clears `chunk` and fills it with at most `max_events` events that follow the previous chunk,
  // plus the frames whose exposure starts before the chunk's last event (all remaining ones at the
  // end). Returns false when nothing is left.
  bool next(Chunk& chunk, size_t max_events);
  // As next(), but appends to what `chunk` holds (readRecording reads a whole file this way, into
  // its final columns). Returns false when nothing was added.
  bool append(Chunk& chunk, size_t max_events);

  // Restricts what next() returns to events with t in [t_begin, t_end) and frames whose exposure
  // starts in it. Formats with an index seek to t_begin; the others skip. Call before next().
  void setTimeWindow(int64_t t_begin, int64_t t_end);

 protected:
  // Appends the next events (≤ max_events) and due frames; returns false at the end.
  virtual bool readChunk(Chunk& chunk, size_t max_events) = 0;
  // Optional fast skip to the first event with t >= t_begin.
  virtual void seek(int64_t /*t_begin*/) {}

  ReaderInfo info_;

 private:
  int64_t window_begin_ = std::numeric_limits<int64_t>::min();
  int64_t window_end_ = std::numeric_limits<int64_t>::max();
  bool past_window_ = false;
};

std::unique_ptr<EventReader> openReader(const std::string& path,
                                        std::optional<Format> format = std::nullopt);

// kDeflate and kBloscLz4 apply to HDF5, kLz4 and kZstd to AEDAT 4, kNone to both.
enum class Compression { kNone, kDeflate, kBloscLz4, kLz4, kZstd };
std::string compressionName(Compression compression);
Compression parseCompression(const std::string& name);

struct WriterOptions {
  // AEDAT 4: kLz4 (default), kZstd or kNone, as DV writes them.
  // HDF5: kBloscLz4 (byte shuffle + LZ4 inside Blosc, as DSEC) reads ~4x faster than kDeflate
  // but needs the Blosc filter plugin to read (Debian: hdf5-filter-plugin; pip: `import
  // hdf5plugin`); kDeflate (shuffle + deflate) is readable by every HDF5 build. Unset: Blosc-LZ4
  // when the plugin is installed, otherwise deflate.
  std::optional<Compression> compression;
  int level = 1;  // deflate 0-9; Blosc clevel 0-9 (1 keeps LZ4 at its fastest); Zstandard 1-19
};

// Writes to "<path>.tmp-<pid>" and renames to `path` on close(); a writer destroyed before close()
// (an exception, a crash) removes its temporary file, so no partial output appears under `path`.
class EventWriter {
 public:
  virtual ~EventWriter() = default;
  virtual void write(const EventSpan& events) = 0;
  virtual void writeFrame(const Frame& frame) = 0;
  virtual void close() = 0;
};

std::unique_ptr<EventWriter> openWriter(const std::string& path, Format format, SensorSize sensor,
                                        const WriterOptions& options = {});

// Whole recordings in memory.
struct Recording {
  EventStore events;
  std::vector<Frame> frames;
  ReaderInfo info;
};

// Reads everything (optionally a time window). When the file does not state the sensor size, it is
// the bounding box of the events (and frames).
Recording readRecording(const std::string& path, std::optional<Format> format = std::nullopt,
                        int64_t t_begin = std::numeric_limits<int64_t>::min(),
                        int64_t t_end = std::numeric_limits<int64_t>::max());
void writeRecording(const std::string& path, const Recording& recording,
                    std::optional<Format> format = std::nullopt, const WriterOptions& options = {});

}  // namespace evkit
