// BeNeRF's training: the start, the optional prefit, the schedule and the wall-time budget, the
// final renders and the summary.

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <numbers>

#include "benerf_checkpoint.h"
#include "benerf_common.h"
#include "evkit/base/error.h"
#include "evkit/deblur/benerf.h"
#include "evkit/deblur/edi.h"
#include "evkit/deblur/metrics.h"
#include "evkit/nerf/adam.h"
#include "evkit/spline/fit.h"

namespace evkit {

using benerf_detail::Checkpoint;
using benerf_detail::readCheckpoint;
using benerf_detail::secondsSince;
using benerf_detail::toFloat;
using benerf_detail::writeCheckpoint;

namespace {

// The ground-truth frame nearest to mid-exposure, when there is one at the camera's size.
const Frame* midGroundTruth(const Observation& obs) {
  const Frame* best = nullptr;
  const int64_t mid = obs.blurry.midExposure();
  for (const Frame& g : obs.gt_frames) {
    if (g.image.size() != obs.blurry.image.size() || g.image.channels() != obs.blurry.image.channels()) continue;
    if (!best || std::llabs(g.exposure_start_us - mid) < std::llabs(best->exposure_start_us - mid)) best = &g;
  }
  return best;
}

}  // namespace

DeblurResult BenerfDeblurrer::run(const Observation& obs, const DeblurRequest& request) {
  const auto start = std::chrono::steady_clock::now();
  DeblurResult result;
  BenerfOptions o = options_;
  const int saved_threads = omp_get_max_threads();
  if (o.threads > 0) omp_set_num_threads(o.threads);
  struct RestoreThreads {
    int n;
    ~RestoreThreads() { omp_set_num_threads(n); }
  } restore_threads{saved_threads};

  int views = o.virtual_views;
  double blur_px = 0;
  if (!o.contrast) o.contrast = obs.contrast;
  const bool estimate = !o.contrast && o.estimate_contrast && o.event_form == BenerfOptions::EventForm::kAuto;
  if (views <= 0 || o.init == BenerfOptions::Init::kEvents || estimate) {
    const BlurMeasurement m = measureBlur(obs, o.contrast);
    blur_px = m.blur_px;
    result.parameters["blur_px_measured"] = blur_px;
    if (estimate && m.inside) {
      o.contrast = std::make_pair(m.c_on, m.c_off);
      result.parameters["contrast_estimated"] = m.c_on;
    }
  }
  if (views <= 0) views = virtualViewsFor(blur_px);
  BenerfProblem<float> problem(obs, o, views);
  if (o.init == BenerfOptions::Init::kEvents) {
    // The knots fitted to a constant rotation through identity at mid-exposure, each then moved by
    // its random jitter.
    const Vector3 omega = rotationFromEvents(obs, problem.camera(), blur_px);
    Trajectory& trajectory = problem.trajectory();
    std::vector<StampedPose> poses;
    for (int k = 0; k <= 20; ++k) {
      const double s = k / 20.0;
      const int64_t t = trajectory.beginUs() + std::llround(s * static_cast<double>(trajectory.endUs() - trajectory.beginUs()));
      poses.push_back({t, SE3(expSO3((s - 0.5) * omega), Vector3::Zero())});
    }
    const Trajectory fitted = fitTrajectory(trajectory.kind(), static_cast<int>(trajectory.knots().size()), trajectory.beginUs(), trajectory.endUs(), poses);
    for (size_t k = 0; k < trajectory.knots().size(); ++k) trajectory.knots()[k] = fitted.knots()[k] * trajectory.knots()[k];
    result.parameters["initial_rotation_deg"] = omega.norm() * 180 / std::numbers::pi;
  }
  nerf::AdamOptions field_adam_options;
  field_adam_options.learning_rate = o.field_lr;
  nerf::Adam<float> field_adam(problem.field().parameters(), field_adam_options);
  const size_t knot_values = 6 * problem.trajectory().knots().size();
  Eigen::VectorXd knot_step = Eigen::VectorXd::Zero(static_cast<Eigen::Index>(knot_values)), knot_gradient = knot_step;
  nerf::AdamOptions knot_adam_options;
  knot_adam_options.learning_rate = o.knot_lr;
  knot_adam_options.epsilon = 1e-12;
  nerf::Adam<double> knot_adam({nerf::ParameterBlock<double>{knot_step.data(), knot_gradient.data(), knot_values, nullptr, 1}}, knot_adam_options);
  std::mt19937_64 rng(o.seed);

  int iterations = o.iterations;
  int first = 0;
  if (!o.resume.empty()) {
    const Checkpoint c = readCheckpoint(o.resume, problem.field(), problem.trajectory(), field_adam, knot_adam, rng);
    if (c.views != views) throw Error(o.resume + ": the checkpoint used " + std::to_string(c.views) + " virtual views, these settings " + std::to_string(views));
    first = c.iteration;
    iterations = std::max(iterations, c.iterations);
  }
  // One learning-rate schedule over the prefit's steps and the training's.
  const auto setSchedule = [&](int total) {
    field_adam.options().decay_rate = knot_adam.options().decay_rate = o.lr_final;
    field_adam.options().decay_steps = knot_adam.options().decay_steps = std::max(1, o.prefit + total);
  };
  setSchedule(iterations);
  // One step of both optimisers; a non-finite loss or gradient is a loud error naming the step.
  const auto trainStep = [&](const BenerfProblem<float>::Batch& batch, const char* step_name, int step) {
    const auto loss = problem.evaluate(batch, &knot_gradient);
    if (!std::isfinite(loss.total) || !knot_gradient.allFinite()) {
      throw Error("benerf: the loss or its gradient became " + std::string(std::isfinite(loss.total) ? "non-finite" : "NaN/Inf") + " at " +
                  step_name + " " + std::to_string(step) + " (blur term " + std::to_string(loss.blur) + ", event term " + std::to_string(loss.event) + ")");
    }
    field_adam.step();
    knot_step.setZero();
    knot_adam.step();
    problem.trajectory().applyKnotSteps(knot_step);
    return loss;
  };
  if (o.prefit > 0 && o.resume.empty()) {
    // The field and knots fitted to EDI's latent frames at the views' times (every band open, no
    // event term), with the training's optimisers, so that their moments carry over.
    const auto prefit_start = std::chrono::steady_clock::now();
    const Trajectory& trajectory = problem.trajectory();
    DeblurRequest edi_request;
    for (int k = 0; k < views; ++k) {
      edi_request.times_us.push_back(trajectory.beginUs() + std::llround(problem.viewTime(k) * static_cast<double>(trajectory.endUs() - trajectory.beginUs())));
    }
    std::vector<cv::Mat> targets;
    for (const Frame& f : EdiDeblurrer{EdiOptions{}}.run(obs, edi_request).frames) targets.push_back(toFloat(f.image));
    problem.setViewTargets(std::move(targets));
    std::mt19937_64 prefit_rng(o.seed + 1);
    for (int it = 0; it < o.prefit; ++it) {
      auto batch = problem.sampleBatch(prefit_rng);
      batch.event_pixels.clear();
      batch.window_begin.clear();
      batch.window_end.clear();
      const auto loss = trainStep(batch, "prefit iteration", it);
      if (it + 1 == o.prefit) result.parameters["prefit_final_term"] = loss.blur;
    }
    problem.setViewTargets({});
    result.timings_s["prefit"] = secondsSince(prefit_start);
  }
  result.timings_s["setup"] = secondsSince(start);

  const Frame* gt = midGroundTruth(obs);
  int psnr_every = gt ? std::max(1, iterations / 10) : 0;
  // The final renders: the requested frames, and the mid-exposure frame for the disparity unless
  // it is one of them.
  const int64_t mid = obs.blurry.midExposure();
  const bool mid_requested = std::find(request.times_us.begin(), request.times_us.end(), mid) != request.times_us.end();
  const int final_renders = static_cast<int>(request.times_us.size()) + (mid_requested ? 0 : 1);
  const auto train_start = std::chrono::steady_clock::now();
  double curve_seconds = 0;  // spent on the training-PSNR renders
  double loss_sum = 0, blur_sum = 0, event_sum = 0, last_blur = 0, last_event = 0;
  int loss_count = 0;
  const int bands = problem.field().bands();
  for (int it = first; it < iterations; ++it) {
    if (o.coarse_to_fine > 0) {
      const double opened = std::clamp(static_cast<double>(it) / (o.coarse_to_fine * iterations), 0.0, 1.0);
      problem.field().setBandLimit(1 + (bands - 2) * opened);
    }
    const auto loss = trainStep(problem.sampleBatch(rng), "iteration", it);
    loss_sum += loss.total;
    blur_sum += loss.blur;
    event_sum += loss.event;
    ++loss_count;
    const int done = it + 1;
    if (done % o.curve_every == 0 || done == iterations) {
      result.curve.emplace_back(done, loss_sum / loss_count);
      if (request.progress) request.progress(done, iterations, loss_sum / loss_count);
      last_blur = blur_sum / loss_count;
      last_event = event_sum / loss_count;
      loss_sum = blur_sum = event_sum = 0;
      loss_count = 0;
    }
    if (psnr_every > 0 && (done % psnr_every == 0 || done == iterations)) {
      const auto curve_start = std::chrono::steady_clock::now();
      result.curve_psnr.emplace_back(done, psnr(problem.render(mid), gt->image));
      curve_seconds += secondsSince(curve_start);
    }
    // A wall-time budget: after a few iterations, the count that fits with the renders still to
    // come (the schedule follows); the training-PSNR curve gets at most a quarter of what is left.
    if (o.budget_seconds > 0 && done == first + 20) {
      const double per_iteration = (secondsSince(train_start) - curve_seconds) / 20;
      const double render_seconds = problem.renderSeconds();
      double left = o.budget_seconds * 0.95 - secondsSince(start) - final_renders * render_seconds;
      int curve_renders = gt ? std::min(10, static_cast<int>(0.25 * std::max(0.0, left) / render_seconds)) : 0;
      left -= curve_renders * render_seconds;
      iterations = std::max(done + 1, static_cast<int>(left / per_iteration) + done);
      setSchedule(iterations);
      psnr_every = curve_renders > 0 ? std::max(1, iterations / curve_renders) : 0;
    }
    const bool stop = o.stop_after > 0 && done >= o.stop_after;
    if (!o.checkpoint.empty() && (done % o.checkpoint_every == 0 || done == iterations || stop)) {
      writeCheckpoint(o.checkpoint, Checkpoint{done, iterations, views}, problem.field(), problem.trajectory(), field_adam, knot_adam, rng);
    }
    if (stop) break;
  }
  result.timings_s["train"] = secondsSince(train_start);
  problem.field().setBandLimit(bands);

  const auto render_start = std::chrono::steady_clock::now();
  for (int64_t t : request.times_us) {
    Frame f;
    f.image = problem.render(t, t == mid ? &result.disparity : nullptr);
    f.exposure_start_us = f.exposure_end_us = t;
    f.bit_depth = obs.blurry.bit_depth;
    result.frames.push_back(std::move(f));
  }
  if (!mid_requested) problem.render(mid, &result.disparity);
  result.timings_s["render"] = secondsSince(render_start);
  std::vector<StampedPose> trajectory;
  const int64_t t0 = obs.blurry.exposure_start_us, t1 = obs.blurry.exposure_end_us;
  for (int k = 0; k <= 100; ++k) {
    const int64_t t = t0 + (t1 - t0) * k / 100;
    trajectory.push_back({t, problem.trajectory().poseAt(t)});
  }
  result.trajectory = std::move(trajectory);
  size_t parameters = 0;
  for (const auto& b : problem.field().parameters()) parameters += b.size;
  result.parameters["iterations"] = iterations;
  result.parameters["virtual_views"] = views;
  result.parameters["field_parameters"] = static_cast<double>(parameters);
  result.parameters["events"] = static_cast<double>(problem.eventsInExposure());
  result.parameters["samples_per_ray"] = o.samples;
  result.parameters["beta"] = problem.beta();
  result.parameters["blur_weight"] = problem.blurWeight();
  result.parameters["events_normalised"] = problem.normalisedEvents() ? 1.0 : 0.0;
  result.parameters["rays_per_step"] = std::max(1, o.blur_rays / views) * views + 2 * o.event_rays;
  if (!result.curve.empty()) {
    result.parameters["final_loss"] = result.curve.back().second;
    // The two terms over the last curve interval: how well the model explains the blurry frame
    // (as a PSNR of the re-blurred renders against it) and the events.
    result.parameters["final_blur_term"] = last_blur;
    result.parameters["final_event_term"] = last_event;
    if (last_blur > 0) result.parameters["blur_fit_psnr"] = -10 * std::log10(last_blur);
  }
  result.timings_s["total"] = secondsSince(start);
  return result;
}

}  // namespace evkit
