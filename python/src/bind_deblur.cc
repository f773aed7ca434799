// evkit.Observation, synth, deblur and the method registry.
#include <pybind11/stl.h>
#include <pybind11/stl/filesystem.h>

#include <cstdlib>
#include <filesystem>

#include "arrays.h"
#include "bindings.h"
#include "evkit/deblur/evaluate.h"
#include "evkit/deblur/recording_job.h"
#include "evkit/synth/generator.h"

namespace evkit::python {

namespace fs = std::filesystem;

namespace {

// TUM rows: t (s) tx ty tz qx qy qz qw, T_world_cam.
py::array poseRows(const std::vector<StampedPose>& poses) {
  py::array_t<double> rows({static_cast<py::ssize_t>(poses.size()), py::ssize_t{8}});
  auto r = rows.mutable_unchecked<2>();
  for (size_t i = 0; i < poses.size(); ++i) {
    const auto& q = poses[i].pose.rotation();
    const auto& t = poses[i].pose.translation();
    const double row[8] = {poses[i].t_us * 1e-6, t.x(), t.y(), t.z(), q.x(), q.y(), q.z(), q.w()};
    for (py::ssize_t k = 0; k < 8; ++k) r(static_cast<py::ssize_t>(i), k) = row[k];
  }
  return rows;
}

Contrast contrastFromPython(py::handle c) {
  Contrast out;
  if (py::isinstance<py::sequence>(c) && !py::isinstance<py::str>(c)) {
    if (py::len(c) != 2) throw Error("contrast: a number or (on, off)");
    out = {c[py::int_(0)].cast<double>(), c[py::int_(1)].cast<double>()};
  } else {
    out.on = out.off = c.cast<double>();
  }
  if (!(out.on > 0) || !(out.off > 0)) throw Error("contrast: thresholds must be positive");
  return out;
}

// evkit.Observation: one shared C++ observation (its events are a view, not a copy).
struct PyObservation {
  std::shared_ptr<Observation> obs;

  Events events() const { return Events(std::shared_ptr<const EventStore>(obs, &obs->events)); }
  py::list gtFrames() const {
    py::list out;
    for (const Frame& f : obs->gt_frames) out.append(frameToPython(f));
    return out;
  }
};

PyObservation makeObservation(py::handle blurry, std::pair<int64_t, int64_t> exposure,
                              py::handle events, py::handle calib, py::handle contrast) {
  auto obs = std::make_shared<Observation>();
  obs->blurry.image = arrayToImage(blurry, "blurry", &obs->blurry.bit_depth);
  obs->blurry.exposure_start_us = exposure.first;
  obs->blurry.exposure_end_us = exposure.second;
  if (exposure.second <= exposure.first)
    throw Error("exposure: (start_us, end_us) with end > start");
  const SensorSize sensor{obs->blurry.image.cols, obs->blurry.image.rows};
  obs->events = *eventsFrom(events, sensor, "events");
  obs->camera = calib.is_none() ? synth::defaultCamera(sensor.width, sensor.height)
                                : cameraFromPython(calib).withSize(sensor.width, sensor.height);
  obs->camera_assumed = calib.is_none();
  if (!contrast.is_none()) obs->contrast = contrastFromPython(contrast);
  obs->source = "python";
  return {obs};
}

PyObservation loadFolder(const fs::path& folder) {
  auto obs = std::make_shared<Observation>();
  {
    py::gil_scoped_release release;
    *obs = asFileError([&] { return loadObservation(folder.string()); });
  }
  return {obs};
}

std::string settingText(py::handle v) {
  if (py::isinstance<py::bool_>(v)) return v.cast<bool>() ? "1" : "0";
  if (py::isinstance<py::str>(v)) return v.cast<std::string>();
  if (py::isinstance<py::sequence>(v)) {
    std::string s;
    for (py::handle e : v) s += (s.empty() ? "" : ",") + settingText(e);
    return s;
  }
  return py::str(v).cast<std::string>();
}

// evkit.DeblurResult.
struct PyResult {
  py::array frames, times;
  py::object trajectory, disparity;
  py::dict summary;
};

py::dict summaryOf(const Observation& obs, const Method& method, const MethodReport& r) {
  py::dict s;
  s["method"] = method.name;
  s["observation"] = obs.source;
  s["settings"] = method.settings;
  s["account"] = r.result.account;
  s["parameters"] = r.result.parameters;
  s["wall_time_s"] = r.wall_s;
  s["timings_s"] = r.result.timings_s;
  s["metrics"] = py::dict(py::arg("psnr_mid") = r.psnr_mid, py::arg("ssim_mid") = r.ssim_mid,
                          py::arg("psnr_mean") = r.psnr_mean, py::arg("ssim_mean") = r.ssim_mean,
                          py::arg("brisque_mid") = r.brisque_mid);
  s["training_curve"] = r.result.curve;
  s["training_psnr"] = r.result.curve_psnr;
  return s;
}

PyResult deblur(const PyObservation& o, const std::string& name, py::object times,
                py::object progress, py::kwargs settings) {
  MethodSettings ms;
  for (auto [k, v] : settings) ms[k.cast<std::string>()] = settingText(v);
  const Method method = makeMethod(name, ms);
  const Observation& obs = *o.obs;
  DeblurRequest request;
  if (times.is_none()) {
    request = completeRequest(obs, defaultRequest(obs));
  } else {
    for (py::handle t : times) {
      const auto us = t.cast<int64_t>();
      if (us < obs.blurry.exposure_start_us || us > obs.blurry.exposure_end_us) {
        throw Error("times: " + std::to_string(us) + " us is outside the exposure [" +
                    std::to_string(obs.blurry.exposure_start_us) + ", " +
                    std::to_string(obs.blurry.exposure_end_us) + "]");
      }
      request.times_us.push_back(us);
    }
    if (request.times_us.empty()) throw Error("times: at least one time");
  }
  // Ctrl-C and the caller's callback, checked whenever the method reports progress; either one's
  // exception unwinds the run (its state is all RAII) and reaches Python as raised.
  request.progress = [&progress](int done, int total, double loss) {
    py::gil_scoped_acquire gil;
    if (PyErr_CheckSignals() != 0) throw py::error_already_set();
    if (!progress.is_none()) progress(done, total, loss);
  };
  MethodReport report;
  {
    py::gil_scoped_release release;
    report = evaluateMethod(obs, method, request);
  }
  PyResult r;
  py::list frames;
  std::vector<int64_t> stamps;
  for (const Frame& f : report.result.frames) {
    frames.append(imageToArray(f.image));
    stamps.push_back(f.exposure_start_us);
  }
  r.frames = py::module_::import("numpy").attr("stack")(frames);
  r.times = py::array_t<int64_t>(static_cast<py::ssize_t>(stamps.size()), stamps.data());
  r.trajectory = report.result.trajectory ? py::object(poseRows(*report.result.trajectory))
                                          : py::object(py::none());
  r.disparity = report.result.disparity.empty() ? py::object(py::none())
                                                : py::object(imageToArray(report.result.disparity));
  r.summary = summaryOf(obs, method, report);
  return r;
}

py::dict deblurRecording(const fs::path& recording, const fs::path& out, const std::string& frames,
                         const std::string& method, const std::string& shard, int latent,
                         std::optional<fs::path> calib, std::optional<fs::path> ground_truth,
                         bool filter_hot_pixels, uint64_t seed, bool merge,
                         const std::string& video, double video_fps, py::object progress,
                         py::kwargs settings) {
  RecordingJob job;
  job.recording = recording.string();
  job.frames = frames;
  job.method = method;
  for (auto [k, v] : settings) job.settings[k.cast<std::string>()] = settingText(v);
  if (job.settings.count("seed"))
    throw Error("deblur_recording: frames are seeded by seed= (frame i: seed + i), not a setting");
  job.latent_per_exposure = latent;
  if (calib) job.calib = calib->string();
  if (ground_truth) job.ground_truth = ground_truth->string();
  if (filter_hot_pixels) job.noise_filter = NoiseFilterOptions{};
  job.seed = seed;
  VideoOptions v;
  v.file = video;
  v.fps = video_fps;
  // Between frames: the caller's callback, and Ctrl-C (KeyboardInterrupt) or the callback's own
  // exception stops the job; finished frames stay finished, so a later call resumes.
  const auto report = [&progress](size_t done, size_t total, const FrameOutcome& o) {
    py::gil_scoped_acquire gil;
    if (PyErr_CheckSignals() != 0) throw py::error_already_set();
    if (!progress.is_none()) progress(done, total, o.frame.index, o.ok ? "ok" : o.message);
  };
  JobSummary s;
  {
    py::gil_scoped_release release;
    s = asFileError(
        [&] { return runRecordingJob(job, out.string(), parseShard(shard), v, report, merge); });
  }
  return py::dict(py::arg("chosen") = s.chosen, py::arg("assigned") = s.assigned,
                  py::arg("done") = s.done, py::arg("skipped") = s.skipped,
                  py::arg("failed") = s.failed, py::arg("merged") = s.merged);
}

PyObservation synthesize(const std::string& scene, std::optional<fs::path> out, double blur_px,
                         int width, int height, int64_t exposure_us, double contrast, double sigma,
                         double shot_noise_hz, double leak_hz, uint64_t seed, bool colour,
                         int64_t preroll_us, double rotation_share,
                         std::optional<fs::path> photos) {
  synth::SynthOptions o;
  o.width = width;
  o.height = height;
  o.exposure_us = exposure_us;
  o.shake.blur_px = blur_px;
  o.shake.seed = seed;
  o.shake.rotation_share = rotation_share;
  o.simulator.contrast_pos = o.simulator.contrast_neg = contrast;
  o.simulator.sigma = sigma;
  o.simulator.shot_noise_rate_hz = shot_noise_hz;
  o.simulator.leak_rate_hz = leak_hz;
  o.preroll_us = preroll_us;
  if (width < 8 || height < 8 || !(blur_px > 0) || exposure_us <= 0 || !(contrast > 0) ||
      !(sigma >= 0) || !(shot_noise_hz >= 0) || !(leak_hz >= 0) || preroll_us < 0 ||
      !(rotation_share >= 0 && rotation_share <= 1)) {
    throw Error(
        "synth: width, height >= 8; blur_px, exposure_us, contrast > 0; sigma, "
        "shot_noise_hz, leak_hz, preroll_us >= 0; rotation_share in [0, 1]");
  }
  synth::SceneOptions so;
  so.colour = colour;
  so.seed = seed;
  if (photos) so.photo_dir = photos->string();
  std::string preset = scene;
  for (const synth::SuiteEntry& e : synth::suiteEntries("all")) {
    if (e.name == scene) {
      e.apply(o);
      preset = e.scene;
    }
  }
  // Without `out`: a private folder (mkdtemp), removed whatever happens.
  struct TemporaryFolder {
    std::string path;
    ~TemporaryFolder() {
      std::error_code ec;
      if (!path.empty()) fs::remove_all(path, ec);
    }
  } scratch;
  std::string dir;
  if (out) {
    dir = out->string();
  } else {
    std::string pattern = (fs::temp_directory_path() / "evkit-synth-XXXXXX").string();
    if (!mkdtemp(pattern.data())) throw FileError(pattern + ": cannot create a temporary folder");
    scratch.path = pattern;
    dir = pattern + "/observation";
  }
  auto obs = std::make_shared<Observation>();
  {
    py::gil_scoped_release release;
    const synth::Scene s = synth::makePreset(preset, so);
    asFileError([&] {
      synth::writeObservation(s, o, dir);
      *obs = loadObservation(dir);
    });
  }
  if (!out) obs->source = "synth:" + scene;
  return {obs};
}

}  // namespace

py::dict cameraToPython(const Calibration& c) {
  return py::dict(py::arg("fx") = c.fx, py::arg("fy") = c.fy, py::arg("cx") = c.cx,
                  py::arg("cy") = c.cy, py::arg("distortion") = c.distortion,
                  py::arg("width") = c.width, py::arg("height") = c.height);
}

Calibration cameraFromPython(py::handle camera) {
  Calibration c;
  if (py::isinstance<py::dict>(camera)) {
    auto d = camera.cast<py::dict>();
    for (const char* k : {"fx", "fy", "cx", "cy"}) {
      if (!d.contains(k)) throw Error(std::string("calib: no ") + k);
    }
    c.fx = d["fx"].cast<double>();
    c.fy = d["fy"].cast<double>();
    c.cx = d["cx"].cast<double>();
    c.cy = d["cy"].cast<double>();
    if (d.contains("distortion")) c.distortion = d["distortion"].cast<std::vector<double>>();
  } else {
    const auto v = camera.cast<std::vector<double>>();
    if (v.size() != 4 && v.size() != 8 && v.size() != 9)
      throw Error("calib: fx, fy, cx, cy[, k1, k2, p1, p2[, k3]]");
    c.fx = v[0], c.fy = v[1], c.cx = v[2], c.cy = v[3];
    c.distortion.assign(v.begin() + 4, v.end());
  }
  if (!(c.fx > 0) || !(c.fy > 0)) throw Error("calib: fx and fy must be positive");
  if (!c.distortion.empty() && c.distortion.size() != 4 && c.distortion.size() != 5)
    throw Error("calib: distortion is k1, k2, p1, p2[, k3]");
  return c;
}

void bindDeblur(py::module_& m) {
  py::class_<PyObservation>(m, "Observation", R"(One blurry frame, its exposure, the events and
the camera: the input of every deblurring method (an observation folder, DESIGN.md §6), with
the ground truth when there is some.)")
      .def(py::init(&makeObservation), py::arg("blurry"), py::arg("exposure"), py::arg("events"),
           py::arg("calib") = py::none(), py::arg("contrast") = py::none(),
           R"(From arrays: blurry (H, W) or (H, W, 3) RGB, float linear [0, 1] or uint8/uint16;
exposure (start_us, end_us); events as evkit.write takes them (inside the image); calib a dict
{fx, fy, cx, cy[, distortion]} or (fx, fy, cx, cy[, k1, k2, p1, p2[, k3]]), else assumed (fx =
fy = 0.9 width at the centre; BeNeRF then estimates the lens's k1); contrast C or (C_on, C_off)
when known.)")
      .def_static("load", &loadFolder, py::arg("folder"),
                  "Reads an observation folder (blurry.png, exposure.txt, events, optional "
                  "calib.txt and contrast.txt, gt/).")
      .def(
          "save",
          [](const PyObservation& o, const fs::path& folder) {
            py::gil_scoped_release release;
            asFileError([&] { saveObservation(*o.obs, folder.string()); });
          },
          py::arg("folder"), "Writes it as an observation folder (atomically).")
      .def_property_readonly(
          "blurry",
          [](const PyObservation& o) {
            py::array a = imageToArray(o.obs->blurry.image);  // grey: a view of the observation's
            a.attr("setflags")(py::arg("write") = false);
            return a;
          },
          "The blurry frame, float32 linear [0, 1] (RGB for colour); read-only")
      .def_property_readonly(
          "exposure",
          [](const PyObservation& o) {
            return std::make_pair(o.obs->blurry.exposure_start_us, o.obs->blurry.exposure_end_us);
          },
          "(start_us, end_us)")
      .def_property_readonly("events", &PyObservation::events, "evkit.Events (a view, no copy)")
      .def_property_readonly(
          "calib", [](const PyObservation& o) { return cameraToPython(o.obs->camera); },
          "The camera: {fx, fy, cx, cy, distortion, width, height}")
      .def_property_readonly(
          "camera_assumed", [](const PyObservation& o) { return o.obs->camera_assumed; },
          "True where no calibration was given (calib is then the assumed camera)")
      .def_property_readonly(
          "contrast",
          [](const PyObservation& o) -> py::object {
            if (!o.obs->contrast) return py::none();
            return py::make_tuple(o.obs->contrast->on, o.obs->contrast->off);
          },
          "(C_on, C_off) when known, else None")
      .def_property_readonly("gt_frames", &PyObservation::gtFrames,
                             "Ground-truth sharp frames (evkit.Frame, exposure_start = their time)")
      .def_property_readonly(
          "gt_poses",
          [](const PyObservation& o) -> py::object {
            if (o.obs->gt_poses.empty()) return py::none();
            return poseRows(o.obs->gt_poses);
          },
          "Ground-truth trajectory, N x 8 TUM rows (t s, tx ty tz, qx qy qz qw), or None")
      .def_property_readonly("width",
                             [](const PyObservation& o) { return o.obs->blurry.image.cols; })
      .def_property_readonly("height",
                             [](const PyObservation& o) { return o.obs->blurry.image.rows; })
      .def_property_readonly("source", [](const PyObservation& o) { return o.obs->source; })
      .def("__repr__", [](const PyObservation& o) {
        return "<evkit.Observation " + std::to_string(o.obs->blurry.image.cols) + "x" +
               std::to_string(o.obs->blurry.image.rows) + ", " +
               std::to_string(o.obs->events.size()) + " events, " +
               std::to_string(o.obs->gt_frames.size()) + " ground-truth frames, from " +
               o.obs->source + ">";
      });

  py::class_<PyResult>(m, "DeblurResult", "What evkit.deblur returns.")
      .def_readonly("frames", &PyResult::frames,
                    "float32 (N, H, W) or (N, H, W, 3) RGB, linear [0, 1]: one per time")
      .def_readonly("times", &PyResult::times, "int64 µs, one per frame")
      .def_readonly("trajectory", &PyResult::trajectory,
                    "N x 8 TUM rows (t s, tx ty tz, qx qy qz qw; T_world_cam) or None")
      .def_readonly("disparity", &PyResult::disparity,
                    "float32 (H, W) 1/depth at mid-exposure (arbitrary scale) or None")
      .def_readonly("summary", &PyResult::summary,
                    "As summary.json: method, settings, account (what the method did, in words), "
                    "parameters, wall_time_s, timings_s, "
                    "metrics (PSNR/SSIM against ground truth, BRISQUE), training curves");

  m.def("deblur", &deblur, py::arg("observation"), py::arg("method") = "edi",
        py::arg("times") = py::none(), py::arg("progress") = py::none(),
        R"(Deblurs an observation: evkit.DeblurResult.

method: 'edi', 'benerf' or 'blurry' (evkit.methods()); the other keyword arguments are the
method's settings (evkit.method_help(method)), e.g. budget='fast', contrast=0.2, seed=1.
times: µs inside the exposure; default five over the exposure, the middle and the ground truth's
times. progress(done, total, loss) is called as an iterative method goes (tqdm fits); Ctrl-C
stops a run at its next report with KeyboardInterrupt. The GIL is released while it works.)");
  m.def("deblur_recording", &deblurRecording, py::arg("recording"), py::arg("out"),
        py::arg("frames") = "all", py::arg("method") = "edi", py::arg("shard") = "0/1",
        py::arg("latent") = 10, py::arg("calib") = py::none(), py::arg("ground_truth") = py::none(),
        py::arg("filter_hot_pixels") = false, py::arg("seed") = 1, py::arg("merge") = true,
        py::arg("video") = "latent.avi", py::arg("video_fps") = 30.0,
        py::arg("progress") = py::none(),
        R"(Deblurs every chosen frame of a recording into `out`, as `evkit deblur --recording`.

frames: 'all', 'A:B' or 'A,B,C'. shard: 'I/N', this worker's share. Each frame's outputs go to
out/frames/<index>/, its row to out/frames.csv; with merge, the last worker also writes the latent
video (latent frames per exposure, video file and fps). Finished frames are never redone, so a
second call resumes. progress(done, total, frame_index, status) after each frame. The other
keyword arguments are the method's settings. Returns {chosen, assigned, done, skipped, failed,
merged}; a frame's failure is in frames.csv and the count, not an exception.)");
  m.def("methods", &deblurrerNames, "The deblurring methods' names.");
  m.def("method_help", &deblurrerHelp, py::arg("method"),
        "Each setting of a method with its type, default and help, one per line.");

  m.def("synth", &synthesize, py::arg("scene") = "planes", py::arg("out") = py::none(),
        py::arg("blur_px") = 30.0, py::arg("width") = 346, py::arg("height") = 260,
        py::arg("exposure_us") = 100'000, py::arg("contrast") = 0.2, py::arg("sigma") = 0.0,
        py::arg("shot_noise_hz") = 0.0, py::arg("leak_hz") = 0.0, py::arg("seed") = 1,
        py::arg("colour") = false, py::arg("preroll_us") = 0, py::arg("rotation_share") = 0.7,
        py::arg("photos") = py::none(),
        R"(A synthetic observation with ground truth: a scene seen through a random camera shake,
its blurry frame and its events (evkit.Observation).

scene: a preset or natural scene (evkit.scenes()), or a suite entry's name such as
'planes_blur40' or 'nat_cat_bricks_blur30_noisy' (its blur, noise, shake and pre-roll apply).
out: keep the observation folder there (default: a temporary folder, removed).)");
  m.def(
      "scenes",
      [] {
        auto names = synth::presetNames();
        for (const auto& n : synth::naturalSceneNames()) names.push_back(n);
        return names;
      },
      "The scenes evkit.synth knows (presets, then natural scenes).");
  m.def(
      "suite",
      [](const std::string& name) {
        std::vector<std::string> names;
        for (const auto& e : synth::suiteEntries(name)) names.push_back(e.name);
        return names;
      },
      py::arg("name"), "The entries of a suite (standard, noisy, hard, natural, all).");
}

}  // namespace evkit::python
