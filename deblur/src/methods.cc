// The registry of deblurring methods: each method's file owns its factory and its settings; this
// file only names them, so that the interface (deblurrer.h) depends on no method.

#include <chrono>

#include "evkit/base/error.h"
#include "evkit/base/text.h"
#include "evkit/deblur/benerf.h"
#include "evkit/deblur/deblurrer.h"
#include "evkit/deblur/edi.h"

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
    result.timings_s["total"] =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    return result;
  }
};

std::unique_ptr<Deblurrer> makeBlurry(const MethodSettings& settings) {
  if (!settings.empty()) throw Error("blurry: takes no settings");
  return std::make_unique<BlurryDeblurrer>();
}

struct RegisteredMethod {
  const char* name;
  std::unique_ptr<Deblurrer> (*make)(const MethodSettings&);
  std::string (*help)();
};

std::string noSettings() { return "  (none)\n"; }
std::string ediHelp() { return ediSettings().help(EdiOptions{}); }
std::string benerfHelp() { return benerfSettings().help(BenerfOptions{}); }

const RegisteredMethod kMethods[] = {
    {"blurry", makeBlurry, noSettings},
    {"edi", makeEdi, ediHelp},
    {"benerf", makeBenerf, benerfHelp},
};

}  // namespace

std::vector<std::string> deblurrerNames() {
  std::vector<std::string> names;
  for (const RegisteredMethod& m : kMethods) names.push_back(m.name);
  return names;
}

std::unique_ptr<Deblurrer> makeDeblurrer(const std::string& name, const MethodSettings& settings) {
  for (const RegisteredMethod& m : kMethods) {
    if (name == m.name) return m.make(settings);
  }
  throw Error("unknown method '" + name + "' (known: " + joinNames(deblurrerNames()) + ")");
}

std::string deblurrerHelp(const std::string& name) {
  for (const RegisteredMethod& m : kMethods) {
    if (name == m.name) return m.help();
  }
  throw Error("unknown method '" + name + "'");
}

}  // namespace evkit
