#include "arrays.h"

#include <cstring>
#include <opencv2/imgproc.hpp>

namespace evkit::python {

namespace {

py::object numpy() { return py::module_::import("numpy"); }

// A view of one column whose base keeps the store alive; read-only.
template <typename T>
py::array columnView(const std::shared_ptr<const EventStore>& store, const std::vector<T>& column) {
  auto* keep = new std::shared_ptr<const EventStore>(store);
  py::capsule base(keep,
                   [](void* p) { delete static_cast<std::shared_ptr<const EventStore>*>(p); });
  py::array view(py::dtype::of<T>(), {column.size()}, {sizeof(T)}, column.data(), base);
  view.attr("setflags")(py::arg("write") = false);
  return view;
}

bool isStructured(py::handle h) {
  return py::isinstance<py::array>(h) &&
         !py::reinterpret_borrow<py::array>(h).dtype().attr("names").is_none();
}

std::string dtypeName(const py::array& a) { return py::str(a.dtype()).cast<std::string>(); }

// One column as a 1-D numpy array of `n` values (n < 0: any length).
py::array columnOf(py::handle events, const char* name, int index, const std::string& what) {
  py::object column;
  if (isStructured(events))
    column = events[py::str(name)];
  else if (py::isinstance<py::dict>(events) || py::hasattr(events, "keys"))
    column = events[py::str(name)];
  else
    column = events[py::int_(index)];
  py::array a = numpy().attr("asarray")(column);
  if (a.ndim() != 1) {
    throw Error(what + ": column " + name + " must be one-dimensional, not of shape " +
                py::str(a.attr("shape")).cast<std::string>());
  }
  return a;
}

// The first index where `bad` (a boolean array) holds, for the messages.
size_t firstTrue(const py::array& bad) { return numpy().attr("argmax")(bad).cast<size_t>(); }

template <typename T>
void copyInto(const py::array& a, const char* dtype, std::vector<T>& out) {
  auto typed = py::array_t<T, py::array::c_style | py::array::forcecast>(
      a.attr("astype")(dtype, py::arg("copy") = false));
  out.resize(static_cast<size_t>(typed.size()));
  if (!out.empty()) std::memcpy(out.data(), typed.data(), out.size() * sizeof(T));
}

void copyTime(const py::array& t, const std::string& what, std::vector<int64_t>& out) {
  const char kind = t.dtype().kind();
  if (kind == 'f') {
    throw Error(what + ": t is " + dtypeName(t) +
                "; evkit takes t as integer microseconds (int64): float seconds lose precision "
                "(a float64 holds Unix time only to about 0.2 us, a float32 to minutes); convert "
                "with (t * 1e6).round().astype(numpy.int64) if t is in seconds");
  }
  if (kind != 'i' && kind != 'u')
    throw Error(what + ": t must be integer microseconds, not " + dtypeName(t));
  copyInto(t, "int64", out);
}

void copyCoordinate(const py::array& c, const char* name, const std::string& what,
                    std::vector<uint16_t>& out) {
  const char kind = c.dtype().kind();
  if (kind != 'i' && kind != 'u' && kind != 'f')
    throw Error(what + ": " + name + " must be integer pixels, not " + dtypeName(c));
  if (c.size() > 0) {
    py::object np = numpy();
    py::array bad = np.attr("logical_or")(np.attr("less")(c, 0), np.attr("greater")(c, 65535));
    if (kind == 'f') bad = np.attr("logical_or")(bad, np.attr("not_equal")(c, np.attr("floor")(c)));
    if (np.attr("any")(bad).cast<bool>()) {
      const size_t i = firstTrue(bad);
      throw Error(what + ": event " + std::to_string(i) + ": " + name + " = " +
                  py::str(c[py::int_(i)]).cast<std::string>() +
                  " is not a pixel coordinate (an integer in 0..65535)");
    }
  }
  copyInto(c, "uint16", out);
}

void copyPolarity(const py::array& p, const std::string& what, std::vector<int8_t>& out) {
  const char kind = p.dtype().kind();
  py::object np = numpy();
  if (kind != 'b') {
    if (kind != 'i' && kind != 'u' && kind != 'f')
      throw Error(what + ": p must be -1/+1, 0/1 or bool, not " + dtypeName(p));
    py::array bad = np.attr("logical_and")(
        np.attr("logical_and")(np.attr("not_equal")(p, -1), np.attr("not_equal")(p, 0)),
        np.attr("not_equal")(p, 1));
    if (p.size() > 0 && np.attr("any")(bad).cast<bool>()) {
      const size_t i = firstTrue(bad);
      throw Error(what + ": event " + std::to_string(i) +
                  ": p = " + py::str(p[py::int_(i)]).cast<std::string>() +
                  " is not a polarity (-1/+1, 0/1 or bool)");
    }
  }
  copyInto(np.attr("where")(np.attr("greater")(p, 0), 1, -1), "int8", out);
}

}  // namespace

py::dtype eventDtype() {
  py::list fields;
  fields.append(py::make_tuple("t", "<i8"));
  fields.append(py::make_tuple("x", "<u2"));
  fields.append(py::make_tuple("y", "<u2"));
  fields.append(py::make_tuple("p", "i1"));
  return py::dtype::from_args(fields);
}

py::array Events::t() const { return columnView(store_, store_->t); }
py::array Events::x() const { return columnView(store_, store_->x); }
py::array Events::y() const { return columnView(store_, store_->y); }
py::array Events::p() const { return columnView(store_, store_->p); }

py::array Events::structured() const {
  if (!structured_) {
    const EventStore& s = *store_;
    py::array out(eventDtype(), std::vector<py::ssize_t>{static_cast<py::ssize_t>(s.size())});
    auto* bytes = static_cast<char*>(out.mutable_data());
    {
      py::gil_scoped_release release;
      constexpr size_t kItem = 13;  // 8 + 2 + 2 + 1, packed
      for (size_t i = 0; i < s.size(); ++i) {
        char* e = bytes + i * kItem;
        std::memcpy(e, &s.t[i], 8);
        std::memcpy(e + 8, &s.x[i], 2);
        std::memcpy(e + 10, &s.y[i], 2);
        std::memcpy(e + 12, &s.p[i], 1);
      }
    }
    structured_ = out;
  }
  return structured_;
}

std::shared_ptr<const EventStore> eventsFrom(py::handle events, SensorSize sensor,
                                             const std::string& what) {
  if (py::isinstance<Events>(events)) {
    const auto& store = events.cast<const Events&>().store();
    if (!sensor.known() || sensor == store->sensor()) return store;
    auto resized = std::make_shared<EventStore>(*store);
    resized->setSensor(sensor);
    validate(resized->view(), what);
    return resized;
  }
  const bool columns = isStructured(events) || py::isinstance<py::dict>(events) ||
                       py::hasattr(events, "keys") ||
                       (py::isinstance<py::sequence>(events) && !py::isinstance<py::str>(events) &&
                        py::len(events) == 4);
  if (!columns) {
    throw Error(what +
                ": expected evkit.Events, a structured array or a dict with fields t, x, y, p, or "
                "a tuple (t, x, y, p); got " +
                py::str(py::type::of(events).attr("__name__")).cast<std::string>());
  }
  py::array t = columnOf(events, "t", 0, what), x = columnOf(events, "x", 1, what),
            y = columnOf(events, "y", 2, what), p = columnOf(events, "p", 3, what);
  if (x.size() != t.size() || y.size() != t.size() || p.size() != t.size()) {
    throw Error(what + ": columns of different lengths (t " + std::to_string(t.size()) + ", x " +
                std::to_string(x.size()) + ", y " + std::to_string(y.size()) + ", p " +
                std::to_string(p.size()) + ")");
  }
  auto store = std::make_shared<EventStore>(sensor);
  copyTime(t, what, store->t);
  copyCoordinate(x, "x", what, store->x);
  copyCoordinate(y, "y", what, store->y);
  copyPolarity(p, what, store->p);
  if (!sensor.known()) store->setSensor(boundingSensor(store->view()));
  validate(store->view(), what);
  return store;
}

py::array imageToArray(const cv::Mat& image) {
  cv::Mat m;
  if (image.depth() != CV_32F)
    image.convertTo(m, CV_32F);
  else
    m = image;
  if (m.channels() == 3) cv::cvtColor(m, m, cv::COLOR_BGR2RGB);
  if (!m.isContinuous()) m = m.clone();
  auto* keep = new cv::Mat(m);
  py::capsule base(keep, [](void* p) { delete static_cast<cv::Mat*>(p); });
  std::vector<py::ssize_t> shape{m.rows, m.cols};
  std::vector<py::ssize_t> strides{static_cast<py::ssize_t>(m.step[0]),
                                   static_cast<py::ssize_t>(m.elemSize())};
  if (m.channels() > 1) {
    shape.push_back(m.channels());
    strides.push_back(sizeof(float));
  }
  return py::array(py::dtype::of<float>(), shape, strides, keep->ptr<float>(), base);
}

cv::Mat arrayToImage(py::handle array, const std::string& what, int* bit_depth) {
  py::array a = numpy().attr("asarray")(array);
  const int channels = a.ndim() == 3 ? static_cast<int>(a.shape(2)) : 1;
  if (a.ndim() < 2 || a.ndim() > 3 || (channels != 1 && channels != 3) || a.shape(0) == 0 ||
      a.shape(1) == 0) {
    throw Error(what + ": expected an image of shape (height, width) or (height, width, 3), not " +
                py::str(a.attr("shape")).cast<std::string>());
  }
  const char kind = a.dtype().kind();
  double scale = 1;
  int depth = 16;  // float pixels are kept as 16-bit where they are written
  if (kind == 'u' && a.itemsize() == 1) {
    scale = 1.0 / 255;
    depth = 8;
  } else if (kind == 'u' && a.itemsize() == 2) {
    scale = 1.0 / 65535;
  } else if (kind != 'f') {
    throw Error(what + ": pixels must be float (linear, 0..1), uint8 or uint16, not " +
                dtypeName(a));
  }
  auto f = py::array_t<float, py::array::c_style | py::array::forcecast>(
      a.attr("astype")("float32", py::arg("copy") = false));
  const int rows = static_cast<int>(a.shape(0)), cols = static_cast<int>(a.shape(1));
  cv::Mat image = cv::Mat(rows, cols, CV_32FC(channels), const_cast<float*>(f.data())).clone();
  if (scale != 1) image *= scale;
  if (cv::checkRange(image, true) == false)
    throw Error(what + ": the image holds NaN or infinite values");
  if (channels == 3) cv::cvtColor(image, image, cv::COLOR_RGB2BGR);
  if (bit_depth) *bit_depth = depth;
  return image;
}

PyFrame frameToPython(const Frame& frame) {
  return PyFrame{imageToArray(frame.image), frame.exposure_start_us, frame.exposure_end_us,
                 frame.bit_depth};
}

Frame frameFromPython(py::handle frame, const std::string& what) {
  Frame f;
  if (py::isinstance<PyFrame>(frame)) {
    const auto& pf = frame.cast<const PyFrame&>();
    f.image = arrayToImage(pf.image, what);
    f.exposure_start_us = pf.exposure_start;
    f.exposure_end_us = pf.exposure_end;
    f.bit_depth = pf.bit_depth;
  } else if (py::isinstance<py::sequence>(frame) && py::len(frame) == 3) {
    f.image = arrayToImage(frame[py::int_(0)], what, &f.bit_depth);
    f.exposure_start_us = frame[py::int_(1)].cast<int64_t>();
    f.exposure_end_us = frame[py::int_(2)].cast<int64_t>();
  } else {
    throw Error(what + ": expected evkit.Frame or (image, exposure_start_us, exposure_end_us)");
  }
  if (f.exposure_end_us < f.exposure_start_us)
    throw Error(what + ": the exposure ends before it starts");
  return f;
}

}  // namespace evkit::python
