// The parts of the Python module, each adding its functions and classes to `m`.
#pragma once

#include <pybind11/pybind11.h>

#include "evkit/events/calibration.h"

namespace evkit::python {

namespace py = pybind11;

// Events, frames, files, representations, the slicer and the simulator (bind_events.cc).
void bindEvents(py::module_& m);
// Observations, the scene generator and the deblurring methods (bind_deblur.cc).
void bindDeblur(py::module_& m);

// A camera as a dict {fx, fy, cx, cy, distortion, width, height}.
py::dict cameraToPython(const Calibration& camera);
// From such a dict or a sequence fx, fy, cx, cy[, k1, k2, p1, p2[, k3]].
Calibration cameraFromPython(py::handle camera);

}  // namespace evkit::python
