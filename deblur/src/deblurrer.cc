#include "evkit/deblur/deblurrer.h"

#include <algorithm>
#include <cmath>

#include "evkit/base/error.h"

namespace evkit {

Contrast contrastSetting(const std::string& method, const std::string& value) {
  const size_t comma = value.find(',');
  const double on = settingNumber(method, "contrast", value.substr(0, comma));
  const double off =
      comma == std::string::npos ? on : settingNumber(method, "contrast", value.substr(comma + 1));
  if (!(on > 0) || !(off > 0))
    throw Error(method + ": contrast must be positive (contrast=C or C_on,C_off)");
  return {on, off};
}

std::optional<Contrast> resolveContrast(const std::optional<Contrast>& setting,
                                        const Observation& obs, bool use_observation) {
  if (setting) return setting;
  if (use_observation) return obs.contrast;
  return std::nullopt;
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
