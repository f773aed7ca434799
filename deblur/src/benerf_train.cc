// BeNeRF's training: the start (blur length, thresholds, views, the knots from the events), the
// optional prefit, the schedule and the wall-time budget, the final renders and the summary.

#include <omp.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <limits>
#include <map>
#include <numbers>
#include <opencv2/imgproc.hpp>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "benerf_checkpoint.h"
#include "benerf_common.h"
#include "evkit/base/error.h"
#include "evkit/deblur/benerf.h"
#include "evkit/deblur/cores.h"
#include "evkit/deblur/edi.h"
#include "evkit/deblur/metrics.h"
#include "evkit/deblur/pixel_grid.h"
#include "evkit/nerf/adam.h"
#include "evkit/spline/fit.h"
#include "pixel_grid_start.h"

namespace evkit {

using benerf_detail::Checkpoint;
using benerf_detail::contrastFromSolves;
using benerf_detail::ediMidFrame;
using benerf_detail::kCountsBand;
using benerf_detail::kHashBlur;
using benerf_detail::kLeastContrast;
using benerf_detail::kMostContrast;
using benerf_detail::kMostCountsFollow;
using benerf_detail::readCheckpoint;
using benerf_detail::secondsSince;
using benerf_detail::SolvedContrast;
using benerf_detail::StartFit;
using benerf_detail::startFit;
using benerf_detail::supportedEvents;
using benerf_detail::toFloat;
using benerf_detail::writeCheckpoint;

namespace {

using Clock = std::chrono::steady_clock;

// The ground-truth frame nearest to mid-exposure, when there is one at the camera's size.
const Frame* midGroundTruth(const Observation& obs) {
  const Frame* best = nullptr;
  const int64_t mid = obs.blurry.midExposure();
  for (const Frame& g : obs.gt_frames) {
    if (g.image.size() != obs.blurry.image.size() ||
        g.image.channels() != obs.blurry.image.channels())
      continue;
    if (!best || std::llabs(g.exposure_start_us - mid) < std::llabs(best->exposure_start_us - mid))
      best = &g;
  }
  return best;
}

// Sets OpenMP's thread count for one run and restores it afterwards: `threads`, or at
// kThreadsFromLoad the cores that other programs leave idle (a step waits for its slowest thread,
// and a thread that shares its core with a busy program holds back all): measured over kLoadWindow
// before the run, then again at most every kFollowEvery between the training's steps (follow), so
// that a load that comes or goes during the run moves the count (the figures are the same at any
// count). The count the run starts on, and the load measured, go to the result's parameters, and
// each change of the count as `thread_changes` and `threads_last`.
class ThreadScope {
 public:
  ThreadScope(int threads, DeblurResult& result) : saved_(omp_get_max_threads()), result_(result) {
    if (threads == kThreadsFromLoad) {
      threads = 0;
      follower_.emplace();
      std::this_thread::sleep_for(kLoadWindow);
      if (const std::optional<CoreLoad> load = follower_->measure(kLoadWindow)) {
        threads = threadsForLoad(*load, saved_);
        result.parameters["busy_cores_elsewhere"] = load->busy_elsewhere;
        result.parameters["thread_changes"] = 0;
      } else {
        follower_.reset();  // nothing to follow (not Linux)
      }
    }
    if (threads > 0) omp_set_num_threads(threads);
    result.parameters["threads"] = omp_get_max_threads();
  }
  ~ThreadScope() { omp_set_num_threads(saved_); }
  ThreadScope(const ThreadScope&) = delete;
  ThreadScope& operator=(const ThreadScope&) = delete;

  bool following() const { return follower_.has_value(); }
  // At kThreadsFromLoad, the count for the load since the last measurement, once kFollowEvery has
  // passed since it.
  void follow() {
    if (!follower_) return;
    const std::optional<CoreLoad> load = follower_->measure(kFollowEvery);
    if (!load) return;
    const int threads = threadsForLoad(*load, saved_);
    if (threads == omp_get_max_threads()) return;
    omp_set_num_threads(threads);
    result_.parameters["thread_changes"] += 1;
    result_.parameters["threads_last"] = threads;
  }

 private:
  // Ten of /proc/stat's ticks: the load to a tenth of a core, 1% of a frame at `fast`.
  static constexpr std::chrono::milliseconds kLoadWindow{100}, kFollowEvery{1000};
  int saved_;
  DeblurResult& result_;
  std::optional<LoadFollower> follower_;
};

// What the run starts from: the thresholds (given, from contrast.txt, or estimated by EDI's search
// inside its range), the number of virtual views and the measured blur length.
struct Start {
  BenerfOptions options;
  int views = 0;
  double blur_px = 0;
  ExposureMotion motion;          // init=frames
  PinholeCamera camera;           // given, assumed, or estimated (calibrateFromLatentFrames)
  bool camera_estimated = false;  // `camera` replaces the observation's assumed one
  bool contrast_given = false;    // by the settings or contrast.txt, not estimated
  BlurMeasurement measured;       // EDI's pass: the blur length and, without thresholds, its search
  double registered_away_c = 0;   // > 0: `motion` registered at this c, away from EDI's
};

// The registration's bar on its misfit at the start: beyond a pixel only with the thresholds known
// (MisfitBar; without them, at the c of the counts, runPixelGrid).
MisfitBar misfitBar(bool contrast_given) {
  return contrast_given ? MisfitBar::kUnlessRepeated : MisfitBar::kOnePixel;
}

// The registration's figures in the summary.
void reportMotion(const ExposureMotion& motion, DeblurResult& result) {
  result.parameters["representation_depth"] = motion.depth ? 1 : 0;
  result.parameters["parallax_px"] = motion.parallax_px;
  result.parameters["depth_agreement"] = motion.depth_agreement;
  result.parameters["depth_agreement_tiles"] = motion.depth_agreement_tiles;
  result.parameters["motion_residual_rotation_px"] = motion.residual_rotation_px;
  result.parameters["motion_residual_plane_px"] = motion.residual_plane_px;
  result.parameters["motion_residual_depth_px"] = motion.residual_depth_px;
  result.parameters["motion_residual_pixels_px"] = motion.residual_pixels_px;
  result.parameters["representation_pixel_depth"] = motion.pixel_depth ? 1 : 0;
  result.parameters["motion_tracks"] = motion.tracks;
  result.parameters["motion_tracks_without_events"] = motion.tracks_without_events;
  if (motion.tracks_few_events > 0)
    result.parameters["motion_tracks_few_events"] = motion.tracks_few_events;
  if (motion.repeated_share >= 0)
    result.parameters["motion_repeated_share"] = motion.repeated_share;
  if (motion.near_edges)
    result.parameters["motion_residual_near_edges_px"] = motion.near_edges->residual_px;
  else
    result.parameters.erase("motion_residual_near_edges_px");  // a registration before this one's
}

Start prepare(const Observation& obs, const BenerfOptions& given, DeblurResult& result) {
  Start s{given, given.virtual_views, 0, {}, obs.camera, false, false, {}, 0};
  BenerfOptions& o = s.options;
  o.contrast = resolveContrast(o.contrast, obs);
  s.contrast_given = o.contrast.has_value();
  const bool estimate =
      !o.contrast && o.estimate_contrast && o.event_form == BenerfOptions::EventForm::kAuto;
  if (s.views <= 0 || o.init == BenerfOptions::Init::kEvents || estimate) {
    const BlurMeasurement m = measureBlur(obs, o.contrast, o.log);
    s.measured = m;
    s.blur_px = m.blur_px;
    result.parameters["blur_px_measured"] = s.blur_px;
    if (estimate && m.inside) {
      o.contrast = Contrast{m.c_on, m.c_off};
      result.parameters["contrast_estimated"] = m.c_on;
    }
  }
  if (s.views <= 0) s.views = virtualViewsFor(s.blur_px);
  if (o.init == BenerfOptions::Init::kFrames || o.field == BenerfOptions::FieldKind::kPixels) {
    const auto registration_start = Clock::now();
    PinholeCamera camera = obs.camera.withSize(obs.blurry.image.cols, obs.blurry.image.rows);
    const MisfitBar bar = misfitBar(s.contrast_given);
    if (obs.camera_assumed && o.calibrate && o.field == BenerfOptions::FieldKind::kPixels) {
      CalibratedMotion c =
          calibrateFromLatentFrames(obs, camera, o.contrast, o.log, kScoredIntervals, bar);
      camera = s.camera = c.camera;
      s.camera_estimated = c.estimated;
      s.motion = std::move(c.motion);
      result.parameters["camera_estimated"] = c.estimated ? 1 : 0;
      result.parameters["camera_residual_assumed_px"] = c.residual_assumed_px;
      result.parameters["cameras_tried"] = c.cameras_tried;
    } else {
      s.motion =
          motionFromLatentFrames(obs, camera, o.contrast, o.log, true, kScoredIntervals, bar);
    }
    // The pixel grid without thresholds: where the registration at EDI's searched c fails, at c's
    // away from it, the first that registers; runPixelGrid refines the c from there.
    if (s.motion.poses.empty() && !s.contrast_given &&
        o.field == BenerfOptions::FieldKind::kPixels && s.measured.searched) {
      double registered_c = 0;
      s.motion = registerAwayFromSearch(
          s.measured, s.motion,
          [&](const Contrast& c) { return motionFromLatentFrames(obs, camera, c, o.log); },
          &registered_c);
      s.registered_away_c = registered_c;
      if (registered_c > 0) result.parameters["contrast_registered"] = registered_c;
    }
    reportMotion(s.motion, result);
    result.timings_s["registration"] = secondsSince(registration_start);
  }
  return s;
}

// The knots fitted to a constant rotation through identity at mid-exposure, found from the events
// (rotationFromEvents), each then moved by its random jitter.
void initialiseFromEvents(const Observation& obs, BenerfProblem<float>& problem, double blur_px,
                          DeblurResult& result) {
  const Vector3 omega = rotationFromEvents(obs, problem.camera(), blur_px);
  Trajectory& trajectory = problem.trajectory();
  std::vector<StampedPose> poses;
  for (int k = 0; k <= 20; ++k) {
    const double s = k / 20.0;
    const int64_t t =
        trajectory.beginUs() +
        std::llround(s * static_cast<double>(trajectory.endUs() - trajectory.beginUs()));
    poses.push_back({t, SE3(expSO3((s - 0.5) * omega), Vector3::Zero())});
  }
  const Trajectory fitted =
      fitTrajectory(trajectory.kind(), static_cast<int>(trajectory.knots().size()),
                    trajectory.beginUs(), trajectory.endUs(), poses);
  for (size_t k = 0; k < trajectory.knots().size(); ++k)
    trajectory.knots()[k] = fitted.knots()[k] * trajectory.knots()[k];
  result.parameters["initial_rotation_deg"] = omega.norm() * 180 / std::numbers::pi;
  result.parameters["initial_from_events"] = 1;
}

// The knots fitted to the motion registered between EDI's latent frames (poses relative to
// mid-exposure), each then moved by its random jitter; without poses (too few tracks, or a rigid
// camera that does not explain them), the events' rotation.
void initialiseFromFrames(const Observation& obs, BenerfProblem<float>& problem,
                          const ExposureMotion& motion, double blur_px, DeblurResult& result) {
  result.parameters["motion_from_frames"] = motion.poses.empty() ? 0 : 1;
  if (motion.poses.empty()) {
    initialiseFromEvents(obs, problem, blur_px, result);
    return;
  }
  Trajectory& trajectory = problem.trajectory();
  const Trajectory fitted =
      fitTrajectory(trajectory.kind(), static_cast<int>(trajectory.knots().size()),
                    trajectory.beginUs(), trajectory.endUs(), motion.poses);
  for (size_t k = 0; k < trajectory.knots().size(); ++k)
    trajectory.knots()[k] = fitted.knots()[k] * trajectory.knots()[k];
  const SE3 over = motion.poses.front().pose.inverse() * motion.poses.back().pose;
  result.parameters["initial_rotation_deg"] =
      logSO3(over.rotation()).norm() * 180 / std::numbers::pi;
  result.parameters["initial_translation"] = over.translation().norm();
  result.parameters["initial_from_events"] = 0;
}

// The two optimisers (the field's; the knots' as right-perturbation steps), their one learning-rate
// schedule over the prefit's and the training's steps, and one step of both.
class Optimisers {
 public:
  Optimisers(BenerfProblem<float>& problem, const BenerfOptions& o)
      : problem_(problem),
        options_(o),
        knot_values_(6 * problem.trajectory().knots().size()),
        knot_step_(Eigen::VectorXd::Zero(static_cast<Eigen::Index>(knot_values_))),
        knot_gradient_(knot_step_),
        field_(problem.field().parameters(), nerf::AdamOptions{.learning_rate = o.field_lr}),
        knots_({nerf::ParameterBlock<double>{knot_step_.data(), knot_gradient_.data(), knot_values_,
                                             nullptr, 1}},
               nerf::AdamOptions{.learning_rate = o.knot_lr, .epsilon = 1e-12}) {}

  void setSchedule(int iterations) {
    field_.options().decay_rate = knots_.options().decay_rate = options_.lr_final;
    field_.options().decay_steps = knots_.options().decay_steps =
        std::max(1, options_.prefit + iterations);
  }

  // One step of both; a non-finite loss or gradient is a loud error naming the step.
  BenerfProblem<float>::Loss step(const BenerfProblem<float>::Batch& batch, const char* step_name,
                                  int step) {
    const auto loss = problem_.evaluate(batch, &knot_gradient_);
    if (!std::isfinite(loss.total) || !knot_gradient_.allFinite()) {
      throw Error("benerf: the loss or its gradient became " +
                  std::string(std::isfinite(loss.total) ? "non-finite" : "NaN/Inf") + " at " +
                  step_name + " " + std::to_string(step) + " (blur term " +
                  std::to_string(loss.blur) + ", event term " + std::to_string(loss.event) + ")");
    }
    field_.step();
    knot_step_.setZero();
    knots_.step();
    problem_.trajectory().applyKnotSteps(knot_step_);
    return loss;
  }

  nerf::Adam<float>& field() { return field_; }
  nerf::Adam<double>& knots() { return knots_; }

 private:
  BenerfProblem<float>& problem_;
  const BenerfOptions& options_;
  size_t knot_values_;
  Eigen::VectorXd knot_step_, knot_gradient_;
  nerf::Adam<float> field_;
  nerf::Adam<double> knots_;
};

// The field and knots fitted to EDI's latent frames at the views' times (every band open, no event
// term), with the training's optimisers, so that their moments carry over.
void prefit(const Observation& obs, BenerfProblem<float>& problem, Optimisers& optimisers,
            const BenerfOptions& o, DeblurResult& result) {
  const auto start = Clock::now();
  const Trajectory& trajectory = problem.trajectory();
  DeblurRequest edi_request;
  for (int k = 0; k < problem.virtualViews(); ++k) {
    edi_request.times_us.push_back(
        trajectory.beginUs() +
        std::llround(problem.viewTime(k) *
                     static_cast<double>(trajectory.endUs() - trajectory.beginUs())));
  }
  std::vector<cv::Mat> targets;
  for (const Frame& f : EdiDeblurrer{EdiOptions{}}.run(obs, edi_request).frames)
    targets.push_back(toFloat(f.image));
  problem.setViewTargets(std::move(targets));
  std::mt19937_64 rng(o.seed + 1);
  for (int it = 0; it < o.prefit; ++it) {
    auto batch = problem.sampleBatch(rng);
    batch.event_pixels.clear();
    batch.window_begin.clear();
    batch.window_end.clear();
    const auto loss = optimisers.step(batch, "prefit iteration", it);
    if (it + 1 == o.prefit) result.parameters["prefit_final_term"] = loss.blur;
  }
  problem.setViewTargets({});
  result.timings_s["prefit"] = secondsSince(start);
}

// The training loop with its curve, the training-PSNR renders, the wall-time budget and the
// checkpoints.
class Training {
 public:
  Training(const Observation& obs, const DeblurRequest& request, BenerfProblem<float>& problem,
           Optimisers& optimisers, const BenerfOptions& o, Clock::time_point run_start)
      : obs_(obs),
        request_(request),
        problem_(problem),
        optimisers_(optimisers),
        o_(o),
        run_start_(run_start) {}

  // Runs iterations [first, iterations) (fewer when the budget or stop_after says so); returns the
  // iteration count it ended with.
  int run(int first, int iterations, std::mt19937_64& rng, DeblurResult& result);

  double lastBlurTerm() const { return last_blur_; }
  double lastEventTerm() const { return last_event_; }

 private:
  void recordCurve(int done, int iterations, DeblurResult& result);
  void fitBudget(int done, int& iterations);

  const Observation& obs_;
  const DeblurRequest& request_;
  BenerfProblem<float>& problem_;
  Optimisers& optimisers_;
  const BenerfOptions& o_;
  Clock::time_point run_start_, train_start_;
  const Frame* gt_ = nullptr;
  int psnr_every_ = 0;
  double curve_seconds_ = 0;  // spent on the training-PSNR renders
  double loss_sum_ = 0, blur_sum_ = 0, event_sum_ = 0, last_blur_ = 0, last_event_ = 0;
  int loss_count_ = 0;
};

int Training::run(int first, int iterations, std::mt19937_64& rng, DeblurResult& result) {
  gt_ = midGroundTruth(obs_);
  psnr_every_ = gt_ ? std::max(1, iterations / 10) : 0;
  train_start_ = Clock::now();
  const int bands = problem_.field().bands();
  for (int it = first; it < iterations; ++it) {
    if (o_.coarse_to_fine > 0) {
      const double opened =
          std::clamp(static_cast<double>(it) / (o_.coarse_to_fine * iterations), 0.0, 1.0);
      problem_.field().setBandLimit(1 + (bands - 2) * opened);
    }
    const auto loss = optimisers_.step(problem_.sampleBatch(rng), "iteration", it);
    loss_sum_ += loss.total;
    blur_sum_ += loss.blur;
    event_sum_ += loss.event;
    ++loss_count_;
    const int done = it + 1;
    recordCurve(done, iterations, result);
    if (o_.budget_seconds > 0 && done == first + 20) fitBudget(done, iterations);
    const bool stop = o_.stop_after > 0 && done >= o_.stop_after;
    if (!o_.checkpoint.empty() && (done % o_.checkpoint_every == 0 || done == iterations || stop)) {
      writeCheckpoint(o_.checkpoint, Checkpoint{done, iterations, problem_.virtualViews()},
                      problem_.field(), problem_.trajectory(), optimisers_.field(),
                      optimisers_.knots(), rng);
    }
    if (stop) break;
  }
  result.timings_s["train"] = secondsSince(train_start_);
  problem_.field().setBandLimit(bands);
  return iterations;
}

void Training::recordCurve(int done, int iterations, DeblurResult& result) {
  if (done % o_.curve_every == 0 || done == iterations) {
    result.curve.emplace_back(done, loss_sum_ / loss_count_);
    if (request_.progress) request_.progress(done, iterations, loss_sum_ / loss_count_);
    last_blur_ = blur_sum_ / loss_count_;
    last_event_ = event_sum_ / loss_count_;
    loss_sum_ = blur_sum_ = event_sum_ = 0;
    loss_count_ = 0;
  }
  if (psnr_every_ > 0 && (done % psnr_every_ == 0 || done == iterations)) {
    const auto start = Clock::now();
    result.curve_psnr.emplace_back(done,
                                   psnr(problem_.render(obs_.blurry.midExposure()), gt_->image));
    curve_seconds_ += secondsSince(start);
  }
}

// A wall-time budget: after a few iterations, the count that fits with the renders still to come
// (the schedule follows); the training-PSNR curve gets at most a quarter of what is left.
void Training::fitBudget(int done, int& iterations) {
  const int64_t mid = obs_.blurry.midExposure();
  const auto& times = request_.times_us;
  const bool mid_requested = std::find(times.begin(), times.end(), mid) != times.end();
  const int final_renders = static_cast<int>(times.size()) + (mid_requested ? 0 : 1);
  const double per_iteration = (secondsSince(train_start_) - curve_seconds_) / 20;
  const double render_seconds = problem_.renderSeconds();
  double left =
      o_.budget_seconds * 0.95 - secondsSince(run_start_) - final_renders * render_seconds;
  const int curve_renders =
      gt_ ? std::min(10, static_cast<int>(0.25 * std::max(0.0, left) / render_seconds)) : 0;
  left -= curve_renders * render_seconds;
  iterations = std::max(done + 1, static_cast<int>(left / per_iteration) + done);
  optimisers_.setSchedule(iterations);
  psnr_every_ = curve_renders > 0 ? std::max(1, iterations / curve_renders) : 0;
}

// The requested frames, the mid-exposure disparity (an extra render unless mid-exposure is asked
// for) and the trajectory over the exposure.
void renderResults(const Observation& obs, const DeblurRequest& request,
                   BenerfProblem<float>& problem, DeblurResult& result) {
  const auto start = Clock::now();
  const int64_t mid = obs.blurry.midExposure();
  const bool mid_requested =
      std::find(request.times_us.begin(), request.times_us.end(), mid) != request.times_us.end();
  for (int64_t t : request.times_us) {
    Frame f;
    f.image = problem.render(t, t == mid ? &result.disparity : nullptr);
    f.exposure_start_us = f.exposure_end_us = t;
    f.bit_depth = obs.blurry.bit_depth;
    result.frames.push_back(std::move(f));
  }
  if (!mid_requested) problem.render(mid, &result.disparity);
  result.timings_s["render"] = secondsSince(start);
  std::vector<StampedPose> trajectory;
  const int64_t t0 = obs.blurry.exposure_start_us, t1 = obs.blurry.exposure_end_us;
  for (int k = 0; k <= 100; ++k) {
    const int64_t t = t0 + (t1 - t0) * k / 100;
    trajectory.push_back({t, problem.trajectory().poseAt(t)});
  }
  result.trajectory = std::move(trajectory);
}

void summarise(BenerfProblem<float>& problem, const BenerfOptions& o, int iterations,
               const Training& training, DeblurResult& result) {
  size_t parameters = 0;
  for (const auto& b : problem.field().parameters()) parameters += b.size;
  const int views = problem.virtualViews();
  result.parameters["iterations"] = iterations;
  result.parameters["virtual_views"] = views;
  result.parameters["field_parameters"] = static_cast<double>(parameters);
  result.parameters["events"] = static_cast<double>(problem.eventsInExposure());
  result.parameters["samples_per_ray"] = o.samples;
  result.parameters["beta"] = problem.beta();
  result.parameters["blur_weight"] = problem.blurWeight();
  result.parameters["events_normalised"] = problem.normalisedEvents() ? 1.0 : 0.0;
  result.parameters["rays_per_step"] = std::max(1, o.blur_rays / views) * views + 2 * o.event_rays;
  if (result.curve.empty()) return;
  result.parameters["final_loss"] = result.curve.back().second;
  // The two terms over the last curve interval: how well the model explains the blurry frame (as a
  // PSNR of the re-blurred renders against it) and the events.
  const double last_blur = training.lastBlurTerm();
  result.parameters["final_blur_term"] = last_blur;
  result.parameters["final_event_term"] = training.lastEventTerm();
  if (last_blur > 0) result.parameters["blur_fit_psnr"] = -10 * std::log10(last_blur);
}

// The contrast at which the grid's beta holds (the suites' C, where it was measured).
constexpr double kBetaContrast = 0.2;

// The fewest knots the grid's trajectory may take from its registered poses; at most two fewer
// than the poses, so that each count is still determined with one pose left out and another to
// spare (9 poses: 7 knots; 17: 15).
constexpr int kMinKnots = 4;
// The count from which nine registered poses no longer settle the knots: within one of the most
// they determine (7), each fit with one pose left out has a pose or two to spare. On shakes that
// turn four times (8 knots) nine poses chose 6 and seventeen 8 (planes: 23.05 -> 34.71 dB, EDI
// 31.91; BENCHMARKS.md, "A motion that turns").
constexpr int kTurningKnots = 6;
// From 17 poses the folds' neighbours are 1/16 of the exposure away and their errors correlated
// (each time's flows start from its inner neighbour's), so the standard error understates the
// spread and the one-standard-error rule took 8-10 knots on smooth shakes whose counts differed by
// hundredths of a pixel (a 6-knot shake: 42.94 dB with 10, 43.58 with the 6 of nine poses). A count
// within a tenth of a pixel of the least held-out RMS qualifies too: less than the grid's
// half-pixel cells resolve.
constexpr double kDenseKnotTolerancePx = 0.1;

// The motion's refinement from the solved image (BenerfOptions::motion_rounds): its
// Levenberg-Marquardt steps (on cat_bricks_blur30 3 gave what 6 did, 40.56 against 40.54 dB, in
// 1.3 s less), and the convergence at which the solves before the last stop (BENCHMARKS.md, "The
// motion again from the solved image": at `fast`'s 3e-3 the two solves took 16 more steps than
// one on the natural suite, 45% more time).
constexpr int kRoundMotionSteps = 3;
constexpr double kRoundConverged = 1e-2;

// One step of the grid's inverse depth from the solved image (BenerfOptions::depth_steps): a
// Gauss-Newton step of the loss in it, over 9 x 9 pixels of one surface, each pixel's sample moved
// by at most half a pixel (PixelGridProblem::refinedInverseDepth), kept where it lowers the grid's
// loss at that image. Both sides are rebuilt, on the refined depth and on the same depth, the image
// carried over (PixelGridProblem::carriedFrom): the problem in hand took its views from the motion
// before its refinement. True where the step was kept (the problem and x then on the new depth).
constexpr int kDepthWindowRadius = 4;

bool stepDepth(std::optional<PixelGridProblem>& problem, std::vector<double>& x,
               const Observation& obs, const PinholeCamera& camera, const Contrast& contrast,
               const PixelGridOptions& po) {
  const cv::Mat refined = problem->refinedInverseDepth(x, kDepthWindowRadius);
  PixelGridProblem same(obs, camera, problem->motion(), problem->inverseDepth(), contrast, po);
  PixelGridProblem next(obs, camera, problem->motion(), refined, contrast, po);
  std::vector<double> next_x = next.carriedFrom(*problem, x);
  if (!(next.evaluate(next_x, nullptr) < same.evaluate(same.carriedFrom(*problem, x), nullptr)))
    return false;
  problem = std::move(next);
  x = std::move(next_x);
  return true;
}

// The smoothness candidates, in the order tried: PixelGridOptions' default first.
constexpr std::array<double, 3> kSmoothness{0.01, 0.03, 0.1};

// The grid's smoothness (BenerfOptions::smooth): each candidate's solve from x, with a quarter of
// the pixels' events held out, scored by the held-out pixels' comparisons with mid-exposure; the
// candidates in turn while the score falls. Each solve takes a quarter of the main solve's steps
// (at half, every choice on the four suites was the same but one of 2%), and stops at the
// budget's deadline.
double chooseSmoothness(const PixelGridProblem& problem, const std::vector<double>& x, int steps,
                        Clock::time_point deadline, DeblurResult& result) {
  PixelGridProblem held = problem;
  held.holdOutEvents();
  const int held_steps = std::max(10, steps / 4);
  double best = std::numeric_limits<double>::infinity(), chosen = kSmoothness.front();
  for (const double smoothness : kSmoothness) {
    held.setSmoothness(smoothness);
    std::vector<double> trial = x;
    held.solve(trial, held_steps, nullptr, deadline);
    const double score = held.heldOutEventTerm(trial);
    char name[32];
    std::snprintf(name, sizeof name, "held_out_events_%g", smoothness);
    result.parameters[name] = score;
    if (!(score < best)) break;
    best = score;
    chosen = smoothness;
  }
  return chosen;
}

// The squared error (px^2) of a predicted camera pose against a registered one, as the image sees
// it: the mean over a 5 x 4 grid of pixels, each at infinity and at the registration's nearest
// depth (inverse depth 1 / 1.5), of the squared distance between where the two poses put it. In
// pose space the registration's split between rotation and translation is noisy where the image
// motion is not (a translation mimics a rotation).
HeldOutError imageMotionError(const PinholeCamera& camera) {
  std::vector<Vector3> bearings;
  for (int j = 0; j < 4; ++j) {
    for (int i = 0; i < 5; ++i) {
      bearings.push_back(nerf::pixelDirection(camera, (i + 0.5) * camera.width / 5.0,
                                              (j + 0.5) * camera.height / 4.0));
    }
  }
  return [camera, bearings](const SE3& predicted, const SE3& pose) {
    double sum = 0;
    int count = 0;
    for (const Vector3& b : bearings) {
      for (const double rho : {0.0, 1 / 1.5}) {
        // The point b / rho of the mid-exposure frame in each camera, scaled by rho.
        const Vector3 in_a = predicted.rotation().conjugate() * (b - rho * predicted.translation());
        const Vector3 in_b = pose.rotation().conjugate() * (b - rho * pose.translation());
        if (in_a.z() <= 1e-6 || in_b.z() <= 1e-6) continue;
        sum += (nerf::projectPoint(camera, in_a) - nerf::projectPoint(camera, in_b)).squaredNorm();
        ++count;
      }
    }
    return count ? sum / count : 0.0;
  };
}

// The pixel-grid scene (pixel_grid.cc) on the registered motion (the caller runs it only where the
// registration gave one), the image found from EDI's mid-exposure frame. Without thresholds it
// declines (returns false, nothing rendered) where the c it finds is at an end of its range: there
// the motion registered at a small c has collapsed with it (EDI's frames barely move, a short
// motion and the blurry frame itself explain the blur), which happens on smooth or weakly textured
// scenes, and the hash field with L2-normalised events, which need no c, does better. It declines
// too where it would keep its start (EDI's frame) at a blur of kHashBlur or more.
bool runPixelGrid(const Observation& given, const DeblurRequest& request, const Start& s,
                  Clock::time_point start, DeblurResult& result) {
  const BenerfOptions& o = s.options;
  // Why it declines, for the account (run).
  const auto decline = [&result](const char* why) {
    result.account = std::string("the pixel grid declined: ") + why;
    return false;
  };
  const PinholeCamera camera =
      given.camera.withSize(given.blurry.image.cols, given.blurry.image.rows);
  const int64_t t0 = given.blurry.exposure_start_us, t1 = given.blurry.exposure_end_us;
  // The trajectory through the registered poses: `knots` where given, else the fewest that predict
  // each pose left out about as well as the best count (within one standard error): a motion that
  // turns within the exposure needs more than one cubic segment (BENCHMARKS.md, "A motion that
  // turns").
  const auto fit = [&](const std::vector<StampedPose>& poses) {
    int knots = o.knots;
    if (knots <= 0) {
      const int most = static_cast<int>(poses.size()) - 2;
      const double tolerance =
          static_cast<int>(poses.size()) > kScoredIntervals + 1 ? kDenseKnotTolerancePx : 0;
      const KnotChoice choice = knotsByLeaveOneOut(o.trajectory, kMinKnots, most, t0, t1, poses,
                                                   imageMotionError(camera), {}, tolerance);
      knots = choice.knots;
      for (size_t i = 0; i < choice.held_out_rms.size(); ++i)
        result.parameters["knots_held_out_" + std::to_string(kMinKnots + i)] =
            choice.held_out_rms[i];
    }
    result.parameters["knots"] = std::max(knots, Trajectory::minimumKnots(o.trajectory));
    return fitTrajectory(o.trajectory, knots, t0, t1, poses);
  };
  ExposureMotion registered = s.motion;
  PixelGridOptions po;
  if (o.beta >= 0) po.beta = o.beta;
  po.dim_frame = o.dim_frame;
  po.log = o.log;
  po.subdivision = o.cells;
  po.event_window = o.alpha;
  po.chroma_smoothness = o.chroma_smooth;
  po.hysteresis = o.hysteresis;
  po.occlusion = o.occlusion;
  po.precondition = o.precondition;
  if (o.smooth > 0) po.smoothness = o.smooth;
  po.max_views = std::max(po.min_views, o.max_views);
  po.views_per_px = o.views_per_px;
  po.between_views_px = o.between_views_px;
  if (o.virtual_views > 0) po.min_views = po.max_views = o.virtual_views;
  // Without thresholds: the scale at which the events' counts match the blurry frame along the
  // registered motion (contrastFromCounts: unbiased by the events' noise), refined by short solves
  // of the grid within kCountsBand of it, and the motion registered between EDI's frames again at
  // the c found.
  Contrast contrast;
  if (s.contrast_given) {
    contrast = *o.contrast;
  } else {
    const auto search_start = Clock::now();
    const BlurMeasurement m =
        s.measured.searched ? s.measured : measureBlur(given, std::nullopt, o.log);
    result.parameters["contrast_searched"] = m.c_on;
    // EDI's search takes one c for both signs; the ratio c_off / c_on is found from the counts
    // (contrastFromCounts), along each motion the counts are taken on before the walk.
    double ratio = m.c_off / m.c_on;
    // The motion registered at too large a c moves the image too far, and the counts' c rises with
    // it (on a rocket before its backdrop, 0.22 along the motion registered at the truth's 0.2,
    // 0.27 at 0.3, 0.29 at 0.4): registered once more at the count and counted again. Not until the
    // count settles: at a small c the motion shrinks with it (EDI's frames barely move), and on a
    // smooth cameraman the rounds ran down to 0.126 for the truth's 0.2 (39.19 dB against 46.73).
    const auto counts = [&](const ExposureMotion& at, const Trajectory& path) {
      return contrastFromCounts(given, camera, path, at.inverse_depth, ratio, o.log);
    };
    const auto countsAndRatio = [&](const ExposureMotion& at, const Trajectory& path) {
      const CountedContrast found =
          contrastFromCounts(given, camera, path, at.inverse_depth, 0.0, o.log);
      if (found.ratio > 0) {
        ratio = found.ratio;
        result.parameters["contrast_ratio_low"] = found.ratio_low;
        result.parameters["contrast_ratio_high"] = found.ratio_high;
      }
      return found;
    };
    const auto inRange = [](double c) { return c >= kLeastContrast && c <= kMostContrast; };
    // The motion the count was taken along, and its trajectory.
    const ExposureMotion* counted_motion = &registered;
    Trajectory counted_path = fit(registered.poses);
    CountedContrast counted = countsAndRatio(registered, counted_path);
    result.parameters["contrast_from_counts_searched"] = counted.c;
    if (!inRange(counted.c)) return decline("the events' counts told no thresholds");
    const double registered_c = s.registered_away_c > 0 ? s.registered_away_c : m.c_on;
    double counted_c = registered_c;  // the c of the motion the count was taken along
    // The registrations at the counts' c and at the c found below ask the misfit of thresholds
    // given (kUnlessRepeated): their c is told by the counts and the solves, not by the misfit,
    // which stands for a wrong c only on the walk from EDI's searched c (registerAwayFromSearch).
    // Held at one pixel, layered photographs whose registration misfits 1.00-1.32 px at the
    // counts' c failed there, and the grid counted along a motion registered away at another c or
    // declined: six frames not in the suites, +1.57 dB on average with the band (-0.12 to +5.87;
    // BENCHMARKS.md, "The registration at the counts' c"). No frame of the suites moved.
    const MisfitBar counted_bar = MisfitBar::kUnlessRepeated;
    const auto again_start = Clock::now();
    const ExposureMotion again =
        motionFromLatentFrames(given, camera, Contrast{counted.c, counted.c * ratio}, o.log, false,
                               kScoredIntervals, counted_bar);
    if (!again.poses.empty()) {
      counted_c = counted.c;
      counted_motion = &again;
      counted_path = fit(again.poses);
      counted = countsAndRatio(again, counted_path);
    }
    result.timings_s["contrast_again"] = secondsSince(again_start);
    result.parameters["contrast_ratio"] = ratio;
    result.parameters["contrast_from_counts"] = counted.c;
    result.parameters["contrast_counts_correlation"] = counted.correlation;
    if (!inRange(counted.c)) return decline("the events' counts told no thresholds");
    // Whether the counts tell c at all: counted once more along the motion registered at twice the
    // c of the last. Where the image holds little but smooth shading, the motion registered grows
    // with the c it is registered at and the counts grow with it, so that every c is nearly a
    // fixed point (ground_blur15_noisy: 0.096, 0.184 and 0.354 along motions registered at 0.1,
    // 0.2 and 0.4); the grid then declines, for the hash field with normalised events, which
    // needs no c. Not below kHashBlur, where no c is told by so short a motion and the grid keeps
    // EDI's frame, better than the hash field there (hard_blur2: the counts follow 0.70, the hash
    // field 31.99 dB). Not where the motion registered at 2c misfits, nor where the count along it
    // is outside the range: such a motion tells nothing either way (the text preset at 120 x 90:
    // 0.211 along the motion registered at 0.2, 9.13 along the one at 0.4).
    const auto doubled_start = Clock::now();
    const double counted_blur = PixelGridProblem::longestImagePath(
        camera, counted_path, counted_motion->inverse_depth, t0, t1);
    const ExposureMotion doubled =
        counted_blur < kHashBlur
            ? ExposureMotion{}
            : motionFromLatentFrames(given, camera, Contrast{2 * counted_c, 2 * counted_c * ratio},
                                     o.log, false);
    const double doubled_count = doubled.poses.empty() ? 0 : counts(doubled, fit(doubled.poses)).c;
    const bool counts_checked = inRange(doubled_count);
    result.timings_s["contrast_doubled"] = secondsSince(doubled_start);
    if (counts_checked) {
      const double follow = std::log2(doubled_count / counted.c);
      result.parameters["contrast_counts_follow"] = follow;
      if (follow > kMostCountsFollow)
        return decline("the events' counts follow any thresholds the motion is registered at");
    }
    const auto walk_start = Clock::now();
    // Without the walk (BenerfOptions::contrast_walk), the counts' c as it is: inside the range,
    // and no walk to tell whether it is told.
    SolvedContrast found;
    found.contrast = Contrast{counted.c, counted.c * ratio};
    if (o.contrast_walk)
      found = contrastFromSolves(given, camera, fit, po, ratio, counted.c, kCountsBand,
                                 counted_blur, o, result);
    result.parameters["contrast_walked"] = o.contrast_walk ? 1 : 0;
    result.timings_s["contrast_walk"] = secondsSince(walk_start);
    if (found.start_misfits) {
      result.parameters["start_blur_misfit"] = found.start.misfit;
      result.parameters["start_change"] = found.start.change;
      result.parameters["start_to_hash"] = 1;
      result.parameters["start_to_hash_in_walk"] = 1;
      return decline("its start misfits the blurry frame");
    }
    // No c where the walk's least is at its range's end; nor where the band stopped it below while
    // its misfit still fell and the counts' own check above had no evidence either, so that
    // nothing told c (ground_blur40_noisy: the counts 0.108 along a motion registered at EDI's
    // 0.1, the motion at twice that not registered, the walk at the band's 0.086, the truth 0.2;
    // the grid there 29.86 dB, EDI 30.71, the hash field 38.69). Where the counts passed their
    // check, a walk to the band's foot is one from counts that a motion registered too far has
    // raised (a rocket before its backdrop: the counts 0.299 and following by 0.48, the walk at
    // the band's 0.237 for the truth 0.2; the grid 35.93 dB, the hash field 19.54). Not below
    // kHashBlur, where the hash field does worse than the grid at any c in the band (hard_blur2
    // without thresholds: the walk at the band's foot, 0.218 for the truth's 0.2, the counts not
    // checked there; the grid 34.42 dB, the hash field 31.61, EDI at its searched c 28.87).
    result.parameters["contrast_at_range_end"] = found.at_end ? 1 : 0;
    const bool untold = found.falls_below_band && !counts_checked && counted_blur >= kHashBlur;
    result.parameters["contrast_falls_below_band"] = found.falls_below_band ? 1 : 0;
    result.parameters["contrast_untold"] = untold ? 1 : 0;
    if (found.at_end) return decline("the thresholds found are at an end of their range");
    if (untold)
      return decline("neither the events' counts nor its short solves told the thresholds");
    contrast = found.contrast;
    result.parameters["contrast_estimated"] = contrast.on;
    const auto at_found_start = Clock::now();
    ExposureMotion at_found =
        motionFromLatentFrames(given, camera, contrast, o.log, true, kScoredIntervals, counted_bar);
    result.timings_s["contrast_at_found"] = secondsSince(at_found_start);
    result.parameters["contrast_registered_at_estimate"] = at_found.poses.empty() ? 0 : 1;
    if (!at_found.poses.empty()) {
      registered = std::move(at_found);
      reportMotion(registered, result);
    } else if (std::abs(std::log(contrast.on / registered_c)) > kCountsBand) {
      // The grid runs on a motion registered within kCountsBand of its c, or not at all: a motion
      // registered at too small a c is too short, at too large a one too long. Where none
      // registers at the c found and the motion in hand was registered farther from it, the
      // hash field, which refines its own trajectory (hard_dark: registered away from EDI's 0.5 at
      // 0.125, the counts 0.21 for the truth's 0.2, and nothing registers there through its
      // repeating texture; the grid on the motion of 0.125 55.93 dB, the hash field 62.06).
      return decline("no motion registered at the thresholds found");
    }
    result.timings_s["contrast"] = secondsSince(search_start);
  }
  result.parameters["motion_from_frames"] = 1;
  Trajectory motion = fit(registered.poses);
  // A motion that turns more than the nine poses registered so far can follow: where they call for
  // kTurningKnots or more, it is registered again at kTrajectoryIntervals + 1 times and the count
  // chosen from those. Not everywhere: measured before kDenseKnotTolerancePx, the rule then took
  // 6-10 knots on smooth shakes (the registration's noise), ground_blur15 43.03 -> 42.02 dB.
  result.parameters["registered_times"] = static_cast<double>(registered.poses.size());
  if (o.knots <= 0 && static_cast<int>(motion.knots().size()) >= kTurningKnots) {
    const auto dense_start = Clock::now();
    ExposureMotion dense = motionFromLatentFrames(
        given, camera, contrast, o.log, true, kTrajectoryIntervals, misfitBar(s.contrast_given));
    if (!dense.poses.empty()) {
      registered = std::move(dense);
      reportMotion(registered, result);
      motion = fit(registered.poses);
      result.parameters["registered_times"] = static_cast<double>(registered.poses.size());
    }
    result.timings_s["registration_dense"] = secondsSince(dense_start);
  }
  cv::Mat inverse_depth = registered.inverse_depth;
  const Observation filtered =
      o.support_px > 0
          ? supportedEvents(
                given, o.support_px,
                PixelGridProblem::longestImagePath(camera, motion, inverse_depth, t0, t1), result)
          : Observation{};
  const Observation& obs = o.support_px > 0 ? filtered : given;
  po.event_robust = o.mid_robust;
  // The event term's error is the events' quantisation, up to a threshold at each end of a
  // comparison, so its variance grows as C^2: its weight is beta at kBetaContrast and
  // (kBetaContrast / C)^2 beta at C (maximum likelihood; the short solves that find c keep beta).
  po.beta *= std::pow(kBetaContrast / (0.5 * (contrast.on + contrast.off)), 2);
  const cv::Mat edi_mid = ediMidFrame(obs, contrast);
  std::optional<PixelGridProblem> problem;
  problem.emplace(obs, camera, motion, inverse_depth, contrast, po);
  std::vector<double> x = problem->start(edi_mid);
  // Where the registration offers the near sides' depths at its depth edges (ExposureMotion::
  // near_edges), the geometry through which EDI's mid frame agrees better with the blurry frame
  // and the events: the grid's loss there, before the motion's refinement (BENCHMARKS.md, "The near
  // side of a depth edge").
  if (registered.near_edges) {
    const auto registered_parameters = result.parameters;  // fit's knots', for the registered
    const Trajectory near_motion = fit(registered.near_edges->poses);
    PixelGridProblem near(obs, camera, near_motion, registered.near_edges->inverse_depth, contrast,
                          po);
    std::vector<double> near_x = near.start(edi_mid);
    const double as_registered = problem->evaluate(x, nullptr),
                 near_loss = near.evaluate(near_x, nullptr);
    const bool take = near_loss < as_registered;
    if (take) {
      problem = std::move(near);
      x = std::move(near_x);
      motion = near_motion;
      inverse_depth = registered.near_edges->inverse_depth;
    } else {
      result.parameters = registered_parameters;
    }
    result.parameters["depth_edges_near_loss"] = near_loss / as_registered;
    result.parameters["depth_edges_near"] = take ? 1 : 0;
  }
  result.timings_s["setup"] = secondsSince(start);
  const auto train_start = Clock::now();
  PixelGridProblem::Terms terms;
  // L-BFGS steps: at most a tenth of the budget's field steps (100 at `fast`: 200 moved the natural
  // suite by -0.05 dB and no standard or noisy scene by more than 0.01), fewer where the loss no
  // longer falls (BenerfOptions::converged); a budget in seconds stops at its deadline.
  const Clock::time_point deadline =
      o.budget_seconds > 0 ? start + std::chrono::duration_cast<Clock::duration>(
                                         std::chrono::duration<double>(0.95 * o.budget_seconds))
                           : Clock::time_point::max();
  const int steps = std::max(2, o.iterations / 10);
  if (po.motion_steps > 0) problem->refineMotion(x, po.motion_steps);
  // The loss after every step, and the caller's progress (which may stop the run by throwing).
  const auto progress = [&](int done, double loss) {
    result.curve.emplace_back(done, loss);
    if (request.progress) request.progress(done, steps, loss);
  };
  // The start is kept where the grid's model misses the blurry frame by at least half of what
  // deblurring changes (kKeepStart): there the blur term would fit the model's own error.
  const StartFit at_start = startFit(*problem, x, obs.blurry);
  const bool misfit = at_start.misfits();
  const bool to_hash = misfit && problem->blurLength() >= kHashBlur,
             keep_start = misfit && !to_hash;
  result.parameters["start_blur_misfit"] = at_start.misfit;
  result.parameters["start_change"] = at_start.change;
  result.parameters["start_kept"] = keep_start ? 1 : 0;
  if (to_hash) {
    result.parameters["start_to_hash"] = 1;
    return decline("its start misfits the blurry frame");
  }
  if (!keep_start && !(o.smooth > 0)) {
    const auto choice_start = Clock::now();
    po.smoothness = chooseSmoothness(*problem, x, steps, deadline, result);
    problem->setSmoothness(po.smoothness);
    result.timings_s["smoothness"] = secondsSince(choice_start);
  }
  result.parameters["smoothness"] = po.smoothness;
  int iterations = 0;
  const int rounds = keep_start || po.motion_steps <= 0 ? 0 : o.motion_rounds;
  const auto convergedIn = [&](int round) {
    return round < rounds ? std::max(o.converged, kRoundConverged) : o.converged;
  };
  if (keep_start)
    terms = at_start.terms;
  else
    iterations = problem->solve(x, steps, &terms, deadline, progress, convergedIn(0));
  result.timings_s["train_first_solve"] = secondsSince(train_start);
  result.parameters["first_solve_steps"] = iterations;
  const auto depth_start = Clock::now();
  // The depth from the solved image (BenerfOptions::depth_steps), before the motion's rounds.
  int depth_kept = 0;
  while (depth_kept < (keep_start ? 0 : o.depth_steps) && Clock::now() < deadline &&
         stepDepth(problem, x, obs, camera, contrast, po))
    ++depth_kept;
  if (depth_kept > 0) inverse_depth = problem->inverseDepth();
  result.parameters["depth_steps_kept"] = depth_kept;
  result.timings_s["train_depth"] = secondsSince(depth_start);
  for (int round = 1; round <= rounds && Clock::now() < deadline; ++round) {
    const auto round_start = Clock::now();
    problem->refineMotion(x, kRoundMotionSteps);
    result.timings_s["train_round_motion"] += secondsSince(round_start);  // over every round
    const int done = iterations;
    iterations += problem->solve(
        x, std::max(PixelGridProblem::kConvergedSteps, steps - done), &terms, deadline,
        [&](int k, double loss) { progress(done + k, loss); }, convergedIn(round));
  }
  result.parameters["motion_rounds"] = rounds;
  result.timings_s["train"] = secondsSince(train_start);
  const auto render_start = Clock::now();
  for (int64_t t : request.times_us) {
    Frame f;
    // A frame as the sensor would record it, read at its top where the image goes above it: where
    // the blurry frame clipped (PixelGridOptions::saturated), or where the events' noise pushed
    // a pixel up (the noisy suite's text, whose truth is at most 0.95).
    f.image = cv::min(problem->render(x, t), 1.0);
    f.exposure_start_us = f.exposure_end_us = t;
    f.bit_depth = obs.blurry.bit_depth;
    result.frames.push_back(std::move(f));
  }
  result.disparity = inverse_depth.empty() ? cv::Mat::zeros(camera.height, camera.width, CV_32F)
                                           : inverse_depth.clone();
  result.timings_s["render"] = secondsSince(render_start);
  std::vector<StampedPose> trajectory;
  for (int k = 0; k <= 100; ++k) {
    const int64_t t = t0 + (t1 - t0) * k / 100;
    trajectory.push_back({t, problem->motion().poseAt(t)});
  }
  result.trajectory = std::move(trajectory);
  result.parameters["iterations"] = iterations;
  result.parameters["virtual_views"] = problem->views();
  result.parameters["field_parameters"] = problem->size();
  result.parameters["blur_px_motion"] = problem->blurLength();
  result.parameters["views_across_depth_edges"] = problem->acrossShare();
  result.parameters["views_behind"] = problem->behindShare();
  result.parameters["beta"] = po.beta;
  result.parameters["final_blur_term"] = terms.blur;
  result.parameters["final_event_term"] = terms.event;
  if (terms.blur > 0) result.parameters["blur_fit_psnr"] = -10 * std::log10(terms.blur);
  const SE3 over = motion.poseAt(t0).inverse() * motion.poseAt(t1);
  result.parameters["initial_rotation_deg"] =
      logSO3(over.rotation()).norm() * 180 / std::numbers::pi;
  return true;
}

// A colour frame whose three channels are the same carries no colour: a grey scene, or a grey
// camera's frames stored as RGB. Deblurred in colour, its chroma would be held by the blur term
// alone, and where the events and the blur disagree (a near object's edges) the grey's weights
// would split the difference among the channels, green the most: fringes of green and purple that
// a grey frame cannot have (BENCHMARKS.md, "A grey frame in three channels").
bool greyInColour(const cv::Mat& image) {
  if (image.channels() != 3) return false;
  std::vector<cv::Mat> channels;
  cv::split(image, channels);
  return cv::countNonZero(channels[0] != channels[1]) == 0 &&
         cv::countNonZero(channels[0] != channels[2]) == 0;
}

// The observation with its frames in one channel: the blurry frame's first (all three are the
// same) and the ground truth's grey.
Observation asGrey(const Observation& given) {
  Observation grey = given;
  cv::extractChannel(given.blurry.image, grey.blurry.image, 0);
  for (Frame& g : grey.gt_frames)
    if (g.image.channels() == 3) cv::cvtColor(g.image, g.image, cv::COLOR_BGR2GRAY);
  return grey;
}

// The account's words (DeblurResult::account) for the camera the run used.
std::string cameraWords(const Observation& obs, const Start& s) {
  if (!obs.camera_assumed) return "the camera from its calibration";
  char words[96];
  if (s.camera_estimated && !s.camera.distortion.empty())
    std::snprintf(words, sizeof words, "a camera assumed at fx %.0f px with k1 %.2f estimated",
                  s.camera.fx, s.camera.distortion[0]);
  else
    std::snprintf(words, sizeof words, "a pinhole camera assumed at fx %.0f px", obs.camera.fx);
  return words;
}

// ... for thresholds c and where they came from (`how`).
std::string thresholdWords(const char* how, const Contrast& c) {
  char words[96];
  std::snprintf(words, sizeof words, "; thresholds %s, %.3f / %.3f", how, c.on, c.off);
  return words;
}

// ... for the fields' event term: normalised, or at the thresholds given or from EDI's search.
std::string fieldThresholdWords(const Start& s, bool normalised) {
  if (normalised || !s.options.contrast) return "; the events L2-normalised (no thresholds)";
  return thresholdWords(s.contrast_given ? "given" : "from EDI's search", *s.options.contrast);
}

// ... for the grid's scene and its thresholds (its parameters).
std::string gridWords(const Start& s, const std::map<std::string, double>& p) {
  const auto value = [&p](const char* key) {
    const auto it = p.find(key);
    return it == p.end() ? std::nan("") : it->second;
  };
  const auto flag = [&value](const char* key) {
    const double v = value(key);
    return !std::isnan(v) && v != 0;
  };
  std::string words = "the pixel grid on ";
  words += flag("representation_pixel_depth") ? "each pixel's depth"
           : flag("representation_depth")     ? "a depth per tile"
                                              : "one plane";
  if (flag("start_kept")) words += ", EDI's frame kept (its model misfits the blurry frame)";
  if (s.contrast_given) return words + thresholdWords("given", *s.options.contrast);
  // EDI's search takes one c for both signs; the grid's own takes c_off / c_on from the counts.
  const double found = value("contrast_estimated"), ratio = value("contrast_ratio");
  if (flag("contrast_edi_retried"))
    return words + thresholdWords("from EDI's search", Contrast{found, found});
  return words + thresholdWords("found from the events",
                                Contrast{found, found * (std::isnan(ratio) ? 1 : ratio)});
}

}  // namespace

DeblurResult BenerfDeblurrer::run(const Observation& given, const DeblurRequest& request) {
  if (greyInColour(given.blurry.image)) {
    DeblurResult result = run(asGrey(given), request);
    for (Frame& f : result.frames) cv::merge(std::vector<cv::Mat>(3, f.image), f.image);
    result.parameters["frame_grey"] = 1;
    return result;
  }
  const auto start = Clock::now();
  DeblurResult result;
  result.parameters["frame_grey"] = 0;
  ThreadScope threads(options_.threads, result);
  // The caller's progress, and at threads=auto the thread count following the load.
  DeblurRequest followed = request;
  if (threads.following()) {
    followed.progress = [&threads, &request](int done, int total, double loss) {
      threads.follow();
      if (request.progress) request.progress(done, total, loss);
    };
  }
  const DeblurRequest& req = threads.following() ? followed : request;
  Start s = prepare(given, options_, result);
  const BenerfOptions& o = s.options;
  // Every later step sees the camera the run uses (an estimated one replaces the assumed).
  std::optional<Observation> calibrated;
  if (s.camera_estimated) {
    calibrated = given;
    calibrated->camera = s.camera;
  }
  const Observation& obs = calibrated ? *calibrated : given;
  result.parameters["camera_given"] = given.camera_assumed ? 0 : 1;
  result.parameters["camera_fx"] = obs.camera.fx;
  result.parameters["camera_k1"] = obs.camera.distortion.empty() ? 0 : obs.camera.distortion[0];
  // The pixel grid needs the registered motion; without it (the rigid camera did not explain the
  // registration), or where it declines (runPixelGrid), the hash field, whose training refines the
  // trajectory.
  result.parameters["representation_pixels"] = 0;
  if (o.field == BenerfOptions::FieldKind::kPixels && (!o.checkpoint.empty() || !o.resume.empty()))
    throw Error(
        "benerf: checkpoint and resume are for field=hash and field=mlp (the pixel grid is solved "
        "in one go)");
  if (o.field == BenerfOptions::FieldKind::kPixels && s.motion.poses.empty())
    result.account = "the pixel grid declined: no rigid motion explains the registration";
  if (o.field == BenerfOptions::FieldKind::kPixels && !s.motion.poses.empty()) {
    bool grid = runPixelGrid(obs, req, s, start, result);
    // Without thresholds, where the grid declined at the c that it found, once more as if EDI's
    // searched c had been given, where that search landed inside its range and the motion was
    // registered there. On smooth or dark scenes with noisy events the grid's own criteria fall
    // towards small c, where the events' noise weighs least and the blur barely tells
    // (BENCHMARKS.md, "Where the grid declines its own c"). Not where the registration walked away
    // from EDI's c: registered there again at the bar of thresholds given, the motion misfit 1.33
    // px on a smooth scene at half size and the grid lost 1.6 dB to the hash field.
    if (!grid && !s.contrast_given && s.measured.searched && s.measured.inside &&
        !(s.registered_away_c > 0)) {
      Start at_edi = s;
      at_edi.contrast_given = true;
      at_edi.options.contrast = Contrast{s.measured.c_on, s.measured.c_off};
      result.parameters.erase("start_to_hash");
      result.parameters["contrast_edi_retried"] = 1;
      result.parameters["contrast_estimated"] = s.measured.c_on;
      grid = runPixelGrid(obs, req, at_edi, start, result);
    }
    if (grid) {
      result.parameters["representation_pixels"] = 1;
      result.account = gridWords(s, result.parameters) + "; " + cameraWords(given, s);
      result.timings_s["total"] = secondsSince(start);
      return result;
    }
  }
  // The hash field starts from the events' rotation, also where a motion was registered and the
  // grid declined: the grid declines where its c or its motion are in doubt, and on the suites'
  // declines the registered motion was off (ground_blur15 without thresholds: 4.42 degrees and a
  // translation 12 times the truth's, for 2.03 degrees) and started the field 0.5-6.2 dB lower on
  // all ten frames (BENCHMARKS.md, "Where the grid declines, the hash field's start"). Where the
  // motion is mostly translation a rotation is a poor start: a photograph not in the suites with
  // 60% of its image motion from translation, which declined until the registration at the counts'
  // c took the band (runPixelGrid), would have gained 1.1 dB from its registered motion, and a
  // rocket before its backdrop at half size (which does not decline) 11.6 dB. Which start to take
  // is not told from the data (neither the warped events' contrast nor the re-blur of EDI's frame
  // ranks them as their results do).
  if (o.field == BenerfOptions::FieldKind::kPixels) {
    s.options.field = BenerfOptions::FieldKind::kHash;
    s.options.init = BenerfOptions::Init::kEvents;
  }
  BenerfProblem<float> problem(obs, o, s.views);
  if (o.init == BenerfOptions::Init::kEvents) initialiseFromEvents(obs, problem, s.blur_px, result);
  if (o.init == BenerfOptions::Init::kFrames)
    initialiseFromFrames(obs, problem, s.motion, s.blur_px, result);
  const auto from = result.parameters.find("initial_from_events");
  result.account +=
      std::string(result.account.empty() ? "" : "; ") +
      (o.field == BenerfOptions::FieldKind::kMlp ? "the MLP field" : "the hash field") +
      (from == result.parameters.end() ? ", its trajectory from identity"
       : from->second != 0             ? ", its trajectory from the events' rotation"
                                       : ", its trajectory from the registered motion") +
      fieldThresholdWords(s, problem.normalisedEvents()) + "; " + cameraWords(given, s);
  Optimisers optimisers(problem, o);
  std::mt19937_64 rng(o.seed);
  int iterations = o.iterations;
  int first = 0;
  if (!o.resume.empty()) {
    const Checkpoint c = readCheckpoint(o.resume, problem.field(), problem.trajectory(),
                                        optimisers.field(), optimisers.knots(), rng);
    if (c.views != s.views) {
      throw Error(o.resume + ": the checkpoint used " + std::to_string(c.views) +
                  " virtual views, these settings " + std::to_string(s.views));
    }
    first = c.iteration;
    iterations = std::max(iterations, c.iterations);
  }
  optimisers.setSchedule(iterations);
  if (o.prefit > 0 && o.resume.empty()) prefit(obs, problem, optimisers, o, result);
  result.timings_s["setup"] = secondsSince(start);

  Training training(obs, req, problem, optimisers, o, start);
  iterations = training.run(first, iterations, rng, result);
  renderResults(obs, req, problem, result);
  summarise(problem, o, iterations, training, result);
  result.timings_s["total"] = secondsSince(start);
  return result;
}

}  // namespace evkit
