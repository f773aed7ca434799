// The camera's motion over the exposure from EDI's latent frames: each frame registered to the
// mid-exposure one by dense optical flow, the flows explained by a rigid camera (a rotation per
// time, optionally a translation per time seen through a per-tile inverse depth), and the choice
// between the two by whether the parallax is observable in the data.

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <opencv2/imgproc.hpp>
#include <opencv2/video/tracking.hpp>
#include <optional>
#include <span>
#include <stdexcept>
#include <tuple>

#include "benerf_common.h"
#include "evkit/deblur/benerf.h"
#include "evkit/deblur/edi.h"
#include "evkit/deblur/metrics.h"

namespace evkit {

namespace benerf_detail {

SeenPoint seenPoint(const PinholeCamera& camera, const Vector3& bearing, double rho,
                    const Matrix3& Rt, const Vector3& p) {
  SeenPoint s;
  Eigen::Matrix<double, 2, 3> projection;
  const Vector3 X = Rt * (bearing - rho * p);
  s.at = nerf::projectPoint(camera, X, projection);
  s.by_motion.leftCols<3>() = projection * hat(X);
  s.by_motion.rightCols<3>() = -rho * projection * Rt;
  s.by_inverse_depth = -projection * (Rt * p);
  return s;
}

}  // namespace benerf_detail

namespace {

using benerf_detail::seenPoint;

// A log image as 8 bits for the flow, on a range shared by every frame (the mid frame's 0.5 and
// 99.5 percentiles); a 3 x 3 median and a Gaussian of 1 px take out isolated event noise.
class FlowImages {
 public:
  FlowImages(const cv::Mat& mid_log) {
    std::vector<float> values(mid_log.begin<float>(), mid_log.end<float>());
    std::sort(values.begin(), values.end());
    lo_ = values[values.size() / 200];
    hi_ = std::max(lo_ + 1e-3f, values[values.size() - 1 - values.size() / 200]);
  }
  cv::Mat convert(const cv::Mat& log_image) const {
    cv::Mat u8;
    log_image.convertTo(u8, CV_8U, 255.0 / (hi_ - lo_), -255.0 * lo_ / (hi_ - lo_));
    cv::medianBlur(u8, u8, 3);
    cv::GaussianBlur(u8, u8, cv::Size(0, 0), 1.0);
    return u8;
  }

 private:
  float lo_ = 0, hi_ = 1;
};

// One tracked point: its bearing at mid-exposure, its tile and where it is seen at each time
// (NaN where the flow there failed its forward-backward check).
struct Track {
  Vector3 bearing;
  Eigen::Vector2d pixel;
  int tile = 0;
  float events = 0;  // the events of the exposure per pixel around it (eventsPerPixel)
  std::vector<Eigen::Vector2d> seen;
};

// The transposed rotation matrix of the rotation vector theta (once per time, not per track).
Matrix3 transposedRotation(const Vector3& theta) {
  return expSO3(theta).toRotationMatrix().transpose();
}

// transposedRotation of each time's rotation vector.
std::vector<Matrix3> transposedRotations(const std::vector<Vector3>& theta) {
  std::vector<Matrix3> Rt(theta.size());
  for (size_t k = 0; k < theta.size(); ++k) Rt[k] = transposedRotation(theta[k]);
  return Rt;
}

// Where the camera at one time (Rt = transposedRotation of its rotation, p its translation) sees a
// mid-exposure point of inverse depth rho (0: at infinity).
Eigen::Vector2d predict(const PinholeCamera& camera, const Vector3& bearing, double rho,
                        const Matrix3& Rt, const Vector3& p) {
  const Vector3 X = Rt * (bearing - rho * p);  // R^T (b / rho - p), scaled by rho
  return nerf::projectPoint(camera, X);
}

constexpr double kHuberPx = 1.0;

// Fewer textured points tracked than this, and no model is fitted (no poses, an infinite misfit).
constexpr int kMinTracks = 50;

// The nearest a fitted depth may put a point, as an inverse depth in the registration's units
// (where the nearest tracks, the 95th percentile, are at depth 1.5): 1 / 1.05, or depth 0.1 in a
// tile whose tracks were seen on both sides of mid-exposure (tileNearest).
constexpr double kNearestScale = 1 / 1.05, kNearestSeen = 10, kSeenEachSide = 0.5;

double huberWeight(double r) { return r <= kHuberPx ? 1.0 : kHuberPx / r; }

// The Huber cost of a residual of r px, whose Gauss-Newton weight is huberWeight.
double huberCost(double r) { return r <= kHuberPx ? r * r : kHuberPx * (2 * r - kHuberPx); }

// The tile of pixel (x, y) in a W x H image cut into tiles_x x tiles_y tiles, row-major.
int tileOf(int x, int y, int W, int H, int tiles_x, int tiles_y) {
  return std::min(tiles_y - 1, y * tiles_y / H) * tiles_x + std::min(tiles_x - 1, x * tiles_x / W);
}

// fitTime's ridge on the translation, over all the tracks.
double translationRidge(const PinholeCamera& camera, const std::vector<Track>& tracks) {
  return 1e-4 * static_cast<double>(tracks.size()) * camera.fx * camera.fx;
}

// Gauss-Newton on one time's motion (rotation, and translation when `translate`), each track's
// inverse depth fixed, with Huber weights; the translation gets a small ridge so that where no
// parallax tells them apart, rotation explains the motion (the terms: seenPoint).
void fitTime(const PinholeCamera& camera, const std::vector<Track>& tracks,
             const std::vector<double>& rho, int time, bool translate, double ridge, Vector3& theta,
             Vector3& p) {
  // Fixed-size terms (no allocation per track); without translation the tracks are seen at
  // infinity, the last three columns of J are zero and the rotation's 3 x 3 block is solved.
  using Matrix26 = Eigen::Matrix<double, 2, 6>;
  using Matrix66 = Eigen::Matrix<double, 6, 6>;
  using Vector6d = Eigen::Matrix<double, 6, 1>;
  for (int iteration = 0; iteration < 8; ++iteration) {
    Matrix66 H = Matrix66::Zero();
    Vector6d g = Vector6d::Zero();
    const Matrix3 Rt = transposedRotation(theta);
    for (size_t i = 0; i < tracks.size(); ++i) {
      const Track& tr = tracks[i];
      const Eigen::Vector2d& q = tr.seen[static_cast<size_t>(time)];
      if (!std::isfinite(q.x())) continue;
      const benerf_detail::SeenPoint seen =
          seenPoint(camera, tr.bearing, translate ? rho[i] : 0.0, Rt, p);
      const Eigen::Vector2d r0 = seen.at - q;
      const Matrix26& J = seen.by_motion;
      const double w = huberWeight(r0.norm());
      H.noalias() += w * J.transpose() * J;
      g.noalias() += w * J.transpose() * r0;
    }
    Vector6d step = Vector6d::Zero();
    if (translate) {
      H.bottomRightCorner<3, 3>() += ridge * Matrix3::Identity();
      g.tail<3>() += ridge * p;
      step = H.ldlt().solve(-g);
    } else {
      step.head<3>() = H.topLeftCorner<3, 3>().ldlt().solve(-g.head<3>());
    }
    if (!step.allFinite()) return;
    theta = logSO3(Quaternion(expSO3(theta) * expSO3(step.head<3>())));
    if (translate) p += step.tail<3>();
    if (step.norm() < 1e-10) break;
  }
}

// A scene's inverse depth as a linear model over the tracks, rho_i = phi_i . w: a plane (1 / Z of
// a plane is affine in the normalised image coordinates: phi = (1, x / z, y / z)) or one value per
// tile (phi = the tile's indicator).
struct DepthModel {
  bool per_tile = false;
  int tiles = 0;
  int size() const { return per_tile ? tiles : 3; }
  // The basis functions that are non-zero for a track, as (index, value).
  void basis(const Track& tr, std::vector<std::pair<int, double>>& out) const {
    out.clear();
    if (per_tile) {
      out.emplace_back(tr.tile, 1.0);
    } else {
      out.emplace_back(0, 1.0);
      out.emplace_back(1, tr.bearing.x() / tr.bearing.z());
      out.emplace_back(2, tr.bearing.y() / tr.bearing.z());
    }
  }
  // How many tracks each weight's basis function reaches.
  std::vector<int> support(const std::vector<Track>& tracks) const {
    std::vector<int> count(static_cast<size_t>(size()), 0);
    std::vector<std::pair<int, double>> phi;
    for (const Track& tr : tracks) {
      basis(tr, phi);
      for (const auto& [j, v] : phi) ++count[static_cast<size_t>(j)];
    }
    return count;
  }
  // A track's inverse depth under the weights w; phi: basis's scratch, holding the track's basis
  // after the call.
  double inverseDepth(const Track& tr, const Eigen::VectorXd& w,
                      std::vector<std::pair<int, double>>& phi) const {
    basis(tr, phi);
    double rho = 0;
    for (const auto& [j, v] : phi) rho += v * w[j];
    return rho;
  }
};

// The depth model's weights given every time's motion, by Gauss-Newton on the linear model (the
// terms: seenPoint's, by the inverse depth); per-tile unknowns without enough tracks keep their
// value.
void fitDepth(const PinholeCamera& camera, const std::vector<Track>& tracks,
              const DepthModel& model, const std::vector<Vector3>& theta,
              const std::vector<Vector3>& p, const std::vector<int>& support, Eigen::VectorXd& w) {
  const int n = model.size();
  // The tracks in kPieces pieces whatever the thread count, each piece's sums on their own and
  // the pieces added in order: one thread and many give the same bits.
  constexpr int kPieces = 16;
  std::vector<Eigen::MatrixXd> Hs(kPieces);
  std::vector<Eigen::VectorXd> gs(kPieces);
  const std::vector<Matrix3> Rt = transposedRotations(theta);
  for (int iteration = 0; iteration < 4; ++iteration) {
#pragma omp parallel for schedule(dynamic)
    for (int piece = 0; piece < kPieces; ++piece) {
      Eigen::MatrixXd& H = Hs[static_cast<size_t>(piece)];
      Eigen::VectorXd& g = gs[static_cast<size_t>(piece)];
      H = Eigen::MatrixXd::Zero(n, n);
      g = Eigen::VectorXd::Zero(n);
      std::vector<std::pair<int, double>> phi;
      const size_t begin = tracks.size() * piece / kPieces,
                   end = tracks.size() * (piece + 1) / kPieces;
      for (size_t i = begin; i < end; ++i) {
        const Track& tr = tracks[i];
        const double rho = model.inverseDepth(tr, w, phi);
        for (size_t k = 0; k < theta.size(); ++k) {
          const Eigen::Vector2d& q = tr.seen[k];
          if (!std::isfinite(q.x())) continue;
          const benerf_detail::SeenPoint seen = seenPoint(camera, tr.bearing, rho, Rt[k], p[k]);
          const Eigen::Vector2d r0 = seen.at - q;
          const Eigen::Vector2d& J = seen.by_inverse_depth;
          const double wt = huberWeight(r0.norm());
          for (const auto& [a, va] : phi) {
            g[a] += wt * va * J.dot(r0);
            for (const auto& [b, vb] : phi) H(a, b) += wt * va * vb * J.squaredNorm();
          }
        }
      }
    }
    Eigen::MatrixXd H = Hs[0];
    Eigen::VectorXd g = gs[0];
    for (int piece = 1; piece < kPieces; ++piece) {
      H += Hs[static_cast<size_t>(piece)];
      g += gs[static_cast<size_t>(piece)];
    }
    for (int j = 0; j < n; ++j) {
      if (support[static_cast<size_t>(j)] < 6)
        H.row(j).setZero(), H.col(j).setZero(), H(j, j) = 1, g[j] = 0;
    }
    const Eigen::VectorXd step = H.ldlt().solve(-g);
    if (!step.allFinite()) return;
    w += step;
  }
}

// Root mean square of the residuals (px) over every tracked point and time, each capped at 3 px.
double rmsResidual(const PinholeCamera& camera, const std::vector<Track>& tracks,
                   const std::vector<double>& rho, const std::vector<Vector3>& theta,
                   const std::vector<Vector3>& p) {
  const std::vector<Matrix3> Rt = transposedRotations(theta);
  double sum = 0;
  size_t count = 0;
  for (size_t i = 0; i < tracks.size(); ++i) {
    for (size_t k = 0; k < theta.size(); ++k) {
      const Eigen::Vector2d& q = tracks[i].seen[k];
      if (!std::isfinite(q.x())) continue;
      const double r = (predict(camera, tracks[i].bearing, rho[i], Rt[k], p[k]) - q).norm();
      sum += std::min(r, 3 * kHuberPx) * std::min(r, 3 * kHuberPx);
      ++count;
    }
  }
  return count ? std::sqrt(sum / static_cast<double>(count)) : 0.0;
}

// One motion model fitted: a rotation and a translation per time and each track's inverse depth.
struct RigidFit {
  std::vector<Vector3> theta, p;
  std::vector<double> rho;           // per track
  std::vector<double> tile_nearest;  // per tile, under the tiles' model (tileNearest)
  Eigen::VectorXd w;                 // the depth model's weights (empty for a rotation alone)
  double residual_px = 0;
  // The largest inverse depth a track may take.
  double nearest(const Track& tr) const {
    return tile_nearest.empty() ? kNearestScale : tile_nearest[static_cast<size_t>(tr.tile)];
  }
};

// Every time's motion but mid-exposure's (the reference), each fitted on its own through f.rho
// (fitTime): each time its own figures, whatever the thread count.
void fitTimes(const PinholeCamera& camera, const std::vector<Track>& tracks, int mid,
              bool translate, double ridge, RigidFit& f) {
  const int times = static_cast<int>(f.theta.size());
#pragma omp parallel for schedule(dynamic)
  for (int k = 0; k < times; ++k) {
    if (k != mid)
      fitTime(camera, tracks, f.rho, k, translate, ridge, f.theta[static_cast<size_t>(k)],
              f.p[static_cast<size_t>(k)]);
  }
}

// The value at `percent` of a copy of `values` (nth_element's order statistic).
double percentileOf(std::vector<double> values, int percent) {
  const auto at = values.begin() + static_cast<std::ptrdiff_t>(values.size() * percent / 100);
  std::nth_element(values.begin(), at, values.end());
  return *at;
}

// The fit's depth weights w, NaN where fewer than 6 tracks reach them (not observed), and its
// residual.
void keepWeights(const PinholeCamera& camera, const std::vector<Track>& tracks,
                 const std::vector<int>& support, const Eigen::VectorXd& w, RigidFit& f) {
  f.w = w;
  for (Eigen::Index j = 0; j < w.size(); ++j) {
    if (support[static_cast<size_t>(j)] < 6) f.w[j] = std::nan("");
  }
  f.residual_px = rmsResidual(camera, tracks, f.rho, f.theta, f.p);
}

// The scale held: every inverse depth (the model's weights and the tracks') and translation scaled
// so that the nearest tracks (the 95th percentile) are at depth 1.5, the NDC near plane being at
// 1, each track within its bound; false where no track has depth.
bool holdScale(const std::vector<Track>& tracks, RigidFit& f, Eigen::VectorXd& w) {
  const double nearest = percentileOf(f.rho, 95);
  if (!(nearest > 0)) return false;
  const double scale = (1 / 1.5) / nearest;
  w *= scale;
  for (size_t i = 0; i < f.rho.size(); ++i)
    f.rho[i] = std::clamp(f.rho[i] * scale, 0.0, f.nearest(tracks[i]));
  for (Vector3& v : f.p) v /= scale;
  return true;
}

// The inverse depths' common offset. Adding c to every inverse depth and refitting each time's
// rotation and translation moves the image nearly alike for any c (a translation through the
// offset is a rotation but for the perspective terms, x / f up to 0.55 at the border), and the
// alternation of motions and depths leaves it near its start, where the translation takes part
// of the rotation. The offsets that put the farthest tracks (5th percentile) at 0, 0.2, ..., 1 of
// the nearest's inverse depth are each scored by the tracks' residual, and a parabola through the
// least and its neighbours refines it. Each candidate's depths are fitted once more through its
// own motions, and its motions again through them, before it is scored: the depths came from the
// alternation at the start's offset, where their shape took up the perspective terms of the
// rotation that offset left out, and held fixed they scored every offset against the start's,
// whose residual they favoured (the farthest tracks' inverse depth chosen at 0.30-0.61 of the
// nearest's for the truth's 0.20-0.49 on six natural scenes, the rotation short by 5-20%;
// BENCHMARKS.md, "Each candidate offset's own depths"). Where the least is below the start's
// residual, what is kept at its offset is the start's depths moved by it and the motions refitted
// through them, as the registration's misfit bar was set on: kept with its own depths, that one
// more round of the depths took 10% off the misfit of two registrations that had locked onto
// repeated texture (8 px off the truth), which then passed the bar.
void chooseDepthOffset(const PinholeCamera& camera, const std::vector<Track>& tracks, int mid,
                       double ridge, const DepthModel& model, const std::vector<int>& support,
                       RigidFit& f, Eigen::VectorXd& w) {
  const double farthest = percentileOf(f.rho, 5), nearest = percentileOf(f.rho, 95);
  if (!(nearest > farthest)) return;
  // The start's fit with every inverse depth moved by c and the motions refitted.
  const auto moved = [&](double c, RigidFit& trial) {
    trial = f;
    for (double& r : trial.rho) r = std::max(r + c, 0.0);
    fitTimes(camera, tracks, mid, true, ridge, trial);
  };
  // A candidate's residual through its own depths.
  const auto score = [&](double c) {
    RigidFit trial;
    moved(c, trial);
    Eigen::VectorXd trial_w = w;
    if (model.per_tile)
      trial_w.array() += c;
    else
      trial_w[0] += c;
    fitDepth(camera, tracks, model, trial.theta, trial.p, support, trial_w);
    // The bounds of fitRigid's depths, at the offset's scale.
    const double scale = (nearest + c) / nearest;
    std::vector<std::pair<int, double>> phi;
    for (size_t i = 0; i < tracks.size(); ++i)
      trial.rho[i] = std::clamp(model.inverseDepth(tracks[i], trial_w, phi), 0.0,
                                scale * trial.nearest(tracks[i]));
    fitTimes(camera, tracks, mid, true, ridge, trial);
    return rmsResidual(camera, tracks, trial.rho, trial.theta, trial.p);
  };
  constexpr int kSteps = 5;
  const double step = nearest / kSteps;
  std::vector<double> residuals;
  size_t least = 0;
  for (int q = 0; q <= kSteps; ++q) {
    residuals.push_back(score(q * step - farthest));
    if (residuals.back() < residuals[least]) least = residuals.size() - 1;
  }
  double best = static_cast<double>(least) * step - farthest, best_residual = residuals[least];
  if (least > 0 && least + 1 < residuals.size()) {
    const double a = residuals[least - 1], b = residuals[least], d = residuals[least + 1];
    const double curvature = a - 2 * b + d;
    if (curvature > 0) {
      const double c = best + 0.5 * step * (a - d) / curvature, at_c = score(c);
      if (at_c < b) best = c, best_residual = at_c;
    }
  }
  if (!(best_residual < rmsResidual(camera, tracks, f.rho, f.theta, f.p))) return;
  moved(best, f);
  if (model.per_tile)
    w.array() += best;
  else
    w[0] += best;
  holdScale(tracks, f, w);
}

// Levenberg-Marquardt on every time's motion and each track's own inverse depth together (a bundle
// adjustment, the mid time fixed; Huber weights and fitTime's ridge on the translations), each
// track's depth eliminated by its Schur complement: the motions' normal equations, 6 unknowns a
// time, are solved with the tracks' depths folded in, then each depth follows. Alternating the
// two (fitRigid, fitTime and fitDepth in turn) barely moves the depths' common offset against the
// rotation, along which the residual is nearly flat; a step in both at once does.
void bundleAdjust(const PinholeCamera& camera, const std::vector<Track>& tracks, int times, int mid,
                  double ridge, RigidFit& f) {
  constexpr int kIterations = 20;
  const int n = 6 * (times - 1);
  const auto column = [&](int k) { return 6 * (k < mid ? k : k - 1); };
  const auto N = static_cast<Eigen::Index>(tracks.size());
  // The Huber cost with the ridge.
  const auto cost = [&](const RigidFit& fit) {
    const std::vector<Matrix3> Rt = transposedRotations(fit.theta);
    double e = 0;
    for (size_t i = 0; i < tracks.size(); ++i) {
      for (size_t k = 0; k < Rt.size(); ++k) {
        const Eigen::Vector2d& q = tracks[i].seen[k];
        if (!std::isfinite(q.x())) continue;
        const double r =
            (predict(camera, tracks[i].bearing, fit.rho[i], Rt[k], fit.p[k]) - q).norm();
        e += huberCost(r);
      }
    }
    for (const Vector3& p : fit.p) e += ridge * p.squaredNorm();
    return e;
  };
  double lambda = 1e-3, e0 = cost(f);
  Eigen::MatrixXd C(n, N);  // each track's depth against the motions
  Eigen::VectorXd h(N), g(N);
  for (int iteration = 0; iteration < kIterations; ++iteration) {
    const std::vector<Matrix3> Rt = transposedRotations(f.theta);
    Eigen::MatrixXd H = Eigen::MatrixXd::Zero(n, n);
    Eigen::VectorXd gm = Eigen::VectorXd::Zero(n);
    C.setZero();
    for (Eigen::Index i = 0; i < N; ++i) {
      const Track& tr = tracks[static_cast<size_t>(i)];
      h[i] = 0, g[i] = 0;
      for (int k = 0; k < times; ++k) {
        const auto ks = static_cast<size_t>(k);
        if (k == mid || !std::isfinite(tr.seen[ks].x())) continue;
        const benerf_detail::SeenPoint seen =
            seenPoint(camera, tr.bearing, f.rho[static_cast<size_t>(i)], Rt[ks], f.p[ks]);
        const Eigen::Vector2d r0 = seen.at - tr.seen[ks];
        const double w = huberWeight(r0.norm());
        const int c = column(k);
        H.block<6, 6>(c, c).noalias() += w * seen.by_motion.transpose() * seen.by_motion;
        gm.segment<6>(c).noalias() += w * seen.by_motion.transpose() * r0;
        C.col(i).segment<6>(c).noalias() += w * seen.by_motion.transpose() * seen.by_inverse_depth;
        h[i] += w * seen.by_inverse_depth.squaredNorm();
        g[i] += w * seen.by_inverse_depth.dot(r0);
      }
    }
    for (int k = 0; k < times; ++k) {
      if (k == mid) continue;
      H.block<3, 3>(column(k) + 3, column(k) + 3) += ridge * Matrix3::Identity();
      gm.segment<3>(column(k) + 3) += ridge * f.p[static_cast<size_t>(k)];
    }
    // Damped steps until one lowers the cost; a track that no time's translation moves has no
    // depth term, and its damped one stays small.
    bool lowered = false;
    for (int attempt = 0; attempt < 8 && !lowered; ++attempt) {
      const Eigen::VectorXd hd = (h * (1 + lambda)).array() + 1e-12;
      const Eigen::MatrixXd Cd = C * hd.cwiseInverse().asDiagonal();
      Eigen::MatrixXd S = H;
      S.diagonal() *= 1 + lambda;
      S.noalias() -= Cd * C.transpose();
      const Eigen::VectorXd dm = S.ldlt().solve(Cd * g - gm);
      const Eigen::VectorXd dr = -(g + C.transpose() * dm).cwiseQuotient(hd);
      if (!dm.allFinite() || !dr.allFinite()) return;
      RigidFit trial = f;
      for (int k = 0; k < times; ++k) {
        if (k == mid) continue;
        const auto ks = static_cast<size_t>(k);
        trial.theta[ks] =
            logSO3(Quaternion(expSO3(f.theta[ks]) * expSO3(dm.segment<3>(column(k)))));
        trial.p[ks] += dm.segment<3>(column(k) + 3);
      }
      for (size_t i = 0; i < tracks.size(); ++i)
        trial.rho[i] = std::clamp(f.rho[i] + dr[static_cast<Eigen::Index>(i)], 0.0, kNearestSeen);
      const double e = cost(trial);
      lowered = e < e0;
      if (lowered) {
        f = std::move(trial);
        e0 = e;
        lambda = std::max(lambda / 3, 1e-9);
      } else {
        lambda *= 10;
      }
    }
    if (!lowered) break;
  }
}

// The tiles' depths and the motions at the common offset that a bundle adjustment with each
// track's own depth settles on (bundleAdjust): its motions give the tiles' depths (fitDepth; given
// the motions, the depths' offset is no longer free), and each time's motion is fitted again
// through those. The scan of the offset (chooseDepthOffset) scores each candidate through the
// tiles, whose own misfit (0.25-0.46 px on exact tracks: tracks at several depths in a tile) is
// thirty times the offset's signal; each track's own depth has no such misfit. Measured on the
// natural suite (BENCHMARKS.md, "The offset settled jointly"): the rotation error over the
// exposure 0.188 -> 0.118 degrees on average, 0.121 -> 0.073 on its noiseless frames with depth.
void settleJointly(const PinholeCamera& camera, const std::vector<Track>& tracks, int times,
                   int mid, const DepthModel& model, RigidFit& f) {
  // The weights that too few tracks reach (NaN; fitDepth leaves them) at the others' median.
  Eigen::VectorXd w = f.w;
  std::vector<double> observed;
  for (const double v : w) {
    if (std::isfinite(v)) observed.push_back(v);
  }
  if (observed.empty()) return;
  const double median = percentileOf(observed, 50);
  for (double& v : w) {
    if (!std::isfinite(v)) v = median;
  }
  const double ridge = translationRidge(camera, tracks);
  RigidFit joint = f;
  bundleAdjust(camera, tracks, times, mid, ridge, joint);
  f.theta = joint.theta;
  f.p = joint.p;
  const std::vector<int> support = model.support(tracks);
  std::vector<std::pair<int, double>> phi;
  fitDepth(camera, tracks, model, f.theta, f.p, support, w);
  for (size_t i = 0; i < tracks.size(); ++i)
    f.rho[i] = std::clamp(model.inverseDepth(tracks[i], w, phi), 0.0, f.nearest(tracks[i]));
  holdScale(tracks, f, w);
  fitTimes(camera, tracks, mid, true, ridge, f);
  keepWeights(camera, tracks, support, w, f);
}

// The nearest inverse depth each tile may take. A near object that few tracks see lies beyond the
// scale's 95th percentile: bounded there (kNearestScale), rocket_layers' cup (1.1 m before gravel
// at 8 m, under 5% of the tracks) was held at a fraction of its parallax and the plane chosen
// (BENCHMARKS.md, "A near object that few tracks see"). A tile takes a nearer depth where its
// tracks were seen on both sides of mid-exposure (at kSeenEachSide of the times on each side or
// more). A point seen on one side alone is leaving the image, where the flow follows its
// neighbours: along the border of ground_blur15's texture-poor wall, two tiles seen before
// mid-exposure alone came out nearer than anything in the scene (4.2 and 3.6 times the nearest
// tracks' inverse depth, the blur found 42 px for 15). Near objects' tiles were seen at 0.61-1 of
// the times on their less seen side, those border tiles at 0-0.07.
std::vector<double> tileNearest(const std::vector<Track>& tracks, int tiles) {
  std::vector<std::array<int, 2>> seen(static_cast<size_t>(tiles), {0, 0}), possible(seen);
  for (const Track& tr : tracks) {
    const size_t mid = tr.seen.size() / 2, j = static_cast<size_t>(tr.tile);
    for (size_t k = 0; k < tr.seen.size(); ++k) {
      if (k == mid) continue;
      const size_t side = k > mid;
      ++possible[j][side];
      seen[j][side] += std::isfinite(tr.seen[k].x());
    }
  }
  std::vector<double> nearest(static_cast<size_t>(tiles), kNearestScale);
  for (size_t j = 0; j < nearest.size(); ++j) {
    bool both = true;
    for (const size_t side : {0, 1})
      both = both && possible[j][side] > 0 && seen[j][side] >= kSeenEachSide * possible[j][side];
    if (both) nearest[j] = kNearestSeen;
  }
  return nearest;
}

// Rotation alone (no depth model) or rotation and translation through a depth model, alternating
// the motions and the depths; the scale (not observable) fixed by putting the nearest tracks (95th
// percentile of the inverse depth) at depth 1.5, the NDC near plane being at 1.
RigidFit fitRigid(const PinholeCamera& camera, const std::vector<Track>& tracks, int times, int mid,
                  const DepthModel* model, const RigidFit* start, bool choose_offset) {
  RigidFit f;
  f.theta =
      start ? start->theta : std::vector<Vector3>(static_cast<size_t>(times), Vector3::Zero());
  f.p.assign(static_cast<size_t>(times), Vector3::Zero());
  f.rho.assign(tracks.size(), model ? 1 / 1.5 : 0.0);
  if (model && model->per_tile) f.tile_nearest = tileNearest(tracks, model->tiles);
  if (!model) {
    fitTimes(camera, tracks, mid, false, 0, f);
    f.residual_px = rmsResidual(camera, tracks, f.rho, f.theta, f.p);
    return f;
  }
  const std::vector<int> support = model->support(tracks);
  std::vector<std::pair<int, double>> phi;
  Eigen::VectorXd w = Eigen::VectorXd::Zero(model->size());
  if (model->per_tile)
    w.setConstant(1 / 1.5);
  else
    w[0] = 1 / 1.5;
  const double ridge = translationRidge(camera, tracks);
  for (int round = 0; round < 6; ++round) {
    fitTimes(camera, tracks, mid, true, ridge, f);
    fitDepth(camera, tracks, *model, f.theta, f.p, support, w);
    for (size_t i = 0; i < tracks.size(); ++i) f.rho[i] = model->inverseDepth(tracks[i], w, phi);
    if (!holdScale(tracks, f, w)) break;
  }
  if (choose_offset) chooseDepthOffset(camera, tracks, mid, ridge, *model, support, f, w);
  keepWeights(camera, tracks, support, w, f);
  return f;
}

// Spearman's rank correlation of the pairs (Pearson's of their ranks; ties take the order they
// come in, which continuous values do not meet). NaN for fewer than three pairs or a constant side.
double rankCorrelation(const std::vector<std::pair<double, double>>& pairs) {
  const size_t n = pairs.size();
  if (n < 3) return std::nan("");
  const auto ranks = [&](auto value) {
    std::vector<size_t> order(n);
    for (size_t i = 0; i < n; ++i) order[i] = i;
    std::sort(order.begin(), order.end(),
              [&](size_t x, size_t y) { return value(pairs[x]) < value(pairs[y]); });
    std::vector<double> rank(n);
    for (size_t i = 0; i < n; ++i) rank[order[i]] = static_cast<double>(i);
    return rank;
  };
  const std::vector<double> ra = ranks([](const auto&q) { return q.first; }),
                            rb = ranks([](const auto&q) { return q.second; });
  const double mean = (static_cast<double>(n) - 1) / 2;
  double sab = 0, saa = 0, sbb = 0;
  for (size_t i = 0; i < n; ++i) {
    sab += (ra[i] - mean) * (rb[i] - mean);
    saa += (ra[i] - mean) * (ra[i] - mean);
    sbb += (rb[i] - mean) * (rb[i] - mean);
  }
  return saa > 0 && sbb > 0 ? sab / std::sqrt(saa * sbb) : std::nan("");
}

// How well the tiles' departures from a plane (inverse depth phi . plane_w) agree between the
// exposure's two halves (ExposureMotion::depth_agreement): each tile's inverse depth fitted again
// (fitDepth, the tiles' motion held) to the times before mid-exposure alone and to those after it
// alone, and the rank correlation over the tiles with six tracks or more of the two halves'
// departures (NaN where fewer than three tiles have them), with the count of those tiles.
std::pair<double, int> splitHalfAgreement(const PinholeCamera& camera,
                                          const std::vector<Track>& tracks, const DepthModel& model,
                                          const RigidFit& tiles, int mid, const Vector3& plane_w) {
  const int n = model.size();
  std::vector<int> support(static_cast<size_t>(n), 0);
  std::vector<double> plane_sum(static_cast<size_t>(n), 0);
  for (const Track& tr : tracks) {
    const auto j = static_cast<size_t>(tr.tile);
    ++support[j];
    plane_sum[j] +=
        plane_w.dot(Vector3(1, tr.bearing.x() / tr.bearing.z(), tr.bearing.y() / tr.bearing.z()));
  }
  std::array<Eigen::VectorXd, 2> halves;
  for (int half = 0; half < 2; ++half) {
    std::vector<Track> seen = tracks;
    for (Track& tr : seen) {
      for (size_t k = 0; k < tr.seen.size(); ++k) {
        if ((static_cast<int>(k) < mid) != (half == 0)) tr.seen[k].setConstant(std::nan(""));
      }
    }
    Eigen::VectorXd w = tiles.w.unaryExpr([](double v) { return std::isfinite(v) ? v : 0.0; });
    fitDepth(camera, seen, model, tiles.theta, tiles.p, support, w);
    halves[static_cast<size_t>(half)] = std::move(w);
  }
  std::vector<std::pair<double, double>> departures;
  for (int j = 0; j < n; ++j) {
    const auto i = static_cast<size_t>(j);
    if (support[i] < 6) continue;
    const double plane = plane_sum[i] / support[i];
    const double a = halves[0][j] - plane, b = halves[1][j] - plane;
    if (std::isfinite(a) && std::isfinite(b)) departures.emplace_back(a, b);
  }
  return {rankCorrelation(departures), static_cast<int>(departures.size())};
}

// The chosen model's inverse depth at every pixel: the plane's, or the tiles' interpolated
// bilinearly between their centres, a tile without tracks taking its observed neighbours' mean.
cv::Mat inverseDepthMap(const PinholeCamera& camera, const DepthModel& model, const RigidFit& fit,
                        int tiles_x, int tiles_y) {
  const int W = camera.width, H = camera.height;
  cv::Mat rho(H, W, CV_32F);
  if (!model.per_tile) {
    for (int y = 0; y < H; ++y) {
      for (int x = 0; x < W; ++x) {
        const Vector3 b = nerf::pixelDirection(camera, x, y);
        rho.at<float>(y, x) =
            static_cast<float>(fit.w[0] + fit.w[1] * b.x() / b.z() + fit.w[2] * b.y() / b.z());
      }
    }
  } else {
    cv::Mat tile(tiles_y, tiles_x, CV_32F);
    for (int j = 0; j < tiles_x * tiles_y; ++j) tile.at<float>(j / tiles_x, j % tiles_x) = fit.w[j];
    for (int pass = 0; pass < tiles_x + tiles_y; ++pass) {  // grow the observed tiles into the rest
      cv::Mat next = tile.clone();
      bool missing = false;
      for (int ty = 0; ty < tiles_y; ++ty) {
        for (int tx = 0; tx < tiles_x; ++tx) {
          if (std::isfinite(tile.at<float>(ty, tx))) continue;
          double sum = 0;
          int count = 0;
          for (int dy = -1; dy <= 1; ++dy) {
            for (int dx = -1; dx <= 1; ++dx) {
              const int yy = ty + dy, xx = tx + dx;
              if (yy < 0 || xx < 0 || yy >= tiles_y || xx >= tiles_x) continue;
              if (std::isfinite(tile.at<float>(yy, xx))) sum += tile.at<float>(yy, xx), ++count;
            }
          }
          if (count > 0)
            next.at<float>(ty, tx) = static_cast<float>(sum / count);
          else
            missing = true;
        }
      }
      tile = next;
      if (!missing) break;
    }
    cv::patchNaNs(tile, 0.0);
    // Tile j covers pixels [j W / tiles, (j + 1) W / tiles): its centre is at (j + 0.5) W / tiles.
    for (int y = 0; y < H; ++y) {
      const double fy = std::clamp((y + 0.5) * tiles_y / H - 0.5, 0.0, tiles_y - 1.0);
      const int y0 = std::min(static_cast<int>(fy), std::max(0, tiles_y - 2));
      const int y1 = std::min(y0 + 1, tiles_y - 1);
      const double ay = fy - y0;
      for (int x = 0; x < W; ++x) {
        const double fx = std::clamp((x + 0.5) * tiles_x / W - 0.5, 0.0, tiles_x - 1.0);
        const int x0 = std::min(static_cast<int>(fx), std::max(0, tiles_x - 2));
        const int x1 = std::min(x0 + 1, tiles_x - 1);
        const double ax = fx - x0;
        const double value =
            (1 - ay) * ((1 - ax) * tile.at<float>(y0, x0) + ax * tile.at<float>(y0, x1)) +
            ay * ((1 - ax) * tile.at<float>(y1, x0) + ax * tile.at<float>(y1, x1));
        // At most as near as the pixel's own tile may be (tileNearest).
        const int j = tileOf(x, y, W, H, tiles_x, tiles_y);
        rho.at<float>(y, x) =
            static_cast<float>(std::min(value, fit.tile_nearest[static_cast<size_t>(j)]));
      }
    }
  }
  cv::max(rho, 0.0, rho);
  if (!model.per_tile) cv::min(rho, kNearestScale, rho);
  return rho;
}

// How much of the prior's cost a pixel's own depth must take away, in units of the tracks'
// residual variance: a likelihood-ratio test on one unknown (chi-squared at 95% is 3.84). Measured
// on six natural scenes with parallax (BENCHMARKS.md, "Each pixel's depth"): 0.05 dB above taking
// every pixel's own depth; at 16 the near layer of cat_bricks_blur60_noisy kept its tiles' depth
// and the residual stayed above 1 px.
constexpr double kDepthTest = 4.0;

// How far (px) around a pixel the near side of a depth edge is looked for (EdgeSide::kNear).
constexpr int kEdgeSideReach = 8;

// Which depth a pixel whose own flows settle nothing takes next to a depth edge: the prior's
// (the tiles', interpolated bilinearly between their centres, so that it ramps from one side's
// depth to the other's over a tile: no surface's depth), or the nearest within kEdgeSideReach px
// (the occluding side's). On cameraman_grass_blur44_noisy a thin bright rim along the near
// phantom's edge, whose flows failed their forward-backward check, kept the ramp's depths, halfway
// between the layers: 223 pixels of it cost 5.5 dB (BENCHMARKS.md, "The near side of a depth
// edge").
enum class EdgeSide { kPrior, kNear };

// Each pixel's inverse depth from its own dense flows (float32), and where they set it (`own`,
// CV_8U: 1 there, else the prior's value stays).
struct OwnDepths {
  cv::Mat rho, own;
};

// Each pixel's inverse depth from its own dense flows, given every time's motion: Gauss-Newton on
// them with Huber weights from the prior map's value, which weighs as one flow a pixel off, kept
// where it passes kDepthTest against the prior (where the translation moves the image too little to
// tell the depths apart, or the flows are noise, the prior's stays). The tiles' depths blur a near
// layer into its far surround over a tile and more; the flows resolve it. `variance`: the tracks'
// residual variance (px^2) under the prior's model.
OwnDepths ownInverseDepths(const PinholeCamera& camera, const std::vector<cv::Mat>& flows, int mid,
                           const std::vector<Vector3>& theta, const std::vector<Vector3>& p,
                           const cv::Mat& prior, double variance) {
  const int W = camera.width, H = camera.height, times = static_cast<int>(theta.size());
  const std::vector<Matrix3> Rt = transposedRotations(theta);
  // A pixel's own inverse depth at most the prior's largest (or kNearestScale): one beyond the
  // nearest the tracks saw is no surface's (see at_bound below); unbounded, such pixels along
  // text_coins_blur60's occluding edges lengthened the blur found from 58 to 90 px (the truth 60).
  double upper = 0;
  cv::minMaxLoc(prior, nullptr, &upper);
  upper = std::max(upper, kNearestScale);
  cv::Mat rho(H, W, CV_32F);
  cv::Mat own(H, W, CV_8U);  // 1 where the pixel's own flows set its depth
#pragma omp parallel for schedule(static)
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      const Vector3 b = nerf::pixelDirection(camera, x, y);
      const double r0 = prior.at<float>(y, x);
      // The Huber cost of the pixel's flows at inverse depth r, and its Gauss-Newton terms through
      // seenPoint's derivative by the inverse depth.
      const auto cost = [&](double r, double* h, double* g) {
        double e = 0;
        for (int k = 0; k < times; ++k) {
          if (k == mid) continue;
          const auto i = static_cast<size_t>(k);
          const cv::Point2f f = flows[i].at<cv::Point2f>(y, x);
          if (!std::isfinite(f.x)) continue;
          const Eigen::Vector2d q(x + f.x, y + f.y);
          if (!h) {
            e += huberCost((predict(camera, b, r, Rt[i], p[i]) - q).norm());
            continue;
          }
          const benerf_detail::SeenPoint s = seenPoint(camera, b, r, Rt[i], p[i]);
          const double n = (s.at - q).norm();
          e += huberCost(n);
          const double w = huberWeight(n);
          *h += w * s.by_inverse_depth.squaredNorm();
          *g += w * s.by_inverse_depth.dot(s.at - q);
        }
        return e;
      };
      double r = r0;
      for (int iteration = 0; iteration < 4; ++iteration) {
        double h = 1.0, g = r - r0;
        cost(r, &h, &g);
        r = std::clamp(r - g / h, 0.0, upper);
      }
      // The pixel's own depth where its flows tell it: it takes away more than kDepthTest times the
      // tracks' residual variance from the prior's cost (a likelihood-ratio test on one unknown).
      // An estimate at a bound of the range is no minimum of the cost: the flows there follow
      // something other than the pixel (an occluding edge's, a failed flow).
      const bool at_bound = r <= 0 || r >= upper;
      const bool kept = !at_bound && cost(r0, nullptr, nullptr) - cost(r, nullptr, nullptr) >
                                         kDepthTest * variance;
      rho.at<float>(y, x) = static_cast<float>(kept ? r : r0);
      own.at<uint8_t>(y, x) = kept ? 1 : 0;
    }
  }
  return {rho, own};
}

// The per-pixel inverse depth map from ownInverseDepths: where a pixel's own flows did not set it,
// with EdgeSide::kNear the nearest around where that moves the image by over a pixel more than the
// farthest around; then a 5 x 5 median, which takes out single pixels' outliers and keeps the
// layers' edges.
cv::Mat pixelInverseDepth(const PinholeCamera& camera, const std::vector<Vector3>& theta,
                          const std::vector<Vector3>& p, const OwnDepths& depths,
                          EdgeSide edge_side) {
  const int W = camera.width, H = camera.height, times = static_cast<int>(theta.size());
  const std::vector<Matrix3> Rt = transposedRotations(theta);
  cv::Mat rho = depths.rho.clone();
  const cv::Mat& own = depths.own;
  if (edge_side == EdgeSide::kNear) {
    const cv::Mat window = cv::getStructuringElement(
        cv::MORPH_RECT, cv::Size(2 * kEdgeSideReach + 1, 2 * kEdgeSideReach + 1));
    cv::Mat nearest, farthest;
    cv::dilate(rho, nearest, window);
    cv::erode(rho, farthest, window);
    cv::Mat sided = rho.clone();
#pragma omp parallel for schedule(static)
    for (int y = 0; y < H; ++y) {
      for (int x = 0; x < W; ++x) {
        const double near = nearest.at<float>(y, x), far = farthest.at<float>(y, x);
        if (own.at<uint8_t>(y, x) || !(near > far)) continue;
        // A depth edge where the two sides' points part by over a pixel at some time.
        const Vector3 b = nerf::pixelDirection(camera, x, y);
        bool edge = false;
        for (int k = 0; k < times && !edge; ++k) {
          const auto i = static_cast<size_t>(k);
          edge = (nerf::projectPoint(camera, Rt[i] * (b - near * p[i])) -
                  nerf::projectPoint(camera, Rt[i] * (b - far * p[i])))
                     .norm() > 1.0;
        }
        if (edge) sided.at<float>(y, x) = static_cast<float>(near);
      }
    }
    rho = sided;
  }
  cv::medianBlur(rho, rho, 5);
  return rho;
}

}  // namespace

namespace {

// The forward flow where it passes the forward-backward check (back to within half a pixel and 5%
// of its length), NaN elsewhere.
cv::Mat checkedFlow(const cv::Mat& forward, const cv::Mat& backward) {
  cv::Mat checked = forward.clone();
  const int W = checked.cols, H = checked.rows;
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      cv::Point2f& f = checked.at<cv::Point2f>(y, x);
      const double qx = x + f.x, qy = y + f.y;
      bool ok = qx >= 0 && qy >= 0 && qx < W - 1 && qy < H - 1;
      if (ok) {
        const cv::Point2f b = backward.at<cv::Point2f>(static_cast<int>(std::lround(qy)),
                                                       static_cast<int>(std::lround(qx)));
        ok = std::hypot(f.x + b.x, f.y + b.y) <= 0.5 + 0.05 * std::hypot(f.x, f.y);
      }
      if (!ok) f = cv::Point2f(NAN, NAN);
    }
  }
  return checked;
}

// The events per pixel over the exposure that a point's neighbourhood (5 x 5 px) must have fired
// to be tracked. EDI's latent frames move only where events fired: elsewhere they are the blurry
// frame, scaled, and their texture stays put while the camera moves, so the flows there fall short
// of the motion and pull the rigid camera's fit. On a smooth retina before the moon at 48 px of
// blur (BENCHMARKS.md, "Only where events fired") the flows were off the truth by a median of 5.9
// px where under 0.84 events per pixel had fired and 1.1 px where over 3.4 had.
constexpr double kLeastEventsPerPixel = 1;

// The events of the exposure per pixel, averaged over each pixel's 5 x 5 neighbourhood (CV_32F).
cv::Mat eventsPerPixel(const Observation& obs) {
  cv::Mat count;
  benerf_detail::exposureEventCounts(obs).convertTo(count, CV_32F);
  cv::blur(count, count, cv::Size(5, 5));
  return count;
}

// The points tracked from mid-exposure into EDI's latent frames: pixels only, so that any camera
// can explain them.
struct TrackedPoints {
  std::vector<Track> tracks;
  std::vector<int64_t> times;
  // Each time's dense flow from the mid frame (CV_32FC2), NaN where its forward-backward check
  // failed; empty at mid-exposure.
  std::vector<cv::Mat> flows;
  int tiles_x = 1, tiles_y = 1;
  int without_events = 0;          // textured points left out: too few events around them
  cv::Mat mid8;                    // the mid frame as the flow saw it
  std::optional<double> repeated;  // repeatedTextureShare of the tracks, once asked
};

TrackedPoints trackLatentFrames(const Observation& obs, const std::optional<Contrast>& contrast,
                                const LogMapping& log, int intervals) {
  if (intervals < 2 || intervals > 64 || intervals % 2 != 0)
    throw std::invalid_argument("motionFromLatentFrames: intervals must be even, 2-64");
  TrackedPoints out;
  const int mid = intervals / 2;
  const int64_t t0 = obs.blurry.exposure_start_us, t1 = obs.blurry.exposure_end_us;
  EdiOptions edi_options;
  edi_options.use_observation_contrast = false;
  edi_options.contrast = contrast;
  DeblurRequest request;
  for (int k = 0; k <= intervals; ++k) request.times_us.push_back(t0 + (t1 - t0) * k / intervals);
  out.times = request.times_us;
  const DeblurResult latent = EdiDeblurrer{edi_options}.run(obs, request);

  const cv::Mat mid_log = benerf_detail::logGrey(latent.frames[mid].image, log);
  const FlowImages to8{mid_log};
  const cv::Mat mid8 = to8.convert(mid_log);
  out.mid8 = mid8;
  cv::Mat texture;
  cv::cornerMinEigenVal(mid8, texture, 5);
  std::vector<float> tex(texture.begin<float>(), texture.end<float>());
  std::nth_element(tex.begin(), tex.begin() + tex.size() * 9 / 10, tex.end());
  const float min_texture = 0.05f * tex[tex.size() * 9 / 10];

  // Tracks on a 4 px grid wherever the mid frame has texture and events fired.
  const int W = mid8.cols, H = mid8.rows, step = 4, margin = 4;
  const cv::Mat fired = eventsPerPixel(obs);
  // Tiles of about 24 px: a few dozen tracks each.
  const int kTilesX = std::max(1, (W + 12) / 24), kTilesY = std::max(1, (H + 12) / 24);
  out.tiles_x = kTilesX;
  out.tiles_y = kTilesY;
  std::vector<Track>& tracks = out.tracks;
  // Where too few points fired events for a fit (an exposure without events), every textured
  // point, whose flows then say how little the frames move.
  int with_events = 0, textured = 0;
  for (int y = margin; y < H - margin; y += step) {
    for (int x = margin; x < W - margin; x += step) {
      if (texture.at<float>(y, x) < min_texture) continue;
      ++textured;
      with_events += fired.at<float>(y, x) >= kLeastEventsPerPixel;
    }
  }
  const double least_events = with_events >= kMinTracks ? kLeastEventsPerPixel : 0;
  out.without_events = with_events >= kMinTracks ? textured - with_events : 0;
  for (int y = margin; y < H - margin; y += step) {
    for (int x = margin; x < W - margin; x += step) {
      if (texture.at<float>(y, x) < min_texture || fired.at<float>(y, x) < least_events) continue;
      Track tr;
      tr.pixel = {x, y};
      tr.tile = tileOf(x, y, W, H, kTilesX, kTilesY);
      tr.events = fired.at<float>(y, x);
      tr.seen.assign(intervals + 1, Eigen::Vector2d::Constant(std::nan("")));
      tracks.push_back(std::move(tr));
    }
  }
  auto dis = cv::DISOpticalFlow::create(cv::DISOpticalFlow::PRESET_MEDIUM);
  out.flows.resize(intervals + 1);
  for (Track& tr : tracks) tr.seen[mid] = tr.pixel;
  // Outwards from mid-exposure, each time's flows started from its inner neighbour's: the image
  // moves a few pixels between neighbouring times but up to half the blur from mid-exposure, and
  // on fine repetitive texture DIS's coarse levels alone lock onto a wrong repeat (gravel at 50 px
  // of blur: the rigid models' residual 1.8 px, no poses).
  for (const int step : {-1, 1}) {
    // The inner neighbour's flows, DIS's start (it starts from a flow given at the images' size);
    // none next to mid-exposure.
    cv::Mat forward, backward;
    for (int k = mid + step; k >= 0 && k <= intervals; k += step) {
      const cv::Mat other = to8.convert(benerf_detail::logGrey(latent.frames[k].image, log));
      dis->calc(mid8, other, forward);
      dis->calc(other, mid8, backward);
      const cv::Mat checked = checkedFlow(forward, backward);
      for (Track& tr : tracks) {
        const cv::Point2f f =
            checked.at<cv::Point2f>(static_cast<int>(tr.pixel.y()), static_cast<int>(tr.pixel.x()));
        if (std::isfinite(f.x)) tr.seen[k] = {tr.pixel.x() + f.x, tr.pixel.y() + f.y};
      }
      out.flows[static_cast<size_t>(k)] = checked;
    }
  }
  return out;
}

// How far fitMotion takes the depth model: to each pixel's own depth (and, where the depths' offset
// is chosen, the near sides' alternative at the depth edges: a registration that feeds a
// trajectory), or the tiles' alone, for a registration scored by its tiles' misfit only (the lens
// ladder's candidates: 0.3 s each on cameraman_grass at 44 px, a tenth of the registration).
enum class Depths { kPixels, kTiles };

// The rigid camera's three models fitted to the tracked points as `camera` sees them.
ExposureMotion fitMotion(const PinholeCamera& camera, TrackedPoints& points, bool choose_offset,
                         MisfitBar bar, Depths depths = Depths::kPixels) {
  ExposureMotion m;
  std::vector<Track>& tracks = points.tracks;
  const int times = static_cast<int>(points.times.size()), mid = times / 2;
  const int kTilesX = points.tiles_x, kTilesY = points.tiles_y;
  for (Track& tr : tracks) tr.bearing = nerf::pixelDirection(camera, tr.pixel.x(), tr.pixel.y());
  m.tracks = static_cast<int>(tracks.size());
  m.tracks_without_events = points.without_events;
  if (m.tracks < kMinTracks) return m;

  // Three models of rising richness: a rotation alone; a rotation and a translation seen through
  // one plane (a homography per time); the same through an inverse depth per tile.
  const RigidFit rotation = fitRigid(camera, tracks, times, mid, nullptr, nullptr, false);
  const DepthModel plane_model{false, 0}, tile_model{true, kTilesX * kTilesY};
  const RigidFit plane =
      fitRigid(camera, tracks, times, mid, &plane_model, &rotation, choose_offset);
  const RigidFit tiles =
      fitRigid(camera, tracks, times, mid, &tile_model, &rotation, choose_offset);
  m.residual_rotation_px = rotation.residual_px;
  m.residual_plane_px = plane.residual_px;
  m.residual_depth_px = tiles.residual_px;
  // Parallax: how far the tiles' depths move the image off the motion of the plane that fits them
  // best, over the exposure (the 99th percentile over the tracks: a near object that few tracks see
  // is under 5% of them; at the 95th, cameraman_grass through a wider lens, its camera at 1.6 m
  // 7-9 px off the motion of the grass at 6 m, showed 0.37 px and the plane was chosen).
  Eigen::Matrix3d A = Eigen::Matrix3d::Zero();
  Vector3 b = Vector3::Zero();
  for (size_t i = 0; i < tracks.size(); ++i) {
    const Vector3 phi(1, tracks[i].bearing.x() / tracks[i].bearing.z(),
                      tracks[i].bearing.y() / tracks[i].bearing.z());
    A += phi * phi.transpose();
    b += phi * tiles.rho[i];
  }
  const Vector3 plane_w = A.ldlt().solve(b);
  const double travel = camera.fx * (tiles.p.back() - tiles.p.front()).head<2>().norm();
  std::vector<double> off(tracks.size());
  for (size_t i = 0; i < tracks.size(); ++i) {
    const Vector3 phi(1, tracks[i].bearing.x() / tracks[i].bearing.z(),
                      tracks[i].bearing.y() / tracks[i].bearing.z());
    off[i] = std::abs(tiles.rho[i] - phi.dot(plane_w)) * travel;
  }
  m.parallax_px = percentileOf(off, 99);
  // Not for the lens ladder's candidates (Depths::kTiles), scored by the tiles' misfit alone.
  if (depths == Depths::kPixels) {
    std::tie(m.depth_agreement, m.depth_agreement_tiles) =
        splitHalfAgreement(camera, tracks, tile_model, tiles, mid, plane_w);
  }
  // The depths where they move the image visibly (over half a pixel) and explain the tracks
  // clearly better than the plane. A near layer on a small part of the image shows less than its
  // parallax here, its tiles blurred into their surround and its tracks a small share: on
  // nat_rocket_layers_blur15 the rocket (7% of the image) moves 5 px more than the backdrop, its
  // parallax_px (then the 95th percentile) 0.82, and at a 1 px bar the plane was chosen (35.07 dB;
  // with the depths 35.73).
  // Or, where they take away less of it, where they explain it better still and depart from the
  // plane alike in the exposure's two halves (depth_agreement, beyond three standard errors of a
  // rank correlation without any, 1 / sqrt(tiles - 1)): the tracks' misfit holds the flows' noise
  // as well as the model's error, and on noisy events that noise can hide a layered scene
  // (BENCHMARKS.md, "The depths beside the plane").
  const bool agreed = tiles.residual_px < plane.residual_px &&
                      m.depth_agreement > kDepthAgreement &&
                      m.depth_agreement * std::sqrt(std::max(m.depth_agreement_tiles - 1, 0)) > 3;
  const bool tiles_explain = tiles.residual_px < 0.85 * plane.residual_px;
  m.depth = m.parallax_px > 0.5 && (tiles_explain || agreed);
  // The chosen model's fit from the tiles' fit `at`: the plane's or the tiles', or where the depth
  // model is chosen and `pixel_depth` allows, each pixel's own depth from the dense flows with
  // each time's motion again through it, kept where it explains the tracks better than the tiles
  // (or where `pixel_depth` says so); and with `near_sides`, the same with the near side's depth
  // where a pixel's flows settle nothing at a depth edge.
  struct Chosen {
    RigidFit fit;
    cv::Mat inverse_depth;
    bool pixel_depth = false;
    double residual_pixels_px = 0;
    std::optional<RigidFit> near_edges;
    cv::Mat near_edges_map;
  };
  const auto chooseFrom = [&](const RigidFit& at, std::optional<bool> pixel_depth,
                              bool near_sides) {
    Chosen c{m.depth ? at : plane, {}, false, 0, {}, {}};
    c.inverse_depth =
        inverseDepthMap(camera, m.depth ? tile_model : plane_model, c.fit, kTilesX, kTilesY);
    if (!m.depth || depths != Depths::kPixels || pixel_depth == false) return c;
    const cv::Mat tile_map = c.inverse_depth;
    const double ridge = translationRidge(camera, tracks);
    const auto own = [&](const RigidFit& fit) {
      return ownInverseDepths(camera, points.flows, mid, fit.theta, fit.p, tile_map,
                              tiles.residual_px * tiles.residual_px);
    };
    // The first round's own depths, through the tiles' motion: the same for both maps.
    const OwnDepths first = own(at);
    const auto refine = [&](EdgeSide side, cv::Mat& map) {
      RigidFit pixels = at;
      for (int round = 0; round < 2; ++round) {
        map = pixelInverseDepth(camera, pixels.theta, pixels.p, round == 0 ? first : own(pixels),
                                side);
        for (size_t i = 0; i < tracks.size(); ++i)
          pixels.rho[i] = map.at<float>(static_cast<int>(tracks[i].pixel.y()),
                                        static_cast<int>(tracks[i].pixel.x()));
        fitTimes(camera, tracks, mid, true, ridge, pixels);
      }
      pixels.residual_px = rmsResidual(camera, tracks, pixels.rho, pixels.theta, pixels.p);
      return pixels;
    };
    cv::Mat map;
    RigidFit pixels = refine(EdgeSide::kPrior, map);
    c.residual_pixels_px = pixels.residual_px;
    if (pixel_depth ? *pixel_depth : pixels.residual_px < at.residual_px) {
      c.fit = std::move(pixels);
      c.inverse_depth = map;
      c.pixel_depth = true;
      // The near sides' alternative where it differs (its poses where it passes the bar below).
      if (near_sides) {
        RigidFit sided = refine(EdgeSide::kNear, c.near_edges_map);
        if (cv::norm(c.near_edges_map, map, cv::NORM_INF) > 0) c.near_edges = std::move(sided);
      }
    }
    return c;
  };
  // Where the offset is to be settled (below), the near sides' alternative waits for it.
  const bool settle = m.depth && tiles_explain && choose_offset && depths == Depths::kPixels;
  Chosen chosen = chooseFrom(tiles, std::nullopt, choose_offset && !settle);
  m.inverse_depth = chosen.inverse_depth;
  m.pixel_depth = chosen.pixel_depth;
  m.residual_pixels_px = chosen.residual_pixels_px;
  // A rigid camera that does not explain the registration (motion beyond the models, a
  // registration that failed): no poses, and the caller starts elsewhere. Within a pixel it does;
  // with kUnlessRepeated up to kMostMisfitPx too unless the texture repeats within the flow's
  // reach, where a flow locks onto a repeat with a bias that the per-pixel depth absorbs into a
  // misfit of about a pixel (BENCHMARKS.md, "What the registration's misfit measures").
  const auto explains = [&](double residual_px, MisfitBar misfit_bar) {
    if (residual_px <= 1.0) return true;
    if (misfit_bar != MisfitBar::kUnlessRepeated || !(residual_px <= kMostMisfitPx)) return false;
    if (!points.repeated) {
      std::vector<Eigen::Vector2d> at;
      for (size_t i = 0; i < tracks.size(); i += kRepeatSampleEvery) at.push_back(tracks[i].pixel);
      points.repeated = repeatedTextureShare(points.mid8, at);
    }
    m.repeated_share = *points.repeated;
    return *points.repeated < kMostRepeatedShare;
  };
  if (!explains(chosen.fit.residual_px, bar)) {
    m.inverse_depth = cv::Mat();
    return m;
  }
  // Where the depths are chosen by their misfit (tiles_explain) and the registration explains the
  // tracks, the depths' common offset and the motions settled jointly with each track's own depth
  // (settleJointly), the same model taken from there. Where the tiles take under 15% off the
  // plane's misfit, the depths' evidence is weak and each track's own depth fits the flows' noise
  // along the offset's flat valley instead of a misfit of the tiles: on coffee_plane_blur60, a
  // plane whose depths were chosen by their agreement alone at the c found without thresholds,
  // the rotation went 0.13 -> 1.01 degrees off and the frame lost 2.8 dB. The misfits above, and
  // the model's choice, stay those of the scan's offset, where the tiles fit best and on which the
  // bar was set: at the offset settled the tiles' own misfit rises by up to 40% (on planes_blur40
  // above the plane's, which was then chosen and cost 0.9 dB), and each track's own depth fits
  // flows that fall short of the motion as well (a dark scene's points that fired little: 1.9 px at
  // the scan's offset, under the bar once settled). Not for the lens ladder's candidates, scored by
  // the tiles' misfit alone, nor the scored registrations that leave the offset unchosen; the near
  // sides' alternative, for a registration that feeds a trajectory, from the offset settled.
  if (settle) {
    RigidFit settled = tiles;
    settleJointly(camera, tracks, times, mid, tile_model, settled);
    chosen = chooseFrom(settled, chosen.pixel_depth, true);
    m.inverse_depth = chosen.inverse_depth;
  }
  const auto posesOf = [&](const RigidFit& fit) {
    std::vector<StampedPose> poses;
    for (int k = 0; k < times; ++k) {
      const auto i = static_cast<size_t>(k);
      poses.push_back({points.times[i], SE3(expSO3(fit.theta[i]), fit.p[i])});
    }
    return poses;
  };
  m.poses = posesOf(chosen.fit);
  // The near sides' alternative where its tracks pass the bar of kUnlessRepeated, whatever the
  // poses' (the points near an occluding edge whose flows failed take the near side's depth there
  // too, and misfit more; with the same c and the same tracks, that is not the sign of a wrong c
  // that kOnePixel watches for).
  if (chosen.near_edges && explains(chosen.near_edges->residual_px, MisfitBar::kUnlessRepeated))
    m.near_edges = {posesOf(*chosen.near_edges), chosen.near_edges_map,
                    chosen.near_edges->residual_px};
  return m;
}

// fitMotion, and with kUnlessRepeated where its rigid camera does not explain the points, fitted
// again to those that fired at least kFiredEventsPerPixel, whose flows follow the motion more
// closely (ExposureMotion in benerf.h); `points` becomes the points of the motion returned.
ExposureMotion fitMotionToFiredPoints(const PinholeCamera& camera, TrackedPoints& points,
                                      bool choose_offset, MisfitBar bar) {
  ExposureMotion motion = fitMotion(camera, points, choose_offset, bar);
  if (!motion.poses.empty() || bar != MisfitBar::kUnlessRepeated) return motion;
  const auto few = [](const Track& tr) { return tr.events < kFiredEventsPerPixel; };
  const auto left_out = std::count_if(points.tracks.begin(), points.tracks.end(), few);
  const auto kept = static_cast<std::ptrdiff_t>(points.tracks.size()) - left_out;
  if (left_out == 0 || kept < kMinTracks) return motion;
  TrackedPoints fired = points;
  fired.repeated.reset();
  std::erase_if(fired.tracks, few);
  ExposureMotion retry = fitMotion(camera, fired, choose_offset, bar);
  if (retry.poses.empty()) return motion;
  retry.tracks_few_events = static_cast<int>(left_out);
  points = std::move(fired);
  return retry;
}

// Whether the neighbourhood of `point` (a pixel of the full image) repeats within the flow's reach
// in `half`, the image at half size (repeatedTextureShare); none where its patch leaves the image.
std::optional<bool> repeatsWithinReach(const cv::Mat& half, const Eigen::Vector2d& point) {
  constexpr int kHalfPatch = kRepeatPatchPx / 4, kReach = kRepeatReachPx / 2;
  if (!point.allFinite() || point.cwiseAbs().maxCoeff() > 1e6) return std::nullopt;
  const cv::Rect inside(0, 0, half.cols, half.rows);
  const int hx = static_cast<int>(point.x()) / 2, hy = static_cast<int>(point.y()) / 2;
  const cv::Rect patch(hx - kHalfPatch, hy - kHalfPatch, 2 * kHalfPatch + 1, 2 * kHalfPatch + 1);
  if ((patch & inside) != patch) return std::nullopt;
  const cv::Rect window = cv::Rect(patch.x - kReach, patch.y - kReach, patch.width + 2 * kReach,
                                   patch.height + 2 * kReach) &
                          inside;
  cv::Mat r;
  cv::matchTemplate(half(window), half(patch), r, cv::TM_CCOEFF_NORMED);
  // The central peak: the places joined to the patch's own (a correlation of 1) above 0.5.
  cv::Mat peak = cv::Mat::zeros(r.size(), CV_8U);
  std::vector<cv::Point> stack{{patch.x - window.x, patch.y - window.y}};
  peak.at<uint8_t>(stack.back()) = 1;
  while (!stack.empty()) {
    const cv::Point at = stack.back();
    stack.pop_back();
    for (int dv = -1; dv <= 1; ++dv) {
      for (int du = -1; du <= 1; ++du) {
        const cv::Point next(at.x + du, at.y + dv);
        if (!next.inside(cv::Rect(0, 0, r.cols, r.rows)) || peak.at<uint8_t>(next) ||
            !(r.at<float>(next) > 0.5f))
          continue;
        peak.at<uint8_t>(next) = 1;
        stack.push_back(next);
      }
    }
  }
  for (int v = 0; v < r.rows; ++v) {
    for (int u = 0; u < r.cols; ++u) {
      if (!peak.at<uint8_t>(v, u) && r.at<float>(v, u) > kRepeatCorrelation) return true;
    }
  }
  return false;
}

}  // namespace

ExposureMotion motionFromLatentFrames(const Observation& obs, const PinholeCamera& camera,
                                      const std::optional<Contrast>& contrast,
                                      const LogMapping& log, bool choose_depth_offset,
                                      int intervals, MisfitBar bar) {
  TrackedPoints points = trackLatentFrames(obs, contrast, log, intervals);
  return fitMotionToFiredPoints(camera, points, choose_depth_offset, bar);
}

double repeatedTextureShare(const cv::Mat& image8, std::span<const Eigen::Vector2d> points) {
  if (image8.empty() || image8.type() != CV_8UC1)
    throw std::invalid_argument("repeatedTextureShare: an 8-bit one-channel image");
  cv::Mat half;
  cv::pyrDown(image8, half);
  int counted = 0, repeated = 0;
  for (const Eigen::Vector2d& point : points) {
    const std::optional<bool> r = repeatsWithinReach(half, point);
    if (!r) continue;
    ++counted;
    repeated += *r;
  }
  return counted == 0 ? 0.0 : static_cast<double>(repeated) / counted;
}

double registrationMisfit(const ExposureMotion& motion) {
  if (motion.tracks < kMinTracks) return std::numeric_limits<double>::infinity();
  if (motion.pixel_depth) return motion.residual_pixels_px;
  return motion.depth ? motion.residual_depth_px : motion.residual_plane_px;
}

ExposureMotion registerAwayFromSearch(
    const BlurMeasurement& measured, const ExposureMotion& at_searched,
    const std::function<ExposureMotion(const Contrast&)>& registerAt, double* registered_c) {
  constexpr int kTries = 6;
  const double ratio = measured.c_off / measured.c_on;
  ExposureMotion motion;
  // The registration at `steps` of 2^(1/3) from EDI's c; its c_on where it registered, else 0.
  const auto registers = [&](int steps) {
    const double c = measured.c_on * std::exp2(steps / 3.0);
    motion = registerAt(Contrast{c, c * ratio});
    *registered_c = motion.poses.empty() ? 0 : c;
    return !motion.poses.empty();
  };
  const EdiOptions edi;
  const bool upper_half = measured.c_on > std::sqrt(edi.search_min * edi.search_max);
  const int first = measured.inside || upper_half ? -1 : 1;
  if (registers(first)) return motion;
  // From inside EDI's range, where the misfit rose one step below EDI's c: up from it instead.
  const bool turned =
      measured.inside && registrationMisfit(motion) > registrationMisfit(at_searched);
  for (int i = 0; i < kTries - 1; ++i) {
    if (registers(turned ? 1 + i : first * (2 + i))) break;
  }
  return motion;
}

CalibratedMotion calibrateFromLatentFrames(const Observation& obs, const PinholeCamera& assumed,
                                           const std::optional<Contrast>& contrast,
                                           const LogMapping& log, int intervals, MisfitBar bar) {
  TrackedPoints points = trackLatentFrames(obs, contrast, log, intervals);
  CalibratedMotion best;
  best.camera = assumed;
  best.motion = fitMotionToFiredPoints(assumed, points, true, bar);
  best.residual_assumed_px = best.motion.residual_depth_px;
  best.cameras_tried = 1;
  if (best.motion.tracks < kMinTracks) return best;
  const auto camera = [&](double k1) {
    PinholeCamera c = assumed;
    c.distortion = {k1, 0, 0, 0};
    return c;
  };
  // The ladder of k1 from the pinhole outwards; a candidate must take away 5% of the best
  // residual so far. Measured on pinhole scenes, the per-tile depths' own misfit (a slanted ground
  // within one tile) lets a small k1 take away 2-6%, and a pincushion one more (a ground plane:
  // 33%); on wide lenses with k1 -0.3 the true direction took away 5-14%.
  double residual = best.motion.residual_depth_px;
  for (const double k1 : kLensK1) {
    if (k1 == 0) continue;
    const ExposureMotion m = fitMotion(camera(k1), points, true, bar, Depths::kTiles);
    ++best.cameras_tried;
    if (!(m.residual_depth_px < (1 - kLensGain) * residual)) continue;
    residual = m.residual_depth_px;
    best.camera = camera(k1);
    best.estimated = true;
  }
  // The winning candidate's motion through each pixel's own depth.
  if (best.estimated) {
    const int few_events = best.motion.tracks_few_events;
    best.motion = fitMotion(best.camera, points, true, bar);
    best.motion.tracks_few_events = few_events;
  }
  return best;
}

}  // namespace evkit
