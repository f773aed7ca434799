// BeNeRF's budgets and its settings, each declared once in benerfSettings().

#include <cctype>
#include <cmath>

#include "evkit/base/error.h"
#include "evkit/deblur/benerf.h"

namespace evkit {

namespace {

int positiveInt(const std::string& key, const std::string& value, int min, int max) {
  const double v = settingNumber("benerf", key, value);
  if (v != std::floor(v) || v < min || v > max) {
    throw Error("benerf: setting " + key + "=" + value + " must be an integer in [" +
                std::to_string(min) + ", " + std::to_string(max) + "]");
  }
  return static_cast<int>(v);
}

}  // namespace

BenerfOptions benerfBudget(const std::string& name) {
  BenerfOptions o;
  o.blur_rays = 2048;
  o.event_rays = 2048;
  o.samples = 8;
  o.hash.grid.levels = 8;
  if (name == "fast") {
    o.iterations = 1000;
    o.max_views = 32;
    o.converged = 3e-3;
    o.hash.grid.log2_table = 15;
  } else if (name == "balanced") {  // twice fast's steps and table
    o.iterations = 2000;
    o.hash.grid.log2_table = 16;
  } else if (name == "quality") {  // twice balanced's steps and table, every step of the grid
    o.iterations = 4000;
    o.converged = 0;
    o.hash.grid.log2_table = 17;
  } else {
    throw Error("benerf: unknown budget '" + name +
                "' (known: fast, balanced, quality, Ns for seconds, N for iterations)");
  }
  return o;
}

BenerfBudget parseBenerfBudget(const std::string& token) {
  if (token == "fast" || token == "balanced" || token == "quality")
    return {token, benerfBudget(token)};
  size_t used = 0;
  double value = 0;
  try {
    value = std::stod(token, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  const std::string unit = token.substr(used);
  const bool digits = !token.empty() &&
                      (std::isdigit(static_cast<unsigned char>(token[0])) != 0 || token[0] == '.');
  if (digits && used > 0 && value > 0 && std::isfinite(value)) {
    if (unit == "s") {
      BenerfOptions o = benerfBudget("balanced");
      o.budget_seconds = value;
      o.iterations = 1000000;  // the budget sets the count after a few steps
      return {shortNumber(value) + " s", o};
    }
    if (unit.empty() && value == std::floor(value) && value <= 1e7) {
      BenerfOptions o = benerfBudget("fast");
      o.iterations = static_cast<int>(value);
      return {token + " it", o};
    }
  }
  throw Error(
      "benerf: budget '" + token +
      "' is not fast, balanced, quality, seconds (60s) or an iteration count of fast (250)");
}

const SettingsTable<BenerfOptions>& benerfSettings() {
  using O = BenerfOptions;
  using Field = O::FieldKind;
  static const SettingsTable<O> table = [] {
    SettingsTable<O> t("benerf");
    const SettingRange positive{0, INFINITY, true}, unit{0, 1}, unit_open{0, 1, true};
    const auto handled = [](O&, const std::string&) {};  // applied before the table (benerfOptions)
    t.custom({"budget", "fast|balanced|quality|Ns|N",
              "fast, balanced, quality, seconds of wall time (60s) or iterations of fast (250)",
              handled, [](const O&) {}, [](const O&) { return std::string("balanced"); }})
        .custom({"preset", "synthetic|real",
                 "the event term compared directly (synthetic) or normalised (real)", handled,
                 [](const O&) {}, [](const O&) { return std::string("none"); }})
        .choice("field", &O::field,
                {{"hash", Field::kHash}, {"mlp", Field::kMlp}, {"pixels", Field::kPixels}},
                "the fast hash-grid field or the paper's 8 x 256 MLP")
        .integer("iterations", &O::iterations, {1}, "training steps")
        .integer("views", &O::virtual_views, {0},
                 "virtual views of the blur term (0: from the blur length, the pixel grid's "
                 "views_per_px per pixel of it, up to max_views)")
        .number("views_per_px", &O::views_per_px, positive,
                "the pixel grid's views per pixel of blur when they follow the blur length")
        .number("between_views_px", &O::between_views_px, {0},
                "with hysteresis, the pixel grid also samples between views more than this far "
                "apart along the longest image path (px; 0: always)")
        .integer("max_views", &O::max_views, {8},
                 "the pixel grid's most views when they follow the blur length (fast: 32, else 64)")
        .number("converged", &O::converged, {0},
                "the pixel grid stops once its loss fell by less than this fraction over its last "
                "10 steps (fast: 3e-3, balanced: 1e-3, quality: 0, every step)")
        .integer("motion_rounds", &O::motion_rounds, {0, 4},
                 "the pixel grid refines the motion from its solved image and solves again, this "
                 "many times")
        .integer("depth_steps", &O::depth_steps, {0, 4},
                 "the pixel grid refines its inverse depth from the solved image this many times "
                 "before the motion's rounds, each step kept where the loss falls")
        .integer("knots", &O::knots, {0},
                 "trajectory knots (0: the pixel grid's from its registered motion by "
                 "leave-one-out, 4 to 7 from 9 poses, to 15 from 17 for a motion that turns; the "
                 "fields' 4)")
        .choice("trajectory", &O::trajectory,
                {{"cubic", TrajectoryKind::kCubicSE3},
                 {"split", TrajectoryKind::kCubicSplit},
                 {"linear", TrajectoryKind::kLinear}},
                "the trajectory's spline")
        .choice("init", &O::init,
                {{"events", O::Init::kEvents},
                 {"frames", O::Init::kFrames},
                 {"identity", O::Init::kIdentity}},
                "the knots' start: the motion registered between EDI's latent frames, the rotation "
                "found from the events, or identity (the paper)")
        .number("alpha", &O::alpha, unit_open, "event window, a fraction of the exposure")
        .number("beta", &O::beta, {},
                "weight of the event term (< 0: by the event term's form: 0.1 direct, 2 per 1,024 "
                "event pixels normalised; the pixel grid 0.01, at C = 0.2, scaled by (0.2 / C)^2)")
        .choice("normalise", &O::event_form,
                {{"auto", O::EventForm::kAuto},
                 {"1", O::EventForm::kNormalised},
                 {"0", O::EventForm::kDirect}},
                "compare L2-normalised events and log changes (1), or directly with known "
                "thresholds (0)")
        .custom({"contrast", "C[,C_off]", "the thresholds of the event term (over contrast.txt)",
                 [](O& o, const std::string& v) { o.contrast = contrastSetting("benerf", v); },
                 [](const O& o) {
                   if (o.contrast && !(o.contrast->on > 0 && o.contrast->off > 0))
                     throw Error("benerf: contrast must be positive");
                 },
                 [](const O& o) {
                   return o.contrast
                              ? shortNumber(o.contrast->on) + "," + shortNumber(o.contrast->off)
                              : "none";
                 }})
        .flag("estimate_contrast", &O::estimate_contrast,
              "without thresholds, take EDI's searched c when it lies inside its range")
        .flag("contrast_walk", &O::contrast_walk,
              "without thresholds, the pixel grid refines the events' counts' c by short solves "
              "(0: runs at the counts' c, about a quarter less time)")
        .integer("windows", &O::windows, {1},
                 "event windows per step, the event pixels dealt among them")
        .integer("prefit", &O::prefit, {0},
                 "steps fitting the field and knots to EDI's latent frames first")
        .number("dim_frame", &O::dim_frame, unit,
                "mean brightness below which the blur term is weighed up")
        .custom({"rays", "integer", "blur_rays and event_rays at once",
                 [](O& o, const std::string& v) {
                   const double n = settingNumber("benerf", "rays", v);
                   if (n != std::floor(n) || n < 1 || n > 1e9)
                     throw Error("benerf: setting rays=" + v + " must be an integer >= 1");
                   o.blur_rays = o.event_rays = static_cast<int>(n);
                 },
                 [](const O&) {}, [](const O& o) { return std::to_string(o.blur_rays); }})
        .integer("blur_rays", &O::blur_rays, {1},
                 "pixels of the blur term per step, split over the views")
        .integer("event_rays", &O::event_rays, {0},
                 "pixels of the event term per step (two rays each)")
        .integer("samples", &O::samples, {2}, "stratified samples per ray")
        .custom({"levels", "integer", "hash-grid levels",
                 [](O& o, const std::string& v) {
                   o.hash.grid.levels = positiveInt("levels", v, 1, 32);
                 },
                 [](const O&) {}, [](const O& o) { return std::to_string(o.hash.grid.levels); }})
        .custom({"features", "integer", "features per hash-grid level",
                 [](O& o, const std::string& v) {
                   o.hash.grid.features = positiveInt("features", v, 1, 64);
                 },
                 [](const O&) {}, [](const O& o) { return std::to_string(o.hash.grid.features); }})
        .custom({"table", "integer", "log2 of the hash table's entries per level",
                 [](O& o, const std::string& v) {
                   o.hash.grid.log2_table = positiveInt("table", v, 8, 24);
                 },
                 [](const O&) {},
                 [](const O& o) { return std::to_string(o.hash.grid.log2_table); }})
        .integer("resolution", &O::finest_resolution, {0},
                 "the finest grid level's cells (0: the image's larger side)")
        .integer("cells", &O::cells, {1, 4}, "the pixel grid's cells per pixel along each axis")
        .number("mid_robust", &O::mid_robust, {0},
                "the pixel grid's comparison with mid-exposure is pseudo-Huber beyond this many "
                "log units (0: squares)")
        .number("smooth", &O::smooth, {0},
                "the pixel grid's smoothness of the log image between neighbouring cells, per "
                "pixel: the same prior at any cells (0: chosen by held-out events)")
        .number("chroma_smooth", &O::chroma_smooth, {0},
                "the pixel grid's smoothness of the chroma between neighbouring cells (colour)")
        .number("hysteresis", &O::hysteresis, {0, 1},
                "the pixel grid's events against the sensor's reference level, which trails the "
                "log level by this many thresholds (0: the level itself)")
        .flag("precondition", &O::precondition,
              "the pixel grid's L-BFGS scaled cell by cell by its loss's curvature (its "
              "Gauss-Newton diagonal), so that bright and dark cells, and cells few views see, "
              "converge alike")
        .flag("occlusion", &O::occlusion,
              "the pixel grid's views see the nearest surface along their rays, and what a near "
              "surface hides at mid-exposure from a second layer of cells behind it")
        .flag("calibrate", &O::calibrate,
              "without a calibration (no calib.txt), estimate the lens's radial distortion k1 "
              "from the registered motion")
        .number("support_px", &O::support_px, {0},
                "the pixel grid keeps events with a neighbour's within this many pixels of motion "
                "(0: all)")
        .number("depth_scale", &O::depth_scale, {0, 1, true}, "the field sees NDC depth times this")
        .number("coarse_to_fine", &O::coarse_to_fine, unit,
                "fraction of the steps over which the field's bands open")
        .number("field_lr", &O::field_lr, positive,
                "the field's learning rate (the MLP's default: 5e-4)")
        .number("knot_lr", &O::knot_lr, positive, "the knots' learning rate")
        .number("knot_init", &O::knot_init, {0, 1, true},
                "the knots' random start, exp(u) with u uniform in [-knot_init, knot_init]^6")
        .number("lr_final", &O::lr_final, positive, "the fraction both learning rates decay to")
        .integer("seed", &O::seed, {0}, "random seed")
        .custom({"threads", "N|auto",
                 "threads (auto: the cores other programs leave idle, measured at the start and "
                 "followed through the run; 0: OpenMP's default, every core)",
                 [](O& o, const std::string& v) {
                   if (v == "auto") {
                     o.threads = kThreadsFromLoad;
                     return;
                   }
                   try {
                     o.threads = positiveInt("threads", v, 0, 4096);
                   } catch (const Error&) {
                     throw Error("benerf: setting threads=" + v +
                                 " must be an integer in [0, 4096] or auto");
                   }
                 },
                 [](const O&) {},
                 [](const O& o) {
                   return o.threads == kThreadsFromLoad ? std::string("auto")
                                                        : std::to_string(o.threads);
                 }})
        .custom(
            {"checkpoint", "path",
             "write a checkpoint here every checkpoint_every steps and at the end",
             [](O& o, const std::string& v) { o.checkpoint = v; }, [](const O&) {},
             [](const O& o) { return o.checkpoint.empty() ? std::string("none") : o.checkpoint; }})
        .integer("checkpoint_every", &O::checkpoint_every, {1}, "steps between checkpoints")
        .custom({"resume", "path",
                 "continue from this checkpoint (the same observation and settings)",
                 [](O& o, const std::string& v) { o.resume = v; }, [](const O&) {},
                 [](const O& o) { return o.resume.empty() ? std::string("none") : o.resume; }})
        .integer("stop_after", &O::stop_after, {0},
                 "stop (after checkpointing) at this step; 0: never")
        .custom(
            {"lin_log", "0|1", "the log mapping's linear segment near black (as the simulator's)",
             [](O& o, const std::string& v) {
               o.log.lin_log = settingNumber("benerf", "lin_log", v) != 0;
             },
             [](const O&) {}, [](const O& o) { return std::string(o.log.lin_log ? "1" : "0"); }});
    return t;
  }();
  return table;
}

void BenerfOptions::check() const { benerfSettings().check(*this); }

BenerfOptions benerfOptions(const MethodSettings& settings) {
  // The budget first (it sets many keys), then the preset, then every other key over them.
  BenerfOptions o = benerfBudget("balanced");
  if (const auto b = settings.find("budget"); b != settings.end())
    o = parseBenerfBudget(b->second).options;
  if (const auto p = settings.find("preset"); p != settings.end()) {
    if (p->second == "synthetic") {
      o.event_form = BenerfOptions::EventForm::kDirect;
    } else if (p->second == "real") {
      o.event_form = BenerfOptions::EventForm::kNormalised;
    } else {
      throw Error("benerf: unknown preset '" + p->second + "' (known: synthetic, real)");
    }
  }
  MethodSettings rest = settings;
  rest.erase("budget");
  rest.erase("preset");
  benerfSettings().apply(o, rest);
  if (o.field == BenerfOptions::FieldKind::kMlp && !settings.count("field_lr"))
    o.field_lr = 5e-4;  // the paper's rate for its MLP
  o.check();
  return o;
}

std::unique_ptr<Deblurrer> makeBenerf(const MethodSettings& settings) {
  return std::make_unique<BenerfDeblurrer>(benerfOptions(settings));
}

}  // namespace evkit
