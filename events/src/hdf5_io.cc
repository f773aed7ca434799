// HDF5 events and frames.
//
// evkit's layout (written and read; see the README for the h5py snippet):
//   /events/t          int64   µs, absolute as the camera wrote them, non-decreasing
//   /events/x, /y      uint16  pixels, top-left origin
//   /events/p          int8    +1 ON / -1 OFF
//   /events/ms_to_idx  uint64  ms_to_idx[k] = index of the first event with t >= t_offset + 1000 k;
//                              attribute t_offset (int64 µs, a multiple of 1000)
//   /frames/images     uint8 or uint16, (N, H, W) grey or (N, H, W, 3) RGB, linear
//   /frames/exposure_start, /frames/exposure_end   int64 µs
//   root attributes    evkit_layout = 1, sensor_width, sensor_height
// All datasets are chunked and compressed (shuffle + deflate by default, or Blosc-LZ4).
//
// Also read:
//   DSEC:        /events/{t (uint32 µs relative to /t_offset), x, y, p (0/1)}, /ms_to_idx,
//   /t_offset event_utils: /events/{xs, ys, ts (float64 s), ps}, /images/image%09d with attribute
//   timestamp (s),
//                root attribute sensor_resolution (height, width)

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <opencv2/imgproc.hpp>

#include "evkit/base/error.h"
#include "evkit/events/atomic_file.h"
#include "evkit/events/image_io.h"
#include "formats.h"
#include "hdf5_filters.h"
#include "hdf5_precheck.h"
#include "hdf5_util.h"

namespace evkit::detail {
namespace fs = std::filesystem;

namespace {

constexpr hsize_t kEventChunk = hsize_t{1} << 17;  // elements per HDF5 chunk of an event column
constexpr size_t kChunkCacheBytes = size_t{32} << 20;
constexpr unsigned kBloscFilter = 32001;             // registered HDF5 filter id of Blosc
constexpr unsigned kBloscLz4 = 1;                    // Blosc compressor code of LZ4
constexpr int64_t kMaxMsIndexEntries = 100'000'000;  // > 27 h of recording: no index
constexpr hsize_t kMaxFrames = 1'000'000;            // 14 h at 20 fps, 17 min at 1 kHz

enum class Layout { kEvkit, kDsec, kEventUtils };

int64_t floorDiv(int64_t a, int64_t b) { return a / b - ((a % b != 0) && ((a < 0) != (b < 0))); }

H5Handle openDataset(hid_t file, const std::string& name, const std::string& path) {
  H5Handle dapl(H5Pcreate(H5P_DATASET_ACCESS));
  H5Pset_chunk_cache(dapl.get(), 521, kChunkCacheBytes, 1.0);
  H5Handle ds(H5Dopen2(file, name.c_str(), dapl.get()));
  if (!ds) throwInFile(path, "cannot open dataset '" + name + "'");
  return ds;
}

class Hdf5Reader final : public EventReader {
 public:
  // libhdf5 keeps freed blocks on free lists of its own, which grow in a process that opens many
  // files; they go back to the system when the reader does.
  ~Hdf5Reader() override {
    for (H5Handle& column : columns_) column = H5Handle();
    images_ = H5Handle();
    file_ = H5Handle();
    H5garbage_collect();
  }
  Hdf5Reader(const Hdf5Reader&) = delete;
  Hdf5Reader& operator=(const Hdf5Reader&) = delete;

  explicit Hdf5Reader(std::string path) : path_(std::move(path)), precheck_(path_) {
    silenceHdf5Errors();
    useCheckedFilters();
    file_ = H5Handle(H5Fopen(path_.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT));
    if (!file_) throwAtByte(path_, 0, "not a readable HDF5 file (corrupt or truncated?)");
    info_.format = Format::kHdf5;
    const hid_t f = file_.get();
    if (exists("events/t")) {
      layout_ = attributeExists(f, "evkit_layout") || !exists("t_offset") ? Layout::kEvkit
                                                                          : Layout::kDsec;
      openColumns({"events/t", "events/x", "events/y", "events/p"});
    } else if (exists("events/ts")) {
      layout_ = Layout::kEventUtils;
      openColumns({"events/ts", "events/xs", "events/ys", "events/ps"});
    } else {
      throwInFile(
          path_,
          "no dataset events/t or events/ts (expected the evkit, DSEC or event_utils layout)");
    }
    info_.layout = layout_ == Layout::kEvkit  ? "evkit"
                   : layout_ == Layout::kDsec ? "dsec"
                                              : "event_utils";
    info_.event_count = static_cast<int64_t>(count_);
    readSensorSize();
    readTimeIndex();
    readFrameIndex();
  }

 protected:
  bool readChunk(Chunk& chunk, size_t max_events) override {
    EventStore& ev = chunk.events;
    ev.setSensor(info_.sensor);
    const hsize_t n = std::min<hsize_t>(max_events, count_ - next_);
    if (n > 0) {
      const size_t base = ev.size();
      ev.t.resize(base + n);
      ev.x.resize(base + n);
      ev.y.resize(base + n);
      ev.p.resize(base + n);
      readTimes(next_, n, ev.t.data() + base);
      readRange(columns_[1].get(), H5T_NATIVE_UINT16, next_, n, ev.x.data() + base, path_,
                names_[1]);
      readRange(columns_[2].get(), H5T_NATIVE_UINT16, next_, n, ev.y.data() + base, path_,
                names_[2]);
      readRange(columns_[3].get(), H5T_NATIVE_INT8, next_, n, ev.p.data() + base, path_, names_[3]);
      checkEvents(ev, base);
      next_ += n;
    }
    const bool at_end = next_ == count_;
    const int64_t last_t = ev.empty() ? INT64_MIN : ev.t.back();
    while (next_frame_ < frame_starts_.size() && (at_end || frame_starts_[next_frame_] <= last_t)) {
      chunk.frames.push_back(loadFrame(next_frame_++));
    }
    return n > 0 || !chunk.frames.empty();
  }

  void seek(int64_t t_begin) override {
    hsize_t index = 0;
    if (!ms_to_idx_.empty()) {
      const int64_t k = floorDiv(t_begin - t_offset_, 1000);
      if (k >= static_cast<int64_t>(ms_to_idx_.size())) {
        index = count_;
      } else if (k > 0) {
        index = std::min<hsize_t>(ms_to_idx_[static_cast<size_t>(k)], count_);
      }
    } else {
      // Binary search on the time column: log2(N) single-element reads.
      hsize_t lo = 0, hi = count_;
      while (lo < hi) {
        const hsize_t mid = lo + (hi - lo) / 2;
        int64_t t;
        readTimes(mid, 1, &t);
        if (t < t_begin)
          lo = mid + 1;
        else
          hi = mid;
      }
      index = lo;
    }
    next_ = std::max(next_, index);
    while (next_frame_ < frame_starts_.size() && frame_starts_[next_frame_] < t_begin)
      ++next_frame_;
  }

 private:
  // Whether `name` exists, checking the object header of every group on the way before the
  // library walks into it (see hdf5_precheck.h).
  bool exists(const std::string& name) const {
    for (size_t slash = name.find('/');; slash = name.find('/', slash + 1)) {
      const std::string prefix = name.substr(0, slash);
      if (H5Lexists(file_.get(), prefix.c_str(), H5P_DEFAULT) <= 0) return false;
      checkHeader(file_.get(), prefix, prefix);
      if (slash == std::string::npos) return true;
    }
  }

  void checkHeader(hid_t loc, const std::string& name, const std::string& what) const {
    H5L_info_t link;
    if (H5Lget_info(loc, name.c_str(), &link, H5P_DEFAULT) >= 0 && link.type == H5L_TYPE_HARD) {
      precheck_.checkObjectHeader(link.u.address, "'" + what + "'");
    }
  }

  H5Handle open(const std::string& name) const {
    checkHeader(file_.get(), name, name);
    return openDataset(file_.get(), name, path_);
  }

  void openColumns(std::initializer_list<const char*> names) {
    size_t i = 0;
    for (const char* name : names) {
      names_[i] = name;
      columns_[i] = open(name);
      const auto shape = datasetShape(columns_[i].get());
      if (shape.size() != 1)
        throwInFile(path_, std::string("dataset ") + name + " is not one-dimensional");
      if (i == 0) count_ = shape[0];
      if (shape[0] != count_) {
        throwInFile(path_, std::string("dataset ") + name + " holds " + std::to_string(shape[0]) +
                               " values but " + names_[0] + " holds " + std::to_string(count_));
      }
      ++i;
    }
    if (layout_ == Layout::kDsec) {
      H5Handle off = open("t_offset");
      const ChunkSizeScope chunk_size(off.get());
      if (H5Dread(off.get(), H5T_NATIVE_INT64, H5S_ALL, H5S_ALL, H5P_DEFAULT, &t_offset_dsec_) <
          0) {
        throwInFile(path_, "cannot read t_offset");
      }
    }
  }

  void readTimes(hsize_t begin, hsize_t n, int64_t* out) {
    switch (layout_) {
      case Layout::kEvkit:
        readRange(columns_[0].get(), H5T_NATIVE_INT64, begin, n, out, path_, names_[0]);
        break;
      case Layout::kDsec:
        readRange(columns_[0].get(), H5T_NATIVE_INT64, begin, n, out, path_, names_[0]);
        for (hsize_t i = 0; i < n; ++i) out[i] += t_offset_dsec_;
        break;
      case Layout::kEventUtils: {
        seconds_.resize(n);
        readRange(columns_[0].get(), H5T_NATIVE_DOUBLE, begin, n, seconds_.data(), path_,
                  names_[0]);
        for (hsize_t i = 0; i < n; ++i) {
          if (!std::isfinite(seconds_[i]) || std::abs(seconds_[i]) > 9e12) {
            throwInFile(path_, names_[0] + "[" + std::to_string(begin + i) +
                                   "]: not a finite time in seconds");
          }
          out[i] = std::llround(seconds_[i] * 1e6);
        }
        break;
      }
    }
  }

  void checkEvents(EventStore& ev, size_t base) {
    const size_t n = ev.size();
    if (layout_ != Layout::kEvkit) {
      for (size_t i = base; i < n; ++i)
        ev.p[i] = ev.p[i] > 0 ? 1 : -1;  // 0/1 (or bool) in the file
    }
    validate(ev.view().subspan(base, n), path_, next_, last_t_);
    if (n > base) last_t_ = ev.t.back();
  }

  void readSensorSize() {
    const hid_t f = file_.get();
    if (attributeExists(f, "sensor_width") && attributeExists(f, "sensor_height")) {
      info_.sensor = SensorSize{static_cast<int>(readIntAttribute(f, "sensor_width", path_)),
                                static_cast<int>(readIntAttribute(f, "sensor_height", path_))};
    } else if (attributeExists(f, "sensor_resolution")) {
      const auto res = readIntArrayAttribute(f, "sensor_resolution", path_);  // (height, width)
      if (res.size() == 2)
        info_.sensor = SensorSize{static_cast<int>(res[1]), static_cast<int>(res[0])};
    }
    if (info_.sensor.known()) {
      if (info_.sensor.width > 65536 || info_.sensor.height > 65536) {
        throwInFile(path_, "implausible sensor size " + std::to_string(info_.sensor.width) + "x" +
                               std::to_string(info_.sensor.height));
      }
      return;
    }
    // Not stated: the bounding box of all events (one pass over x and y).
    std::vector<uint16_t> buf;
    uint16_t max_x = 0, max_y = 0;
    for (hsize_t b = 0; b < count_; b += kEventChunk * 8) {
      const hsize_t n = std::min(kEventChunk * 8, count_ - b);
      buf.resize(n);
      readRange(columns_[1].get(), H5T_NATIVE_UINT16, b, n, buf.data(), path_, names_[1]);
      max_x = std::max(max_x, *std::max_element(buf.begin(), buf.end()));
      readRange(columns_[2].get(), H5T_NATIVE_UINT16, b, n, buf.data(), path_, names_[2]);
      max_y = std::max(max_y, *std::max_element(buf.begin(), buf.end()));
    }
    if (count_ > 0) info_.sensor = SensorSize{max_x + 1, max_y + 1};
  }

  void readTimeIndex() {
    const std::string name = layout_ == Layout::kDsec ? "ms_to_idx" : "events/ms_to_idx";
    if (layout_ == Layout::kEventUtils || !exists(name)) return;
    H5Handle ds = open(name);
    const auto shape = datasetShape(ds.get());
    if (shape.size() != 1 || shape[0] > static_cast<hsize_t>(kMaxMsIndexEntries)) return;
    if (layout_ == Layout::kDsec) {
      t_offset_ = t_offset_dsec_;
    } else if (attributeExists(ds.get(), "t_offset")) {
      t_offset_ = readIntAttribute(ds.get(), "t_offset", path_);
    } else {
      return;
    }
    // One entry per millisecond up to about the last event: an index that claims more (a damaged
    // dataspace) is not read, and the reader falls back to binary search on t.
    if (count_ == 0) return;
    int64_t last_t = 0;
    readTimes(count_ - 1, 1, &last_t);
    const int64_t span_ms = last_t >= t_offset_ ? (last_t - t_offset_) / 1000 : -1;
    if (span_ms < 0 || shape[0] > static_cast<hsize_t>(span_ms) + 1000) {  // a second of slack
      info_.warnings.push_back(path_ + ": " + name + " does not match the events' times; ignored");
      return;
    }
    ms_to_idx_.resize(shape[0]);
    readRange(ds.get(), H5T_NATIVE_UINT64, 0, shape[0], ms_to_idx_.data(), path_, name);
  }

  void readFrameIndex() {
    const hid_t f = file_.get();
    if (layout_ == Layout::kEvkit && exists("frames/images")) {
      images_ = open("frames/images");
      frame_shape_ = datasetShape(images_.get());
      if (frame_shape_.size() != 3 && !(frame_shape_.size() == 4 && frame_shape_[3] == 3)) {
        throwInFile(path_, "frames/images must be (N, H, W) or (N, H, W, 3)");
      }
      if (frame_shape_[1] > 65536 || frame_shape_[2] > 65536) {
        throwInFile(path_, "frames/images has implausible dimensions");
      }
      const hsize_t n = frame_shape_[0];
      // A damaged dataspace can claim any count; no recording holds this many frames.
      if (n > kMaxFrames)
        throwInFile(path_, "frames/images claims " + std::to_string(n) + " frames");
      for (const char* name : {"frames/exposure_start", "frames/exposure_end"}) {
        H5Handle ds = open(name);
        const auto shape = datasetShape(ds.get());
        if (shape.size() != 1 || shape[0] != n) {
          throwInFile(path_, std::string(name) + " must hold one value per frame");
        }
        auto& dst = std::strcmp(name, "frames/exposure_start") == 0 ? frame_starts_ : frame_ends_;
        dst.resize(n);
        readRange(ds.get(), H5T_NATIVE_INT64, 0, n, dst.data(), path_, name);
      }
      H5Handle type(H5Dget_type(images_.get()));
      frame_bits_ = H5Tget_size(type.get()) >= 2 ? 16 : 8;
    } else if (layout_ == Layout::kEventUtils && exists("images")) {
      H5Handle group(H5Gopen2(f, "images", H5P_DEFAULT));
      H5G_info_t ginfo;
      if (!group || H5Gget_info(group.get(), &ginfo) < 0) throwInFile(path_, "cannot list /images");
      for (hsize_t i = 0; i < ginfo.nlinks; ++i) {
        char name[256];
        if (H5Lget_name_by_idx(group.get(), ".", H5_INDEX_NAME, H5_ITER_INC, i, name, sizeof(name),
                               H5P_DEFAULT) < 0) {
          continue;
        }
        checkHeader(group.get(), name, std::string("images/") + name);
        H5Handle ds(H5Dopen2(group.get(), name, H5P_DEFAULT));
        if (!ds || !attributeExists(ds.get(), "timestamp")) continue;
        H5Handle attr(H5Aopen(ds.get(), "timestamp", H5P_DEFAULT));
        double ts = 0;
        H5Aread(attr.get(), H5T_NATIVE_DOUBLE, &ts);
        if (!std::isfinite(ts))
          throwInFile(path_, std::string("images/") + name + ": timestamp is not finite");
        event_utils_images_.emplace_back(std::llround(ts * 1e6), std::string("images/") + name);
      }
      std::sort(event_utils_images_.begin(), event_utils_images_.end());
      for (const auto& [t, name] : event_utils_images_) {
        frame_starts_.push_back(t);
        frame_ends_.push_back(t);
      }
    }
  }

  Frame loadFrame(size_t i) {
    Frame frame;
    frame.exposure_start_us = frame_starts_[i];
    frame.exposure_end_us = frame_ends_[i];
    cv::Mat raw;
    if (layout_ == Layout::kEvkit) {
      const int h = static_cast<int>(frame_shape_[1]), w = static_cast<int>(frame_shape_[2]);
      const int c = frame_shape_.size() == 4 ? 3 : 1;
      raw.create(h, w, CV_MAKETYPE(frame_bits_ == 16 ? CV_16U : CV_8U, c));
      H5Handle file_space(H5Dget_space(images_.get()));
      std::vector<hsize_t> start(frame_shape_.size(), 0), count = frame_shape_;
      start[0] = i;
      count[0] = 1;
      H5Handle mem_space(H5Screate_simple(static_cast<int>(count.size()), count.data(), nullptr));
      H5Sselect_hyperslab(file_space.get(), H5S_SELECT_SET, start.data(), nullptr, count.data(),
                          nullptr);
      const ChunkSizeScope chunk_size(images_.get());
      if (H5Dread(images_.get(), frame_bits_ == 16 ? H5T_NATIVE_UINT16 : H5T_NATIVE_UINT8,
                  mem_space.get(), file_space.get(), H5P_DEFAULT, raw.data) < 0) {
        throwInFile(path_,
                    "cannot read frames/images[" + std::to_string(i) + "] (truncated or corrupt?)");
      }
      if (c == 3) cv::cvtColor(raw, raw, cv::COLOR_RGB2BGR);
    } else {
      const std::string& name = event_utils_images_[i].second;
      H5Handle ds = open(name);
      const auto shape = datasetShape(ds.get());
      if ((shape.size() != 2 && !(shape.size() == 3 && shape[2] == 3)) || shape[0] > 65536 ||
          shape[1] > 65536) {
        throwInFile(path_, name + " must be (H, W) or (H, W, 3)");
      }
      H5Handle type(H5Dget_type(ds.get()));
      const bool wide = H5Tget_size(type.get()) >= 2;
      raw.create(static_cast<int>(shape[0]), static_cast<int>(shape[1]),
                 CV_MAKETYPE(wide ? CV_16U : CV_8U, shape.size() == 3 ? 3 : 1));
      const ChunkSizeScope chunk_size(ds.get());
      if (H5Dread(ds.get(), wide ? H5T_NATIVE_UINT16 : H5T_NATIVE_UINT8, H5S_ALL, H5S_ALL,
                  H5P_DEFAULT, raw.data) < 0) {
        throwInFile(path_, "cannot read " + name);
      }
      if (raw.channels() == 3) cv::cvtColor(raw, raw, cv::COLOR_RGB2BGR);
    }
    frame.bit_depth = raw.depth() == CV_16U ? 16 : 8;
    raw.convertTo(frame.image, CV_32F, frame.bit_depth == 16 ? 1.0 / 65535.0 : 1.0 / 255.0);
    return frame;
  }

  std::string path_;
  Hdf5Precheck precheck_;
  H5Handle file_;
  Layout layout_ = Layout::kEvkit;
  H5Handle columns_[4];
  std::string names_[4];
  hsize_t count_ = 0;
  hsize_t next_ = 0;
  int64_t last_t_ = INT64_MIN;
  int64_t t_offset_dsec_ = 0;
  std::vector<double> seconds_;
  std::vector<uint64_t> ms_to_idx_;
  int64_t t_offset_ = 0;
  // Frames.
  H5Handle images_;
  std::vector<hsize_t> frame_shape_;
  int frame_bits_ = 8;
  std::vector<int64_t> frame_starts_, frame_ends_;
  std::vector<std::pair<int64_t, std::string>> event_utils_images_;
  size_t next_frame_ = 0;
};

// ---- Writer ----------------------------------------------------------------------------------

bool bloscAvailable() { return H5Zfilter_avail(kBloscFilter) > 0; }

void applyCompression(hid_t dcpl, const WriterOptions& options, const std::string& path) {
  const Compression compression =
      options.compression ? *options.compression
                          : (bloscAvailable() ? Compression::kBloscLz4 : Compression::kDeflate);
  switch (compression) {
    case Compression::kNone:
      break;
    case Compression::kDeflate:
      H5Pset_shuffle(dcpl);
      H5Pset_deflate(dcpl, static_cast<unsigned>(std::clamp(options.level, 0, 9)));
      break;
    case Compression::kBloscLz4: {
      if (!bloscAvailable()) {
        throwInFile(path,
                    "the Blosc HDF5 filter plugin is not installed (Debian: hdf5-filter-plugin); "
                    "use --compression deflate");
      }
      // cd_values: 4 reserved (filled by the filter), level, shuffle, compressor.
      const unsigned cd[7] = {
          0, 0, 0, 0, static_cast<unsigned>(std::clamp(options.level, 0, 9)), 1, kBloscLz4};
      H5Pset_filter(dcpl, kBloscFilter, H5Z_FLAG_MANDATORY, 7, cd);
      break;
    }
    case Compression::kLz4:
    case Compression::kZstd:
      throwInFile(path, "HDF5 compresses with blosc-lz4, deflate or none, not " +
                            compressionName(compression));
  }
}

// Frames, exposure times and the time index always use shuffle + deflate: they are small, and the
// Blosc plugin of Debian 12 silently writes zeros for chunks below its 128-byte minimum.
const WriterOptions kSmallDataOptions{Compression::kDeflate, 4};

class Hdf5Writer final : public EventWriter {
 public:
  Hdf5Writer(const std::string& path, SensorSize sensor, const WriterOptions& options)
      : out_(path), sensor_(sensor), options_(options), buffer_(sensor) {
    silenceHdf5Errors();
    useCheckedFilters();  // the same streams as the built-in filters: round trips test them
    file_ =
        H5Handle(H5Fcreate(out_.temporaryPath().c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT));
    if (!file_) throwInFile(path, "cannot create HDF5 file");
    H5Handle group(H5Gcreate2(file_.get(), "events", H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT));
    const hid_t types[4] = {H5T_STD_I64LE, H5T_STD_U16LE, H5T_STD_U16LE, H5T_STD_I8LE};
    const char* names[4] = {"events/t", "events/x", "events/y", "events/p"};
    for (int i = 0; i < 4; ++i)
      columns_[i] = createExtendible(names[i], types[i], 1, &kEventChunk, options_);
    buffer_.reserve(kEventChunk);
  }

  void write(const EventSpan& events) override {
    for (size_t begin = 0; begin < events.size();) {
      const size_t n =
          std::min(events.size() - begin, static_cast<size_t>(kEventChunk) - buffer_.size());
      const EventSpan part = events.subspan(begin, begin + n);
      check(part);
      buffer_.append(part);
      begin += n;
      if (buffer_.size() == kEventChunk) flushEvents();
    }
  }

  void writeFrame(const Frame& frame) override {
    const cv::Mat& img = frame.image;
    const int c = img.channels();
    if (img.empty() || (c != 1 && c != 3))
      throwInFile(out_.finalPath(), "frame must be grey or colour");
    if (!images_) {
      H5Handle group(H5Gcreate2(file_.get(), "frames", H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT));
      frame_bits_ = frame.bit_depth == 16 ? 16 : 8;
      frame_dims_ = {0, static_cast<hsize_t>(img.rows), static_cast<hsize_t>(img.cols)};
      if (c == 3) frame_dims_.push_back(3);
      std::vector<hsize_t> chunk = frame_dims_;
      chunk[0] = 1;
      images_ = createExtendible("frames/images", frame_bits_ == 16 ? H5T_STD_U16LE : H5T_STD_U8LE,
                                 static_cast<int>(chunk.size()), chunk.data(), kSmallDataOptions);
      const hsize_t one = 64;
      starts_ds_ =
          createExtendible("frames/exposure_start", H5T_STD_I64LE, 1, &one, kSmallDataOptions);
      ends_ds_ = createExtendible("frames/exposure_end", H5T_STD_I64LE, 1, &one, kSmallDataOptions);
    } else if (static_cast<hsize_t>(img.rows) != frame_dims_[1] ||
               static_cast<hsize_t>(img.cols) != frame_dims_[2] ||
               (c == 3) != (frame_dims_.size() == 4)) {
      throwInFile(out_.finalPath(),
                  "all frames of a recording must have the same size and channels");
    }
    cv::Mat q = quantize(img, frame_bits_);
    if (c == 3) cv::cvtColor(q, q, cv::COLOR_BGR2RGB);
    if (!q.isContinuous()) q = q.clone();
    std::vector<hsize_t> count = frame_dims_;
    count[0] = 1;
    appendRows(images_.get(), frame_bits_ == 16 ? H5T_NATIVE_UINT16 : H5T_NATIVE_UINT8,
               frame_count_, count, q.data);
    const std::vector<hsize_t> one{1};
    appendRows(starts_ds_.get(), H5T_NATIVE_INT64, frame_count_, one, &frame.exposure_start_us);
    appendRows(ends_ds_.get(), H5T_NATIVE_INT64, frame_count_, one, &frame.exposure_end_us);
    ++frame_count_;
  }

  void close() override {
    flushEvents();
    const hid_t f = file_.get();
    writeIntAttribute(f, "evkit_layout", 1);
    SensorSize sensor = sensor_;
    if (!sensor.known()) sensor = SensorSize{max_x_ + 1, max_y_ + 1};
    if (written_ == 0 && !sensor_.known()) sensor = SensorSize{};
    writeIntAttribute(f, "sensor_width", sensor.width);
    writeIntAttribute(f, "sensor_height", sensor.height);
    if (index_valid_) {
      const hsize_t n = ms_to_idx_.size();
      const hsize_t chunk = std::clamp<hsize_t>(n, 1, 1 << 16);
      H5Handle ds =
          createExtendible("events/ms_to_idx", H5T_STD_U64LE, 1, &chunk, kSmallDataOptions);
      appendRows(ds.get(), H5T_NATIVE_UINT64, 0, {n}, ms_to_idx_.data());
      writeIntAttribute(ds.get(), "t_offset", t_offset_);
    }
    // Chunks are compressed and written when a dataset closes: a failure shows up only here.
    bool ok = true;
    for (H5Handle* ds : {&columns_[0], &columns_[1], &columns_[2], &columns_[3], &images_,
                         &starts_ds_, &ends_ds_}) {
      if (ds->valid()) ok &= H5Dclose(ds->release()) >= 0;
    }
    ok &= H5Fclose(file_.release()) >= 0;
    if (!ok)
      throwInFile(out_.finalPath(),
                  "cannot finish the HDF5 file (disk full, or a compression filter failed)");
    out_.commit();
  }

 private:
  H5Handle createExtendible(const char* name, hid_t type, int rank, const hsize_t* chunk,
                            const WriterOptions& compression) {
    std::vector<hsize_t> dims(chunk, chunk + rank), maxdims(chunk, chunk + rank);
    dims[0] = 0;
    maxdims[0] = H5S_UNLIMITED;
    H5Handle space(H5Screate_simple(rank, dims.data(), maxdims.data()));
    H5Handle dcpl(H5Pcreate(H5P_DATASET_CREATE));
    H5Pset_chunk(dcpl.get(), rank, chunk);
    applyCompression(dcpl.get(), compression, out_.finalPath());
    H5Handle ds(
        H5Dcreate2(file_.get(), name, type, space.get(), H5P_DEFAULT, dcpl.get(), H5P_DEFAULT));
    if (!ds) throwInFile(out_.finalPath(), std::string("cannot create dataset ") + name);
    return ds;
  }

  void appendRows(hid_t ds, hid_t mem_type, hsize_t at, std::vector<hsize_t> count,
                  const void* data) {
    std::vector<hsize_t> dims = count;
    dims[0] = at + count[0];
    std::vector<hsize_t> start(count.size(), 0);
    start[0] = at;
    if (H5Dset_extent(ds, dims.data()) < 0) throwInFile(out_.finalPath(), "cannot extend dataset");
    H5Handle file_space(H5Dget_space(ds));
    H5Handle mem_space(H5Screate_simple(static_cast<int>(count.size()), count.data(), nullptr));
    if (H5Sselect_hyperslab(file_space.get(), H5S_SELECT_SET, start.data(), nullptr, count.data(),
                            nullptr) < 0 ||
        H5Dwrite(ds, mem_type, mem_space.get(), file_space.get(), H5P_DEFAULT, data) < 0) {
      throwInFile(out_.finalPath(), "HDF5 write failed (disk full?)");
    }
  }

  void check(const EventSpan& part) {
    for (size_t i = 0; i < part.size(); ++i) {
      const int64_t t = part.t[i];
      const size_t index = written_ + buffer_.size() + i;
      if (t < last_t_) {
        throwInFile(out_.finalPath(), "event " + std::to_string(index) + ": timestamp " +
                                          std::to_string(t) +
                                          " us goes back in time; events must be sorted");
      }
      if (part.p[i] != 1 && part.p[i] != -1) {
        throwInFile(out_.finalPath(),
                    "event " + std::to_string(index) + ": polarity must be +1 or -1");
      }
      if (sensor_.known() && !sensor_.contains(part.x[i], part.y[i])) {
        throwInFile(out_.finalPath(),
                    "event " + std::to_string(index) + " lies outside the sensor");
      }
      max_x_ = std::max<int>(max_x_, part.x[i]);
      max_y_ = std::max<int>(max_y_, part.y[i]);
      // ms_to_idx[k] = first index with t >= t_offset + 1000 k.
      if (index == 0) t_offset_ = floorDiv(t, 1000) * 1000;
      if (index_valid_) {
        const int64_t k_needed =
            floorDiv(t - t_offset_, 1000);  // entries 0..k_needed point here or before
        if (k_needed >= kMaxMsIndexEntries) {
          index_valid_ = false;
          ms_to_idx_.clear();
          ms_to_idx_.shrink_to_fit();
        } else {
          while (static_cast<int64_t>(ms_to_idx_.size()) <= k_needed) ms_to_idx_.push_back(index);
        }
      }
      last_t_ = t;
    }
  }

  void flushEvents() {
    const hsize_t n = buffer_.size();
    if (n == 0) return;
    appendRows(columns_[0].get(), H5T_NATIVE_INT64, written_, {n}, buffer_.t.data());
    appendRows(columns_[1].get(), H5T_NATIVE_UINT16, written_, {n}, buffer_.x.data());
    appendRows(columns_[2].get(), H5T_NATIVE_UINT16, written_, {n}, buffer_.y.data());
    appendRows(columns_[3].get(), H5T_NATIVE_INT8, written_, {n}, buffer_.p.data());
    written_ += n;
    buffer_.clear();
  }

  AtomicPath out_;
  SensorSize sensor_;
  WriterOptions options_;
  H5Handle file_;
  H5Handle columns_[4];
  EventStore buffer_;
  hsize_t written_ = 0;
  int64_t last_t_ = INT64_MIN;
  int max_x_ = -1, max_y_ = -1;
  int64_t t_offset_ = 0;
  bool index_valid_ = true;
  std::vector<uint64_t> ms_to_idx_;
  H5Handle images_, starts_ds_, ends_ds_;
  std::vector<hsize_t> frame_dims_;
  int frame_bits_ = 8;
  hsize_t frame_count_ = 0;
};

}  // namespace

std::unique_ptr<EventReader> openHdf5Reader(const std::string& path) {
  return std::make_unique<Hdf5Reader>(path);
}

std::unique_ptr<EventWriter> openHdf5Writer(const std::string& path, SensorSize sensor,
                                            const WriterOptions& options) {
  return std::make_unique<Hdf5Writer>(path, sensor, options);
}

}  // namespace evkit::detail
