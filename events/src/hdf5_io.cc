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

constexpr hsize_t kMaxFrames = 1'000'000;  // 14 h at 20 fps, 17 min at 1 kHz
// Samples of one frame (rows x columns x channels): 8K colour is 2^26.6; a damaged dataspace can
// state 65,536 x 65,536 x 3, which would size a 25 GB image before any byte is read.
constexpr hsize_t kMaxFrameSamples = hsize_t{1} << 27;

// Whether a frame of rows x columns x channels is one a camera could have written.
bool plausibleFrame(hsize_t rows, hsize_t cols, hsize_t channels) {
  return rows <= 65536 && cols <= 65536 && rows * cols * channels <= kMaxFrameSamples;
}

enum class Layout { kEvkit, kDsec, kEventUtils };

H5Handle openDataset(hid_t file, const std::string& name, const std::string& path) {
  H5Handle ds(H5Dopen2(file, name.c_str(), H5P_DEFAULT));
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
    // The millisecond index where it covers t_begin; past its end (a short or damaged index),
    // binary search on the time column: log2(N) single-element reads.
    const int64_t k = ms_to_idx_.empty() ? -1 : floorDiv(saturatingSub(t_begin, t_offset_), 1000);
    hsize_t index = 0;
    if (!ms_to_idx_.empty() && k < static_cast<int64_t>(ms_to_idx_.size())) {
      if (k > 0) index = std::min<hsize_t>(ms_to_idx_[static_cast<size_t>(k)], count_);
    } else {
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
      const auto shape = datasetShape(off.get());
      if (shape.size() == 1 && shape[0] == 1) {  // (1,) rather than a scalar: maybe chunked
        readRange(off.get(), H5T_NATIVE_INT64, 0, 1, &t_offset_dsec_, path_, "t_offset");
      } else if (!shape.empty() || H5Dread(off.get(), H5T_NATIVE_INT64, H5S_ALL, H5S_ALL,
                                           H5P_DEFAULT, &t_offset_dsec_) < 0) {
        throwInFile(path_, "cannot read t_offset (expected one integer)");
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
        for (hsize_t i = 0; i < n; ++i) {
          if (__builtin_add_overflow(out[i], t_offset_dsec_, &out[i])) {
            throwInFile(path_, "event " + std::to_string(begin + i) +
                                   ": time plus t_offset lies outside int64 microseconds");
          }
        }
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
    const int64_t span_ms = last_t >= t_offset_ ? saturatingSub(last_t, t_offset_) / 1000 : -1;
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
      if (!plausibleFrame(frame_shape_[1], frame_shape_[2], frame_shape_.size() == 4 ? 3 : 1)) {
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
        const double ts = readDoubleAttribute(ds.get(), "timestamp", path_,
                                              std::string("images/") + name + "/timestamp");
        if (!std::isfinite(ts) || std::abs(ts) > 9e12)
          throwInFile(
              path_, std::string("images/") + name + ": timestamp is not a finite time in seconds");
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
      std::vector<hsize_t> start(frame_shape_.size(), 0), count = frame_shape_;
      start[0] = i;
      count[0] = 1;
      readHyperslab(images_.get(), frame_bits_ == 16 ? H5T_NATIVE_UINT16 : H5T_NATIVE_UINT8, start,
                    count, raw.data, path_, "frames/images");
      if (c == 3) cv::cvtColor(raw, raw, cv::COLOR_RGB2BGR);
    } else {
      const std::string& name = event_utils_images_[i].second;
      H5Handle ds = open(name);
      const auto shape = datasetShape(ds.get());
      if ((shape.size() != 2 && !(shape.size() == 3 && shape[2] == 3)) ||
          !plausibleFrame(shape[0], shape[1], shape.size() == 3 ? 3 : 1)) {
        throwInFile(path_, name + " must be (H, W) or (H, W, 3), of at most 2^27 samples");
      }
      H5Handle type(H5Dget_type(ds.get()));
      const bool wide = H5Tget_size(type.get()) >= 2;
      raw.create(static_cast<int>(shape[0]), static_cast<int>(shape[1]),
                 CV_MAKETYPE(wide ? CV_16U : CV_8U, shape.size() == 3 ? 3 : 1));
      readHyperslab(ds.get(), wide ? H5T_NATIVE_UINT16 : H5T_NATIVE_UINT8,
                    std::vector<hsize_t>(shape.size(), 0), shape, raw.data, path_, name);
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

}  // namespace

std::unique_ptr<EventReader> openHdf5Reader(const std::string& path) {
  return std::make_unique<Hdf5Reader>(path);
}

}  // namespace evkit::detail
