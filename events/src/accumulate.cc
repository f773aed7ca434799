#include "evkit/events/accumulate.h"

#include <algorithm>
#include <cassert>
#include <cmath>
#include <opencv2/imgproc.hpp>

namespace evkit {

namespace {

cv::Mat zeroImage(const EventSpan& events) {
  return cv::Mat::zeros(events.sensor.height, events.sensor.width, CV_32F);
}

// Calls f(pixel_index, i) for every event inside the sensor.
template <typename F>
void forEachEvent(const EventSpan& events, F&& f) {
  const uint32_t w = static_cast<uint32_t>(events.sensor.width);
  const uint32_t h = static_cast<uint32_t>(events.sensor.height);
  const uint16_t* xs = events.x.data();
  const uint16_t* ys = events.y.data();
  const size_t n = events.size();
  for (size_t i = 0; i < n; ++i) {
    const uint32_t x = xs[i], y = ys[i];
    if (x < w && y < h) f(y * w + x, i);
  }
}

float percentileOfNonZero(const cv::Mat& a, double q) {
  std::vector<float> v;
  for (int r = 0; r < a.rows; ++r) {
    const float* row = a.ptr<float>(r);
    for (int c = 0; c < a.cols; ++c) {
      if (row[c] != 0) v.push_back(std::abs(row[c]));
    }
  }
  if (v.empty()) return 1.0f;
  const size_t k = std::min(v.size() - 1, static_cast<size_t>(q * static_cast<double>(v.size())));
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(k), v.end());
  return std::max(v[k], 1.0f);
}

}  // namespace

cv::Mat accumulateSigned(const EventSpan& events, float c_on, float c_off) {
  cv::Mat img = zeroImage(events);
  float* data = img.ptr<float>();
  const int8_t* p = events.p.data();
  if (c_on == 1.0f && c_off == 1.0f) {
    forEachEvent(events,
                 [&](uint32_t pixel, size_t i) { data[pixel] += static_cast<float>(p[i]); });
  } else {
    const float gain[3] = {-c_off, 0.0f, c_on};
    forEachEvent(events, [&](uint32_t pixel, size_t i) { data[pixel] += gain[p[i] + 1]; });
  }
  return img;
}

PolarityCounts accumulateCounts(const EventSpan& events) {
  PolarityCounts counts{zeroImage(events), zeroImage(events)};
  float* planes[2] = {counts.off.ptr<float>(), counts.on.ptr<float>()};
  const int8_t* p = events.p.data();
  forEachEvent(events, [&](uint32_t pixel, size_t i) { planes[p[i] > 0][pixel] += 1.0f; });
  return counts;
}

cv::Mat accumulateNormalized(const EventSpan& events) {
  cv::Mat img = accumulateSigned(events);
  const double norm = cv::norm(img, cv::NORM_L2);
  if (norm > 0) img /= norm;
  return img;
}

TimeSurface timeSurface(const EventSpan& events, int64_t t_ref_us, double tau_us) {
  assert(tau_us > 0);
  const size_t pixels =
      static_cast<size_t>(events.sensor.width) * static_cast<size_t>(events.sensor.height);
  std::vector<int64_t> last[2] = {std::vector<int64_t>(pixels, INT64_MIN),
                                  std::vector<int64_t>(pixels, INT64_MIN)};
  const size_t end = events.lowerBound(t_ref_us == INT64_MAX ? t_ref_us : t_ref_us + 1);
  const EventSpan upto = events.subspan(0, end);
  forEachEvent(upto, [&](uint32_t pixel, size_t i) { last[upto.p[i] > 0][pixel] = upto.t[i]; });
  TimeSurface ts{zeroImage(events), zeroImage(events)};
  cv::Mat* out[2] = {&ts.off, &ts.on};
  for (int pol = 0; pol < 2; ++pol) {
    float* data = out[pol]->ptr<float>();
    for (size_t k = 0; k < pixels; ++k) {
      if (last[pol][k] != INT64_MIN) {
        data[k] =
            static_cast<float>(std::exp(-static_cast<double>(t_ref_us - last[pol][k]) / tau_us));
      }
    }
  }
  return ts;
}

std::vector<cv::Mat> voxelGrid(const EventSpan& events, int bins, int64_t t0_us, int64_t t1_us) {
  assert(bins >= 1);
  std::vector<cv::Mat> grid(static_cast<size_t>(bins));
  for (cv::Mat& g : grid) g = zeroImage(events);
  const double span = static_cast<double>(t1_us - t0_us);
  const double scale = span > 0 ? (bins - 1) / span : 0.0;
  std::vector<float*> planes;
  for (cv::Mat& g : grid) planes.push_back(g.ptr<float>());
  forEachEvent(events, [&](uint32_t pixel, size_t i) {
    const double tn =
        std::clamp(static_cast<double>(events.t[i] - t0_us) * scale, 0.0, double(bins - 1));
    const int b = std::min(static_cast<int>(tn), bins - 1);
    const float frac = static_cast<float>(tn - b);
    const float pol = events.p[i];
    planes[static_cast<size_t>(b)][pixel] += pol * (1.0f - frac);
    if (b + 1 < bins) planes[static_cast<size_t>(b + 1)][pixel] += pol * frac;
  });
  return grid;
}

std::vector<std::pair<size_t, size_t>> windowsByTime(const EventSpan& events, int64_t duration_us) {
  assert(duration_us > 0);
  std::vector<std::pair<size_t, size_t>> windows;
  if (events.empty()) return windows;
  size_t begin = 0;
  int64_t t_start = events.t.front();
  while (begin < events.size()) {
    // Guard against overflow near INT64_MAX.
    const int64_t t_end = t_start > INT64_MAX - duration_us ? INT64_MAX : t_start + duration_us;
    const size_t end = t_end == INT64_MAX ? events.size() : events.lowerBound(t_end);
    windows.emplace_back(begin, end);
    begin = end;
    t_start = t_end;
  }
  return windows;
}

std::vector<std::pair<size_t, size_t>> windowsByCount(const EventSpan& events, size_t count) {
  assert(count > 0);
  std::vector<std::pair<size_t, size_t>> windows;
  for (size_t b = 0; b < events.size(); b += count)
    windows.emplace_back(b, std::min(events.size(), b + count));
  return windows;
}

cv::Mat renderPolarity(const PolarityCounts& counts, float saturation) {
  const float sat = saturation > 0 ? saturation : percentileOfNonZero(counts.on + counts.off, 0.99);
  cv::Mat out(counts.on.size(), CV_8UC3, cv::Scalar(255, 255, 255));
  for (int r = 0; r < out.rows; ++r) {
    const float* on = counts.on.ptr<float>(r);
    const float* off = counts.off.ptr<float>(r);
    cv::Vec3b* px = out.ptr<cv::Vec3b>(r);
    for (int c = 0; c < out.cols; ++c) {
      // Fade from white towards pure red (ON) and pure blue (OFF); both present mixes to purple.
      const float a_on = std::min(on[c] / sat, 1.0f), a_off = std::min(off[c] / sat, 1.0f);
      const auto level = [](float v) {
        return static_cast<uchar>(std::lround(255.0f * std::clamp(v, 0.0f, 1.0f)));
      };
      px[c] = cv::Vec3b(level(1.0f - a_on), level(1.0f - a_on - a_off), level(1.0f - a_off));
    }
  }
  return out;
}

cv::Mat renderPolarity(const cv::Mat& signed_frame, float saturation) {
  PolarityCounts counts;
  counts.on = cv::max(signed_frame, 0.0f);
  counts.off = cv::max(-signed_frame, 0.0f);
  return renderPolarity(counts, saturation);
}

cv::Mat renderColormap(const cv::Mat& values) {
  cv::Mat v;
  values.convertTo(v, CV_32F);
  cv::patchNaNs(v, 0.0);
  double lo, hi;
  cv::minMaxLoc(v, &lo, &hi);
  const double range = hi > lo ? hi - lo : 1.0;
  cv::Mat u8;
  v.convertTo(u8, CV_8U, 255.0 / range, -lo * 255.0 / range);
  cv::Mat out;
  cv::applyColorMap(u8, out, cv::COLORMAP_VIRIDIS);
  return out;
}

}  // namespace evkit
