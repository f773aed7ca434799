#include "evkit/nerf/camera.h"

#include <cassert>

namespace evkit::nerf {

Vector3 pixelDirection(const PinholeCamera& camera, double u, double v) {
  const std::array<double, 2> n = normalisedOfPixel(camera, u, v);
  return Vector3(n[0], n[1], 1.0);
}

Eigen::Vector2d projectPoint(const PinholeCamera& camera, const Vector3& p) {
  const std::array<double, 2> q = pixelOfNormalised(camera, p.x() / p.z(), p.y() / p.z());
  return {q[0], q[1]};
}

Eigen::Vector2d projectPoint(const PinholeCamera& camera, const Vector3& p,
                             Eigen::Matrix<double, 2, 3>& jacobian) {
  const double x = p.x() / p.z(), y = p.y() / p.z(), iz = 1 / p.z();  // as projectPoint
  // The normalised coordinates' derivative by the point: (1 / z) [1 0 -x; 0 1 -y].
  Eigen::Matrix<double, 2, 3> dn;
  dn << iz, 0, -x * iz, 0, iz, -y * iz;
  // The distortion's (base/camera.h, distortNormalised): radial 1 + k1 r2 + k2 r2^2 + k3 r2^3
  // and the tangential terms, differentiated in x and y.
  Eigen::Matrix2d dd = Eigen::Matrix2d::Identity();
  const std::vector<double>& k = camera.distortion;
  if (!k.empty()) {
    const double k1 = k.size() > 0 ? k[0] : 0, k2 = k.size() > 1 ? k[1] : 0,
                 p1 = k.size() > 2 ? k[2] : 0, p2 = k.size() > 3 ? k[3] : 0,
                 k3 = k.size() > 4 ? k[4] : 0;
    const double r2 = x * x + y * y;
    const double radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3));
    const double slope = k1 + r2 * (2 * k2 + 3 * k3 * r2);  // d radial / d r2
    const double cross = 2 * x * y * slope + 2 * p1 * x + 2 * p2 * y;
    dd << radial + 2 * x * x * slope + 2 * p1 * y + 6 * p2 * x, cross, cross,
        radial + 2 * y * y * slope + 6 * p1 * y + 2 * p2 * x;
  }
  jacobian = Eigen::DiagonalMatrix<double, 2>(camera.fx, camera.fy) * dd * dn;
  const std::array<double, 2> q = pixelOfNormalised(camera, x, y);
  return {q[0], q[1]};
}

Ray worldRay(const PinholeCamera& camera, const SE3& T, double u, double v) {
  return Ray{T.translation(), T.rotation() * pixelDirection(camera, u, v)};
}

NdcRay toNdc(const Ray& ray, const PinholeCamera& camera, double near) {
  const Vector3& o = ray.origin;
  const Vector3& d = ray.direction;
  assert(d.z() > 0);
  const double ax = 2 * camera.fx / camera.width, ay = 2 * camera.fy / camera.height;
  const Vector3 on = o + ((near - o.z()) / d.z()) * d;  // onto z = near
  NdcRay r;
  r.origin = Vector3(ax * on.x() / near, ay * on.y() / near, -1.0);
  r.direction =
      Vector3(ax * (d.x() / d.z() - on.x() / near), ay * (d.y() / d.z() - on.y() / near), 2.0);
  return r;
}

Eigen::Matrix<double, 3, 6> ndcPointPoseJacobian(const PinholeCamera& camera, const SE3& T,
                                                 double u, double v, double t, double n) {
  const Vector3 d_cam = pixelDirection(camera, u, v);
  const Matrix3 R = T.rotationMatrix();
  const Vector3 o = T.translation(), d = R * d_cam;
  const double ax = 2 * camera.fx / camera.width, ay = 2 * camera.fy / camera.height;
  const double rx = d.x() / d.z(), ry = d.y() / d.z();
  Eigen::Matrix<double, 3, 3> dp_do = Eigen::Matrix3d::Zero(), dp_dd = Eigen::Matrix3d::Zero();
  const double s = (1 - t) / n;
  dp_do(0, 0) = ax * s;
  dp_do(0, 2) = -ax * s * rx;
  dp_do(1, 1) = ay * s;
  dp_do(1, 2) = -ay * s * ry;
  const double gx = ax * ((1 - t) * (n - o.z()) / n + t),
               gy = ay * ((1 - t) * (n - o.z()) / n + t);  // dp/dr
  dp_dd(0, 0) = gx / d.z();
  dp_dd(0, 2) = -gx * d.x() / (d.z() * d.z());
  dp_dd(1, 1) = gy / d.z();
  dp_dd(1, 2) = -gy * d.y() / (d.z() * d.z());
  Eigen::Matrix<double, 3, 6> J;
  J.leftCols<3>() = dp_do * R;
  J.rightCols<3>() = -dp_dd * R * hat(d_cam);
  return J;
}

}  // namespace evkit::nerf
