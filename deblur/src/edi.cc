#include "evkit/deblur/edi.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <opencv2/imgproc.hpp>
#include <tuple>

#include "evkit/base/error.h"
#include "evkit/deblur/metrics.h"

namespace evkit {

namespace {

constexpr double kMaxExponent = 600.0;  // exp() stays finite in double

double seconds(std::chrono::steady_clock::time_point since) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - since).count();
}

cv::Mat gradientMagnitude(const cv::Mat& img) {
  cv::Mat gx, gy, mag;
  cv::Sobel(img, gx, CV_32F, 1, 0, 3);
  cv::Sobel(img, gy, CV_32F, 0, 1, 3);
  cv::magnitude(gx, gy, mag);
  return mag;
}

}  // namespace

EdiModel::EdiModel(const EventSpan& all, int width, int height, int64_t t_begin_us,
                   int64_t t_end_us)
    : width_(width), height_(height), t_begin_(t_begin_us), t_end_(t_end_us) {
  if (t_end_us <= t_begin_us) throw Error("EDI: the exposure must have a positive duration");
  // The events by pixel and nothing more: the levels each pixel held are read from its events in
  // latent(). A table of them (16 bytes a level) took 0.15 s to fill for 3.4 million events
  // (nat_motorcycle_blur60_noisy), the index 0.035 s, and a BeNeRF run without thresholds builds
  // the model thirteen times (BENCHMARKS.md, "EDI").
  events_ = PixelEventIndex(all.sliceTime(t_begin_us, t_end_us + 1), width, height);
  const size_t pixels = static_cast<size_t>(width) * static_cast<size_t>(height);
  for (size_t p = 0; p < pixels; ++p)
    max_events_per_pixel_ = std::max(max_events_per_pixel_, static_cast<int>(events_.count(p)));
}

cv::Mat EdiModel::latent(const cv::Mat& blurry, int64_t t_us, double c_on, double c_off,
                         const EdiOptions& options) const {
  CV_Assert(blurry.rows == height_ && blurry.cols == width_ && blurry.depth() == CV_32F);
  const cv::Mat grey = toGrey(blurry);
  const int channels = blurry.channels();
  cv::Mat out(blurry.size(), blurry.type());
  const double T = static_cast<double>(t_end_ - t_begin_);
  // Levels are integers: exp(c_on (on - on_f)) and exp(-c_off (off - off_f)) come from two tables
  // indexed by the count difference, instead of one exp() per segment.
  const int K = max_events_per_pixel_;
  std::vector<double> up(static_cast<size_t>(2 * K + 1)), down(static_cast<size_t>(2 * K + 1));
  for (int k = -K; k <= K; ++k) {
    up[static_cast<size_t>(k + K)] = std::exp(std::clamp(c_on * k, -kMaxExponent, kMaxExponent));
    down[static_cast<size_t>(k + K)] =
        std::exp(std::clamp(-c_off * k, -kMaxExponent, kMaxExponent));
  }
#pragma omp parallel for schedule(static)
  for (int y = 0; y < height_; ++y) {
    const float* b = blurry.ptr<float>(y);
    const float* g = grey.ptr<float>(y);
    float* o = out.ptr<float>(y);
    for (int x = 0; x < width_; ++x) {
      const size_t p =
          static_cast<size_t>(y) * static_cast<size_t>(width_) + static_cast<size_t>(x);
      double gain = 1.0;
      bool masked = g[x] <= options.black;
      for (int c = 0; c < channels; ++c) masked |= b[x * channels + c] >= options.saturated;
      const bool deblurred = !masked && events_.count(p) > 0;
      if (deblurred && options.levels == EdiOptions::Levels::kLinear) {
        gain = linearGain(p, t_us, c_on, c_off);
      } else if (deblurred) {
        // Level at t: the events of this pixel up to t.
        int32_t on_f = 0, off_f = 0;
        for (uint32_t e = events_.begin(p); e < events_.end(p) && events_.t()[e] <= t_us; ++e) {
          (events_.polarity()[e] > 0 ? on_f : off_f) += 1;
        }
        // (1/T) integral exp(c E(t) - c E(f)) dt over the levels the pixel held for a positive
        // time, each the counts of its events before it.
        double integral = 0.0;
        const auto held = [&](int32_t on, int32_t off, int64_t duration) {
          integral += static_cast<double>(duration) * up[static_cast<size_t>(on - on_f + K)] *
                      down[static_cast<size_t>(off - off_f + K)];
        };
        int32_t on = 0, off = 0;
        int64_t prev = t_begin_;
        for (uint32_t e = events_.begin(p); e < events_.end(p); ++e) {
          const int64_t t_e = events_.t()[e];
          if (t_e > prev) held(on, off, t_e - prev);
          prev = std::max(prev, t_e);
          on += events_.polarity()[e] > 0;
          off += events_.polarity()[e] <= 0;
        }
        if (t_end_ > prev) held(on, off, t_end_ - prev);
        integral /= T;
        if (integral > 0 && std::isfinite(integral)) gain = 1.0 / integral;
      }
      for (int c = 0; c < channels; ++c) {
        o[x * channels + c] = static_cast<float>(std::clamp(b[x * channels + c] * gain, 0.0, 1.0));
      }
    }
  }
  return out;
}

// The knots of a pixel's log level with EdiOptions::Levels::kLinear, relative to its level at the
// window's start as the steps count it. At each event the log intensity has just crossed the
// sensor's next level, so the level there is exact; between two events of one sign it rose (or
// fell) from one to the next, taken as straight; between events of opposite signs it turned
// somewhere unseen, so it holds until the second. Before the first event and after the last, the
// log intensity lies within a threshold of that event's level, on the side it came from and on
// the side it went to: with the sensor's reference at an unknown phase (a real sensor has been
// firing before the exposure), half a threshold is its expected offset, reached at the pace of
// the two events beside it where they agree in sign, else at once.
void EdiModel::linearKnots(size_t p, double c_on, double c_off,
                           std::vector<std::pair<double, double>>& knots) const {
  const std::vector<int64_t>& ev_t = events_.t();
  const std::vector<int8_t>& ev_p = events_.polarity();
  const uint32_t first = events_.begin(p), last = events_.end(p);
  const auto step = [&](uint32_t e) { return ev_p[e] > 0 ? c_on : -c_off; };
  const auto time = [&](uint32_t e) { return static_cast<double>(ev_t[e]); };
  // The half interval beside the run's end event `e` (the neighbour `n`), 0 where none.
  const auto halfPace = [&](uint32_t e, uint32_t n) {
    return (step(e) > 0) == (step(n) > 0) ? 0.5 * std::abs(time(e) - time(n)) : 0.0;
  };
  knots.clear();
  knots.emplace_back(time(first) - (last - first >= 2 ? halfPace(first, first + 1) : 0.0),
                     0.5 * step(first));
  double level = 0;
  for (uint32_t e = first; e < last; ++e) {
    if (e > first && (step(e) > 0) != (step(e - 1) > 0)) knots.emplace_back(time(e), level);
    level += step(e);
    knots.emplace_back(time(e), level);
  }
  knots.emplace_back(time(last - 1) + (last - first >= 2 ? halfPace(last - 1, last - 2) : 0.0),
                     level + 0.5 * step(last - 1));
}

double EdiModel::linearGain(size_t p, int64_t t_us, double c_on, double c_off) const {
  thread_local std::vector<std::pair<double, double>> knots;
  linearKnots(p, c_on, c_off, knots);
  // The level at t: straight between knots, constant beyond them; at a jump, the level after it
  // (the events at t count, as with the steps).
  const double t = static_cast<double>(t_us);
  size_t k = 0;
  while (k + 1 < knots.size() && knots[k + 1].first <= t) ++k;
  double level_t = knots[k].second;
  if (k + 1 < knots.size() && knots[k].first <= t) {
    const auto& [ta, la] = knots[k];
    const auto& [tb, lb] = knots[k + 1];
    level_t = la + (lb - la) * (t - ta) / (tb - ta);  // tb > t >= ta
  }
  // (1/T) integral over the window of exp(l(s) - l(t)): exact on each straight piece.
  const double begin = static_cast<double>(t_begin_), end = static_cast<double>(t_end_);
  const auto relative = [&](double l) {
    return std::exp(std::clamp(l - level_t, -kMaxExponent, kMaxExponent));
  };
  double integral = 0, from_t = begin, from_level = knots.front().second;
  for (const auto& [to_t, to_level] : knots) {
    const double a = std::clamp(from_t, begin, end), b = std::clamp(to_t, begin, end);
    if (b > a) {
      const double slope = (to_level - from_level) / (to_t - from_t);
      const double la = from_level + slope * (a - from_t), d = slope * (b - a);
      integral += (b - a) * relative(la) * (std::abs(d) > 1e-9 ? std::expm1(d) / d : 1.0);
    }
    from_t = to_t;
    from_level = to_level;
  }
  if (end > std::max(from_t, begin))
    integral += (end - std::max(from_t, begin)) * relative(from_level);
  integral /= end - begin;
  return integral > 0 && std::isfinite(integral) ? 1.0 / integral : 1.0;
}

// Energy of the latent frame at t: the normalised sparsity ||grad L||_1 / ||grad L||_2 of its
// gradient magnitude (Krishnan, Tay, Fergus, CVPR 2011). Too small a c leaves edges spread over the
// blur (many small gradients), too large a c adds ghost edges; sharp edges are few large gradients.
// Measured on the synthetic suite (C = 0.2): the total variation alone falls monotonically towards
// small c, and the correlation with the event edges is nearly flat; this ratio peaks at C.
double EdiModel::sparsityEnergy(const cv::Mat& blurry_grey, int64_t t_us, double c, double ratio,
                                const EdiOptions& options) const {
  const cv::Mat g = gradientMagnitude(latent(blurry_grey, t_us, c, c * ratio, options));
  cv::Mat g2;
  cv::multiply(g, g, g2);
  const double l2 = std::sqrt(cv::mean(g2)[0]);
  return l2 > 0 ? cv::mean(g)[0] / l2 : 1.0;
}

double EdiModel::searchContrast(const cv::Mat& blurry_grey, int64_t t_us, double ratio,
                                const EdiOptions& options) const {
  const int n = std::max(3, options.search_grid);
  const double lo = options.search_min, hi = options.search_max;
  std::vector<double> grid(static_cast<size_t>(n)), value(static_cast<size_t>(n));
  const auto f = [&](double c) { return sparsityEnergy(blurry_grey, t_us, c, ratio, options); };
  size_t best = 0;
  for (size_t i = 0; i < grid.size(); ++i) {
    grid[i] = lo + (hi - lo) * static_cast<double>(i) / (n - 1);
    value[i] = f(grid[i]);
    if (value[i] < value[best]) best = i;
  }
  // Golden-section search in the bracket around the best grid point.
  double a = grid[best > 0 ? best - 1 : 0], b = grid[std::min(best + 1, grid.size() - 1)];
  const double phi = (std::sqrt(5.0) - 1) / 2;
  double x1 = b - phi * (b - a), x2 = a + phi * (b - a), f1 = f(x1), f2 = f(x2);
  for (int it = 0; it < 12; ++it) {
    if (f1 < f2) {
      b = x2;
      x2 = x1;
      f2 = f1;
      x1 = b - phi * (b - a);
      f1 = f(x1);
    } else {
      a = x1;
      x1 = x2;
      f1 = f2;
      x2 = a + phi * (b - a);
      f2 = f(x2);
    }
  }
  const double refined = 0.5 * (a + b);
  return f(refined) <= value[best] ? refined : grid[best];
}

DeblurResult EdiDeblurrer::run(const Observation& obs, const DeblurRequest& request) {
  const auto start = std::chrono::steady_clock::now();
  DeblurResult result;
  const int64_t t0 = obs.blurry.exposure_start_us - options_.margin_us,
                t1 = obs.blurry.exposure_end_us + options_.margin_us;
  const EdiModel model(obs.events.view(), obs.blurry.image.cols, obs.blurry.image.rows, t0, t1);
  result.timings_s["model"] = seconds(start);
  double c_on, c_off;
  bool searched = false;
  if (const auto given =
          resolveContrast(options_.contrast, obs, options_.use_observation_contrast)) {
    c_on = given->on;
    c_off = given->off;
  } else {
    const auto s = std::chrono::steady_clock::now();
    const cv::Mat grey = toGrey(obs.blurry.image);
    c_on = c_off = model.searchContrast(grey, t0 + (t1 - t0) / 2, 1.0, options_);
    result.timings_s["search"] = seconds(s);
    searched = true;
  }
  const auto s = std::chrono::steady_clock::now();
  for (int64_t t : request.times_us) {
    Frame f;
    f.image = model.latent(obs.blurry.image, t, c_on, c_off, options_);
    f.exposure_start_us = f.exposure_end_us = t;
    f.bit_depth = obs.blurry.bit_depth;
    result.frames.push_back(std::move(f));
  }
  result.timings_s["latent_per_frame"] =
      request.times_us.empty() ? 0.0 : seconds(s) / static_cast<double>(request.times_us.size());
  result.timings_s["total"] = seconds(start);
  result.parameters["contrast_on"] = c_on;
  result.parameters["contrast_off"] = c_off;
  result.parameters["contrast_searched"] = searched ? 1.0 : 0.0;
  result.parameters["events"] = static_cast<double>(obs.events.sliceTime(t0, t1 + 1).size());
  char account[96];
  if (searched)
    std::snprintf(account, sizeof account, "thresholds %.3f by the sharpness search", c_on);
  else
    std::snprintf(account, sizeof account, "thresholds given, %.3f / %.3f", c_on, c_off);
  result.account = account;
  return result;
}

const SettingsTable<EdiOptions>& ediSettings() {
  using O = EdiOptions;
  static const SettingsTable<O> table = [] {
    SettingsTable<O> t("edi");
    t.custom({"contrast", "C[,C_off]", "fixed thresholds (over contrast.txt and the search)",
              [](O& o, const std::string& v) { o.contrast = contrastSetting("edi", v); },
              [](const O& o) {
                if (o.contrast && !(o.contrast->on > 0 && o.contrast->off > 0)) {
                  throw Error("edi: contrast must be positive");
                }
              },
              [](const O& o) {
                return o.contrast ? shortNumber(o.contrast->on) + "," + shortNumber(o.contrast->off)
                                  : "none";
              }})
        .custom({"search", "0|1", "1: search c even when contrast.txt gives the thresholds",
                 [](O& o, const std::string& v) {
                   o.use_observation_contrast = settingNumber("edi", "search", v) == 0;
                 },
                 [](const O&) {},
                 [](const O& o) { return std::string(o.use_observation_contrast ? "0" : "1"); }})
        .number("c_min", &O::search_min, {0, INFINITY, true}, "lowest c of the search")
        .number("c_max", &O::search_max, {0, INFINITY, true}, "highest c of the search")
        .integer("margin_us", &O::margin_us, {0}, "widen the integration window on both sides (µs)")
        .choice("levels", &O::levels,
                {{"steps", O::Levels::kSteps}, {"linear", O::Levels::kLinear}},
                "each pixel's log level between its events: held since the last (the published "
                "EDI) or straight from one event's level to the next");
    return t;
  }();
  return table;
}

void EdiOptions::check() const {
  ediSettings().check(*this);
  if (!(search_max > search_min)) throw Error("edi: need c_min < c_max");
}

EdiOptions ediOptions(const MethodSettings& settings) {
  EdiOptions o;
  ediSettings().apply(o, settings);
  o.check();
  return o;
}

std::unique_ptr<Deblurrer> makeEdi(const MethodSettings& settings) {
  return std::make_unique<EdiDeblurrer>(ediOptions(settings));
}

}  // namespace evkit
