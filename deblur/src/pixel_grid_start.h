// What the pixel grid starts from (benerf_train.cc): EDI's mid-exposure frame, the events that a
// neighbouring pixel supports and, without thresholds, the scale c with the motion registered at
// it.
#pragma once

#include <cmath>
#include <functional>
#include <opencv2/core.hpp>
#include <vector>

#include "evkit/deblur/benerf.h"
#include "evkit/deblur/deblurrer.h"
#include "evkit/deblur/pixel_grid.h"

namespace evkit::benerf_detail {

// The observation with only the events that a neighbouring pixel supports within the time the
// image takes to move `support_px` pixels (by the motion), and the share dropped in `result`.
Observation supportedEvents(const Observation& obs, double support_px, double blur_px,
                            DeblurResult& result);

// EDI's mid-exposure frame with thresholds c, each pixel's level straight between its events
// (EdiOptions::Levels::kLinear; BENCHMARKS.md, "EDI's levels between events").
cv::Mat ediMidFrame(const Observation& obs, const Contrast& c);

// The share of deblurring's change (StartFit) from which the grid's misfit at the start keeps it:
// measured on the natural, standard, noisy and hard suites (BENCHMARKS.md, "The pixel grid"), the
// scenes where the solve ended below its start had 0.54-0.93, those where it gained 0.04-0.37.
inline constexpr double kKeepStart = 0.5;
// The blur (the grid's longest image path, px) from which a start the grid would keep is left to
// the hash field instead. Below it the start is kept because the grid's bilinear cells cannot model
// so short a blur, and EDI's frame is the better answer (hard_blur2: EDI 40.3 dB, the hash field
// 31.2, the blurry frame 31.3). Above it the registered motion does not re-make the blurry frame
// (the rgbd scenes: smooth texture registers a short motion, 11.3 px on rgbd_blur15, and their
// height field ends at the mid frame's border), and the hash field, whose training refines its
// own trajectory from the events, did better on 8 of 9 such scenes (BENCHMARKS.md, "A kept start").
inline constexpr double kHashBlur = 5;
// How well the grid's model re-makes the blurry frame from where it starts (EDI's frame on the
// refined motion), against how much deblurring changes it: `misfit`, the RMS of the start's
// re-blur less the blurry frame (the blur term there), and `change`, the RMS of the start's
// mid-exposure frame less the blurry frame. Where the misfit is a good share of the change, the
// blur term cannot tell what deblurring changes from the model's own error (BENCHMARKS.md, "The
// pixel grid"). `terms`: the loss's terms there.
struct StartFit {
  double misfit = 0, change = 0;
  PixelGridProblem::Terms terms;
  bool misfits() const;  // the misfit is kKeepStart of the change or more
};
StartFit startFit(const PixelGridProblem& problem, const std::vector<double>& x,
                  const Frame& blurry);

// The range of c searched without thresholds: a c found at an end of it is declined.
inline constexpr double kLeastContrast = 0.05, kMostContrast = 1.0;
// The short solves stay within this of contrastFromCounts' c in log c, 2^(1/3): the counts' c was
// 0.81-1.16 of the truth on 51 of 52 frames of photographs (BENCHMARKS.md, "The thresholds from
// the events' counts").
inline const double kCountsBand = std::log(2.0) / 3;
// How far the counts may follow the c that their motion was registered at before they are taken to
// tell no c: the exponent s of counts ~ c_registered^s between a registration at c and one at 2c.
// The count's fixed point then carries the counts' own error times 1 / (1 - s), four times at 3/4.
// Measured on the 53 frames of the suites and 6 smooth, noisy photographs at half size: at most
// 0.35 wherever a photograph or a texture is; 0.53 on a rocket before its backdrop at half size
// (85% of the image motion from translation, registered at 0.39 and 0.77, where a motion registered
// at too large a c moves the image too far: the grid 35.18 dB, the hash field 19.54); 0.98 on
// smooth shading with noisy events (ground_blur15_noisy: 0.090 along the motion registered at
// 0.098, 0.178 along the one at 0.197; the grid at the count 6.2 dB below the hash field).
// BENCHMARKS.md, "Whether the counts tell c".
inline constexpr double kMostCountsFollow = 0.75;
// The views of the search for c (contrastFromSolves' grids, contrastFromCounts' paths): the blur
// integral coarser than the run's, alike for every c.
inline constexpr int kSearchViews = 20;
// Whether the short solves refine each candidate's motion before solving, at a blur of `blur_px`
// (the longest image path along the motion the counts were taken along): from 5 px, where the blur
// tells c (below it, the counts' c stands: hard_blur2 39.78 -> 34.22 dB), to where kSearchViews
// views are 2 px apart (38 px; at 70 px, 3.5 px apart, the refined motions fit the views'
// sampling and the walk ends low: hard_blur70 31.41 -> 28.82). BENCHMARKS.md, "The walk's motion".
inline bool refineWalkMotions(double blur_px) {
  constexpr double kLeastBlur = 5, kMostViewSpacing = 2;
  return blur_px >= kLeastBlur && blur_px <= kMostViewSpacing * (kSearchViews - 1);
}
// The walk of contrastFromSolves over l = log c: from l (its misfit `first`, and `second` at l + h)
// by steps of h, up while misfit(l) falls, else down, within [below, above]; the least seen, moved
// to the vertex of the parabola through it and its neighbours, and whether the misfit was still
// falling where `below` stopped it (falling_at_below: the point beyond was not tried).
struct WalkedLeast {
  double l = 0;
  bool falling_at_below = false;
};
WalkedLeast walkToLeast(const std::function<double(double)>& misfit, double l, double first,
                        double second, double h, double below, double above);
// The thresholds refined from `c0` by short solves of the grid, each on the motion registered at
// its own c, or where refineWalkMotions(blur_px) on the first one's registration refined at its own
// c and without the smoothness: the c within `band` of c0 (in log c) at which the solved image
// re-blurs closest to the frame.
struct SolvedContrast {
  Contrast contrast;
  bool at_end = false;  // the least at an end of [0.05, 1]
  // The misfit still falling where the band ends below: no least within it (contrastFromSolves).
  bool falls_below_band = false;
  // Where the first candidate's start misfits (StartFit::misfits) at a blur of kHashBlur or more,
  // the walk stops there (no contrast found), and `start` says how.
  bool start_misfits = false;
  StartFit start;
};
SolvedContrast contrastFromSolves(
    const Observation& given, const PinholeCamera& camera,
    const std::function<Trajectory(const std::vector<StampedPose>&)>& fit, PixelGridOptions po,
    double ratio, double c0, double band, double blur_px, const BenerfOptions& o,
    DeblurResult& result);

}  // namespace evkit::benerf_detail
