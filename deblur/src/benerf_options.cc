// BeNeRF's budgets and its `--set KEY=VALUE` settings.

#include <cctype>
#include <cmath>

#include "evkit/base/error.h"
#include "evkit/deblur/benerf.h"

namespace evkit {

BenerfOptions benerfBudget(const std::string& name) {
  BenerfOptions o;
  if (name == "fast") {
    o.iterations = 1000;
    o.blur_rays = 2048;
    o.event_rays = 2048;
    o.samples = 8;
    o.hash.grid.levels = 8;
    o.hash.grid.log2_table = 15;
  } else if (name == "balanced") {  // twice fast's steps and table (32 samples, 1,024 + 2 x 1,024 rays until session 8)
    o.iterations = 2000;
    o.blur_rays = 2048;
    o.event_rays = 2048;
    o.samples = 8;
    o.hash.grid.levels = 8;
    o.hash.grid.log2_table = 16;
  } else if (name == "quality") {  // twice balanced's steps and table (6,000 iterations, 48 samples, 12 levels until session 9)
    o.iterations = 4000;
    o.blur_rays = 2048;
    o.event_rays = 2048;
    o.samples = 8;
    o.hash.grid.levels = 8;
    o.hash.grid.log2_table = 17;
  } else {
    throw Error("benerf: unknown budget '" + name + "' (known: fast, balanced, quality, or seconds)");
  }
  return o;
}

namespace {

double number(const std::string& key, const std::string& value) { return settingNumber("benerf", key, value); }

int settingInt(const std::string& key, const std::string& value, int min) {
  const double v = number(key, value);
  if (v != std::floor(v) || v < min || v > 1e9) throw Error("benerf: setting " + key + "=" + value + " must be an integer >= " + std::to_string(min));
  return static_cast<int>(v);
}

}  // namespace

std::unique_ptr<Deblurrer> makeBenerf(const MethodSettings& settings) {
  BenerfOptions o = benerfBudget("balanced");
  if (const auto b = settings.find("budget"); b != settings.end()) {
    const std::string& v = b->second;
    if (!v.empty() && (std::isdigit(static_cast<unsigned char>(v[0])) != 0 || v[0] == '.')) {
      o.budget_seconds = number("budget", v);
      if (!(o.budget_seconds > 0)) throw Error("benerf: budget must be fast, balanced, quality or a positive number of seconds");
      o.iterations = 1000000;
    } else {
      o = benerfBudget(v);
    }
  }
  if (const auto p = settings.find("preset"); p != settings.end()) {
    if (p->second == "synthetic") {
      o.event_form = BenerfOptions::EventForm::kDirect;
    } else if (p->second == "real") {
      o.event_form = BenerfOptions::EventForm::kNormalised;
    } else {
      throw Error("benerf: unknown preset '" + p->second + "' (known: synthetic, real)");
    }
  }
  for (const auto& [key, value] : settings) {
    if (key == "budget" || key == "preset") continue;
    if (key == "field") {
      if (value != "hash" && value != "mlp") throw Error("benerf: field must be hash or mlp, not '" + value + "'");
      o.field = value;
    } else if (key == "iterations") {
      o.iterations = settingInt(key, value, 1);
    } else if (key == "views") {
      o.virtual_views = settingInt(key, value, 1);
    } else if (key == "knots") {
      o.knots = settingInt(key, value, 2);
    } else if (key == "trajectory") {
      try {
        o.trajectory = parseTrajectoryKind(value);
      } catch (const Error&) {
        throw Error("benerf: trajectory must be cubic, split or linear, not '" + value + "'");
      }
    } else if (key == "alpha") {
      o.alpha = number(key, value);
      if (!(o.alpha > 0 && o.alpha <= 1)) throw Error("benerf: alpha must lie in (0, 1]");
    } else if (key == "beta") {
      o.beta = number(key, value);
      if (!(o.beta >= 0)) throw Error("benerf: beta must be >= 0");
    } else if (key == "normalise") {
      o.event_form = number(key, value) != 0 ? BenerfOptions::EventForm::kNormalised : BenerfOptions::EventForm::kDirect;
    } else if (key == "windows") {
      o.windows = settingInt(key, value, 1);
    } else if (key == "rays") {
      o.blur_rays = o.event_rays = settingInt(key, value, 1);
    } else if (key == "blur_rays") {
      o.blur_rays = settingInt(key, value, 1);
    } else if (key == "event_rays") {
      o.event_rays = settingInt(key, value, 0);
    } else if (key == "samples") {
      o.samples = settingInt(key, value, 2);
    } else if (key == "contrast") {
      o.contrast = contrastSetting("benerf", value);
    } else if (key == "estimate_contrast") {
      o.estimate_contrast = number(key, value) != 0;
    } else if (key == "levels") {
      o.hash.grid.levels = settingInt(key, value, 1);
    } else if (key == "features") {
      o.hash.grid.features = settingInt(key, value, 1);
    } else if (key == "table") {
      o.hash.grid.log2_table = settingInt(key, value, 8);
      if (o.hash.grid.log2_table > 24) throw Error("benerf: table (log2 entries) must be at most 24");
    } else if (key == "depth_scale") {
      o.depth_scale = number(key, value);
      if (!(o.depth_scale > 0 && o.depth_scale <= 1)) throw Error("benerf: depth_scale must lie in (0, 1]");
    } else if (key == "resolution") {
      o.finest_resolution = settingInt(key, value, 2);
    } else if (key == "dim_frame") {
      o.dim_frame = number(key, value);
      if (!(o.dim_frame >= 0 && o.dim_frame <= 1)) throw Error("benerf: dim_frame must lie in [0, 1] (a mean linear brightness)");
    } else if (key == "prefit") {
      o.prefit = settingInt(key, value, 0);
    } else if (key == "coarse_to_fine") {
      o.coarse_to_fine = number(key, value);
      if (!(o.coarse_to_fine >= 0 && o.coarse_to_fine <= 1)) throw Error("benerf: coarse_to_fine must lie in [0, 1] (the fraction of the iterations over which the field's bands open)");
    } else if (key == "init") {
      if (value == "events") {
        o.init = BenerfOptions::Init::kEvents;
      } else if (value == "identity") {
        o.init = BenerfOptions::Init::kIdentity;
      } else {
        throw Error("benerf: init must be events or identity, not '" + value + "'");
      }
    } else if (key == "field_lr") {
      o.field_lr = number(key, value);
    } else if (key == "knot_lr") {
      o.knot_lr = number(key, value);
    } else if (key == "lr_final") {
      o.lr_final = number(key, value);
      if (!(o.lr_final > 0)) throw Error("benerf: setting lr_final=" + value + " must be positive (the fraction the learning rates decay to)");
    } else if (key == "seed") {
      o.seed = static_cast<uint64_t>(settingInt(key, value, 0));
    } else if (key == "threads") {
      o.threads = settingInt(key, value, 1);
    } else if (key == "checkpoint") {
      o.checkpoint = value;
    } else if (key == "resume") {
      o.resume = value;
    } else if (key == "stop_after") {
      o.stop_after = settingInt(key, value, 1);
    } else if (key == "lin_log") {
      o.log.lin_log = number(key, value) != 0;
    } else {
      throw Error("benerf: unknown setting '" + key +
                  "' (known: budget, preset, field, iterations, views, knots, trajectory, init, alpha, beta, normalise, contrast, estimate_contrast, windows, prefit, dim_frame, rays, blur_rays, event_rays, samples, levels, "
                  "features, table, resolution, depth_scale, coarse_to_fine, field_lr, knot_lr, lr_final, seed, threads, checkpoint, resume, stop_after, lin_log)");
    }
  }
  if (o.field == "mlp" && !settings.count("field_lr")) o.field_lr = 5e-4;  // the paper's rate for its MLP
  return std::make_unique<BenerfDeblurrer>(o);
}

}  // namespace evkit