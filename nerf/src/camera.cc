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
