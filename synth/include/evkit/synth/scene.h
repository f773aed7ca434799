// Synthetic scenes with known geometry, rendered exactly by ray casting.
//
// Frames: the camera frame is OpenCV's (x right, y down, z forward); poses are T_world_cam; pixel
// centres sit at integer coordinates, so pixel (x, y) looks along ((x - cx)/fx, (y - cy)/fy, 1).
// Radiance is linear in [0, 1], grey (1 channel) or colour (3 channels, BGR).
//
// Objects: textured rectangles (planes; boxes are six of them) and an RGB-D height field (a colour
// image with a depth map, seen from the identity pose, ray-marched along each ray).
#pragma once

#include <array>
#include <memory>
#include <opencv2/core.hpp>
#include <optional>
#include <string>
#include <vector>

#include "evkit/events/calibration.h"
#include "evkit/spline/lie.h"

namespace evkit::synth {

// A texture image covering [0,1]^2 of an object's surface, sampled bilinearly; with an alpha
// matte, the surface is partly transparent (a cut-out with soft edges: an occlusion boundary).
struct Texture {
  cv::Mat image;                               // CV_32FC1 or CV_32FC3, linear [0,1]
  cv::Mat alpha;                               // empty (opaque) or CV_32FC1 in [0,1], image's size
  cv::Vec3f sample(double s, double t) const;  // s, t in [0,1]; clamped at the border
  float opacity(double s, double t) const;     // 1 without a matte
};

struct TextureSpec {
  std::string kind = "noise";          // noise | stripes | checker | text | image
  int resolution = 1024;               // texture image size (square)
  double mean = 0.45, contrast = 0.7;  // output range [mean - contrast/2, mean + contrast/2]
  double scale =
      0.08;  // noise: finest feature size as a fraction of the texture; stripes/checker: period
  double angle = 0.3;          // stripes: direction (rad)
  std::string text = "evkit";  // text
  std::string path;            // image
  bool colour = false;
  uint64_t seed = 1;
};
Texture makeTexture(const TextureSpec& spec);

struct Rectangle {
  Rectangle() = default;
  Rectangle(const Vector3& c, const Vector3& u, const Vector3& v, double w, double h,
            std::shared_ptr<const Texture> tex)
      : center(c),
        axis_u(u),
        axis_v(v),
        normal(u.cross(v)),
        width(w),
        height(h),
        texture(std::move(tex)) {}
  Vector3 center;  // world
  Vector3 axis_u;  // unit, along the texture's s (width)
  Vector3 axis_v;  // unit, along t (height)
  Vector3 normal;  // axis_u x axis_v
  double width = 1, height = 1;
  std::shared_ptr<const Texture> texture;
};

struct HeightField {
  cv::Mat image;  // CV_32FC1/3 linear
  cv::Mat depth;  // CV_32F, metres along z of the source camera (identity pose)
  Calibration intrinsics;
  double z_min = 0, z_max = 0;

  // z_min, z_max: the depth map's range with a margin (the ray march's bounds).
  void fitDepthRange();
};

struct Scene {
  std::vector<Rectangle> rectangles;
  std::optional<HeightField> height_field;
  double background = 0.1;  // radiance of rays that hit nothing
  bool colour = false;

  void addBox(const Vector3& center, const Vector3& size, const Vector3& rotation,
              const std::shared_ptr<const Texture>& texture);
};

// The camera-frame direction (z = 1) that pixel (u, v) sees, through the camera's lens distortion.
inline Vector3 cameraDirection(const Calibration& camera, double u, double v) {
  const std::array<double, 2> n = normalisedOfPixel(camera, u, v);
  return Vector3(n[0], n[1], 1.0);
}

struct RenderOptions {
  int supersample = 2;  // k x k rays per pixel, averaged (anti-aliasing)
  // The camera-frame directions of every sample (row-major pixels, k x k samples each), as
  // sampleDirections gives them: a renderer called many times through a distorting lens takes
  // them from here instead of undistorting every sample again. Null: computed per sample.
  const std::vector<Vector3>* directions = nullptr;
};

// The camera-frame directions of every sample that render() casts, for RenderOptions::directions.
std::vector<Vector3> sampleDirections(const Calibration& camera, int width, int height,
                                      int supersample);

// Renders radiance (and, if asked, the depth along z of the first hit at each pixel centre that is
// at least half opaque; 0 where nothing is hit) at a pose. Surfaces with an alpha matte are
// composited front to back over what lies behind them. Parallel over rows.
cv::Mat render(const Scene& scene, const Calibration& camera, int width, int height,
               const SE3& T_world_cam, const RenderOptions& options = {}, cv::Mat* depth = nullptr);

}  // namespace evkit::synth
