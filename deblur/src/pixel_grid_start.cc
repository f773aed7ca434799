// What the pixel grid starts from: EDI's mid-exposure frame, the supported events and, without
// thresholds, the scale c (pixel_grid_start.h).

#include "pixel_grid_start.h"

#include <omp.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <exception>
#include <limits>
#include <mutex>
#include <optional>
#include <type_traits>
#include <utility>

#include "evkit/deblur/edi.h"
#include "evkit/deblur/metrics.h"
#include "evkit/events/accumulate.h"
#include "evkit/events/event_store.h"
#include "evkit/events/filters.h"
#include "evkit/nerf/camera.h"
#include "pixel_grid_geometry.h"

namespace evkit::benerf_detail {

namespace {

// The shift, in units of the spacing h, from the middle of three equally spaced points (a, b, c;
// b the least) to the vertex of the parabola through them; 0 where they are not convex. Within
// half a spacing, since b is the least.
double vertexShift(double a, double b, double c, double h) {
  const double curvature = a - 2 * b + c;
  return std::isfinite(curvature) && curvature > 0 ? 0.5 * h * (a - c) / curvature : 0.0;
}

// The mean of value(0), ..., value(n - 1) over the interval they sample, by the trapezoid rule: the
// two ends half a step each (n >= 2).
template <typename Value>
double trapezoidMean(int n, Value value) {
  double sum = 0.5 * (value(0) + value(n - 1));
  for (int k = 1; k + 1 < n; ++k) sum += value(k);
  return sum / (n - 1);
}

// Runs a() and b() at once, each on half of OpenMP's threads (their own parallel loops nested
// inside), or one after the other where there is one thread. What each computes does not depend on
// its threads: the grid's sums are over fixed blocks (BENCHMARKS.md, "The same bits at any thread
// count").
void bothAtOnce(const std::function<void()>& a, const std::function<void()>& b) {
  const int threads = omp_get_max_threads();
  if (threads < 2 || omp_in_parallel()) {
    a();
    b();
    return;
  }
  const int levels = omp_get_max_active_levels();
  omp_set_max_active_levels(std::max(levels, 2));
  std::exception_ptr failed[2];
#pragma omp parallel num_threads(2)
  {
    const int me = omp_get_thread_num(), team = omp_get_num_threads();
    omp_set_num_threads(std::max(1, (threads + team - 1 - me) / team));  // the threads shared out
    for (int task = me; task < 2; task += team) {
      try {
        (task == 0 ? a : b)();
      } catch (...) {
        failed[task] = std::current_exception();
      }
    }
  }
  omp_set_max_active_levels(levels);
  for (const std::exception_ptr& f : failed)
    if (f) std::rethrow_exception(f);
}

}  // namespace

WalkedLeast walkToLeast(const std::function<double(double)>& misfit, double l, double first,
                        double second, double h, double below, double above) {
  // Three points h apart, the middle one the least seen: up from l while the misfit falls, else
  // down; a point beyond [below, above] is not tried (NaN), which ends the walk there.
  const double none = std::numeric_limits<double>::quiet_NaN();
  std::array<double, 3> f{none, first, second};
  if (f[2] < f[1]) {
    do {
      f[0] = f[1];
      f[1] = f[2];
      l += h;
      f[2] = l + h <= above + 1e-9 ? misfit(l + h) : none;
    } while (f[2] < f[1]);
  } else {
    f[0] = misfit(l - h);
    while (f[0] < f[1]) {
      f[2] = f[1];
      f[1] = f[0];
      l -= h;
      f[0] = l - h >= below - 1e-9 ? misfit(l - h) : none;
    }
  }
  return {l + vertexShift(f[0], f[1], f[2], h), std::isnan(f[0])};
}

cv::Mat exposureEventCounts(const Observation& obs) {
  const Frame& blurry = obs.blurry;
  EventSpan span = obs.events.sliceTime(blurry.exposure_start_us, blurry.exposure_end_us);
  span.sensor = {blurry.image.cols, blurry.image.rows};
  const PolarityCounts counts = accumulateCounts(span);
  cv::Mat both;
  cv::add(counts.on, counts.off, both, cv::noArray(), CV_64F);
  return both;
}

// The observation with only the events that a neighbouring pixel supports within the time the
// image takes to move `support_px` pixels (by the motion), and the share dropped.
Observation supportedEvents(const Observation& obs, double support_px, double blur_px,
                            DeblurResult& result) {
  Observation out;
  out.blurry = obs.blurry;
  out.camera = obs.camera;
  out.contrast = obs.contrast;
  const int64_t exposure = obs.blurry.exposure_end_us - obs.blurry.exposure_start_us;
  const auto window = static_cast<int64_t>(support_px * exposure / std::max(blur_px, 1.0));
  int64_t dropped = 0;
  out.events = filterUnsupported(obs.events.view(), window, &dropped);
  result.parameters["events_unsupported"] =
      obs.events.empty() ? 0.0 : static_cast<double>(dropped) / obs.events.size();
  return out;
}

// EDI's mid-exposure frame with thresholds c, each pixel's level straight between its events
// (EdiOptions::Levels::kLinear; BENCHMARKS.md, "EDI's levels between events").
cv::Mat ediMidFrame(const Observation& obs, const Contrast& c) {
  EdiOptions edi_options;
  edi_options.use_observation_contrast = false;
  edi_options.contrast = c;
  edi_options.levels = EdiOptions::Levels::kLinear;
  DeblurRequest request;
  request.times_us = {obs.blurry.midExposure()};
  return EdiDeblurrer{edi_options}.run(obs, request).frames.front().image;
}

bool StartFit::misfits() const { return misfit >= kKeepStart * change; }

StartFit startFit(const PixelGridProblem& problem, const std::vector<double>& x,
                  const Frame& blurry) {
  StartFit fit;
  problem.evaluate(x, nullptr, &fit.terms);
  const cv::Mat mid = problem.render(x, blurry.midExposure());
  cv::Mat frame;
  blurry.image.convertTo(frame, mid.type());
  const double n = static_cast<double>(mid.total()) * mid.channels();
  fit.misfit = std::sqrt(fit.terms.blur);
  fit.change = cv::norm(mid, frame, cv::NORM_L2) / std::sqrt(n);
  return fit;
}

// The thresholds, when none are given, refined from `c0` (contrastFromCounts') by the grid itself:
// the scale of `ratio` within `band` of c0 at which the image, solved for a few steps on the motion
// registered at that scale, best re-makes the blurry frame. At a wrong c the events ask the image
// for log changes that the blur does not show, so the solved image re-blurs away from the frame.
// Where refineWalkMotions, the candidates share one registration, at the first candidate's c, and
// each refines it from there (as the final solve refines its own) before a short solve without the
// smoothness. With the final solve's smoothness the least was above the truth along the true
// motion and depths as well (0.22-0.23 for the truth's 0.2 on a ground plane of gravel and on
// noisy text): the prior flattens the solved image's contrast, and a larger c makes it up. Without
// it the least is at the truth there, and on one registration, refined for each c, the misfit is
// smooth in c with its least at the truth whether the registration was at 0.17 or at 0.24, where
// each candidate's own registration moved it by several percent from one c to the next
// (BENCHMARKS.md, "The walk's smoothness"). Elsewhere each candidate registers its own motion: on
// one motion registered at a c that is too low and not refined, the solves are biased low as well
// (BENCHMARKS.md, "The walk's motion"). The band holds the walk where its misfit falls towards
// small c without a least (smooth content with noisy events: the events' noise weighs least at a
// small c, and smooth content blurred looks much like itself; BENCHMARKS.md, "The thresholds from
// the events' counts"); within it the walk's sharp least refines the counts' c, which is up to 20%
// off. A walk that the band stops below while its misfit still falls has found no least there
// (SolvedContrast::falls_below_band): either the counts were raised by a motion registered too
// far and the truth lies beyond the band, or nothing tells c, which the caller judges by the
// counts' own check (runPixelGrid; BENCHMARKS.md, "Where the walk finds no least"). Not above: the
// fall towards small c is the misfit's bias, so a walk that climbs to the band's top went against
// it. The candidates' registrations leave the depths' offset unchosen (only their image
// motion is scored). Each pixel's share of the misfit counts as many times as the pixel saw events
// over the exposure: a pixel that the motion barely moves fires a few, each up to a threshold off
// what it stands for, and EDI's frame at a smaller c follows that quantisation less, so over all
// pixels alike the misfit fell towards low c wherever most of the image barely moves (a backdrop at
// 8 m with 85% of the image motion from translation: 0.130 for the truth 0.2, 3 dB lost;
// BENCHMARKS.md, "Outside the suites: exposure, translation, long blur, the sensor's size"). A
// pixel with n events tells its log change to about one threshold in n. A walk in log c by steps of
// 2^(1/6) from c0 to the least, then a parabola through it and its neighbours. The misfit has a
// sharp, lopsided minimum (in log, a cusp: on text_blur15 without thresholds it rises from the
// least at 0.215 about twice as steeply towards lower c), so a parabola through points 2^(1/3)
// apart put the least at 0.229, half a step off; at 2^(1/6) the points bracket it closely and the
// vertex is off by a fraction of the finer step. The first candidate's start is checked as the
// final solve's is (StartFit): where it misfits, the grid would decline after the walk, and the
// walk stops. On the suites and 60 photographs not in them, without thresholds, the first
// candidate's misfit was 0.58 of the change or more on four frames that the final check sent to the
// hash field, and 0.34 at most on the frames that the grid solved (the final check: 0.36 at most;
// BENCHMARKS.md, "Where the grid declines, the hash field's start").
SolvedContrast contrastFromSolves(
    const Observation& given, const PinholeCamera& camera,
    const std::function<Trajectory(const std::vector<StampedPose>&)>& fit, PixelGridOptions po,
    double ratio, double c0, double band, double blur_px, const BenerfOptions& o,
    DeblurResult& result) {
  // Ten L-BFGS steps (five left nat_text_coins_blur60 at a start of 0.164 where the truth is 0.2)
  // on at most kSearchViews views, after three Levenberg-Marquardt steps of the motion's
  // refinement where refineWalkMotions(blur_px) (30 or 100 L-BFGS steps did not move the walk's
  // least; the refinement did).
  constexpr int kSteps = 10, kRefineSteps = 3;
  const bool refine_motions = refineWalkMotions(blur_px);
  result.parameters["contrast_solves_refine_motion"] = refine_motions ? 1 : 0;
  po.max_views = std::max(po.min_views, kSearchViews);
  // One view per pixel of blur, not the final solve's two: on nat_gravel_ground_blur15 two and
  // three moved the walk's c by under 1% (0.2277 -> 0.2291 and 0.2285; BENCHMARKS.md, "Two views
  // per pixel of blur"), at up to 1.4 times the candidates' time.
  po.views_per_px = 1;
  // The short solves read the events as the log level, not as the sensor's reference level that
  // the final solve reads (PixelGridOptions::hysteresis): on the natural suite without thresholds
  // the walk found c as far from the truth either way (7.9% on average), and BeNeRF's frames came
  // out the same (37.68 against 37.65 dB), in 6.7 s of search a frame against 8.4 and 15.5 s in
  // all against 20.1 (BENCHMARKS.md, "The sensor's reference level").
  po.hysteresis = 0;
  // Nor the second layer's cells (PixelGridOptions::occlusion): a short solve's misfit scores a c.
  po.occlusion = false;
  // Nor the smoothness, where the motions are refined (above).
  if (refine_motions) po.smoothness = 0;
  // Nor the preconditioner (PixelGridOptions::precondition): ten plain steps are what the walk's
  // misfits were measured on. Preconditioned, the ten steps go further where the cells are bright
  // and the walk's least moved low (astronaut_plane and coffee_plane at 120 x 90: 0.184 and 0.169
  // for the truth's 0.2, against 0.195 and 0.199 with plain steps; gravel_ground 0.157 against
  // 0.191).
  po.precondition = false;
  const int64_t t0 = given.blurry.exposure_start_us, t1 = given.blurry.exposure_end_us;
  const cv::Mat counts = exposureEventCounts(given);
  const double events = cv::sum(counts)[0], channels = given.blurry.image.channels();
  SolvedContrast out;
  po.event_robust = o.mid_robust;
  const double lo = std::log(kLeastContrast), hi = std::log(kMostContrast), h = std::log(2.0) / 6;
  // The walk stays within `band` of c0 (in log c) and inside the range.
  const double below = std::max(lo, std::log(c0) - band), above = std::min(hi, std::log(c0) + band);
  double l = std::clamp(std::log(c0), lo + h, hi - h);
  // The candidates' one registration, at the first one's c, where they refine it.
  std::optional<ExposureMotion> shared;
  if (refine_motions)
    shared = motionFromLatentFrames(given, camera, Contrast{std::exp(l), std::exp(l) * ratio},
                                    o.log, false);
  std::mutex fit_mutex;
  // A candidate's misfit; the first's start is checked against the blurry frame (out.start).
  const auto misfit = [&](double l, bool first) {
    const Contrast contrast{std::exp(l), std::exp(l) * ratio};
    const ExposureMotion registered =
        refine_motions && !shared->poses.empty()
            ? *shared
            : motionFromLatentFrames(given, camera, contrast, o.log, false);
    if (registered.poses.empty()) return std::numeric_limits<double>::infinity();
    const Trajectory motion = [&] {
      const std::lock_guard lock(fit_mutex);  // fit reports its knots in the result
      return fit(registered.poses);
    }();
    DeblurResult unused;
    const Observation obs =
        o.support_px > 0 ? supportedEvents(given, o.support_px,
                                           PixelGridProblem::longestImagePath(
                                               camera, motion, registered.inverse_depth, t0, t1),
                                           unused)
                         : given;
    PixelGridProblem problem(obs, camera, motion, registered.inverse_depth, contrast, po);
    std::vector<double> x = problem.start(ediMidFrame(obs, contrast));
    if (refine_motions) problem.refineMotion(x, kRefineSteps);
    if (first) {
      out.start = startFit(problem, x, obs.blurry);
      out.start_misfits = out.start.misfits() && problem.blurLength() >= kHashBlur;
      if (out.start_misfits) return 0.0;
    }
    PixelGridProblem::Terms terms;
    problem.solve(x, kSteps, &terms);
    const double misfit =
        events > 0 ? counts.dot(problem.blurResiduals(x)) / (events * channels) : terms.blur;
    return std::log(std::max(misfit, 1e-30));
  };
  // The walk's first two candidates, c0 and one step up, are always solved (unless the first's
  // start misfits). Where each registers its own motion, at once, each on half the threads: a
  // registration and a problem's set-up use two threads poorly (nat_motorcycle_blur60_noisy
  // without thresholds: the search 11.6 -> 9.4 s). Not where they share one registration and
  // refine it, which two threads share well (nat_coffee_plane_blur15_noisy: 4.3 -> 5.2 s at once;
  // BENCHMARKS.md, "The walk's first two candidates at once").
  double first = 0, second = 0;
  if (refine_motions) {
    first = misfit(l, true);
    if (!out.start_misfits) second = misfit(l + h, false);
  } else {
    bothAtOnce([&] { first = misfit(l, true); }, [&] { second = misfit(l + h, false); });
  }
  // Where the first's start misfits, the walk stops there (the second is not counted).
  int solves = out.start_misfits ? 1 : 2;
  result.parameters["contrast_solves"] = solves;
  if (out.start_misfits) return out;
  const WalkedLeast walked = walkToLeast(
      [&](double at) {
        ++solves;
        return misfit(at, false);
      },
      l, first, second, h, below, above);
  l = walked.l;
  out.falls_below_band = walked.falling_at_below && below > lo + h / 2;
  // At an end within half a step of it: the walk's points are c0's steps of 2^(1/6), not the
  // range's, and can stop a hair inside an end (the noisy ground_blur15 without thresholds: at
  // 0.05002, where the motion had collapsed with c; the grid then 6.5 dB below the frame of the
  // hash field with normalised events, which the end hands it to).
  out.at_end = l < lo + h / 2 || l > hi - h / 2;
  result.parameters["contrast_solves"] = solves;
  out.contrast = {std::exp(l), std::exp(l) * ratio};
  return out;
}

}  // namespace evkit::benerf_detail

namespace evkit {

CountedContrast contrastFromCounts(const Observation& obs, const PinholeCamera& camera,
                                   const Trajectory& motion, const cv::Mat& inverse_depth,
                                   double ratio, const LogMapping& log) {
  // The path at kSearchViews + 1 times from the exposure's start to its end, both included.
  constexpr int kTimes = benerf_detail::kSearchViews + 1;
  const Frame& blurry = obs.blurry;
  const int W = blurry.image.cols, H = blurry.image.rows;
  const int64_t t0 = blurry.exposure_start_us, t1 = blurry.exposure_end_us;
  CountedContrast out{std::numeric_limits<double>::quiet_NaN(), 0.0};
  if (W < 2 || H < 2) return out;  // no bilinear stencil fits
  const size_t N = static_cast<size_t>(W) * H;
  const EventSpan span = obs.events.sliceTime(t0, t1);
  // The exposure's ON and OFF counts apart, where the ratio is to be found: over [t0, t1), as the
  // levels below.
  const bool find_ratio = !(ratio > 0);
  cv::Mat on_count, off_count;
  if (find_ratio) {
    on_count = cv::Mat::zeros(H, W, CV_64F);
    off_count = cv::Mat::zeros(H, W, CV_64F);
    for (size_t i = 0; i < span.size(); ++i) {
      if (span.x[i] >= W || span.y[i] >= H) continue;
      (span.p[i] > 0 ? on_count : off_count).at<double>(span.y[i], span.x[i]) += 1;
    }
  }
  cv::Mat grey;
  toGrey(blurry.image).convertTo(grey, CV_64F);
  cv::Mat log_blurry(H, W, CV_64F);
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x)
      log_blurry.at<double>(y, x) = log.logOf(std::max(0.0, grey.at<double>(y, x)));
  std::vector<Matrix3> rotations(kTimes);
  std::vector<Vector3> translations(kTimes);
  for (int k = 0; k < kTimes; ++k) {
    const SE3 pose = motion.poseAt(t0 + (t1 - t0) * k / (kTimes - 1));
    rotations[static_cast<size_t>(k)] = pose.rotationMatrix();
    translations[static_cast<size_t>(k)] = pose.translation();
  }
  // Bilinear within [0, W - 1] x [0, H - 1], which the paths kept stay inside.
  const auto at = [](const cv::Mat& image, const Eigen::Vector2d& q) {
    const int x0 = std::min(static_cast<int>(q.x()), image.cols - 2),
              y0 = std::min(static_cast<int>(q.y()), image.rows - 2);
    const double ax = q.x() - x0, ay = q.y() - y0;
    const double* a = image.ptr<double>(y0);
    const double* b = image.ptr<double>(y0 + 1);
    return (1 - ay) * ((1 - ax) * a[x0] + ax * a[x0 + 1]) +
           ay * ((1 - ax) * b[x0] + ax * b[x0 + 1]);
  };
  // Each pixel's path on the mid image, where it stays inside the frame, as float offsets from the
  // pixel (under 1e-4 px off at a path of 1,000 px): 155 MB at 1280 x 720, where the points in
  // double took 310.
  std::vector<Eigen::Vector2f> paths(N * kTimes);
  std::vector<uint8_t> inside(N, 0);
#pragma omp parallel for schedule(static)
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      const size_t pixel = static_cast<size_t>(y) * W + x;
      const Vector3 d = nerf::pixelDirection(camera, x, y);
      bool in = true;
      for (int k = 0; k < kTimes && in; ++k) {
        const Eigen::Vector2d q = pixel_grid_detail::reproject(
            camera, inverse_depth, x, y, rotations[static_cast<size_t>(k)] * d,
            translations[static_cast<size_t>(k)], nullptr);
        in = q.x() >= 0 && q.x() <= W - 1 && q.y() >= 0 && q.y() <= H - 1;
        paths[pixel * kTimes + static_cast<size_t>(k)] = (q - Eigen::Vector2d(x, y)).cast<float>();
      }
      inside[pixel] = in ? 1 : 0;
    }
  }
  // The sums of the regression of `along` averaged along the paths on the difference of `ends`
  // between the paths' ends; each row's, then the rows' in order: the same bits at any thread
  // count. The average stands for the blur's integral over the exposure, by the trapezoid rule at
  // the path's times (the ends half a step each): weighed alike, the ends counted a whole step and
  // the c came out high by about one part in the times' count (BENCHMARKS.md, "The counts as a
  // quadrature").
  struct Sums {
    double n = 0, sa = 0, sb = 0, saa = 0, sbb = 0, sab = 0;
  };
  // Each pixel whose path stays inside the frame, row by row: add(row's sums, x, y, point), with
  // point(k) where pixel (x, y) sees the mid-exposure image at the path's k-th time; the rows'
  // sums, each from `zero`, returned in order to be added so.
  const auto sumOverPaths = [&](const auto& zero, const auto& add) {
    std::vector<std::decay_t<decltype(zero)>> rows(static_cast<size_t>(H), zero);
#pragma omp parallel for schedule(static)
    for (int y = 0; y < H; ++y) {
      auto& row = rows[static_cast<size_t>(y)];
      for (int x = 0; x < W; ++x) {
        const size_t pixel = static_cast<size_t>(y) * W + x;
        if (!inside[pixel]) continue;
        const Eigen::Vector2f* path = &paths[pixel * kTimes];
        const Eigen::Vector2d here(x, y);
        add(row, x, y, [&](int k) { return here + path[k].cast<double>(); });
      }
    }
    return rows;
  };
  const auto regress = [&](const cv::Mat& along, const cv::Mat& ends, const cv::Mat& scale) {
    const auto rows = sumOverPaths(Sums{}, [&](Sums& row, int x, int y, const auto& point) {
      double averaged =
          benerf_detail::trapezoidMean(kTimes, [&](int k) { return at(along, point(k)); });
      double change = at(ends, point(kTimes - 1)) - at(ends, point(0));
      if (!scale.empty()) {
        const double w = 1.0 / scale.at<double>(y, x);
        averaged *= w;
        change *= w;
      }
      row.n += 1;
      row.sa += change;
      row.sb += averaged;
      row.saa += change * change;
      row.sbb += averaged * averaged;
      row.sab += change * averaged;
    });
    Sums all;
    for (const Sums& row : rows) {
      all.n += row.n;
      all.sa += row.sa;
      all.sb += row.sb;
      all.saa += row.saa;
      all.sbb += row.sbb;
      all.sab += row.sab;
    }
    return all;
  };
  // The ratio c_off / c_on where it was not given. Averaged along the paths, the ON counts b_on
  // and the OFF counts b_off meet the log change a between the paths' ends as a = c_on b_on -
  // c_off b_off, that is b_on = a / c_on + ratio b_off. Most of the counts' spread over the pixels
  // is texture passing by, up and down (ON and OFF counts in the ratio's proportion), so b_off is
  // mostly signal; the counts' noise pulls a regression's slope towards 0 all the same, b_on's on
  // b_off low and b_off's on b_on low the other way round. Both are fitted, each with an
  // intercept (noise events of either sign at one rate) and the log change, and the ratio is their
  // geometric mean, where the two pulls cancel to first order: the same ratio, inverted, with the
  // signs swapped. The two are also bounds on it (Frisch's, for errors in both variables): the
  // one pulled low, the inverse of the other pulled high, their product the squared partial
  // correlation, at most 1. Where the counts are mostly quantisation (smooth shading whose pixels
  // change by less than a threshold) the bounds are wide: 0.28-3.4 on the standard suite's
  // ground_blur15 along the motion registered at the truth, where a mean of 0.945 moved the
  // counts' c from 0.77 to 0.52 (the truth 0.2) and the grid then solved at 0.41. Where they hold
  // 1, the counts cannot tell the thresholds apart and the ratio is 1, as a sensor's nominal
  // setting and EDI's search have it (BENCHMARKS.md, "Two thresholds").
  const auto ratioFromCounts = [&](const cv::Mat& log_frame) {
    using Moments = Eigen::Matrix4d;  // of (1, a, b_on, b_off)
    const auto rows =
        sumOverPaths(Moments::Zero().eval(), [&](Moments& row, int, int, const auto& point) {
          const Eigen::Vector4d v(
              1.0, at(log_frame, point(kTimes - 1)) - at(log_frame, point(0)),
              benerf_detail::trapezoidMean(kTimes, [&](int k) { return at(on_count, point(k)); }),
              benerf_detail::trapezoidMean(kTimes, [&](int k) { return at(off_count, point(k)); }));
          row.noalias() += v * v.transpose();
        });
    Moments all = Moments::Zero();
    for (const Moments& row : rows) all += row;
    // The slope of column `on` on (1, a, column `off`), by the normal equations.
    const auto slope = [&](int on, int off) {
      const std::array<int, 3> x{0, 1, off};
      Eigen::Matrix3d xx;
      Eigen::Vector3d xy;
      for (int r = 0; r < 3; ++r) {
        for (int c = 0; c < 3; ++c) xx(r, c) = all(x[r], x[c]);
        xy(r) = all(x[r], on);
      }
      return xx.ldlt().solve(xy)(2);
    };
    const double on_on_off = slope(2, 3), off_on_on = slope(3, 2);
    if (!(on_on_off > 0 && off_on_on > 0)) return;
    out.ratio_low = on_on_off;
    out.ratio_high = 1 / off_on_on;
    out.ratio =
        out.ratio_low <= 1 && out.ratio_high >= 1 ? 1.0 : std::sqrt(out.ratio_low * out.ratio_high);
  };
  // Each pixel's net count (ON less `r` OFF) from the exposure's start to each of the path's
  // times, pixel by pixel (level[pixel * kTimes + k]): the events of each interval between them,
  // then added up. The last is the exposure's net count, and the others make EDI's frames for the
  // refinement of c and the correction of the ratio below. In float: exact for counts under 2^24
  // where the ratio is 1, to seven digits otherwise; a 1280 x 720 frame's levels take 77 MB, where
  // doubles for each time's ON, OFF and level took 464.
  std::vector<float> level;
  cv::Mat net(H, W, CV_64F);
  const auto fillLevels = [&](double r) {
    level.assign(N * kTimes, 0.0f);
    const float off_step = -static_cast<float>(r);
    for (size_t i = 0; i < span.size(); ++i) {
      const int k = 1 + static_cast<int>((span.t[i] - t0) * (kTimes - 1) / (t1 - t0));
      if (k < 1 || k >= kTimes || span.x[i] >= W || span.y[i] >= H) continue;
      const size_t pixel = static_cast<size_t>(span.y[i]) * W + span.x[i];
      level[pixel * kTimes + static_cast<size_t>(k)] += span.p[i] > 0 ? 1.0f : off_step;
    }
    for (size_t pixel = 0; pixel < N; ++pixel) {
      float* levels = &level[pixel * kTimes];
      for (int k = 1; k < kTimes; ++k) levels[k] += levels[k - 1];
      net.at<double>(static_cast<int>(pixel / W), static_cast<int>(pixel % W)) = levels[kTimes - 1];
    }
  };
  // EDI's frame at c over the exposure at one pixel, as its largest exponent c level_k (at least 0:
  // level_0 = 0) and the trapezoid's mean of exp(c level_k - top) below it: no overflow however
  // many events.
  struct Exposed {
    double top, mean;
  };
  // f(y, x, the pixel's levels, its Exposed) at every pixel, the rows in parallel.
  const auto eachPixelExposed = [&](double c, const auto& f) {
#pragma omp parallel for schedule(static)
    for (int y = 0; y < H; ++y)
      for (int x = 0; x < W; ++x) {
        const float* levels = &level[(static_cast<size_t>(y) * W + x) * kTimes];
        Exposed e{0.0, 0.0};
        for (int k = 1; k < kTimes; ++k) e.top = std::max(e.top, c * levels[k]);
        e.mean = benerf_detail::trapezoidMean(
            kTimes, [&](int k) { return std::exp(c * levels[k] - e.top); });
        f(y, x, levels, e);
      }
  };
  // The blurry frame in linear intensity, and EDI's change over the exposure at each pixel (c's
  // fixed point below), made once for every round of the ratio.
  cv::Mat linear(H, W, CV_64F), change(H, W, CV_64F);
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) linear.at<double>(y, x) = std::exp(log_blurry.at<double>(y, x));
  // c (out.c, out.correlation) from the levels: first in the log, then in linear intensity.
  const auto fitContrast = [&]() {
    out.c = std::numeric_limits<double>::quiet_NaN();
    const Sums sums = regress(net, log_blurry, cv::Mat());
    if (sums.sab > 0) out.c = sums.saa / sums.sab;
    const double n = std::max(sums.n, 1.0);
    const double va = sums.saa - sums.sa * sums.sa / n, vb = sums.sbb - sums.sb * sums.sb / n;
    out.correlation =
        va > 0 && vb > 0 ? (sums.sab - sums.sa * sums.sb / n) / std::sqrt(va * vb) : 0.0;
    if (!(out.c > 0)) return;
    // Then in linear intensity, where the blur's identity holds without the log's curvature: EDI's
    // frames at c (each pixel's level from its own events) change from the exposure's start to its
    // end by L_end - L_start = L_start (exp(c n) - 1), and averaged along each path that change is
    // the blurry frame at the path's end less that at its start. The averaged change over c,
    // against the frame's difference, has the slope 1 / c: a fixed point from the log's c, each
    // round's EDI frames at the c of the round before, until c moves by under 1e-4 of itself. Both
    // sides are taken relative to the pixel's own blurry value, so that each pixel weighs as in the
    // log (in linear units the bright pixels of a backdrop that barely moves, whose few events each
    // stand for up to a threshold, outweighed the rest: a rocket before its backdrop 0.377 against
    // 0.333). The events' noise is again in the regressand. The log of a blur is not the blur of
    // the log: where bright content smears into dark (stars behind a rocket) the log's c came out
    // at 0.29-0.30 for the truth's 0.2, along the true motion too (0.21 and 0.19 from the blur of
    // the true frame's log), and the fixed point at 0.22.
    for (int round = 0; round < 8; ++round) {
      const double c = out.c;
      // L_start (exp(c n) - 1) / c with L_start = B / mean_k exp(c level_k) (the trapezoid's mean).
      eachPixelExposed(c, [&](int y, int x, const float* levels, const Exposed& e) {
        const double end = c * levels[kTimes - 1];
        change.at<double>(y, x) =
            linear.at<double>(y, x) * (std::exp(end - e.top) - std::exp(-e.top)) / (e.mean * c);
      });
      const Sums l = regress(change, linear, linear);
      if (!(l.sab > 0)) break;
      out.c = l.saa / l.sab;
      if (std::abs(out.c / c - 1) < 1e-4) break;
    }
  };
  if (!find_ratio) {
    fillLevels(ratio);
    fitContrast();
    return out;
  }
  // The ratio, then c at it, then the ratio again from the blurry frame's log less each pixel's
  // Jensen gap at that c and ratio, until the ratio moves by under 1e-3 of itself. The counts
  // averaged along a path meet the blur of the log between its ends, the blurry frame's log is the
  // log of the blur, and the two differ by log mean_t exp(c n(t)) - c mean_t n(t) at each pixel, n
  // its net count from the exposure's start: EDI's frame's spread over the exposure, from the
  // pixel's own events. It is largest where a few bright moments dominate a pixel's blur, which
  // the content passing up and down makes unlike between ON and OFF counts: along the motion
  // registered at the truth, half-size cat_bricks and hubble_rocket (equal thresholds) came out
  // at 1.06-1.08 from the log of the blur and at 1.02-1.04 from the sharp frames' blur of the log
  // (BENCHMARKS.md, "Two thresholds"). Where the bounds hold 1 the counts cannot tell the
  // thresholds apart, and there is nothing to correct: the gaps come from a c that such counts do
  // not tell either (the standard suite's rgbd_blur15, smooth shading, counts' c 0.35 for 0.2: its
  // gaps at that c moved the bounds from 0.64-5.7 to 1.04-4.5 and the ratio from 1 to 2.16).
  cv::Mat log_frame = log_blurry, corrected;
  out.ratio = std::numeric_limits<double>::quiet_NaN();
  for (int round = 0; round < 4; ++round) {
    const double before = out.ratio;
    ratioFromCounts(log_frame);
    if (!(out.ratio > 0)) {
      out.c = std::numeric_limits<double>::quiet_NaN();
      return out;
    }
    fillLevels(out.ratio);
    fitContrast();
    if (!(out.c > 0) || out.ratio == 1.0 || std::abs(out.ratio / before - 1) < 1e-3) break;
    corrected.create(H, W, CV_64F);
    const double c = out.c;
    eachPixelExposed(c, [&](int y, int x, const float* levels, const Exposed& e) {
      corrected.at<double>(y, x) =
          log_blurry.at<double>(y, x) -
          (e.top + std::log(e.mean) -
           c * benerf_detail::trapezoidMean(kTimes, [&](int k) { return double{levels[k]}; }));
    });
    log_frame = corrected;
  }
  return out;
}

}  // namespace evkit
