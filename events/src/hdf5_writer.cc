// The HDF5 writer of evkit's layout (hdf5_io.cc describes the layout and reads it).

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <opencv2/imgproc.hpp>

#include "evkit/base/error.h"
#include "evkit/events/atomic_file.h"
#include "evkit/events/image_io.h"
#include "formats.h"
#include "hdf5_precheck.h"
#include "hdf5_util.h"

namespace evkit::detail {

namespace {

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
      if (index == 0) {
        // A first time within a millisecond of int64's floor has no millisecond origin: no index.
        if (t < INT64_MIN + 1000)
          index_valid_ = false;
        else
          t_offset_ = floorDiv(t, 1000) * 1000;
      }
      if (index_valid_) {
        // Entries 0..k_needed point here or before.
        const int64_t k_needed = floorDiv(saturatingSub(t, t_offset_), 1000);
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

std::unique_ptr<EventWriter> openHdf5Writer(const std::string& path, SensorSize sensor,
                                            const WriterOptions& options) {
  return std::make_unique<Hdf5Writer>(path, sensor, options);
}

}  // namespace evkit::detail
