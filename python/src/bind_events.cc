// evkit.Events, Frame, Recording, read, open, write, accumulate, EventSlicer and simulate.
#include <pybind11/stl.h>
#include <pybind11/stl/filesystem.h>

#include <limits>

#include "arrays.h"
#include "bindings.h"
#include "evkit/events/accumulate.h"
#include "evkit/events/io.h"
#include "evkit/events/simulator.h"
#include "evkit/events/slicer.h"

namespace evkit::python {

namespace {

constexpr int64_t kNoStart = std::numeric_limits<int64_t>::min();
constexpr int64_t kNoEnd = std::numeric_limits<int64_t>::max();

// Events with the frames that came with them: a whole recording, or one chunk of a stream.
class FramedEvents : public Events {
 public:
  FramedEvents(std::shared_ptr<const EventStore> store, py::list frames, py::dict info)
      : Events(std::move(store)), frames(std::move(frames)), info(std::move(info)) {}
  py::list frames;
  py::dict info;
};

py::list framesToPython(const std::vector<Frame>& frames) {
  py::list out;
  for (const Frame& f : frames) out.append(frameToPython(f));
  return out;
}

py::dict infoToPython(const ReaderInfo& info) {
  py::dict d;
  d["format"] = formatName(info.format);
  d["layout"] = info.layout;
  d["camera"] = info.camera;
  d["counters"] = info.counters;
  d["warnings"] = info.warnings;
  if (info.event_count) d["event_count"] = *info.event_count;
  if (info.calibration) d["calibration"] = cameraToPython(*info.calibration);
  return d;
}

std::optional<Format> formatArg(const std::optional<std::string>& name) {
  if (!name) return std::nullopt;
  return parseFormat(*name);
}

SensorSize sensorArg(std::optional<int> width, std::optional<int> height) {
  if (width.has_value() != height.has_value())
    throw Error("give both width and height, or neither");
  if (!width) return {};
  if (*width <= 0 || *height <= 0 || *width > 65536 || *height > 65536)
    throw Error("width and height must be in 1..65536");
  return {*width, *height};
}

FramedEvents readFile(const std::filesystem::path& file, std::optional<int64_t> start,
                      std::optional<int64_t> end, const std::optional<std::string>& format) {
  const std::string path = file.string();
  Recording rec;
  {
    py::gil_scoped_release release;
    rec = asFileError([&] {
      return readRecording(path, formatArg(format), start.value_or(kNoStart), end.value_or(kNoEnd));
    });
  }
  auto store = std::make_shared<EventStore>(std::move(rec.events));
  return FramedEvents(std::move(store), framesToPython(rec.frames), infoToPython(rec.info));
}

// evkit.open(): chunks of a file in bounded memory.
class Stream {
 public:
  Stream(const std::string& path, size_t chunk, std::optional<int64_t> start,
         std::optional<int64_t> end, const std::optional<std::string>& format)
      : path_(path), chunk_(chunk) {
    if (chunk == 0) throw Error("chunk must be at least 1 event");
    reader_ = asFileError([&] { return openReader(path, formatArg(format)); });
    if (start || end) reader_->setTimeWindow(start.value_or(kNoStart), end.value_or(kNoEnd));
  }
  FramedEvents next() {
    if (!reader_ || done_) throw py::stop_iteration();
    Chunk chunk;
    bool more;
    {
      py::gil_scoped_release release;
      more = asFileError([&] { return reader_->next(chunk, chunk_); });
    }
    if (!more) {
      done_ = true;  // the reader stays open for info(), whose counters are complete now
      throw py::stop_iteration();
    }
    if (!chunk.events.sensor().known()) chunk.events.setSensor(reader_->info().sensor);
    auto store = std::make_shared<EventStore>(std::move(chunk.events));
    return FramedEvents(std::move(store), framesToPython(chunk.frames), info());
  }
  py::dict info() const {
    if (!reader_) throw Error(path_ + ": the stream is closed");
    return infoToPython(reader_->info());
  }
  void close() { reader_.reset(); }

 private:
  std::string path_;
  size_t chunk_;
  std::unique_ptr<EventReader> reader_;
  bool done_ = false;
};

void writeFile(const std::filesystem::path& file, py::handle events, py::object frames,
               std::optional<int> width, std::optional<int> height,
               const std::optional<std::string>& format,
               const std::optional<std::string>& compression, int level) {
  const std::string path = file.string();
  const SensorSize given = sensorArg(width, height);
  const auto store = eventsFrom(events, given, "events");
  std::vector<Frame> frame_list;
  if (!frames.is_none()) {
    size_t i = 0;
    for (py::handle f : frames)
      frame_list.push_back(frameFromPython(f, "frame " + std::to_string(i++)));
  }
  SensorSize sensor = store->sensor();
  for (const Frame& f : frame_list) {
    if (!given.known()) {
      sensor.width = std::max(sensor.width, f.image.cols);
      sensor.height = std::max(sensor.height, f.image.rows);
    } else if (f.image.cols != sensor.width || f.image.rows != sensor.height) {
      throw Error("frames: an image of " + std::to_string(f.image.cols) + "x" +
                  std::to_string(f.image.rows) + " on a " + std::to_string(sensor.width) + "x" +
                  std::to_string(sensor.height) + " sensor");
    }
  }
  WriterOptions options;
  if (compression) options.compression = parseCompression(*compression);
  options.level = level;
  py::gil_scoped_release release;
  // writeRecording's steps over the shared store (a Recording would hold a copy of the events).
  asFileError([&] {
    const Format f = format ? parseFormat(*format) : outputFormat(path);
    auto writer = openWriter(path, f, sensor, options);
    writer->write(store->view());
    for (const Frame& frame : frame_list) writer->writeFrame(frame);
    writer->close();
  });
}

py::array stack(const std::vector<cv::Mat>& planes) {
  py::list arrays;
  for (const cv::Mat& m : planes) arrays.append(imageToArray(m));
  return py::module_::import("numpy").attr("stack")(arrays);
}

py::array accumulate(py::handle events, std::optional<int> width, std::optional<int> height,
                     const std::string& repr, double c_on, double c_off,
                     std::optional<int64_t> t_ref, double tau_us, int bins,
                     std::optional<int64_t> t0, std::optional<int64_t> t1) {
  const auto store = eventsFrom(events, sensorArg(width, height), "events");
  const EventSpan view = store->view();
  if (repr == "frame") {
    return imageToArray(
        accumulateSigned(view, static_cast<float>(c_on), static_cast<float>(c_off)));
  }
  if (repr == "counts") {
    const PolarityCounts c = accumulateCounts(view);
    return stack({c.on, c.off});
  }
  if (repr == "normalized") return imageToArray(accumulateNormalized(view));
  if (repr == "timesurface") {
    if (!(tau_us > 0)) throw Error("accumulate: tau_us must be positive");
    const int64_t ref = t_ref.value_or(view.empty() ? 0 : view.t.back());
    const TimeSurface s = timeSurface(view, ref, tau_us);
    return stack({s.on, s.off});
  }
  if (repr == "voxel") {
    if (bins < 1) throw Error("accumulate: bins must be at least 1");
    const int64_t begin = t0.value_or(view.empty() ? 0 : view.t.front());
    const int64_t end = t1.value_or(view.empty() ? 0 : view.t.back());
    if (end < begin) throw Error("accumulate: t1 is before t0");
    return stack(voxelGrid(view, bins, begin, end));
  }
  throw Error("accumulate: repr must be frame, counts, normalized, timesurface or voxel, not '" +
              repr + "'");
}

// evkit.EventSlicer: the C++ slicer, windows handed back as lists (each window's events copied).
struct Window {
  size_t index;
  int64_t t_begin, t_end;
  Events events;
};

class Slicer {
 public:
  explicit Slicer(EventSlicer slicer) : slicer_(std::move(slicer)) {}
  py::list accept(py::handle events) {
    const auto store = eventsFrom(events, {}, "events");
    py::list out;
    slicer_.accept(store->view(), collect(out));
    return out;
  }
  py::list finish() {
    py::list out;
    slicer_.finish(collect(out));
    return out;
  }
  EventSlicer& get() { return slicer_; }

 private:
  EventSlicer::Callback collect(py::list& out) {
    return [&out](const EventSlicer::Window& w) {
      auto copy = std::make_shared<EventStore>(w.events.sensor);
      copy->append(w.events);
      out.append(Window{w.index, w.t_begin, w.t_end, Events(std::move(copy))});
      return true;
    };
  }
  EventSlicer slicer_;
};

Events simulate(py::handle frames, py::handle timestamps_us, double contrast,
                std::optional<double> contrast_off, double sigma, int64_t refractory_us,
                double shot_noise_hz, double leak_hz, uint64_t seed, bool lin_log, double eps,
                bool bayer_rggb) {
  const auto times = py::array_t<int64_t, py::array::c_style | py::array::forcecast>(
      py::module_::import("numpy").attr("asarray")(timestamps_us));
  const size_t n = py::len(frames);
  if (times.ndim() != 1 || static_cast<size_t>(times.size()) != n)
    throw Error("simulate: one timestamp per frame (" + std::to_string(n) + " frames)");
  SimulatorOptions o;
  o.contrast_pos = contrast;
  o.contrast_neg = contrast_off.value_or(contrast);
  o.sigma = sigma;
  o.refractory_us = refractory_us;
  o.shot_noise_rate_hz = shot_noise_hz;
  o.leak_rate_hz = leak_hz;
  o.seed = seed;
  o.log.lin_log = lin_log;
  o.log.eps = eps;
  if (!(o.contrast_pos > 0) || !(o.contrast_neg > 0) || !(sigma >= 0) || refractory_us < 0 ||
      !(shot_noise_hz >= 0) || !(leak_hz >= 0) || !(eps > 0)) {
    throw Error(
        "simulate: contrast and eps must be positive; sigma, refractory_us, shot_noise_hz "
        "and leak_hz not negative");
  }
  auto out = std::make_shared<EventStore>();
  std::optional<EventSimulator> sim;
  size_t i = 0;
  for (py::handle f : frames) {
    const std::string what = "simulate: frame " + std::to_string(i);
    const cv::Mat image = toSensorIntensity(arrayToImage(f, what), bayer_rggb);
    if (!sim) {
      const SensorSize sensor{image.cols, image.rows};
      out->setSensor(sensor);
      sim.emplace(sensor, o);
    } else if (image.cols != out->sensor().width || image.rows != out->sensor().height) {
      throw Error(what + ": its size differs from the first frame's");
    }
    if (i > 0 && times.at(i) <= times.at(i - 1)) throw Error(what + ": timestamps must increase");
    py::gil_scoped_release release;
    sim->addFrame(image, times.at(i), *out);
    ++i;
  }
  return Events(std::move(out));
}

}  // namespace

void bindEvents(py::module_& m) {
  py::class_<Events>(m, "Events", R"(Events in memory, shared with numpy without a copy.

t (int64 µs), x, y (uint16), p (int8, ±1) are read-only column views of the C++ buffers;
`events` is the structured array (t, x, y, p) as tonic lays it out (built once, then cached).)")
      .def_property_readonly("t", &Events::t, "Timestamps, int64 microseconds (a view, no copy).")
      .def_property_readonly("x", &Events::x, "Columns, uint16 pixels (a view, no copy).")
      .def_property_readonly("y", &Events::y, "Rows, uint16 pixels (a view, no copy).")
      .def_property_readonly("p", &Events::p, "Polarity, int8: +1 ON, -1 OFF (a view, no copy).")
      .def_property_readonly("events", &Events::structured,
                             "Structured array with fields t, x, y, p (one copy, cached).")
      .def_property_readonly("width", [](const Events& e) { return e.get().sensor().width; })
      .def_property_readonly("height", [](const Events& e) { return e.get().sensor().height; })
      .def("__len__", [](const Events& e) { return e.get().size(); })
      .def("__repr__", [](py::object self) {
        const EventStore& s = self.cast<const Events&>().get();
        std::string r = "<evkit." + py::type::of(self).attr("__name__").cast<std::string>() + " " +
                        std::to_string(s.size()) + " events, " + std::to_string(s.sensor().width) +
                        "x" + std::to_string(s.sensor().height);
        if (!s.empty())
          r += ", t " + std::to_string(s.t.front()) + ".." + std::to_string(s.t.back()) + " us";
        return r + ">";
      });

  py::class_<FramedEvents, Events>(m, "Recording",
                                   "Events with their frames and what the file says of itself.")
      .def_readonly("frames", &FramedEvents::frames,
                    "The frames (evkit.Frame) whose exposure starts in the events' time span.")
      .def_readonly("info", &FramedEvents::info,
                    "format, layout, camera, counters, warnings[, event_count, calibration].");

  py::class_<PyFrame>(m, "Frame", "An intensity frame with its exposure interval.")
      .def(py::init<py::array, int64_t, int64_t, int>(), py::arg("image"),
           py::arg("exposure_start"), py::arg("exposure_end"), py::arg("bit_depth") = 8)
      .def_readonly("image", &PyFrame::image,
                    "float32, linear [0, 1]; (height, width) or (height, width, 3) in RGB.")
      .def_readonly("exposure_start", &PyFrame::exposure_start, "µs")
      .def_readonly("exposure_end", &PyFrame::exposure_end, "µs")
      .def_readonly("bit_depth", &PyFrame::bit_depth, "8 or 16: the source's depth.")
      .def(
          "__array__", [](const PyFrame& f, py::object) { return f.image; },
          py::arg("dtype") = py::none())
      .def("__repr__", [](const PyFrame& f) {
        return "<evkit.Frame " + py::str(f.image.attr("shape")).cast<std::string>() +
               ", exposure " + std::to_string(f.exposure_start) + ".." +
               std::to_string(f.exposure_end) + " us>";
      });

  m.def("read", &readFile, py::arg("path"), py::arg("start") = py::none(),
        py::arg("end") = py::none(), py::arg("format") = py::none(),
        R"(Reads a whole recording (events and frames) into memory.

The format comes from the extension and the file's first bytes unless `format` names it (text,
hdf5, rpg, aedat2, aedat31, aedat4, evt2, evt3, dat). `start`/`end` (µs) keep events with t in
[start, end). A bad file raises evkit.FileError naming the file, the position and what was
expected.)");

  py::class_<Stream>(m, "Stream", "Chunks of a file in bounded memory (from evkit.open).")
      .def("__iter__", [](py::object self) { return self; })
      .def("__next__", &Stream::next)
      .def("__enter__", [](py::object self) { return self; })
      .def("__exit__", [](Stream& s, py::args) { s.close(); })
      .def("close", &Stream::close, "Closes the file; iteration ends.")
      .def_property_readonly("info", &Stream::info,
                             "What the file says of itself (counters complete at the end).");
  m.def(
      "open",
      [](const std::filesystem::path& path, size_t chunk, std::optional<int64_t> start,
         std::optional<int64_t> end, const std::optional<std::string>& format) {
        return Stream(path.string(), chunk, start, end, format);
      },
      py::arg("path"), py::arg("chunk") = size_t{1} << 20, py::arg("start") = py::none(),
      py::arg("end") = py::none(), py::arg("format") = py::none(),
      R"(Streams a file: `for chunk in evkit.open(path, chunk=2**20)` yields evkit.Recording
objects of at most `chunk` events each (with the frames that fall in them), holding one chunk in
memory at a time. `start`/`end` (µs) restrict to [start, end); formats with an index seek.)");

  m.def("write", &writeFile, py::arg("path"), py::arg("events"), py::arg("frames") = py::none(),
        py::arg("width") = py::none(), py::arg("height") = py::none(),
        py::arg("format") = py::none(), py::arg("compression") = py::none(), py::arg("level") = 1,
        R"(Writes events (and frames) to a file; the format from the extension unless named.

`events`: evkit.Events, a structured array or dict with fields t, x, y, p, or a tuple of the four
columns; t integer µs (float t is refused: it loses precision), p ±1, 0/1 or bool, sorted by t.
`frames`: evkit.Frame objects or (image, exposure_start, exposure_end) tuples. The sensor is
width x height, else the events' own, else their bounding box. Writable: .txt, .h5, .aedat4.
`compression`: none, deflate, blosc-lz4 (HDF5), lz4, zstd (AEDAT 4). The file appears whole or
not at all.)");

  m.def("accumulate", &accumulate, py::arg("events"), py::arg("width") = py::none(),
        py::arg("height") = py::none(), py::arg("repr") = "frame", py::arg("c_on") = 1.0,
        py::arg("c_off") = 1.0, py::arg("t_ref") = py::none(), py::arg("tau_us") = 50'000.0,
        py::arg("bins") = 5, py::arg("t0") = py::none(), py::arg("t1") = py::none(),
        R"(An event representation as float32, of shape (height, width) or (k, height, width).

repr: 'frame' Σ p·C per pixel (C = c_on / c_off); 'counts' (2, H, W) ON and OFF counts;
'normalized' the signed count over its L2 norm (BeNeRF's event image); 'timesurface' (2, H, W)
exp(-(t_ref - t_last) / tau_us) per polarity, t_ref the last event by default; 'voxel' (bins, H, W)
E2VID's bilinear voxel grid over [t0, t1] (the events' span by default).)");

  py::class_<Window>(m, "Window", "One window of an EventSlicer.")
      .def_readonly("index", &Window::index)
      .def_readonly("t_begin", &Window::t_begin, "µs, included")
      .def_readonly("t_end", &Window::t_end, "µs, excluded")
      .def_readonly("events", &Window::events)
      .def("__repr__", [](const Window& w) {
        return "<evkit.Window " + std::to_string(w.index) + ": " +
               std::to_string(w.events.get().size()) + " events in [" + std::to_string(w.t_begin) +
               ", " + std::to_string(w.t_end) + ") us>";
      });
  py::class_<Slicer>(m, "EventSlicer", R"(Cuts a stream into windows by time or by count, in
bounded memory, as dv-processing's EventStreamSlicer: feed chunks in time order with accept(),
which returns the windows they completed; finish() returns the last, partial one.)")
      .def_static(
          "by_time",
          [](int64_t length_us, int width, int height) {
            if (length_us <= 0) throw Error("EventSlicer: length_us must be positive");
            return Slicer(EventSlicer::byTime(length_us, {width, height}));
          },
          py::arg("length_us"), py::arg("width") = 0, py::arg("height") = 0,
          "Windows of length_us, from the first event (or the origin).")
      .def_static(
          "by_count",
          [](size_t count, int width, int height) {
            if (count == 0) throw Error("EventSlicer: count must be positive");
            return Slicer(EventSlicer::byCount(count, {width, height}));
          },
          py::arg("count"), py::arg("width") = 0, py::arg("height") = 0, "Windows of count events.")
      .def(
          "set_origin", [](Slicer& s, int64_t t) { s.get().setOrigin(t); }, py::arg("t_us"),
          "Before the first accept(): where the first window starts.")
      .def(
          "set_end", [](Slicer& s, int64_t t) { s.get().setEnd(t); }, py::arg("t_us"),
          "Before the first accept(): events from t_us on are ignored.")
      .def("accept", &Slicer::accept, py::arg("events"),
           "Feeds the next events; returns the windows they completed.")
      .def("finish", &Slicer::finish, "Returns what is left (the last, partial window).");

  m.def("simulate", &simulate, py::arg("frames"), py::arg("timestamps_us"),
        py::arg("contrast") = 0.2, py::arg("contrast_off") = py::none(), py::arg("sigma") = 0.0,
        py::arg("refractory_us") = 0, py::arg("shot_noise_hz") = 0.0, py::arg("leak_hz") = 0.0,
        py::arg("seed") = 1, py::arg("lin_log") = false, py::arg("eps") = 1e-3,
        py::arg("bayer_rggb") = false,
        R"(Events from video frames (ESIM-like, with v2e's noise): evkit.Events.

frames: a sequence of images (or an array (N, H, W[, 3])), linear intensity in [0, 1] (uint8 and
uint16 are scaled); colour is converted to the sensor's intensity (or an RGGB mosaic).
timestamps_us: one increasing int64 per frame. contrast (C+) and contrast_off (C-, default C+) in
log units; sigma per-pixel mismatch; refractory_us; shot_noise_hz and leak_hz per pixel; seed.)");
}

}  // namespace evkit::python
