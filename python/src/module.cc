// The compiled core of `import evkit` (python/evkit/__init__.py re-exports it): exceptions, then
// the events part and the deblurring part.
#include <pybind11/pybind11.h>

#include "arrays.h"
#include "bindings.h"

namespace py = pybind11;

PYBIND11_MODULE(_evkit, m) {
  m.doc() = "evkit's C++ core: events, files, representations, simulation, synthesis, deblurring.";

  // evkit.Error is a ValueError; evkit.FileError (a file's problem) is also an OSError. Both carry
  // the one-line message the command line prints.
  static py::exception<evkit::Error> error(m, "Error", PyExc_ValueError);
  error.attr("__module__") = "evkit";
  error.doc() =
      "A problem with evkit's input: the message names the file, the position and what "
      "was expected.";
  py::tuple bases = py::make_tuple(error, py::handle(PyExc_OSError));
  static py::object file_error = py::reinterpret_steal<py::object>(PyErr_NewExceptionWithDoc(
      "evkit.FileError", "A bad or unreadable file (evkit.Error, OSError).", bases.ptr(), nullptr));
  m.attr("FileError") = file_error;
  py::register_exception_translator([](std::exception_ptr p) {
    try {
      if (p) std::rethrow_exception(p);
    } catch (const evkit::python::FileError& e) {
      PyErr_SetString(file_error.ptr(), e.what());
    } catch (const evkit::Error& e) {
      PyErr_SetString(error.ptr(), e.what());
    }
  });

  evkit::python::bindEvents(m);
  evkit::python::bindDeblur(m);
}
