// What the Python module shares between its parts: events and images between C++ and numpy.
//
// Events that C++ made (read, simulated, an observation's) stay in their EventStore; numpy sees
// them through views whose base is a capsule holding the store (no copy, read-only: the store's
// order is an invariant). Events from Python (a structured array, a dict or a tuple of columns, any
// integer dtypes) are converted once and validated, with one clear message per problem.
#pragma once

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include <memory>
#include <opencv2/core.hpp>
#include <string>

#include "evkit/base/error.h"
#include "evkit/events/event_store.h"
#include "evkit/events/frame.h"

namespace evkit::python {

namespace py = pybind11;

// A file's problem: raised as evkit.FileError, which is both evkit.Error and OSError.
class FileError : public Error {
 public:
  using Error::Error;
};

// Runs `f`; an evkit::Error it throws becomes a FileError (for the functions that take a path).
template <typename F>
auto asFileError(F&& f) -> decltype(f()) {
  try {
    return f();
  } catch (const FileError&) {
    throw;
  } catch (const Error& e) {
    throw FileError(e.what());
  }
}

// evkit.Events: a store shared with the numpy views made of it.
class Events {
 public:
  explicit Events(std::shared_ptr<const EventStore> store) : store_(std::move(store)) {}
  virtual ~Events() = default;

  const std::shared_ptr<const EventStore>& store() const { return store_; }
  const EventStore& get() const { return *store_; }

  py::array t() const;
  py::array x() const;
  py::array y() const;
  py::array p() const;
  // The structured array (t, x, y, p) as tonic lays it out: built once on first use (a copy, as
  // numpy's records cannot view four separate columns), then the same array every time.
  py::array structured() const;

 private:
  std::shared_ptr<const EventStore> store_;
  mutable py::object structured_;
};

// The dtype of Events.structured: packed [('t', '<i8'), ('x', '<u2'), ('y', '<u2'), ('p', 'i1')].
py::dtype eventDtype();

// Events given by Python: evkit.Events (shared, no copy), a structured array or any mapping with
// fields t, x, y, p, or a sequence of the four columns. t must be integer microseconds; x, y
// non-negative integers; p in {-1, +1} or {0, 1} (0 is OFF) or bool. With a known `sensor`, events
// outside it are refused; otherwise the sensor is the events' own (Events) or their bounding box.
// Throws evkit::Error naming `what`.
std::shared_ptr<const EventStore> eventsFrom(py::handle events, SensorSize sensor,
                                             const std::string& what = "events");

// An image for numpy without a copy (the array's base holds the cv::Mat); colour as RGB (a copy).
py::array imageToArray(const cv::Mat& image);
// An image from numpy: H×W or H×W×3 (RGB), float (linear [0, 1]) or uint8/uint16 (scaled to
// [0, 1], the bit depth returned in *bit_depth); a float32 CV_32FC1/CV_32FC3 (BGR) copy.
cv::Mat arrayToImage(py::handle array, const std::string& what, int* bit_depth = nullptr);

// evkit.Frame: an image with its exposure.
struct PyFrame {
  py::array image;
  int64_t exposure_start = 0, exposure_end = 0;
  int bit_depth = 8;
};
PyFrame frameToPython(const Frame& frame);
// A Frame object, or (image, exposure_start, exposure_end).
Frame frameFromPython(py::handle frame, const std::string& what);

}  // namespace evkit::python
