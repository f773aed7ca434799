#include "evkit/deblur/deblurrer.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <tuple>

#include "evkit/deblur/benerf.h"
#include "evkit/deblur/edi.h"
#include "evkit/base/error.h"

namespace evkit {

namespace {

// The reference point of every comparison: the blurry frame itself, at every requested time.
class BlurryDeblurrer final : public Deblurrer {
 public:
  std::string name() const override { return "blurry"; }
  DeblurResult run(const Observation& obs, const DeblurRequest& request) override {
    const auto start = std::chrono::steady_clock::now();
    DeblurResult result;
    for (int64_t t : request.times_us) {
      Frame f = obs.blurry;
      f.image = obs.blurry.image.clone();
      f.exposure_start_us = f.exposure_end_us = t;
      result.frames.push_back(std::move(f));
    }
    result.timings_s["total"] = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    return result;
  }
};

std::unique_ptr<Deblurrer> makeEdi(const MethodSettings& settings) {
  EdiOptions o;
  for (const auto& [key, value] : settings) {
    if (key == "contrast") {
      std::tie(o.contrast_on, o.contrast_off) = contrastSetting("edi", value);
    } else if (key == "search") {
      o.use_observation_contrast = settingNumber("edi", key, value) == 0;
    } else if (key == "c_min") {
      o.search_min = settingNumber("edi", key, value);
    } else if (key == "c_max") {
      o.search_max = settingNumber("edi", key, value);
    } else if (key == "margin_us") {
      o.margin_us = static_cast<int64_t>(settingNumber("edi", key, value));
    } else {
      throw Error("edi: unknown setting '" + key + "' (known: contrast=C[,C_off], search=1, c_min, c_max, margin_us)");
    }
  }
  if (!(o.search_min > 0) || !(o.search_max > o.search_min)) throw Error("edi: need 0 < c_min < c_max");
  return std::make_unique<EdiDeblurrer>(o);
}

}  // namespace

double settingNumber(const std::string& method, const std::string& key, const std::string& value) {
  try {
    size_t used = 0;
    const double v = std::stod(value, &used);
    if (used == value.size() && std::isfinite(v)) return v;
  } catch (const std::exception&) {
  }
  throw Error(method + ": setting " + key + "=" + value + " is not a number");
}

std::pair<double, double> contrastSetting(const std::string& method, const std::string& value) {
  const size_t comma = value.find(',');
  const double on = settingNumber(method, "contrast", value.substr(0, comma));
  const double off = comma == std::string::npos ? on : settingNumber(method, "contrast", value.substr(comma + 1));
  if (!(on > 0) || !(off > 0)) throw Error(method + ": contrast must be positive (contrast=C or C_on,C_off)");
  return {on, off};
}

std::vector<std::string> deblurrerNames() { return {"blurry", "edi", "benerf"}; }

std::unique_ptr<Deblurrer> makeDeblurrer(const std::string& name, const MethodSettings& settings) {
  if (name == "blurry") {
    if (!settings.empty()) throw Error("blurry: takes no settings");
    return std::make_unique<BlurryDeblurrer>();
  }
  if (name == "edi") return makeEdi(settings);
  if (name == "benerf") return makeBenerf(settings);
  std::string known;
  for (const std::string& n : deblurrerNames()) known += (known.empty() ? "" : ", ") + n;
  throw Error("unknown method '" + name + "' (known: " + known + ")");
}

DeblurRequest defaultRequest(const Observation& obs, int n) {
  DeblurRequest r;
  const int64_t t0 = obs.blurry.exposure_start_us, t1 = obs.blurry.exposure_end_us;
  for (int k = 0; k < n; ++k) r.times_us.push_back(t0 + (t1 - t0) * k / std::max(1, n - 1));
  const int64_t mid = t0 + (t1 - t0) / 2;
  if (std::find(r.times_us.begin(), r.times_us.end(), mid) == r.times_us.end()) {
    r.times_us.push_back(mid);
    std::sort(r.times_us.begin(), r.times_us.end());
  }
  return r;
}

}  // namespace evkit
