#include "evkit/events/simulator.h"

#include <algorithm>
#include <cassert>
#include <cmath>
#include <opencv2/imgproc.hpp>
#include <random>

namespace evkit {

namespace {

constexpr float kMinContrast = 0.01f;

// splitmix64: decorrelated seeds for independent streams (pixel, interval).
uint64_t mix(uint64_t x) {
  x += 0x9e3779b97f4a7c15ULL;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ULL;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebULL;
  return x ^ (x >> 31);
}

constexpr float kMaxPerInterval = 1e5f;  // events of one pixel in one frame interval, at most
constexpr int64_t kMaxCountingSortSpan = int64_t{1}
                                         << 24;  // µs; longer intervals use a stable sort

// Time of a crossing inside [t_a, t_b]: where the linear ramp from da to db reaches `level`.
inline uint32_t crossingOffset(float da, float db, float level, int64_t dt) {
  double frac = (static_cast<double>(level) - da) / (static_cast<double>(db) - da);
  // A level already reached at t_a (float round-off left D on it, da == db): fires at t_a. In
  // [t_a, t_b] a crossing that rounds to t_a still follows every event of earlier intervals.
  if (!(frac >= 0.0)) frac = 0.0;  // also NaN
  if (frac > 1.0) frac = 1.0;
  return static_cast<uint32_t>(frac * static_cast<double>(dt) + 0.5);  // round, >= 0
}

}  // namespace

EventSimulator::EventSimulator(SensorSize sensor, const SimulatorOptions& options)
    : sensor_(sensor), options_(options) {
  const size_t n = static_cast<size_t>(sensor.width) * static_cast<size_t>(sensor.height);
  c_pos_.resize(n);
  c_neg_.resize(n);
  std::mt19937_64 rng(mix(options.seed));
  std::normal_distribution<double> normal(0.0, 1.0);
  for (size_t i = 0; i < n; ++i) {
    const double zp = options.sigma > 0 ? normal(rng) : 0.0;
    const double zn = options.sigma > 0 ? normal(rng) : 0.0;
    c_pos_[i] =
        std::max(kMinContrast, static_cast<float>(options.contrast_pos + options.sigma * zp));
    c_neg_[i] =
        std::max(kMinContrast, static_cast<float>(options.contrast_neg + options.sigma * zn));
  }
  last_event_.assign(n, INT64_MIN / 2);
  counts_.resize(n);
}

void EventSimulator::addFrame(const cv::Mat& grey, int64_t t_us, EventStore& out) {
  assert(grey.type() == CV_32F && grey.rows == sensor_.height && grey.cols == sensor_.width);
  const int W = sensor_.width, H = sensor_.height;
  const size_t n = static_cast<size_t>(W) * static_cast<size_t>(H);
  log_next_.resize(n);
  if (!options_.log.lin_log) {
    // log(max(I, 0) + eps) with OpenCV's vectorised log (the same mapping as LogMapping::toLog).
    cv::Mat dst(H, W, CV_32F, log_next_.data());
    cv::max(grey, 0.0, dst);
    dst += static_cast<float>(options_.log.eps);
    cv::log(dst, dst);
  } else {
#pragma omp parallel for schedule(static)
    for (int y = 0; y < H; ++y) {
      const float* row = grey.ptr<float>(y);
      float* dst = log_next_.data() + static_cast<size_t>(y) * static_cast<size_t>(W);
      for (int x = 0; x < W; ++x) dst[x] = options_.log.toLog(std::max(row[x], 0.0f));
    }
  }
  ++stats_.frames;
  if (!initialized_) {
    log_prev_ = log_next_;
    ref_ = log_next_;
    if (options_.leak_rate_hz > 0) {
      // Random leak phase per pixel, so that still pixels do not leak in lockstep.
      std::mt19937_64 rng(mix(options_.seed ^ 0x1eaf));
      std::uniform_real_distribution<float> u(0.0f, 1.0f);
      for (size_t i = 0; i < n; ++i) ref_[i] -= u(rng) * c_pos_[i];
    }
    t_prev_ = t_us;
    initialized_ = true;
    return;
  }
  assert(t_us > t_prev_);
  const int64_t dt = t_us - t_prev_;
  const float leak = static_cast<float>(options_.leak_rate_hz * static_cast<double>(dt) * 1e-6);
  const int64_t refractory = options_.refractory_us;

  // Each pixel follows D(t) = L(t) - ref(t): the log intensity minus its reference, which the leak
  // lowers linearly over the interval. D is linear in t, from da = la - ref to
  // db = lb - ref + leak C+; events fire where D reaches k C+ or -k C-.
  // Pass 1: count events per pixel (and how many pixels moved by more than C).
  int64_t over_c = 0;
#pragma omp parallel for schedule(static) reduction(+ : over_c)
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      const size_t i = static_cast<size_t>(y) * static_cast<size_t>(W) + static_cast<size_t>(x);
      const float lb = log_next_[i];
      const float d = lb - ref_[i] + leak * c_pos_[i];
      // floor(|d| / C) for the threshold of d's sign (truncation is floor for |d| >= 0); a
      // non-finite input (NaN) gives none, and no pixel emits more than kMaxPerInterval at once.
      const float q = d >= 0 ? d / c_pos_[i] : -d / c_neg_[i];
      counts_[i] = q >= 0 ? static_cast<uint32_t>(std::min(q, kMaxPerInterval)) : 0u;
      over_c += std::abs(lb - log_prev_[i]) > std::min(c_pos_[i], c_neg_[i]);
    }
  }
  last_fraction_over_c_ = static_cast<double>(over_c) / static_cast<double>(n);
  stats_.max_fraction_over_c = std::max(stats_.max_fraction_over_c, last_fraction_over_c_);
  if (last_fraction_over_c_ > options_.undersampling_fraction) ++stats_.undersampled_intervals;

  // Prefix sum: where each pixel writes.
  std::vector<uint64_t>& start = start_;
  start.resize(n + 1);
  start[0] = 0;
  for (size_t i = 0; i < n; ++i) start[i + 1] = start[i] + counts_[i];
  const size_t total = start[n];
  offsets_.resize(total);
  pixel_of_.resize(total);
  pol_.resize(total);

  // Pass 2: write each pixel's crossings (its own interpolated times), update references.
  int64_t dropped = 0;
#pragma omp parallel for schedule(static) reduction(+ : dropped)
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      const size_t i = static_cast<size_t>(y) * static_cast<size_t>(W) + static_cast<size_t>(x);
      const uint32_t k = counts_[i];
      const float drift = leak * c_pos_[i];
      if (k == 0) {
        ref_[i] -= drift;
        continue;
      }
      const float da = log_prev_[i] - ref_[i], db = log_next_[i] - ref_[i] + drift;
      const bool up = db >= 0;
      const float c = up ? c_pos_[i] : c_neg_[i];
      const float step = up ? c : -c;
      uint64_t w = start[i];
      for (uint32_t j = 1; j <= k; ++j) {
        const uint32_t off = crossingOffset(da, db, static_cast<float>(j) * step, dt);
        const int64_t t = t_prev_ + off;
        if (t - last_event_[i] < refractory) {
          ++dropped;
          continue;
        }
        last_event_[i] = t;
        offsets_[w] = off;
        pixel_of_[w] = static_cast<uint32_t>(i);
        pol_[w] = up ? 1 : -1;
        ++w;
      }
      counts_[i] = static_cast<uint32_t>(w - start[i]);  // emitted
      ref_[i] = ref_[i] - drift + static_cast<float>(k) * step;
    }
  }
  stats_.refractory_dropped += dropped;

  // Shot noise: one sequential draw per interval (deterministic whatever the thread count).
  std::vector<uint32_t> noise_off, noise_pix;
  std::vector<int8_t> noise_pol;
  if (options_.shot_noise_rate_hz > 0) {
    std::mt19937_64 rng(mix(options_.seed ^ mix(static_cast<uint64_t>(stats_.frames))));
    std::poisson_distribution<int64_t> count(options_.shot_noise_rate_hz * static_cast<double>(n) *
                                             static_cast<double>(dt) * 1e-6);
    std::uniform_int_distribution<uint64_t> pixel(0, n - 1);
    std::uniform_int_distribution<int64_t> when(0, dt - 1);
    const int64_t m = count(rng);
    for (int64_t e = 0; e < m; ++e) {
      noise_pix.push_back(static_cast<uint32_t>(pixel(rng)));
      noise_off.push_back(static_cast<uint32_t>(when(rng)));
      noise_pol.push_back(rng() & 1 ? 1 : -1);
    }
    stats_.noise_events += m;
  }

  // Gather the emitted events (compacting the refractory holes), then a stable counting sort on
  // the µs offset: equal times keep pixel order, so the output does not depend on threads.
  size_t emitted = dropped == 0 ? total : 0;
  for (size_t i = 0; dropped > 0 && i < n; ++i) {
    const uint64_t s = start[i];
    for (uint32_t j = 0; j < counts_[i]; ++j, ++emitted) {
      offsets_[emitted] = offsets_[s + j];
      pixel_of_[emitted] = pixel_of_[s + j];
      pol_[emitted] = pol_[s + j];
    }
  }
  offsets_.resize(emitted);
  pixel_of_.resize(emitted);
  pol_.resize(emitted);
  offsets_.insert(offsets_.end(), noise_off.begin(), noise_off.end());
  pixel_of_.insert(pixel_of_.end(), noise_pix.begin(), noise_pix.end());
  pol_.insert(pol_.end(), noise_pol.begin(), noise_pol.end());
  const size_t m = offsets_.size();
  // order[k] = the event written k-th: stable by offset.
  order_.resize(m);
  if (dt <= kMaxCountingSortSpan) {
    bucket_.assign(static_cast<size_t>(dt) + 2, 0);
    for (size_t e = 0; e < m; ++e) ++bucket_[offsets_[e] + 1];
    for (size_t b = 1; b < bucket_.size(); ++b) bucket_[b] += bucket_[b - 1];
    for (size_t e = 0; e < m; ++e) order_[bucket_[offsets_[e]]++] = static_cast<uint32_t>(e);
  } else {
    for (size_t e = 0; e < m; ++e) order_[e] = static_cast<uint32_t>(e);
    std::stable_sort(order_.begin(), order_.end(),
                     [&](uint32_t a, uint32_t b) { return offsets_[a] < offsets_[b]; });
  }
  const size_t base = out.size();
  out.t.resize(base + m);
  out.x.resize(base + m);
  out.y.resize(base + m);
  out.p.resize(base + m);
  // Gather in output order: sequential writes, independent reads, in parallel.
  int64_t* out_t = out.t.data() + base;
  uint16_t* out_x = out.x.data() + base;
  uint16_t* out_y = out.y.data() + base;
  int8_t* out_p = out.p.data() + base;
  const uint32_t* order = order_.data();
  const int64_t t_prev = t_prev_;
#pragma omp parallel for schedule(static)
  for (size_t k = 0; k < m; ++k) {
    const uint32_t e = order[k];
    const uint32_t pix = pixel_of_[e];
    out_t[k] = t_prev + offsets_[e];
    out_x[k] = static_cast<uint16_t>(pix % static_cast<uint32_t>(W));
    out_y[k] = static_cast<uint16_t>(pix / static_cast<uint32_t>(W));
    out_p[k] = pol_[e];
  }
  stats_.events += static_cast<int64_t>(m);
  log_prev_.swap(log_next_);
  t_prev_ = t_us;
}

cv::Mat toSensorIntensity(const cv::Mat& image, bool bayer_rggb) {
  cv::Mat f;
  image.convertTo(f, CV_32F);
  if (f.channels() == 1) return f;
  if (f.channels() == 4) cv::cvtColor(f, f, cv::COLOR_BGRA2BGR);
  cv::Mat grey(f.rows, f.cols, CV_32F);
  for (int y = 0; y < f.rows; ++y) {
    const cv::Vec3f* in = f.ptr<cv::Vec3f>(y);
    float* out = grey.ptr<float>(y);
    for (int x = 0; x < f.cols; ++x) {
      if (bayer_rggb) {
        // RGGB: R at (even x, even y), B at (odd, odd), G elsewhere; BGR indices 2, 0, 1.
        const int channel = (y % 2 == 0) ? (x % 2 == 0 ? 2 : 1) : (x % 2 == 0 ? 1 : 0);
        out[x] = in[x][channel];
      } else {
        out[x] = 0.114f * in[x][0] + 0.587f * in[x][1] + 0.299f * in[x][2];
      }
    }
  }
  return grey;
}

BlurAccumulator::BlurAccumulator(std::vector<Exposure> exposures)
    : exposures_(std::move(exposures)) {
  std::sort(exposures_.begin(), exposures_.end(),
            [](const Exposure& a, const Exposure& b) { return a.end_us < b.end_us; });
  sums_.resize(exposures_.size());
}

size_t BlurAccumulator::pending() const { return exposures_.size() - next_done_; }

// The frame interval [t0, t1] with intensities I0 -> I1 (linear in time) contributes to an
// exposure [s, e] the integral over [a, b] = [t0, t1] ∩ [s, e]: (b - a) (I(a) + I(b)) / 2.
std::vector<std::pair<BlurAccumulator::Exposure, cv::Mat>> BlurAccumulator::addFrame(
    const cv::Mat& linear, int64_t t_us) {
  std::vector<std::pair<Exposure, cv::Mat>> done;
  cv::Mat cur;
  linear.convertTo(cur, CV_32F);
  if (have_prev_ && t_us > t_prev_) {
    const double span = static_cast<double>(t_us - t_prev_);
    for (size_t k = next_done_; k < exposures_.size(); ++k) {
      const Exposure& e = exposures_[k];
      const int64_t a = std::max(e.start_us, t_prev_), b = std::min(e.end_us, t_us);
      if (b <= a) continue;
      const double wa = static_cast<double>(a - t_prev_) / span,
                   wb = static_cast<double>(b - t_prev_) / span;
      // I(a) + I(b) = (2 - wa - wb) I0 + (wa + wb) I1
      const double scale = static_cast<double>(b - a) / 2.0;
      cv::Mat contribution = prev_ * ((2.0 - wa - wb) * scale) + cur * ((wa + wb) * scale);
      if (sums_[k].empty()) sums_[k] = cv::Mat::zeros(cur.size(), cur.type());
      sums_[k] += contribution;
    }
  }
  // Exposures that end at or before this frame are complete.
  while (next_done_ < exposures_.size() && exposures_[next_done_].end_us <= t_us) {
    const Exposure& e = exposures_[next_done_];
    if (!sums_[next_done_].empty() && e.end_us > e.start_us) {
      done.emplace_back(e, sums_[next_done_] / static_cast<double>(e.end_us - e.start_us));
    } else if (e.end_us == e.start_us && t_us == e.end_us) {
      done.emplace_back(e, cur.clone());  // zero-length exposure: the frame itself
    }
    sums_[next_done_].release();
    ++next_done_;
  }
  prev_ = cur;
  t_prev_ = t_us;
  have_prev_ = true;
  return done;
}

}  // namespace evkit
