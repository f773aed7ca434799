// RPG text events: "t x y p" per line, t in seconds (decimal, exact to the µs), p 0/1 or ±1,
// separated by spaces, tabs or commas; '#' starts a comment line; an optional first line
// "width height" (as rpg_e2vid writes) gives the sensor size. Frames, which text cannot hold, live
// in the folder "<stem>_frames" beside the file (see writeFrameFolder).

#include <algorithm>
#include <cstdio>
#include <cstring>
#include <filesystem>

#include "evkit/base/error.h"
#include "evkit/events/atomic_file.h"
#include "evkit/events/decimal.h"
#include "evkit/events/image_io.h"
#include "formats.h"
#include "unique_file.h"

namespace evkit::detail {
namespace fs = std::filesystem;

namespace {

constexpr size_t kBufferBytes = size_t{1} << 22;
constexpr size_t kMaxLineBytes = size_t{1} << 16;

std::string frameFolderFor(const std::string& path) {
  const fs::path p(path);
  return (p.parent_path() / (p.stem().string() + "_frames")).string();
}

// Decimal digits of v at out; returns the end. At most 5 characters.
inline char* writeUint16(uint16_t v, char* out) {
  char digits[5];
  int n = 0;
  do {
    digits[n++] = static_cast<char>('0' + v % 10);
    v = static_cast<uint16_t>(v / 10);
  } while (v != 0);
  while (n > 0) *out++ = digits[--n];
  return out;
}

inline bool isDigit(char c) { return static_cast<unsigned char>(c - '0') < 10; }

// Fast path for the common shape "123.456789" (at most 12 integer and 6 fractional digits, no
// sign or exponent); returns false without moving p otherwise, and the exact general parser runs.
inline bool parsePlainSeconds(const char*& p, const char* end, int64_t& micros) {
  const char* s = p;
  uint64_t whole = 0;
  const char* digits_end = std::min(end, s + 12);
  const char* start = s;
  while (s < digits_end && isDigit(*s)) whole = whole * 10 + static_cast<uint64_t>(*s++ - '0');
  if (s == start || s == end || isDigit(*s)) return false;
  uint64_t frac = 0;
  int frac_digits = 0;
  if (*s == '.') {
    ++s;
    while (s < end && frac_digits < 6 && isDigit(*s)) {
      frac = frac * 10 + static_cast<uint64_t>(*s++ - '0');
      ++frac_digits;
    }
    if (s < end && (isDigit(*s) || *s == 'e' || *s == 'E')) return false;
  } else if (*s == 'e' || *s == 'E') {
    return false;
  }
  static constexpr uint64_t kScale[7] = {1000000, 100000, 10000, 1000, 100, 10, 1};
  micros = static_cast<int64_t>(whole * 1000000 + frac * kScale[frac_digits]);
  p = s;
  return true;
}

// Fast unsigned integer of at most 5 digits (x, y); false if malformed or > max.
inline bool parseSmallUnsigned(const char*& p, const char* end, uint32_t max, uint32_t& value) {
  const char* s = p;
  uint32_t v = 0;
  const char* limit = std::min(end, s + 5);
  while (s < limit && isDigit(*s)) v = v * 10 + static_cast<uint32_t>(*s++ - '0');
  if (s == p || (s < end && isDigit(*s)) || v > max) return false;
  value = v;
  p = s;
  return true;
}

inline bool isSeparator(char c) { return c == ' ' || c == '\t' || c == ','; }

inline void skipSeparators(const char*& p, const char* end) {
  while (p < end && isSeparator(*p)) ++p;
}

std::string snippet(const char* begin, const char* end) {
  std::string s;
  for (const char* p = begin; p < end && *p != '\n' && s.size() < 60; ++p) {
    const unsigned char c = static_cast<unsigned char>(*p);
    if (c == '\r') continue;
    if (c >= 32 && c < 127) {
      s += static_cast<char>(c);
    } else {
      char hex[8];
      std::snprintf(hex, sizeof(hex), "\\x%02x", c);
      s += hex;
    }
  }
  return s;
}

class TextReader final : public EventReader {
 public:
  explicit TextReader(std::string path) : path_(std::move(path)) {
    file_ = openFile(path_, "rb");
    if (!file_) throwInFile(path_, "cannot open for reading");
    // No bigger than the file needs (plus the spare byte for a missing final newline).
    std::error_code ec;
    const uintmax_t size = fs::file_size(path_, ec);
    buffer_.resize(ec ? kBufferBytes
                      : static_cast<size_t>(std::min<uintmax_t>(kBufferBytes, size + 2)));
    info_.format = Format::kText;
    info_.layout = "rpg-text";
    fill();
    if (len_ == 0) throwInFile(path_, "empty file (expected lines 't x y p')");
    if (std::memchr(buffer_.data(), '\0', std::min<size_t>(len_, 4096))) {
      throwAtByte(
          path_,
          static_cast<int64_t>(static_cast<const char*>(std::memchr(buffer_.data(), '\0', len_)) -
                               buffer_.data()),
          "binary data in a text event file (wrong --format?)");
    }
    readOptionalHeader();
    const std::string frames = frameFolderFor(path_);
    if (fs::is_regular_file(frames + "/frames.csv")) pending_frames_ = readFrameFolder(frames);
  }

 protected:
  bool readChunk(Chunk& chunk, size_t max_events) override {
    EventStore& ev = chunk.events;
    ev.setSensor(info_.sensor);
    size_t added = 0;
    while (added < max_events) {
      if (pos_ >= complete_end_) {
        if (!fill()) break;
        continue;
      }
      const char* p = buffer_.data() + pos_;
      const char* end = buffer_.data() + complete_end_;
      // Hot loop over complete lines.
      while (p < end && added < max_events) {
        const char* line_start = p;
        ++line_;
        skipSeparators(p, end);
        if (*p == '\n' || *p == '\r' || *p == '#') {
          p = static_cast<const char*>(std::memchr(p, '\n', static_cast<size_t>(end - p)));
          p = p ? p + 1 : end;
          continue;
        }
        int64_t t, pol;
        uint32_t x, y;
        if (!parsePlainSeconds(p, end, t) && !parseSecondsAsMicros(p, end, t)) {
          fail(line_start, end, "the timestamp t (seconds)");
        }
        skipSeparators(p, end);
        if (!parseSmallUnsigned(p, end, 65535, x))
          fail(line_start, end, "x (an integer in 0..65535)");
        skipSeparators(p, end);
        if (!parseSmallUnsigned(p, end, 65535, y))
          fail(line_start, end, "y (an integer in 0..65535)");
        skipSeparators(p, end);
        if (*p == '0' || *p == '1') {
          pol = *p++ - '0';
          if (p < end && isDigit(*p)) fail(line_start, end, "polarity p (0/1 or -1/+1)");
        } else if (!parseInt(p, end, -1, 1, pol)) {
          fail(line_start, end, "polarity p (0/1 or -1/+1)");
        }
        skipSeparators(p, end);
        if (p < end && *p == '\r') ++p;
        if (p < end && *p != '\n') fail(line_start, end, "end of line after 4 fields");
        ++p;
        if (info_.sensor.known() && (x >= static_cast<uint32_t>(info_.sensor.width) ||
                                     y >= static_cast<uint32_t>(info_.sensor.height))) {
          throwAtLine(path_, line_,
                      "event (x, y) = (" + std::to_string(x) + ", " + std::to_string(y) +
                          ") lies outside the " + std::to_string(info_.sensor.width) + "x" +
                          std::to_string(info_.sensor.height) + " sensor of the header");
        }
        if (t < last_t_) {
          throwAtLine(path_, line_,
                      "timestamp " + std::string(tbuf(t)) + " s goes back in time (previous " +
                          tbuf(last_t_) + " s); events must be sorted by time");
        }
        last_t_ = t;
        ev.push_back(t, static_cast<uint16_t>(x), static_cast<uint16_t>(y), pol > 0 ? 1 : -1);
        ++added;
      }
      pos_ = static_cast<size_t>(p - buffer_.data());
    }
    // Frames due: those whose exposure starts before the last event read (all at the end).
    const bool at_end = added < max_events;
    while (next_frame_ < pending_frames_.size() &&
           (at_end || pending_frames_[next_frame_].exposure_start_us <= last_t_)) {
      chunk.frames.push_back(std::move(pending_frames_[next_frame_++]));
    }
    return added > 0 || !chunk.frames.empty();
  }

 private:
  const char* tbuf(int64_t t) {
    char* e = formatMicrosAsSeconds(t, tbuf_[tbuf_i_]);
    *e = '\0';
    const char* out = tbuf_[tbuf_i_];
    tbuf_i_ ^= 1;
    return out;
  }

  [[noreturn]] void fail(const char* line_start, const char* end, const char* what) {
    throwAtLine(path_, line_,
                std::string("expected 't x y p'; cannot read ") + what + " in '" +
                    snippet(line_start, end) + "'");
  }

  // Moves the unread tail to the front and reads more; sets complete_end_ to the end of the last
  // complete line (or the end of the data at EOF). Returns false when nothing is left.
  bool fill() {
    if (pos_ > 0) {
      std::memmove(buffer_.data(), buffer_.data() + pos_, len_ - pos_);
      len_ -= pos_;
      bytes_before_ += static_cast<int64_t>(pos_);
      pos_ = 0;
    }
    complete_end_ = 0;  // whatever is left is at most a partial line
    if (!eof_) {
      const size_t got =
          std::fread(buffer_.data() + len_, 1, buffer_.size() - 1 - len_, file_.get());
      if (got == 0) {
        if (std::ferror(file_.get()))
          throwAtByte(path_, bytes_before_ + static_cast<int64_t>(len_), "read error");
        eof_ = true;
      }
      len_ += got;
    }
    if (len_ == 0) return false;
    const void* last_nl = memrchr(buffer_.data(), '\n', len_);
    if (last_nl) {
      complete_end_ = static_cast<size_t>(static_cast<const char*>(last_nl) - buffer_.data()) + 1;
    } else if (eof_) {
      buffer_[len_] =
          '\n';  // the last line has no newline: give it one (the buffer keeps a spare byte)
      complete_end_ = ++len_;
    } else if (len_ > kMaxLineBytes) {
      throwAtLine(path_, line_ + 1, "line longer than 64 KiB (not a text event file?)");
    } else {
      complete_end_ = 0;
      return fill();
    }
    return true;
  }

  void readOptionalHeader() {
    // The first non-comment line is a header if it holds exactly two integers.
    size_t pos = 0;
    int64_t line = 0;
    while (pos < complete_end_) {
      const char* p = buffer_.data() + pos;
      const char* nl = static_cast<const char*>(std::memchr(p, '\n', complete_end_ - pos));
      const char* end = nl ? nl : buffer_.data() + complete_end_;
      ++line;
      const char* s = p;
      skipSeparators(s, end);
      if (s == end || *s == '\r' || *s == '#') {
        pos = static_cast<size_t>(end - buffer_.data()) + 1;
        continue;
      }
      int64_t w, h;
      const char* q = s;
      if (parseInt(q, end, 1, 65536, w)) {
        skipSeparators(q, end);
        if (parseInt(q, end, 1, 65536, h)) {
          skipSeparators(q, end);
          if (q < end && *q == '\r') ++q;
          if (q == end) {
            info_.sensor = SensorSize{static_cast<int>(w), static_cast<int>(h)};
            pos_ = static_cast<size_t>(end - buffer_.data()) + 1;
            line_ = line;
          }
        }
      }
      return;
    }
  }

  std::string path_;
  UniqueFile file_;
  std::vector<char> buffer_;
  size_t pos_ = 0;           // next unread byte
  size_t len_ = 0;           // bytes in the buffer
  size_t complete_end_ = 0;  // end of the last complete line in the buffer
  bool eof_ = false;
  int64_t bytes_before_ = 0;  // file offset of buffer_[0]
  int64_t line_ = 0;          // number of the last line parsed
  int64_t last_t_ = INT64_MIN;
  std::vector<Frame> pending_frames_;
  size_t next_frame_ = 0;
  char tbuf_[2][32] = {};
  int tbuf_i_ = 0;
};

class TextWriter final : public EventWriter {
 public:
  TextWriter(const std::string& path, SensorSize sensor) : out_(path) {
    file_ = openFile(out_.temporaryPath(), "wb");
    if (!file_) throwInFile(path, "cannot open for writing");
    buffer_.reserve(kBufferBytes + 256);
    if (sensor.known()) {
      buffer_ += std::to_string(sensor.width) + " " + std::to_string(sensor.height) + "\n";
    }
  }

  void write(const EventSpan& events) override {
    char line[64];
    for (size_t i = 0; i < events.size(); ++i) {
      char* p = formatMicrosAsSeconds(events.t[i], line);
      *p++ = ' ';
      p = writeUint16(events.x[i], p);
      *p++ = ' ';
      p = writeUint16(events.y[i], p);
      *p++ = ' ';
      *p++ = events.p[i] > 0 ? '1' : '0';
      *p++ = '\n';
      buffer_.append(line, p);
      if (buffer_.size() >= kBufferBytes) flush();
    }
  }

  void writeFrame(const Frame& frame) override { frames_.push_back(frame); }

  void close() override {
    flush();
    if (!closeFile(file_)) throwInFile(out_.finalPath(), "write failed (disk full?)");
    if (!frames_.empty()) writeFrameFolder(frameFolderFor(out_.finalPath()), frames_);
    out_.commit();
  }

 private:
  void flush() {
    if (std::fwrite(buffer_.data(), 1, buffer_.size(), file_.get()) != buffer_.size()) {
      throwInFile(out_.finalPath(), "write failed (disk full?)");
    }
    buffer_.clear();
  }

  AtomicPath out_;
  UniqueFile file_;
  std::string buffer_;
  std::vector<Frame> frames_;
};

}  // namespace

std::unique_ptr<EventReader> openTextReader(const std::string& path) {
  return std::make_unique<TextReader>(path);
}

std::unique_ptr<EventWriter> openTextWriter(const std::string& path, SensorSize sensor) {
  return std::make_unique<TextWriter>(path, sensor);
}

}  // namespace evkit::detail
