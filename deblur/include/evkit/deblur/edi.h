// The Event-based Double Integral (Pan, Scheerlinck, Yu, Hartley, Liu, Dai, CVPR 2019).
//
// Per pixel, with E(t) the signed event count since the exposure start (a step function) and
// log L(t) = log L(f) + c (E(t) - E(f)), the blurry frame is
//   B = L(f) (1/T) integral_T exp(c (E(t) - E(f))) dt,
// so L(f) = B exp(c E(f)) / ((1/T) sum_n D_n exp(c n)), where D_n is the time the pixel spent at
// level n: an exact finite sum (double precision) over the pixel's events. With separate
// thresholds the level is c_on n_on - c_off n_off. The same per-pixel gain multiplies every colour
// channel. Saturated and black pixels (B outside [black, saturated]) keep B. c comes from the
// settings, the observation's contrast.txt, or a 1-D search minimising a sharpness energy of the
// latent frame at mid-exposure (see EdiModel::searchContrast). With `levels=linear` the level runs
// straight from each event's level to the next instead of holding between them (the integral stays
// exact, piece by piece): the steps sit up to a threshold behind the log intensity that fired them.
#pragma once

#include <opencv2/core.hpp>
#include <optional>
#include <vector>

#include "evkit/deblur/deblurrer.h"
#include "evkit/deblur/settings.h"
#include "evkit/events/pixel_index.h"

namespace evkit {

struct EdiOptions {
  std::optional<Contrast> contrast;  // fixed thresholds; else contrast.txt; else the search
  bool use_observation_contrast = true;
  double search_min = 0.1, search_max = 0.5;          // the published range for DAVIS data
  int search_grid = 21;                               // coarse grid, then golden-section refinement
  double saturated = Frame::kClipped, black = 0.005;  // masks (linear intensity)
  int64_t margin_us = 0;                              // widen the integration window on both sides
  // How each pixel's log level runs between its events: kSteps holds the level since the last
  // event (the published EDI); kLinear passes through each event's level at its time, straight
  // between events, and half a threshold beyond the first and the last (EdiModel::linearKnots).
  enum class Levels { kSteps, kLinear } levels = Levels::kSteps;

  // Throws evkit::Error naming the first setting out of its range.
  void check() const;
};

// Every `--set KEY=VALUE` of EDI: key, type, range, help.
const SettingsTable<EdiOptions>& ediSettings();
// Options from settings, checked.
EdiOptions ediOptions(const MethodSettings& settings);
// Parses EDI's settings (ediSettings) and makes the method.
std::unique_ptr<Deblurrer> makeEdi(const MethodSettings& settings);

// One exposure's events by pixel, reusable across c values and latent times.
class EdiModel {
 public:
  // Events of [t_begin, t_end] (others are ignored), on a width x height sensor.
  EdiModel(const EventSpan& events, int width, int height, int64_t t_begin_us, int64_t t_end_us);
  // Latent frame at t (grey or colour like `blurry`), for thresholds c_on, c_off.
  cv::Mat latent(const cv::Mat& blurry, int64_t t_us, double c_on, double c_off,
                 const EdiOptions& options) const;
  // The sharpness energy of the grey latent frame at t (lower is sharper): the normalised
  // sparsity ||grad L||_1 / ||grad L||_2 of its gradient magnitude (Krishnan et al., CVPR 2011),
  // i.e. total variation against gradient energy.
  double sparsityEnergy(const cv::Mat& blurry_grey, int64_t t_us, double c, double ratio,
                        const EdiOptions& options) const;
  // c_on minimising the energy over [search_min, search_max] (c_off = ratio * c_on): a grid,
  // then golden-section refinement around its best point.
  double searchContrast(const cv::Mat& blurry_grey, int64_t t_us, double ratio,
                        const EdiOptions& options) const;

 private:
  // The (time, level) knots of pixel p's log level with the linear levels (it has events).
  void linearKnots(size_t p, double c_on, double c_off,
                   std::vector<std::pair<double, double>>& knots) const;
  // Pixel p's gain at t with the linear levels: 1 / ((1/T) integral exp(l(s) - l(t)) ds).
  double linearGain(size_t p, int64_t t_us, double c_on, double c_off) const;

  int width_, height_;
  int64_t t_begin_, t_end_;
  PixelEventIndex events_;  // the exposure's events by pixel
  int max_events_per_pixel_ = 0;
};

class EdiDeblurrer final : public Deblurrer {
 public:
  explicit EdiDeblurrer(const EdiOptions& options) : options_(options) {}
  std::string name() const override { return "edi"; }
  DeblurResult run(const Observation& obs, const DeblurRequest& request) override;

 private:
  EdiOptions options_;
};

}  // namespace evkit
