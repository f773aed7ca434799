// Pinhole camera with optional radial-tangential distortion, rays for any pose (poses in double),
// and the normalised device coordinates (NDC) of forward-facing scenes.
//
// Camera frame: x right, y down, z forward (OpenCV). NDC (Mildenhall et al. 2020, appendix C,
// written for +z forward): a point (x, y, z) of the world (= reference camera) frame maps to
// (a_x x / z, a_y y / z, 1 - 2 near / z) with a_x = 2 fx / W, a_y = 2 fy / H; a ray from the near
// plane to infinity becomes the segment p(t) = o' + t d', t in [0, 1):
//   o' = (a_x o_x / n, a_y o_y / n, -1) with o moved onto z = n along the ray,
//   d' = (a_x (d_x / d_z - o_x / n), a_y (d_y / d_z - o_y / n), 2).
#pragma once

#include <Eigen/Core>
#include <vector>

#include "evkit/base/camera.h"
#include "evkit/spline/lie.h"

namespace evkit::nerf {

using PinholeCamera = evkit::PinholeCamera;  // base/camera.h: the one camera type

// Camera-frame direction (z = 1) of pixel coordinates (u, v): undistorted by fixed-point iteration
// when there is distortion.
Vector3 pixelDirection(const PinholeCamera& camera, double u, double v);
// Pixel coordinates of a camera-frame point (distorted).
Eigen::Vector2d projectPoint(const PinholeCamera& camera, const Vector3& p_cam);
// The same and its derivative by the point (2 x 3), the distortion's polynomial included.
Eigen::Vector2d projectPoint(const PinholeCamera& camera, const Vector3& p_cam,
                             Eigen::Matrix<double, 2, 3>& jacobian);

struct Ray {
  Vector3 origin, direction;  // world frame; direction = R d_cam (not normalised)
};

Ray worldRay(const PinholeCamera& camera, const SE3& T_world_cam, double u, double v);

struct NdcRay {
  Vector3 origin, direction;  // p(t) = origin + t direction, t in [0, 1)
};

// Requires the ray to point forward (direction.z > 0).
NdcRay toNdc(const Ray& ray, const PinholeCamera& camera, double near);

// d p(t) / d eps: 3 x 6 Jacobian of the NDC point at t of pixel (u, v) with respect to a right
// perturbation T_world_cam exp(eps), eps = (rho, phi). With r = d / d_z:
//   p_x = a_x ((1 - t)/n (o_x + (n - o_z) r_x) + t r_x),  p_y alike,  p_z = 2 t - 1;
//   do/drho = R, dd/dphi = -R [d_cam]x.
Eigen::Matrix<double, 3, 6> ndcPointPoseJacobian(const PinholeCamera& camera,
                                                 const SE3& T_world_cam, double u, double v,
                                                 double t, double near);

}  // namespace evkit::nerf
