// BeNeRF (Li, Wan, Wang et al., "BeNeRF: Neural Radiance Fields from a Single Blurry Image and
// Event Stream", ECCV 2024): a radiance field and the camera trajectory of one exposure, recovered
// from the blurry frame and the events of that exposure alone.
//
// Model (DESIGN.md §5):
//  - trajectory: a spline over the exposure (cumulative cubic SE(3), 4 knots in the paper, knots
//    initialised within knot_init of identity; split or linear selectable; the pixel grid takes
//    4 to 7 from its registered motion), poses T_world_cam in double;
//  - blur term: a blurry pixel is the mean of n virtual sharp renders at poses spread over the
//    exposure (midpoints s_k = (k + 1/2) / n: the midpoint rule of the exposure integral);
//    L_p = mean over pixels and channels of (mean_k C_k - B)^2;
//  - event term: the events of a random window of length alpha T (each step deals its event pixels
//    among `windows` such windows; the paper has one), accumulated per pixel (C_on n_on
//    - C_off n_off with known thresholds, n_on - n_off otherwise), against the change of the shared
//    log mapping of the grey renders at the window's ends, log I(t_b) - log I(t_a); both
//    L2-normalised over the batch (the paper; the authors' code on real data), or compared directly
//    when the thresholds are known (the authors' code on synthetic data);
//    L_e = mean over pixels of the squared difference;
//  - L = L_p + beta L_e; two Adam optimisers (field; knots as right-perturbation steps) with
//    exponentially decaying learning rates.
// Gradients reach the knots through the field's position gradients, the NDC ray's pose Jacobian
// (affine in the ray parameter, so two Jacobians per ray suffice) and the spline's knot Jacobians.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <functional>
#include <memory>
#include <opencv2/core.hpp>
#include <optional>
#include <random>
#include <span>
#include <string>
#include <vector>

#include "evkit/deblur/deblurrer.h"
#include "evkit/deblur/settings.h"
#include "evkit/events/log_intensity.h"
#include "evkit/events/pixel_index.h"
#include "evkit/nerf/camera.h"
#include "evkit/nerf/field.h"
#include "evkit/nerf/ray_batch.h"
#include "evkit/spline/fit.h"
#include "evkit/spline/trajectory.h"

namespace evkit {

// BenerfOptions::threads for the cores that other programs leave idle.
inline constexpr int kThreadsFromLoad = -1;

// The defaults are the `balanced` budget's (benerfBudget); every setting, its range and its help
// are declared once in benerfSettings() (benerf_options.cc).
struct BenerfOptions {
  // Field: the fast hash-grid field, the paper's 8 x 256 MLP (the reference), or the pixel grid
  // (PixelGridProblem, evkit/deblur/pixel_grid.h): the mid-exposure camera's frustum with `cells`
  // x `cells` cells per pixel at the inverse depth registered between EDI's latent frames
  // (motionFromLatentFrames), the image found by L-BFGS on BeNeRF's two terms with the registered
  // trajectory. Where the registration gives no motion, the hash field.
  enum class FieldKind { kHash, kMlp, kPixels };
  FieldKind field = FieldKind::kPixels;
  int cells = 2;
  // The pixel grid keeps only the events a neighbouring pixel supports within the time the image
  // takes to move this many pixels (filterUnsupported, evkit/events/filters.h), so that shot noise
  // is not fitted as texture; 0: every event.
  double support_px = 2;
  // The pixel grid compares each view with mid-exposure by the pseudo-Huber penalty with this
  // scale in log units (PixelGridOptions::event_robust; 0: squares). A real pixel's ON and OFF
  // thresholds differ from the nominal, so its events drift from its log change by a share of the
  // change it has crossed (not a multiple of C), and that drift grows with the time from
  // mid-exposure. Measured against squares at `fast` (BENCHMARKS.md, "The pixel grid"): noisy
  // suite 33.72 -> 34.84 dB, natural 34.97 -> 35.14 (every noisy scene up), hard_noisy 27.28 ->
  // 30.69; standard 36.26 -> 36.11. Scaled with C (2C) instead, hard_dense (C = 0.08) lost 0.4 dB.
  double mid_robust = 0.4;
  // The pixel grid's smoothness of the chroma in colour (PixelGridOptions::chroma_smoothness). The
  // events see brightness only, so the chroma is held by the blur term alone, which leaves its fine
  // detail free: on a photograph of bricks through a wide lens the grid's brightness was 0.9 dB
  // ahead of EDI's and its chroma 8.6 dB behind (fringes along every edge). Measured at `fast` on
  // eleven colour observations (BENCHMARKS.md, "The pixel grid"): 0 -> 0.03 raised every one but
  // one (unchanged) by 0.5-1.6 dB; 0.1 and above lost again where the scene has strong colour
  // edges (the astronaut's suit, the motorcycle).
  double chroma_smooth = 0.03;
  // The pixel grid compares the events with the sensor's reference level, which follows the log
  // level with this much play in thresholds (PixelGridOptions::hysteresis; 0: the level itself).
  // The events over half the exposure count 0.80-0.98 of the true log change on the natural
  // suite's noiseless scenes, 0.55-0.87 where they are as sparse as on a real DAVIS346. Measured
  // against the level at `fast` (BENCHMARKS.md, "The sensor's reference level"): natural suite
  // 35.71 -> 38.39 dB (every scene up, +0.38 to +5.07), standard 36.53 -> 36.76, hard 33.35 ->
  // 33.64; noisy 35.80 -> 35.70 (flat areas keep more of the events' noise).
  double hysteresis = 0.5;
  // The pixel grid's views see the nearest surface along their rays, and what a near surface hides
  // at mid-exposure from a second layer of cells (PixelGridOptions::occlusion).
  bool occlusion = true;
  // The pixel grid's L-BFGS scaled cell by cell by the loss's curvature (PixelGridOptions::
  // precondition).
  bool precondition = true;
  // The pixel grid's smoothness of the log image (PixelGridOptions::smoothness). 0: chosen by the
  // events it was not fitted to. Its solve is run with the events of a quarter of the pixels held
  // out, at 0.01, 0.03 and 0.1 in turn while the held-out pixels' comparisons with mid-exposure
  // fall, and the last of those is used. A pixel grid follows each pixel's own events, so where a
  // smooth texture fires few of them the noise events become speckle in the image; on textured
  // scenes more smoothing blurs the texture that the held-out events see. Measured at `fast`
  // (BENCHMARKS.md, "The pixel grid"): every natural and hard scene kept 0.01; noisy 35.08 -> 35.25
  // dB (ground_blur15_noisy chose 0.03: 41.24 -> 42.99), standard 36.76 -> 36.79. Not the default:
  // the short solves make a frame about 40% slower, which takes the natural suite's colour scenes
  // without thresholds to 28-31 s at `fast`, over its 25 s.
  double smooth = 0.01;
  // Where no calibration is given (Observation::camera_assumed), the pixel grid's registration
  // estimates the lens's radial distortion (calibrateFromLatentFrames) and every later step uses
  // that camera; the summary says which camera was used (camera_given, camera_estimated,
  // camera_fx, camera_k1).
  bool calibrate = true;
  nerf::HashFieldConfig
      hash;  // levels, features, table; finest resolution adapted to the image when 0
  int finest_resolution = 0;  // 0: the image's larger side
  // The field sees NDC (x, y, depth_scale * z): below 1 the grid's levels have fewer cells along
  // depth than across the image. The views of one exposure differ by millimetres, so depth is
  // weakly observed while the image plane needs pixel resolution. Measured on the fast budget
  // (BENCHMARKS.md): 1 -> 0.1 -> 0.02 took hard_blur2 from 19.9 to 27.7 to 30.0 dB.
  double depth_scale = 0.02;
  nerf::MlpFieldConfig mlp;
  TrajectoryKind trajectory = TrajectoryKind::kCubicSE3;
  // 0: the pixel grid takes the count from its registered motion (knotsByLeaveOneOut, 4 to 7), the
  // fields 4.
  int knots = 0;
  // The pixel grid's L-BFGS stops once its loss fell by less than this fraction of itself over the
  // last 10 steps (0: every step of the budget). `fast` 3e-3, `balanced` 1e-3, `quality` 0. On the
  // natural suite at `fast`'s 100 steps, 1e-3 stopped after 63 on average (no scene moving by more
  // than 0.03 dB), 3e-3 after 45 (at most 0.06 dB; 11.0 -> 6.3 s a frame; BENCHMARKS.md, "When the
  // grid has converged").
  double converged = 1e-3;
  // After its solve the pixel grid refines the motion again from the solved image (3
  // Levenberg-Marquardt steps) and solves the image again from where it was, this many times; the
  // solves before the last stop at a looser convergence (1e-2), since the image moves again. The
  // first refinement, from EDI's frame, leaves the motion short where EDI's frames are (the events
  // under-report small changes); from the solved image, read as the sensor's reference level, it
  // lengthens it. Measured at `fast` against 0 (BENCHMARKS.md, "The motion again from the solved
  // image"): natural suite 38.39 -> 38.59 dB (-0.05 to +0.79), image motion error 0.54 -> 0.50 px.
  int motion_rounds = 1;
  // Before those rounds the pixel grid refines its inverse depth from the solved image this many
  // times: a Gauss-Newton step of its loss (both terms) in each pixel's inverse depth (one change
  // over the 9 x 9 pixels of each pixel's own surface, the samples moved by at most half a pixel),
  // kept where the loss falls. The registration's depth is per tile from EDI's noisy frames; the
  // grid's terms see every pixel. Measured at `fast` against 0 (BENCHMARKS.md, "The depth from the
  // solved image"): natural suite 38.96 -> 39.15 dB (36.45 -> 36.95 over the exposure).
  int depth_steps = 1;
  double knot_init = 0.01;  // knots start at exp(u), u uniform in [-knot_init, knot_init]^6
  // Where the trajectory starts. kIdentity: every knot near identity (the paper). kEvents: a
  // constant rotation over the exposure found from the events by contrast maximisation
  // (rotationFromEvents), the knots fitted to it, then jittered as above; a departure from the
  // paper that takes away the early phase where the trajectory has to find the motion (and the runs
  // that never do; BENCHMARKS.md).
  // kFrames (the default): the motion registered between EDI's latent frames at 9 times
  // (motionFromLatentFrames): a rotation and a translation per time through a plane, or through
  // per-tile depths refined to each pixel's where the parallax is observed (the representation,
  // in the summary), the knots fitted to it, then jittered. It follows the shake's changes of speed
  // and direction and its parallax, which one constant rotation cannot; measured on the natural
  // suite at `fast` (BENCHMARKS.md): events 32.60 dB -> frames 33.2, the exposure's rotation error
  // 0.97 -> 0.4 deg.
  enum class Init { kIdentity, kEvents, kFrames };
  Init init = Init::kFrames;
  int virtual_views = 0;  // n; 0: adapted to the blur length (measured from the events)
  // The pixel grid's most views when they follow the blur length (PixelGridOptions::max_views):
  // `fast` 32, else 64. At 60 px of blur the natural suite's scenes with 32 views instead of 52-60
  // moved by -0.09 to +0.46 dB at about 0.7 times the solve's time, but sharp synthetic edges at
  // 40 px lost up to 0.25 dB (BENCHMARKS.md, "How many views").
  int max_views = 64;
  // The pixel grid's views per pixel of blur (PixelGridOptions::views_per_px), up to max_views.
  // Two instead of one, measured at `fast` with the thresholds given (BENCHMARKS.md, "Two views per
  // pixel of blur"): the natural suite's eight 15 px frames +0.12 to +0.61 dB (+0.33 on average),
  // the noisy suite's 15 px frames +0.19 to +0.43, the standard suite's -0.07 to +0.26, in about
  // 1.5 times the frame's time; at 30 px and more `fast`'s bound of 32 views held the count.
  double views_per_px = 2;
  // The pixel grid takes samples between consecutive views for the sensor's reference (and the
  // blur term) where the views are more than this far apart along the longest image path
  // (PixelGridOptions::between_views_px; px, 0: always).
  double between_views_px = 0.5;
  double alpha = 0.1;  // event window, fraction of the exposure
  // Event windows per step, the event pixels dealt among them (the paper: one window per step). A
  // single window gives all of a step's event gradients the same two times; many windows spread
  // them over the exposure at the cost of two pose evaluations each. Measured on the standard suite
  // at `fast` (BENCHMARKS.md): 1 -> 34.6 dB, 32 -> 34.8, 128 -> 35.3, 256 -> 35.0, 2048 slower and
  // no better.
  int windows = 128;
  // Thresholds (C_on, C_off) of the event term, over contrast.txt. With neither, and the form
  // kAuto, EDI's search estimates c (estimate_contrast): a c inside the search's range is used in
  // the direct form; at an end of the range (the search's energy was monotonic, as on low-texture
  // scenes) the events are normalised. Measured without thresholds at `fast` (BENCHMARKS.md):
  // standard suite 34.41 -> 34.97 dB, noisy 34.48 -> 34.72.
  std::optional<Contrast> contrast;
  bool estimate_contrast = true;
  // The pixel grid without thresholds: the events' counts give c (contrastFromCounts), and the
  // short solves of the grid walk from there to the c whose solved image re-blurs closest to the
  // frame (contrastFromSolves). Off, the grid runs at the counts' c: about a quarter less time a
  // frame, and on the natural suite and 24 photographs outside it no less accurate on average
  // (39.01 -> 39.13 and 40.42 -> 40.51 dB), but the walk is what corrects counts raised by a
  // motion registered too far (a rocket before a far backdrop, mostly translation: c 0.238 -> 0.300
  // for the truth's 0.2, 36.40 -> 34.83 dB) and what tells where nothing fixes c (the grid then
  // declines for the hash field: ground_blur40_noisy 38.69 -> 31.00 without it); the standard,
  // noisy and hard suites lose 0.18, 0.78 and 0.14 dB without it. BENCHMARKS.md, "The counts' c
  // alone".
  bool contrast_walk = true;
  // The event term's form: kDirect compares C-weighted events with the log change (the authors'
  // code on synthetic data; needs known thresholds), kNormalised compares both L2-normalised over
  // the batch (the paper; real data); kAuto: direct when the observation has contrast.txt.
  enum class EventForm { kAuto, kDirect, kNormalised };
  EventForm event_form = EventForm::kAuto;
  // Weight of the event term; < 0: by form, the paper's presets: 0.1 direct (synthetic data), 2
  // normalised (real data) at the paper's 1,024 event pixels per step, scaled with event_rays (the
  // normalised term is a mean of squared differences of unit vectors, so it falls as 1 / pixels:
  // 4 at `fast`'s 2,048; measured without contrast.txt on the standard suite at `fast`,
  // BENCHMARKS.md: β 2 -> 33.5 dB, 4 -> 34.4, 6 -> 34.4). The direct form's accumulated events are
  // off the true log change by up to a threshold at each end of the window; with 0.1 the exact
  // blurry frame weighs more (measured on the standard suite at `fast`, BENCHMARKS.md: 0.1 -> 34.7
  // dB, 0.25 -> 34.5, 1 -> 33.3, 0.05 lost planes_blur40).
  double beta = -1;
  // The blur term is in linear intensity and the event term in log intensity, so their balance
  // shifts with the frame's mean brightness m as m^2. Below dim_frame the blur term is weighed by
  // (dim_frame / m)^2, as if the frame were that bright; 0: never. Measured (BENCHMARKS.md): on
  // hard_dark (m ~ 0.007), without it the field follows the events' log changes with no absolute
  // anchor, 42.9 dB, below the blurry input (48.2); with it 62.7.
  double dim_frame = 0.1;
  int iterations = 2000;
  int blur_rays = 2048;   // split over the n views: blur_rays / n pixels per step
  int event_rays = 2048;  // pixels of the event term per step (2 rays each)
  int samples = 8;        // stratified samples per ray
  double near = 1.0;      // NDC near plane
  // Coarse to fine (BARF, Lin et al., ICCV 2021; not in BeNeRF): the field's encoding starts with
  // its two coarsest bands (hash levels; the MLP's raw position and first frequency) and opens the
  // rest one by one over this fraction of the iterations; 0: every band from the start. Measured at
  // `fast` (BENCHMARKS.md): box_blur40, whose trajectory otherwise locks in late or not at all,
  // 20.8 -> 28.0 dB.
  double coarse_to_fine = 0.4;
  // Iterations fitting the field and knots to EDI's latent frames at the views' times before the
  // BeNeRF loss takes over (not in the paper); 0: none.
  int prefit = 0;
  double field_lr = 1e-2, knot_lr = 3e-3;
  double lr_final = 0.1;  // both rates decay exponentially to this fraction at the last iteration
  double budget_seconds = 0;  // > 0: the iteration count is chosen so that the whole run (training
                              // and renders) fits this wall time
  uint64_t seed = 1;
  // kThreadsFromLoad: the cores that other programs leave idle (of OpenMP's, every core or
  // OMP_NUM_THREADS), measured before the run and followed through it (cores.h); 0: OpenMP's
  // count; N: N threads. With the pixel grid and the hash field the figures are the same bit for
  // bit at any thread count; the MLP's only at one count.
  int threads = kThreadsFromLoad;
  LogMapping log;
  // Checkpoint: written every checkpoint_every iterations and at the end when a path is given;
  // resume continues from one (the same observation and settings).
  std::string checkpoint, resume;
  int checkpoint_every = 500;
  int stop_after =
      0;  // > 0: stop (after checkpointing) at this iteration; resume continues the same run
  int curve_every = 25;  // training-curve points

  // Throws evkit::Error naming the first setting out of its range.
  void check() const;
};

// The budgets: fast, balanced, quality (iterations, rays, samples, field size); throws for others.
BenerfOptions benerfBudget(const std::string& name);

// The one budget grammar of `--set budget=` and `evkit bench --budgets`: a named budget, "60s"
// (seconds of wall time for the whole run, balanced's settings) or "250" (iterations of fast's
// settings). Throws evkit::Error otherwise.
struct BenerfBudget {
  std::string label;  // "fast", "60 s", "250 it"
  BenerfOptions options;
};
BenerfBudget parseBenerfBudget(const std::string& token);

// Every `--set KEY=VALUE` of BeNeRF but budget and preset: key, type, range, help.
const SettingsTable<BenerfOptions>& benerfSettings();
// Options from settings: the budget (balanced without one), then the preset (synthetic: the event
// term compared directly; real: normalised), then every other key; checked.
BenerfOptions benerfOptions(const MethodSettings& settings);

// The blur length in pixels measured from the events: with a contrast c, the events of a pixel
// count the total variation of its log intensity over the exposure, which is about the path length
// times the directional gradient; so length ~ c N_events / ((2/pi) sum |grad log L|), with L a
// latent frame at mid-exposure from EDI.
double measureBlurLength(const Observation& obs);
// The same with the thresholds given (none: EDI searches c) and the log mapping of the run (the
// gradient is of log L as the event model sees it), and the thresholds it used.
struct BlurMeasurement {
  double blur_px = 0;
  double c_on = 0, c_off = 0;
  bool searched = false;  // c from EDI's search
  bool inside = false;    // ... and not at an end of the search's range
};
BlurMeasurement measureBlur(const Observation& obs, const std::optional<Contrast>& contrast,
                            const LogMapping& log = {});
// n from the blur length: about one view per 2 px of motion, within [5, 19].
int virtualViewsFor(double blur_px);

// The camera's rotation over the exposure from its events alone, by contrast maximisation
// (Gallego, Rebecq, Scaramuzza, "A Unifying Contrast Maximization Framework for Event Cameras",
// CVPR 2018): the rotation vector omega (rad, mid-exposure camera frame) such that warping every
// event to mid-exposure by exp(omega (s - 1/2)), s its normalised time, gives the sharpest image of
// warped events (largest variance, Gaussian-smoothed). A constant angular velocity; translation is
// not modelled (it shows up as part of the rotation). blur_px sets the search's first step.
Vector3 rotationFromEvents(const Observation& obs, const nerf::PinholeCamera& camera,
                           double blur_px);

// The camera's motion over the exposure from EDI's latent frames (thresholds as given; none: EDI's
// search): 9 frames at equal steps over the exposure, each registered to the mid-exposure one by
// dense optical flow (DIS, Kroeger et al., ECCV 2016) on a grid of textured points kept where the
// forward and backward flows agree; the flows then explained by a rigid camera (the motion field of
// Longuet-Higgins and Prazdny, 1980, solved exactly by Gauss-Newton with Huber weights) in three
// models of rising richness: a rotation per time alone; a rotation and a translation per time seen
// through one plane (a homography per time); the same through an inverse depth per tile of about
// 24 x 24 px. The scale is not observable: the nearest points (95th percentile of the inverse
// depth) are put at depth 1.5, the NDC near plane being at 1. The representation chosen is the
// plane unless the parallax is observed in the data: the tiles' depths move the image off the best
// plane's motion by more than half a pixel over the exposure (99th percentile of the tracks) and
// take away at least 15% of the plane's residual. The depths' common offset (nearly flat for the
// flows, and where it sits the translation takes part of the rotation) is chosen by the tracks'
// residual over offsets that put the farthest tracks at 0 to 1 of the nearest's inverse depth.
// A tile whose tracks were seen on both sides of mid-exposure may be up to fifteen times nearer
// than those nearest points (a near object that few tracks see), the others no nearer than 1.05.
// Where the depths are chosen, each pixel then takes its own inverse depth from its dense flows
// (Gauss-Newton on the flows at the 8 other times, from the tiles' value, then a 5 x 5 median), and
// each time's motion is fitted again through them, twice; the tiles' depths blur a near layer into
// its surround over a tile and more (a rocket at 2 m before a backdrop at 10 m: 1.3-1.8 px of image
// motion error on the rocket, per pixel 0.8-1.2). That refinement is kept where it lowers the
// tracks' residual (pixel_depth). Where the chosen model's RMS residual is above 1 px (the rigid
// camera does not explain the registration), or fewer than 50 points are tracked, there are no
// poses; with MisfitBar::kUnlessRepeated, between 1 px and kMostMisfitPx there are unless the
// tracked texture repeats (repeatedTextureShare at least kMostRepeatedShare). Measured with the
// thresholds known: on photographs the tracks follow 92-94% of the true path at misfits of
// 1.04-1.27 px, the residual spread over every track; on a grating and a checkerboard 63-81% at
// 1.07-1.09 px, the flows locked onto a repeat and the per-pixel depth absorbing the bias
// (BENCHMARKS.md, "What the registration's misfit measures"). Without the thresholds a misfit
// above 1 px is also the sign of a wrong c, which the search walks away from
// (registerAwayFromSearch): kOnePixel there (at 1.5 px the walk stopped at EDI's c of 0.28 for the
// truth's 0.2 on nat_hubble_rocket_blur60_noisy, and the c found from that motion collapsed it:
// 42.02 -> 27.73 dB); the pixel grid's registrations at the c that the events' counts tell take
// kUnlessRepeated (benerf_train.cc, runPixelGrid).
// With kUnlessRepeated, where the rigid camera does not explain every tracked point, it is fitted
// again to the points whose neighbourhood fired at least kFiredEventsPerPixel (where that leaves
// kMinTracks or more and drops some): EDI's latent frames report only part of the scene's change
// where few events fired, and their flows fall short of the motion there (on a dark scene of four
// smooth layers with noisy events the flows reached 0.80-0.86 of the true motion where 1-2 events
// per pixel had fired, 0.89-0.96 at 2-4 and 0.97-1.0 beyond, and the points under 2 held every
// model's misfit above 1.5 px; BENCHMARKS.md, "Where few events fired").
enum class MisfitBar { kOnePixel, kUnlessRepeated };
inline constexpr double kMostMisfitPx = 1.5, kMostRepeatedShare = 0.4, kFiredEventsPerPixel = 2;
struct ExposureMotion {
  std::vector<StampedPose> poses;  // T_mid_t: the camera at each time in the mid-exposure frame
  bool depth = false;              // the depth model chosen (else the plane)
  double parallax_px = 0;  // the tiles' image motion off the best plane's, over the exposure
  // The rank correlation over the tiles of their inverse depths' departures from the best plane,
  // fitted to the times before mid-exposure and to those after it apart (NaN: too few tiles). A
  // depth that the image shows moves it alike in both halves; the flows' errors differ between
  // the halves' frames, and an error of the mid frame's own departs with opposite signs, the
  // translation turning about mid-exposure. Where the tiles take away under 15% of the plane's
  // misfit, they are chosen above kDepthAgreement, and beyond three standard errors of a rank
  // correlation without any where the tiles are few (measured with the thresholds: -0.17-0.32 on
  // the planar frames that the rule can reach, 0.43-0.94 on the five layered ones it took, where
  // the depths gained 0.02-0.97 dB; ranks, not values: a few border tiles whose departures agreed
  // put a planar frame at 0.61 by value; BENCHMARKS.md, "The depths beside the plane").
  double depth_agreement = std::nan("");
  int depth_agreement_tiles = 0;  // the tiles it is taken over
  double residual_rotation_px = 0, residual_plane_px = 0,
         residual_depth_px = 0;   // RMS of each model's residuals
  bool pixel_depth = false;       // the depth model refined to each pixel's own depth
  double residual_pixels_px = 0;  // its RMS residual
  int tracks = 0;                 // textured points tracked
  // Textured points not tracked: their neighbourhood fired under one event per pixel over the
  // exposure, and EDI's latent frames do not move there.
  int tracks_without_events = 0;
  // Tracked points left out of the fit where every point's did not explain the registration: they
  // fired under kFiredEventsPerPixel (0 where all were kept).
  int tracks_few_events = 0;
  // The chosen model's inverse depth (1 / z in the poses' units) at every pixel of the mid-exposure
  // frame (float32); empty without poses.
  cv::Mat inverse_depth;
  // repeatedTextureShare of the tracked points where the misfit asked for it (above 1 px and up to
  // kMostMisfitPx); -1 elsewhere.
  double repeated_share = -1;
  // With pixel_depth, the same refinement where each pixel whose own flows settle nothing next to a
  // depth edge takes the nearest depth within 8 px (the occluding side's) instead of the tiles'
  // (which ramp from one side's depth to the other's: no surface's); present where the depths'
  // offset was chosen, it differs and its tracks' residual passes kUnlessRepeated's bar (with
  // either bar for the poses: its extra misfit is its own, at the pixels whose flows failed). Which
  // of the two the data favour is for the caller to judge (the pixel grid: by its loss on EDI's mid
  // frame).
  struct NearEdges {
    std::vector<StampedPose> poses;
    cv::Mat inverse_depth;
    double residual_px = 0;
  };
  std::optional<NearEdges> near_edges;
};

// The share of `points` (pixels of an 8-bit image) whose neighbourhood repeats within the flow's
// reach: the kRepeatPatchPx square around the point, at half size, correlated (normalised) with the
// image within kRepeatReachPx of it, a repeat being a place above kRepeatCorrelation outside the
// central peak (the places joined to the point's own above a correlation of 0.5). Points whose
// patch leaves the image, or not finite, are not counted; 0 where none is. Measured on every
// textured point: 0-33% on the natural suite's and other photographs (brick walls the most),
// 47-81% on the synthetic suites' checkerboards, gratings and stripes; on every fourth track, as
// the registration asks it, 2-8% on the three photographs that the band lets through and 61-66%
// on the two suite frames that it declines.
inline constexpr int kRepeatPatchPx = 22, kRepeatReachPx = 32, kRepeatSampleEvery = 4;
inline constexpr float kRepeatCorrelation = 0.9f;
double repeatedTextureShare(const cv::Mat& image8, std::span<const Eigen::Vector2d> points);
// choose_depth_offset false: the depths' common offset is left where the alternation of motions and
// depths put it (the image motion nearly alike, the split between rotation and translation less
// right; about 0.5 s less), and no near sides' alternative (ExposureMotion::near_edges) is made,
// for registrations that are only scored. `intervals`: the exposure is
// cut into that many (even, 2-64), EDI's latent frame is made at each end and the motion
// registered there: kScoredIntervals (the default, half the cost) for the contrast's search and the
// first registration, kTrajectoryIntervals where those nine poses are too few for the trajectory.
// Nine poses determine a spline of at most 7 knots with one pose left out and another to spare; a
// shake that turns four times within the exposure (8 knots) needs more: on one at 30 px the pixel
// grid got 23.05 dB from nine poses and 34.71 from seventeen (EDI 31.91; BENCHMARKS.md, "A motion
// that turns").
inline constexpr int kScoredIntervals = 8, kTrajectoryIntervals = 16;
ExposureMotion motionFromLatentFrames(const Observation& obs, const PinholeCamera& camera,
                                      const std::optional<Contrast>& contrast,
                                      const LogMapping& log = {}, bool choose_depth_offset = true,
                                      int intervals = kScoredIntervals,
                                      MisfitBar bar = MisfitBar::kOnePixel);

// The registration's misfit: its chosen model's RMS residual (px); infinite where too few points
// were tracked to fit one.
double registrationMisfit(const ExposureMotion& motion);
// Without thresholds, where the registration at EDI's searched c (`at_searched`) failed: the
// registration (`registerAt`) at c's away from it by steps of 2^(1/3), at most six, and the first
// that registers, with its c_on in `registered_c` (0 where none did; the poses empty then). Down
// from the top of EDI's range (its search scores sharpness, which a c too large raises too, and
// EDI's frames then carry ghost edges that the flow cannot follow: most natural scenes), up from
// its bottom (frames still blurred: below the bottom's 0.1 on a 50 px blur with noise, truth 0.2,
// the first to register was 0.025, a motion collapsed with its c), and from inside it the way the
// misfit falls (on that scene least at the truth, 0.67 px, against 1.14 at 0.1; BENCHMARKS.md,
// "Outside the suites: shakes, seeds and blurs not in them").
ExposureMotion registerAwayFromSearch(
    const BlurMeasurement& measured, const ExposureMotion& at_searched,
    const std::function<ExposureMotion(const Contrast&)>& registerAt, double* registered_c);

// The thresholds, when none are given, from the events' counts and the blurry frame alone, along
// the motion. Over the exposure a pixel's net count n = N_on - ratio N_off is its log change in
// units of c_on. Averaged along each pixel's path (as the blur averages the scene), the count image
// equals, where the image motion is locally uniform, the log of the blurry frame at the path's end
// less that at its start, over c, to first order in the log's curvature along the path: the
// least-squares slope of the one on the other is 1 / c, the start. In linear intensity the blur's
// identity holds without that approximation: EDI's frames at c change over the exposure by
// L_start (exp(c n) - 1) at each pixel, and that change averaged along each path is the blurry
// frame at the path's end less at its start; the slope of the averaged change over c on that
// difference (each pixel's relative to its own blurry value) is 1 / c, a fixed point from the
// start. In both the events' noise is in the regressand and does not bias the slope, where it
// biases the short solves' misfit towards small c wherever it is a good share of the events
// (BENCHMARKS.md, "The thresholds from the events' counts"). `correlation`: of the counts and the
// log change, over the pixels whose paths stay inside the frame; c is NaN where they do not rise
// together. Where `ratio` is not positive, the ratio c_off / c_on is found from the counts first
// (`ratio`), with the bounds the two regressions of the ON and OFF counts on each other put on it
// (`ratio_low`, `ratio_high`); where those hold 1 the counts cannot tell the thresholds apart and
// the ratio is 1; NaN where the two regressions' slopes are not both positive (c is not counted
// then). The counts meet the blur of the log, the blurry frame gives the log of the blur: the ratio
// is found again from the frame's log less each pixel's Jensen gap, which EDI's frame at the c and
// ratio found gives, until it settles. The exposure's events are those in [start, end).
struct CountedContrast {
  double c = 0, correlation = 0;
  double ratio = 0, ratio_low = 0, ratio_high = 0;
};
CountedContrast contrastFromCounts(const Observation& obs, const PinholeCamera& camera,
                                   const Trajectory& motion, const cv::Mat& inverse_depth,
                                   double ratio, const LogMapping& log);
// The camera where no calibration was given: the radial distortion k1 (OpenCV's model, k2 = p1 =
// p2 = 0) that lets the rigid camera explain the points tracked between EDI's latent frames best
// (the per-tile depth model's RMS residual), over the barrel ladder below, and the motion
// registered through it. Lens distortion is not a projective map, so no rigid motion of a pinhole
// camera explains it: on a wide lens a rotation moves the image's corners less than its centre.
// The assumed camera stays unless a k1 takes away kLensGain of the residual. The focal length is
// kept: one exposure's motion hardly tells it, and on the wide lenses measured (fx 0.72 width;
// BENCHMARKS.md, "Without a calibration") a search over 0.6-1.5 times the assumed one kept the
// assumed one.
inline constexpr double kLensK1[] = {0, -0.1, -0.2, -0.3, -0.4, -0.5};
inline constexpr double kLensGain = 0.05;
inline constexpr double kDepthAgreement = 0.4;  // ExposureMotion::depth_agreement
struct CalibratedMotion {
  PinholeCamera camera;
  ExposureMotion motion;
  bool estimated = false;  // a candidate won over the assumed camera
  double residual_assumed_px = 0;
  int cameras_tried = 0;
};
CalibratedMotion calibrateFromLatentFrames(const Observation& obs, const PinholeCamera& assumed,
                                           const std::optional<Contrast>& contrast,
                                           const LogMapping& log = {},
                                           int intervals = kScoredIntervals,
                                           MisfitBar bar = MisfitBar::kOnePixel);

// One optimisation problem: the observation's data, the field and the trajectory. Templated on the
// scalar so that the whole pipeline can be checked against finite differences in double.
template <typename T>
class BenerfProblem {
 public:
  BenerfProblem(const Observation& obs, const BenerfOptions& options, int virtual_views);

  struct Batch {
    std::vector<int> blur_pixels;  // pixel indices y * width + x
    std::vector<int> event_pixels;
    std::vector<int64_t> window_begin,
        window_end;  // the event windows (event pixel i: window i mod count)
    std::vector<float>
        jitter;  // per ray and sample, in [0, 1): blur rays first, then event rays (a, b)
  };
  Batch sampleBatch(std::mt19937_64& rng) const;

  struct Loss {
    double total = 0, blur = 0, event = 0;
  };
  // Loss of the batch; zeroes, then fills the field's gradients and knot_gradient (6 per knot:
  // right-perturbation tangent) when it is not null.
  Loss evaluate(const Batch& batch, Eigen::VectorXd* knot_gradient);
  // Per-view targets (float32, the blurry frame's size and channels, one per virtual view): while
  // set, the blur term compares each view's render with its target instead of their mean with the
  // blurry frame. Empty: the blurry frame.
  void setViewTargets(std::vector<cv::Mat> targets);

  // A sharp render at time t (linear, the blurry frame's channels) and, optionally, its disparity
  // (1 / depth in the units of the NDC frame, background = 0).
  cv::Mat render(int64_t t_us, cv::Mat* disparity = nullptr);
  // Wall seconds of one full render, extrapolated from rendering one batch of rows.
  double renderSeconds();

  nerf::RadianceField<T>& field() { return *field_; }
  Trajectory& trajectory() { return trajectory_; }
  const nerf::PinholeCamera& camera() const { return camera_; }
  int virtualViews() const { return views_; }
  double viewTime(int k) const {
    return (k + 0.5) / views_;
  }  // view k's normalised time in the exposure
  int64_t eventsInExposure() const { return static_cast<int64_t>(events_.size()); }
  bool normalisedEvents() const { return normalised_; }
  double beta() const { return beta_; }
  double blurWeight() const { return blur_weight_; }

 private:
  double accumulatedEvents(int pixel, int64_t t_begin, int64_t t_end) const;
  // The two terms of the loss over the batch's rendered rays; each adds its dL/d(colour).
  double blurTerm(const Batch& batch, std::vector<T>& d_colour) const;
  double eventTerm(const Batch& batch, std::vector<T>& d_colour) const;
  int rowsPerRenderBatch() const;
  cv::Mat renderRows(int64_t t_us, cv::Mat* disparity, int rows);  // the first `rows` rows

  BenerfOptions options_;
  nerf::PinholeCamera camera_;
  int channels_, views_;
  cv::Mat blurry_;                     // float32
  std::vector<cv::Mat> view_targets_;  // float32; empty: the blur term
  Trajectory trajectory_;
  std::unique_ptr<nerf::RadianceField<T>> field_;
  nerf::RayBatchOptions rays_options_;
  nerf::RayBatch<T> rays_;  // the training batch's rays, samples and renders
  double c_on_ = 1, c_off_ = 1;
  bool known_contrast_ = false;
  bool normalised_ = true;  // the event term's form
  double beta_ = 1;
  double blur_weight_ = 1;           // the blur term's weight: 1, more for a dim frame
  PixelEventIndex events_;           // the exposure's events by pixel
  std::vector<double> event_level_;  // per event of events_: the accumulated polarity after it
};

class BenerfDeblurrer final : public Deblurrer {
 public:
  explicit BenerfDeblurrer(const BenerfOptions& options) : options_(options) {}
  std::string name() const override { return "benerf"; }
  DeblurResult run(const Observation& obs, const DeblurRequest& request) override;

 private:
  BenerfOptions options_;
};

// Parses `evkit deblur --method benerf --set KEY=VALUE` settings (documented in the README).
std::unique_ptr<Deblurrer> makeBenerf(const MethodSettings& settings);

}  // namespace evkit
