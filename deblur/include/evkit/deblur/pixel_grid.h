// BeNeRF's scene as a pixel grid at the mid-exposure camera, each cell at its registered inverse
// depth (pixel_grid.cc, pixel_grid_views.cc).
#pragma once

#include <Eigen/Core>
#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <functional>
#include <opencv2/core.hpp>
#include <vector>

#include "evkit/deblur/observation.h"
#include "evkit/events/log_intensity.h"
#include "evkit/nerf/camera.h"
#include "evkit/spline/trajectory.h"

namespace evkit {

struct PixelGridOptions {
  double beta = 0.01;      // weight of the event term (a mean over pixels and views)
  double dim_frame = 0.1;  // as BenerfOptions::dim_frame
  int min_views = 8, max_views = 64;
  // The views per pixel of the longest image path over the exposure, within [min_views,
  // max_views]: the blur integral by the midpoint rule at 1 / views_per_px px apart.
  double views_per_px = 1;
  // With hysteresis, the sensor's reference and the blur term take samples between consecutive
  // views as well (PixelGridProblem::BlurQuadrature) where the views are more than this far apart
  // along the longest image path (px; 0: at any spacing).
  double between_views_px = 0.5;
  int subdivision = 1;  // cells per pixel along each axis
  // Weight of the squared log differences between neighbouring cells, the same prior over the
  // image at any subdivision (as set for 2 x 2 cells a pixel; pixel_grid.cc, evaluate).
  double smoothness = 1e-2;
  // In colour, the weight of the same for the chroma (each channel's log less the mean of the
  // channels' logs), over `smoothness`: the events see brightness only.
  double chroma_smoothness = 0;
  // The penalty of the comparison with mid-exposure: r^2 for 0 (BeNeRF's), else the pseudo-Huber
  // 2 d^2 (sqrt(1 + (r / d)^2) - 1), r^2 near 0 and linear beyond d (log units), so that a pixel
  // whose own thresholds have drifted it (see event_window) or a noise event weighs less over the
  // rest of the exposure. The windows' comparisons stay squared.
  double event_robust = 0;
  // The event term compares each view with mid-exposure and, when event_window > 0 (a fraction
  // of the exposure, as BeNeRF's random windows, BenerfOptions::alpha), also each view with the
  // view that far on, each a mean weighted by beta. Long windows alone add up the pixels' own
  // threshold errors (a DAVIS pixel's ON and OFF thresholds differ from the nominal by 10-20%
  // each, so that crossing a dark bar and back leaves it tenths of a log unit off where it
  // started); the short ones hold the local changes (BENCHMARKS.md, "The pixel grid").
  double event_window = 0;
  int motion_steps = 6;  // Levenberg-Marquardt steps on the motion before the image
  // The events are compared with the sensor's reference level rather than the log level itself,
  // when > 0. A DAVIS pixel fires when its log level has moved a threshold from the level of its
  // last event, so its reference trails a rising level by up to C_on and a falling one by up to
  // C_off, and a level that turns back within that band fires nothing: the events under-report
  // every change that turns (a shake, texture passing by). Over the pixels' unknown offsets the
  // expected reference follows the level with play: it stays put until the level is more than
  // `hysteresis` C_on above it or `hysteresis` C_off below it, then trails it by that much
  // (0.5: the mean of a uniform offset). The views and mid-exposure are its samples in time order;
  // where in the band the first one starts is unknown, so the reference is the mean of four plays
  // started at the midpoints of four equal parts of it.
  double hysteresis = 0;
  // A channel of the blurry frame at or above this (linear intensity) is taken as clipped by the
  // sensor: it says only that the exposure's mean reached the top, so a re-blur above it costs
  // nothing there (the blur term's residual is min(mean of the views, B) - B). 0 or below: every
  // pixel is a mean. EdiOptions::saturated masks the same pixels (both Frame::kClipped).
  double saturated = Frame::kClipped;
  // Where the registered depths have edges, each view's pixel sees the nearest surface its ray
  // meets on the mid image (a z-buffer over the depths around where it lands), and what a near
  // surface hides at mid-exposure from a second layer of cells behind the first, so that the
  // background the near surface's edge uncovers has cells of its own (PixelGridProblem::layered).
  // false: each pixel's two lookups alone (a cheaper problem for the thresholds' search).
  bool occlusion = true;
  // solve's L-BFGS takes the loss's curvature in each unknown (PixelGridProblem::curvature) as its
  // initial inverse Hessian's shape, scaled as usual by the newest pair. The blur term is stiffer
  // in bright cells than in dark ones by the intensity squared (the unknowns are log intensities)
  // and the cells that few views see (the margin, the layer behind) are softer than the rest, so
  // that one step size for all held the bright cells back. Measured at `fast` on the natural suite
  // (BENCHMARKS.md, "The solve's curvature"): 16% fewer steps, the most where the solve was
  // longest.
  bool precondition = true;
  LogMapping log;
};

// The blur term is in linear intensity and the event term in log intensity, so their balance
// shifts with the frame's mean brightness m as m^2: below dim_frame the blur term is weighed as if
// the frame were that bright, (dim_frame / m)^2 (BenerfOptions::dim_frame); else 1.
double dimFrameWeight(const cv::Mat& blurry, double dim_frame);

// A position on the canvas: its bilinear stencil's top-left cell and the offsets.
struct CanvasTaps {
  int index;
  float ax, ay;
};

class PixelGridProblem {
 public:
  // `motion`: the camera at each time of the exposure in the mid-exposure camera's frame (T_mid_t);
  // `inverse_depth`: 1 / z of the scene at each mid-exposure pixel in the motion's units (float32;
  // empty: at infinity, rotation alone moves the image).
  PixelGridProblem(const Observation& obs, const PinholeCamera& camera, const Trajectory& motion,
                   const cv::Mat& inverse_depth, const Contrast& contrast,
                   const PixelGridOptions& options);

  struct Terms {
    double blur = 0, event = 0;  // the two terms' means, unweighted
  };
  // The unknowns: the canvas's log intensities (the image and its margin), row-major, channels
  // interleaved, then those of the layer behind's cells (layered()) in the canvas's order.
  int size() const { return (canvas_w_ * canvas_h_ + behindCells()) * channels_; }
  // Whether some view sees what a nearer surface hides at mid-exposure, so that the canvas has a
  // second layer of cells behind the first there (the background a near surface's edge uncovers):
  // the cells of its samples' stencils and kBehindApron cells around them.
  bool layered() const { return !behind_cell_.empty(); }
  int behindCells() const { return static_cast<int>(behind_cell_.size()); }
  // The share of the views' samples taken from the layer behind: 0 where not layered().
  double behindShare() const;
  // Whether view `view`'s sample of pixel (x, y) is taken from the layer behind.
  bool seenBehind(int view, int x, int y) const {
    return behind(taps_[viewSlot(view, static_cast<size_t>(y) * camera_.width + x)]);
  }
  int views() const { return views_; }
  // Whether the blur term and the sensor's reference take samples between the views as well
  // (BlurQuadrature; PixelGridOptions::between_views_px).
  bool samplesBetweenViews() const { return between_gap_ >= 0; }
  int margin() const { return margin_; }
  // The longest image path of a pixel over the exposure, by the motion and the inverse depth
  // (empty: at infinity), sampled at the centres of a 16 x 16 grid of cells: the longest but for
  // the 2% longest, which a few pixels' own depths far off can make (pixel_depth).
  // On the natural suite (`fast`) the longest alone was 20-56% over the truth on 6 of 24 scenes,
  // from pixels along the border, while the paths' 50th, 95th and 99th percentiles were within 1 px
  // of the truth's.
  double blurLength() const { return blur_px_; }
  static double longestImagePath(const PinholeCamera& camera, const Trajectory& motion,
                                 const cv::Mat& inverse_depth, int64_t t0_us, int64_t t1_us);
  // The canvas with `mid_image` inside and its border replicated into the margin.
  std::vector<double> start(const cv::Mat& mid_image) const;
  // The loss (weighted blur term + weighted event term) and, optionally, its gradient.
  double evaluate(const std::vector<double>& x, std::vector<double>* gradient,
                  Terms* terms = nullptr) const;
  // L-BFGS from x until `iterations` or the deadline (or until no step lowers the loss, or the
  // loss fell by less than the fraction `converged` of itself over the last kConvergedSteps steps);
  // returns the iterations done. progress(iteration, loss) after each.
  static constexpr int kConvergedSteps = 10;
  int solve(
      std::vector<double>& x, int iterations, Terms* terms = nullptr,
      std::chrono::steady_clock::time_point deadline = std::chrono::steady_clock::time_point::max(),
      const std::function<void(int, double)>& progress = {}, double converged = 0) const;
  // A Gauss-Newton approximation of the loss's curvature in each unknown at u, each residual's
  // samples taken alone (a pixel's samples that share a cell are not summed before squaring) and
  // the reference level's plays as the level itself: solve's preconditioner (L-BFGS's initial
  // inverse Hessian, up to its scale). The blur term's curvature in a cell's log intensity grows as
  // the intensity squared and the event term's does not, so that bright cells are stiffer than
  // dark ones by the image's contrast squared, and a cell that few views see (the margin, the
  // layer behind) is softer than one that all see.
  std::vector<double> curvature(const std::vector<double>& u) const;
  // Levenberg-Marquardt steps on the motion with the image u fixed, on every other row and column
  // (the normal equations and each trial motion's blur and event terms there; a step is taken when
  // they fall); returns those terms at the motion kept.
  double refineMotion(const std::vector<double>& u, int iterations);
  // The loss's gradient with respect to the knots' right perturbations (6 per knot), with the
  // image u fixed, from every `stride`-th row and column.
  Eigen::VectorXd motionGradient(const std::vector<double>& u, int stride = 1) const;
  // The loss's gradient in each mid-frame pixel's inverse depth (the blur and event terms; the
  // image and the motion fixed), and a Gauss-Newton curvature there: each view's sample is taken
  // through the depth at one mid-frame pixel, whose derivative it takes. CV_64F maps at the
  // camera's size, in evaluate's units. Samples taken behind a nearer surface or across a depth
  // edge are left out.
  struct DepthNormals {
    cv::Mat curvature, gradient;
    cv::Mat move_rate;  // the most a view's sample of the pixel moves per unit of its depth (px)
  };
  DepthNormals depthNormals(const std::vector<double>& u) const;
  // The inverse depth after one Gauss-Newton step of the loss in it, each pixel's step the
  // least squares of one change over the (2 radius + 1)^2 pixels around it that lie on its own
  // surface (their normals summed; a depth edge's other side left out).
  cv::Mat refinedInverseDepth(const std::vector<double>& u, int radius) const;
  const cv::Mat& inverseDepth() const { return inverse_depth_; }
  // The solved canvas of `other` (a problem on the same frame) in this one's layout: each cell and
  // each cell of the layer behind that both hold, the rest from this problem's start at the
  // other's rendered mid frame.
  std::vector<double> carriedFrom(const PixelGridProblem& other,
                                  const std::vector<double>& u) const;
  const Trajectory& motion() const { return motion_; }
  void setMotion(const Trajectory& motion);  // the same exposure's
  void setSmoothness(double smoothness) { options_.smoothness = smoothness; }
  // Leaves the events of one 8 x 8 block of pixels in four out of the loss (evaluate, solve), so
  // that heldOutEventTerm scores the image on events it was not fitted to.
  void holdOutEvents();
  // The mean penalty of the held-out pixels' comparisons with mid-exposure (the event term's
  // first part, unweighted); 0 when none are held out.
  double heldOutEventTerm(const std::vector<double>& u) const;
  // The share of the views' samples seen across a depth edge, whose comparisons with the events
  // are left out (across_): 0 on a plane.
  double acrossShare() const;
  // Whether view `view`'s sample of pixel (x, y) is one of them.
  bool seenAcrossDepthEdge(int view, int x, int y) const {
    return across_[viewSlot(view, static_cast<size_t>(y) * camera_.width + x)] != 0;
  }
  // Each pixel's share of the blur term, unweighted: the squared residuals of its channels, summed
  // (float64, the frame's size).
  cv::Mat blurResiduals(const std::vector<double>& u) const;
  // The image the camera sees at time t.
  cv::Mat render(const std::vector<double>& x, int64_t t_us) const;

 private:
  // Where pixel (x, y) of the camera at the pose (R, t) sees the mid image (no margin), and the
  // inverse depth it took.
  Eigen::Vector2d cellOf(int x, int y, const Matrix3& R, const Vector3& t,
                         double* rho_used = nullptr) const;
  // What pixel (x, y) of the camera at the pose (R, t) sees: where on the mid image (no margin),
  // through which inverse depth, whether from the layer behind, and whether seen across a depth
  // edge (across_) (pixel_grid_views.cc). `allocating`: the layer behind's cells are being chosen,
  // and it is taken to hold every cell.
  struct ViewSample {
    Eigen::Vector2d q;
    double rho = 0;
    bool behind = false, across = false;
  };
  ViewSample viewSample(int x, int y, const Matrix3& R, const Vector3& t,
                        bool allocating = false) const;
  // viewSample's first part: the two lookups on the inverse depth and whether across a depth edge,
  // for the ray direction Rd = R d (pixel_grid_geometry.h).
  ViewSample lookups(int x, int y, const Vector3& Rd, const Vector3& t) const;
  // The stencil of a mid-image position on the canvas's cells, in the layer behind for `behind`
  // (its index then -1 less the canvas's cell: behind()).
  CanvasTaps tapsOf(const Eigen::Vector2d& q, bool behind) const;
  static bool behind(const CanvasTaps& t) { return t.index < 0; }
  // Whether the layer behind has cells for a stencil at q.
  bool behindHolds(const Eigen::Vector2d& q) const;
  // A stencil's four cells among the unknowns (top-left, top-right, bottom-left, bottom-right).
  std::array<size_t, 4> corners(const CanvasTaps& t) const;
  // The channels of the unknowns x at a stencil of the layer behind, and at one of either layer.
  void sampleBehind(const double* x, const CanvasTaps& t, double* out) const;
  void sampleTaps(const double* x, const CanvasTaps& t, double* out) const;
  // The image's value at cell (i, j) of a canvas with S cells per pixel (image coordinates (i / S -
  // margin, j / S - margin), bilinear; outside the image the nearest edge's value), channel c.
  double canvasValue(const cv::Mat& image, int i, int j, int c, int S) const;
  // Gives the layer behind cells where the views' samples need them (after buildTaps with
  // `allocating`; findBlockRows then gives the blocks' ranges of them).
  void allocateBehind();
  // The start of the layer behind: the mid image with each depth edge's far side carried into its
  // near side.
  cv::Mat behindStart(const cv::Mat& mid_image) const;

  // change_: each view's log change since mid-exposure from the events of the exposure.
  void accumulateEvents(const EventSpan& events, const Contrast& contrast);
  // nearest_, farthest_ and most_move_ from the inverse depth and the views' poses.
  void findSurfaces();
  // Every view's stencils from the motion, and block_rows_ (not while `allocating`, viewSample's).
  // With a `stride` over 1, only those of every stride-th row and column (and across_pixels_ of
  // those pixels alone), and no block_rows_: the stencils of the loss on those pixels alone
  // (dataTerms).
  void buildTaps(bool allocating = false, int stride = 1);
  void findBlockRows();  // block_rows_ from the stencils
  // The frame's rows in kRowBlocks blocks whatever the thread count: each block's sums and its
  // share of the gradient (over the canvas rows its views reach, block_rows_) are its own, and the
  // blocks are added in order, so that one thread and many give the same bits.
  static constexpr int kRowBlocks = 16;
  int blockBegin(int block) const { return camera_.height * block / kRowBlocks; }
  // The event term's window in views (0: against mid-exposure).
  int eventLag() const {
    if (!(options_.event_window > 0)) return 0;
    return std::clamp(static_cast<int>(std::lround(options_.event_window * views_)), 1,
                      std::max(1, views_ - 1));
  }
  // The blur and event terms of evaluate, in its units, from the cells' intensities x on every
  // `stride`-th row and column; with `blocks`, each row block's gradient of them in x (over the
  // canvas rows it reaches, block_rows_, and the layer behind's cells, block_behind_). With a
  // stride over 1 no gradient: the stencils of the other pixels may be stale (buildTaps' stride).
  struct DataTerms {
    double blur = 0, event = 0;
  };
  struct BlockGradients {
    std::vector<std::vector<double>> front, behind;
  };
  DataTerms dataTerms(const std::vector<double>& x, int stride, BlockGradients* blocks) const;
  // The weights of the data terms' squared residuals in evaluate's units: the blur term's (a mean
  // over pixels and channels), and the event term's comparisons with mid-exposure and its windows'
  // (means over pixels and views, and over the views a window fits, weighted by beta).
  struct TermScales {
    double blur = 0, event = 0, window = 0;
  };
  TermScales termScales() const;
  // The smoothness's divisor (evaluate): the canvas's pixels times the channels and the default
  // cells a pixel, so that its weights are per pixel at any subdivision.
  double smoothnessPixels() const;
  // The Gauss-Newton normal equations of the loss in the knots' right perturbations, from
  // intensities x (the weighted sum's half gradient and its approximate Hessian).
  void normalEquations(const std::vector<double>& x, int stride, Eigen::MatrixXd& hessian,
                       Eigen::VectorXd& gradient) const;
  double intensityOf(double u, double* slope) const;
  // Every cell's intensity from its log value, and optionally each dI/du.
  std::vector<double> intensities(const std::vector<double>& u,
                                  std::vector<double>* slopes = nullptr) const;
  void intensities(const std::vector<double>& u, std::vector<double>& x,
                   std::vector<double>* slopes) const;
  // Where pixel (px, y)'s mid-exposure cell, the first of its S x S, starts among the cells'
  // values.
  size_t midCell(int px, int y) const {
    const int S = options_.subdivision;
    return (static_cast<size_t>((y + margin_) * S) * canvas_w_ +
            static_cast<size_t>((px + margin_) * S)) *
           static_cast<size_t>(channels_);
  }
  // Where view `view` of pixel `pixel` is in taps_ and change_.
  size_t viewSlot(int view, size_t pixel) const {
    return pixel * static_cast<size_t>(views_) + static_cast<size_t>(view);
  }
  static constexpr int kReferencePlays = 4;
  int referencePlays() const { return band_up_ > 0 || band_down_ > 0 ? kReferencePlays : 1; }
  // The event term's penalty of a residual and its weight w (the penalty's derivative is 2 w r).
  double eventPenalty(double r, double* weight) const;  // from a log value, and dI/du
  // A mid-image coordinate on the canvas's cell grid.
  double cellCoordinate(double image) const { return (image + margin_) * options_.subdivision; }
  // The channels of the unknowns x at a stencil (either layer), and their derivatives in the
  // stencil's position along x and y (per pixel of the mid image).
  void sampleSlopes(const double* x, const CanvasTaps& t, double* value, double* du,
                    double* dv) const;

  // The blur term's quadrature of one pixel's exposure (dataTerms, normalEquations, depthNormals,
  // blurResiduals). The views are the midpoints of V equal parts of the exposure, and between two
  // consecutive views the pixel's path on the canvas is taken as straight, so that the midpoint of
  // their two positions is what it sees at the time between theirs: the mean over the exposure is
  // the midpoint rule on 2V - 1 samples half a view apart, the views' and the V - 1 between them,
  // each weighted 1 / (2V), the first and the last view 3 / (4V) (they stand for the exposure's
  // first and last quarter of a view as well). The samples between views also serve the sensor's
  // reference level (sampleOrder), where they matter most (BENCHMARKS.md, "The samples between the
  // views"). Where the two views' samples are not on one stretch of canvas (either is from the
  // layer behind, or they are farther apart than the path's step allows: a depth edge between
  // them), the mean of the two stands for the sample between, and the reference does without it.
  struct BlurQuadrature {
    std::vector<double> view_weight;  // per view, with its shares of the means that stand in
    std::vector<CanvasTaps> between;  // per pair of consecutive views, the stencil between them
    std::vector<uint8_t> sampled;     // per pair, whether `between` is sampled
    double between_weight = 0;
  };
  // The quadrature of the pixel whose views' stencils are taps[0..V).
  void blurQuadrature(const CanvasTaps* taps, BlurQuadrature& out) const;
  // The channels of the quadrature's samples between views from x ((V - 1) x C; those not
  // sampled left as they are).
  void sampleBetween(const double* x, const BlurQuadrature& quadrature, double* between) const;
  // A pixel's samples from x and their greys and log levels, indexed as referenceLevels takes
  // them (the views, V: mid-exposure, whose cell starts at `mid`, V + 1 + i: the sample between
  // views i and i + 1): the views' channels into `colour` (V x C), the quadrature, the samples
  // between views into `between` (sampleBetween), and the order of the samples in time
  // (sampleOrder), whose count it returns. Only the samples between views that the order takes
  // have a level.
  int pixelLevels(const double* x, size_t pixel, size_t mid, BlurQuadrature& quadrature,
                  double* colour, double* between, double* greys, double* levels, int* order) const;
  // The sample between views i and i + 1 (sampled): its channels and their derivatives in its
  // position (sampleSlopes), its log level, and that level's derivative in its position (0 where
  // it is dark).
  Eigen::Vector2d betweenLevel(const double* x, const BlurQuadrature& quadrature, size_t i,
                               double* value, double* du, double* dv, double* level) const;
  // The blur term's mean of one pixel's channels from its views' samples (V x C) and those between
  // them (sampleBetween).
  void blurMean(const double* colours, const double* between, const BlurQuadrature& quadrature,
                double* mean) const;
  // A pixel's samples of the exposure as one array of levels (2V entries): the views 0..V-1,
  // mid-exposure V, the samples between views k and k + 1 at V + 1 + k.
  // The sensor's reference level at each sample of `order` (count indices into the levels, in time
  // order; sampleOrder) from their log levels (PixelGridOptions::hysteresis): the mean of
  // referencePlays() plays, each started at another offset within the band (the pixel's offset when
  // the exposure opens is unknown), each the log level of its source sample source[i * plays + m]
  // plus a constant; without hysteresis the levels themselves (one play, its own source).
  void referenceLevels(const double* levels, const int* order, int count, double* reference,
                       int* source) const;
  // The gradient of the loss to the samples' log levels (d_level, 2V entries, 0 where not in the
  // order) from its gradient to their references (d_reference), through referenceLevels' sources:
  // each reference is the mean of its plays' source levels.
  void referenceGradient(const double* d_reference, const int* order, int count, const int* source,
                         double* d_level) const;
  // The samples the reference's plays run over, in time order, into `order` (at most 2V); returns
  // their count: the views, mid-exposure and, with hysteresis, the samples between views that the
  // blur term takes (BlurQuadrature; the one at mid-exposure's time is mid's own). A play that
  // steps from view to view misses every turn of the level between them, where texture passes the
  // pixel faster than the views sample it: on the natural suite's 60 px frames 64 views gained
  // 0.6-0.8 dB over 32 with the hysteresis and nothing without it (BENCHMARKS.md, "The samples
  // between the views").
  int sampleOrder(const BlurQuadrature& quadrature, int* order) const;

  // A channel of the frame that the sensor clipped (PixelGridOptions::saturated), and the blur
  // term's residual there and elsewhere (`flat`: clipped with the mean above the top).
  bool clipped(float frame) const;
  double blurResidual(double mean, float frame, bool* flat = nullptr) const;

  PinholeCamera camera_;
  PixelGridOptions options_;
  int channels_;
  Trajectory motion_;
  cv::Mat inverse_depth_;
  std::vector<Vector3> directions_;
  int64_t mid_us_ = 0;
  double blur_px_ = 0, blur_weight_ = 1;
  // The farthest apart (in canvas cells, squared) two consecutive views' samples are taken as on
  // one stretch of the pixel's path (BlurQuadrature): twice the longest path's step and a pixel;
  // below 0 where no samples are taken between views.
  double between_gap_ = 0;
  int views_ = 0, margin_ = 0, canvas_w_ = 0, canvas_h_ = 0;
  // The layer behind, on a grid of one cell per pixel and the margin (behind_w_ x behind_h_: the
  // background a near surface uncovers is seen briefly, at its edge, and finer cells there only
  // slowed the solve): per grid cell its place among the unknowns' cells there (-1: none; empty:
  // no layer), per such cell its grid cell, and per row block the range of them its samples reach.
  int behind_w_ = 0, behind_h_ = 0;
  std::vector<int> behind_slot_, behind_cell_;
  std::vector<std::array<int, 2>> block_behind_;
  // The nearest and the farthest inverse depth within the layers' parallax of each pixel (float32;
  // empty where the depths' range moves no view by half a pixel): the surfaces a view's pixel may
  // see besides the one its two lookups settled on.
  cv::Mat nearest_, farthest_;
  bool occluding_ = false;  // nearest_ and farthest_ are not empty
  double most_move_ = 0;    // a bound on a view's move of a pixel per unit of inverse depth (px)
  std::vector<int64_t> times_us_;
  // Per pixel and view, a pixel's views side by side (viewSlot): the loss reads them pixel by
  // pixel.
  std::vector<CanvasTaps> taps_;
  // Per view slot, 1 where the view's sample is seen across a depth edge (acrossDepthEdge in
  // pixel_grid_geometry.h): it looks past an occluding edge at what the mid-exposure image does not
  // hold, and the events there record that (a background coming into view), which no cell can
  // render. Such a sample stays in the blur term (the blurry frame averages whatever the pixel saw)
  // but its comparisons with the events are left out of the event term, the motion's normal
  // equations and the held-out score: fitted, they pull the near surface's cells towards the
  // background's changes (BENCHMARKS.md, "Views across a depth edge").
  std::vector<uint8_t> across_;
  std::vector<uint8_t> across_pixels_;          // per pixel, 1 where any of its views' samples is
  std::vector<std::array<int, 2>> block_rows_;  // per row block, the canvas rows [first, last)
  std::vector<float> change_;                   // the events' log change since mid-exposure
  std::vector<uint8_t> held_out_;               // per pixel, when some are held out (holdOutEvents)
  double band_up_ = 0, band_down_ = 0;  // the reference's play (PixelGridOptions::hysteresis)
  int mid_slot_ = 0;                    // mid-exposure's place among the views in time order
  cv::Mat blurry_;
  // evaluate's intensities, their slopes and the blocks' gradients, kept from one call to the next:
  // allocated afresh each call, their pages were faulted in and zeroed again every evaluation, 4.4%
  // of a frame without thresholds (BENCHMARKS.md, "What a view costs"). So evaluate, though const,
  // is not to be called on one problem from two threads at once. A copy starts without them.
  struct Scratch {
    Scratch() = default;
    Scratch(const Scratch&) {}
    Scratch& operator=(const Scratch&) { return *this; }
    std::vector<double> x, slope;
    BlockGradients blocks;
  };
  mutable Scratch scratch_;
};

}  // namespace evkit
