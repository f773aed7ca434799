// A thin RAII layer over the HDF5 C API, with errors turned into evkit::Error.
#pragma once

#include <hdf5.h>

#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "evkit/base/error.h"

namespace evkit::detail {

// Owns one HDF5 identifier and closes it with the right H5?close.
class H5Handle {
 public:
  H5Handle() = default;
  explicit H5Handle(hid_t id) : id_(id) {}
  H5Handle(H5Handle&& other) noexcept : id_(std::exchange(other.id_, H5I_INVALID_HID)) {}
  H5Handle& operator=(H5Handle&& other) noexcept {
    if (this != &other) {
      reset();
      id_ = std::exchange(other.id_, H5I_INVALID_HID);
    }
    return *this;
  }
  ~H5Handle() { reset(); }
  H5Handle(const H5Handle&) = delete;
  H5Handle& operator=(const H5Handle&) = delete;

  hid_t get() const { return id_; }
  // Gives up ownership (the caller closes the identifier).
  hid_t release() { return std::exchange(id_, H5I_INVALID_HID); }
  bool valid() const { return id_ >= 0; }
  explicit operator bool() const { return valid(); }
  void reset();

 private:
  hid_t id_ = H5I_INVALID_HID;
};

// What the reader and the writer of evkit's layout share.
inline constexpr hsize_t kEventChunk = hsize_t{1}
                                       << 17;    // elements per HDF5 chunk of an event column
inline constexpr unsigned kBloscFilter = 32001;  // registered HDF5 filter id of Blosc
inline constexpr unsigned kBloscLz4 = 1;         // Blosc compressor code of LZ4
inline constexpr int64_t kMaxMsIndexEntries = 100'000'000;  // > 27 h of recording: no index
inline int64_t floorDiv(int64_t a, int64_t b) {
  return a / b - ((a % b != 0) && ((a < 0) != (b < 0)));
}
// a - b, clamped to int64's range: a damaged file's times may sit anywhere in it.
inline int64_t saturatingSub(int64_t a, int64_t b) {
  int64_t d;
  if (!__builtin_sub_overflow(a, b, &d)) return d;
  return b < 0 ? INT64_MAX : INT64_MIN;
}

// Silences HDF5's own error-stack printing; evkit reports errors itself.
void silenceHdf5Errors();

bool linkExists(hid_t loc, const std::string& path);
bool attributeExists(hid_t loc, const std::string& name);

// Read an attribute that holds one number (a scalar or a single element, integer or floating
// point), converted; anything else is an error naming the attribute (as `shown`, when given).
int64_t readIntAttribute(hid_t loc, const std::string& name, const std::string& file);
double readDoubleAttribute(hid_t loc, const std::string& name, const std::string& file,
                           const std::string& shown = "");
void writeIntAttribute(hid_t loc, const std::string& name, int64_t value);
void writeStringAttribute(hid_t loc, const std::string& name, const std::string& value);
// Reads an integer array attribute (e.g. event_utils' sensor_resolution).
std::vector<int64_t> readIntArrayAttribute(hid_t loc, const std::string& name,
                                           const std::string& file);

// Dimensions of a dataset.
std::vector<hsize_t> datasetShape(hid_t dataset);

}  // namespace evkit::detail
