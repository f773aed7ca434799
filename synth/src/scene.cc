#include "evkit/synth/scene.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <opencv2/imgproc.hpp>
#include <random>

#include "evkit/base/error.h"
#include "evkit/events/image_io.h"

namespace evkit::synth {

namespace {

constexpr double kNoHit = std::numeric_limits<double>::infinity();

// Multi-scale value noise: random grids from coarse to `finest` cells, upsampled bicubically,
// weighted 1/octave (a 1/f-like spectrum).
cv::Mat noise(int res, double finest, std::mt19937_64& rng) {
  cv::Mat sum = cv::Mat::zeros(res, res, CV_32F);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  double weight_sum = 0;
  for (int cells = 4; cells <= std::max(4, static_cast<int>(1.0 / finest)); cells *= 2) {
    cv::Mat grid(cells, cells, CV_32F);
    for (int i = 0; i < grid.rows; ++i) {
      for (int j = 0; j < grid.cols; ++j) grid.at<float>(i, j) = u(rng);
    }
    cv::Mat up;
    cv::resize(grid, up, cv::Size(res, res), 0, 0, cv::INTER_CUBIC);
    const double w = 4.0 / cells;
    sum += up * w;
    weight_sum += w;
  }
  sum /= weight_sum;
  cv::normalize(sum, sum, 0.0, 1.0, cv::NORM_MINMAX);
  return sum;
}

cv::Mat pattern(const TextureSpec& spec, std::mt19937_64& rng) {
  const int res = spec.resolution;
  cv::Mat out(res, res, CV_32F);
  if (spec.kind == "noise") return noise(res, spec.scale, rng);
  if (spec.kind == "stripes") {
    const double c = std::cos(spec.angle), s = std::sin(spec.angle), period = spec.scale * res;
    for (int y = 0; y < res; ++y) {
      for (int x = 0; x < res; ++x)
        out.at<float>(y, x) =
            static_cast<float>(0.5 + 0.5 * std::sin(2 * M_PI * (c * x + s * y) / period));
    }
    return out;
  }
  if (spec.kind == "checker") {
    const int cell = std::max(1, static_cast<int>(spec.scale * res));
    for (int y = 0; y < res; ++y) {
      for (int x = 0; x < res; ++x) out.at<float>(y, x) = ((x / cell + y / cell) % 2) ? 1.0f : 0.0f;
    }
    cv::GaussianBlur(out, out, cv::Size(0, 0), 0.7);  // no aliasing in the texture itself
    return out;
  }
  if (spec.kind == "text") {
    out.setTo(0.15f);
    cv::Mat canvas(res, res, CV_8U, cv::Scalar(0));
    const double size = res / 256.0;
    int line = 0;
    for (int y = static_cast<int>(40 * size); y < res; y += static_cast<int>(48 * size), ++line) {
      const std::string words = spec.text + " " + std::to_string(line * 7 + 3) + " " + spec.text;
      cv::putText(canvas, words, cv::Point(static_cast<int>(8 * size + (line % 3) * 10 * size), y),
                  cv::FONT_HERSHEY_SIMPLEX, size * 0.9, cv::Scalar(255),
                  std::max(1, static_cast<int>(2 * size)), cv::LINE_AA);
    }
    canvas.convertTo(out, CV_32F, 1.0 / 255.0);
    return out;
  }
  throw Error("unknown texture kind '" + spec.kind +
              "' (known: noise, stripes, checker, text, image)");
}

// Ray-rectangle intersection: distance along the (unit-free) direction, texture coordinates.
inline double intersect(const Rectangle& r, const Vector3& o, const Vector3& d, double& s,
                        double& t) {
  const Vector3& n = r.normal;
  const double denom = n.dot(d);
  if (std::abs(denom) < 1e-12) return kNoHit;
  const double lambda = n.dot(r.center - o) / denom;
  if (lambda <= 1e-9) return kNoHit;
  const Vector3 p = o + lambda * d - r.center;
  s = p.dot(r.axis_u) / r.width + 0.5;
  t = p.dot(r.axis_v) / r.height + 0.5;
  if (s < 0 || s > 1 || t < 0 || t > 1) return kNoHit;
  return lambda;
}

cv::Vec3f bilinear(const cv::Mat& img, double x, double y) {
  x = std::clamp(x, 0.0, img.cols - 1.0);
  y = std::clamp(y, 0.0, img.rows - 1.0);
  const int x0 = std::min(static_cast<int>(x), img.cols - 2 < 0 ? 0 : img.cols - 2);
  const int y0 = std::min(static_cast<int>(y), img.rows - 2 < 0 ? 0 : img.rows - 2);
  const int x1 = std::min(x0 + 1, img.cols - 1), y1 = std::min(y0 + 1, img.rows - 1);
  const float fx = static_cast<float>(x - x0), fy = static_cast<float>(y - y0);
  const auto at = [&](int yy, int xx) {
    if (img.channels() == 1) {
      const float v = img.at<float>(yy, xx);
      return cv::Vec3f(v, v, v);
    }
    return img.at<cv::Vec3f>(yy, xx);
  };
  return (at(y0, x0) * (1 - fx) + at(y0, x1) * fx) * (1 - fy) +
         (at(y1, x0) * (1 - fx) + at(y1, x1) * fx) * fy;
}

// Bilinear sample of a single-channel float image at pixel coordinates (clamped).
inline float bilinearScalar(const cv::Mat& img, double x, double y) {
  x = std::clamp(x, 0.0, img.cols - 1.0);
  y = std::clamp(y, 0.0, img.rows - 1.0);
  const int x0 = std::min(static_cast<int>(x), std::max(img.cols - 2, 0));
  const int y0 = std::min(static_cast<int>(y), std::max(img.rows - 2, 0));
  const int x1 = std::min(x0 + 1, img.cols - 1);
  const float fx = static_cast<float>(x - x0), fy = static_cast<float>(y - y0);
  const float* r0 = img.ptr<float>(y0);
  const float* r1 = img.ptr<float>(std::min(y0 + 1, img.rows - 1));
  return (r0[x0] * (1 - fx) + r0[x1] * fx) * (1 - fy) + (r1[x0] * (1 - fx) + r1[x1] * fx) * fy;
}

// First hit of the height field along o + lambda d: march in steps of at most half a source pixel,
// then refine by regula falsi. Returns the hit's z (source depth) or kNoHit.
double marchHeightField(const HeightField& hf, const Vector3& o, const Vector3& d,
                        cv::Vec3f& colour) {
  if (d.z() <= 0) return kNoHit;
  const Calibration& k = hf.intrinsics;
  const double l0 = std::max(1e-6, (hf.z_min - o.z()) / d.z()), l1 = (hf.z_max - o.z()) / d.z();
  if (l1 <= l0) return kNoHit;
  const auto project = [&](double lambda, double& u, double& v, double& z) {
    const Vector3 p = o + lambda * d;
    z = p.z();
    u = k.fx * p.x() / z + k.cx;
    v = k.fy * p.y() / z + k.cy;
  };
  // r(lambda) = z - depth(u, v): negative in front of the surface, >= 0 behind it; off the image
  // the ray counts as in front (it may enter the image further on).
  const auto residual = [&](double lambda) {
    double u, v, z;
    project(lambda, u, v, z);
    if (u < -0.5 || v < -0.5 || u > hf.depth.cols - 0.5 || v > hf.depth.rows - 0.5) return -1.0;
    return z - static_cast<double>(bilinearScalar(hf.depth, u, v));
  };
  double u0, v0, z0, u1, v1, z1;
  project(l0, u0, v0, z0);
  project(l1, u1, v1, z1);
  const int steps = std::clamp(static_cast<int>(2 * std::hypot(u1 - u0, v1 - v0)) + 2, 2, 4096);
  double a = l0, ra = residual(l0);
  if (ra >= 0) return kNoHit;  // starts behind the surface (inside the near margin): nothing to see
  for (int i = 1; i <= steps; ++i) {
    double b = l0 + (l1 - l0) * i / steps;
    double rb = residual(b);
    if (rb >= 0) {
      // Regula falsi inside the bracket [a, b] (the depth map is smooth at this scale).
      for (int it = 0; it < 4 && rb - ra > 1e-12; ++it) {
        const double m = a + (b - a) * (-ra) / (rb - ra);
        const double rm = residual(m);
        if (rm >= 0) {
          b = m;
          rb = rm;
        } else {
          a = m;
          ra = rm;
        }
      }
      const double root = rb - ra > 1e-12 ? a + (b - a) * (-ra) / (rb - ra) : b;
      double u, v, z;
      project(root, u, v, z);
      colour = bilinear(hf.image, u, v);
      return z;
    }
    a = b;
    ra = rb;
  }
  return kNoHit;
}

// What a ray sees along o + lambda d (lambda = depth along z when d = R (.., .., 1)): the surfaces
// it meets, composited front to back (a matte lets part of what lies behind through), over the
// height field or the background. Returns the lambda of the first hit at least half opaque.
double nearest(const Scene& scene, const Vector3& o, const Vector3& d, cv::Vec3f& colour) {
  const float bg = static_cast<float>(scene.background);
  cv::Vec3f behind(bg, bg, bg);
  double far = kNoHit;
  if (scene.height_field) {
    cv::Vec3f c;
    const double z = marchHeightField(*scene.height_field, o, d, c);
    if (z < kNoHit) {
      far = (z - o.z()) / d.z();
      behind = c;
    }
  }
  struct Hit {
    double lambda;
    const Rectangle* r;
    double s, t;
  };
  Hit hits[16];
  int n = 0;
  for (const Rectangle& r : scene.rectangles) {
    double s, t;
    const double lambda = intersect(r, o, d, s, t);
    if (lambda >= far) continue;
    if (n < 16) {
      hits[n++] = {lambda, &r, s, t};
    } else {  // more than 16 surfaces on one ray: keep the nearest 16
      Hit* last = std::max_element(hits, hits + n,
                                   [](const Hit& a, const Hit& b) { return a.lambda < b.lambda; });
      if (lambda < last->lambda) *last = {lambda, &r, s, t};
    }
  }
  std::sort(hits, hits + n, [](const Hit& a, const Hit& b) { return a.lambda < b.lambda; });
  colour = cv::Vec3f(0, 0, 0);
  float transmitted = 1.0f;
  double depth = kNoHit;
  for (int i = 0; i < n && transmitted > 1e-4f; ++i) {
    const float a = hits[i].r->texture->opacity(hits[i].s, hits[i].t);
    if (a <= 0) continue;
    colour += transmitted * a * hits[i].r->texture->sample(hits[i].s, hits[i].t);
    if (depth == kNoHit && a >= 0.5f) depth = hits[i].lambda;
    transmitted *= 1.0f - a;
  }
  colour += transmitted * behind;
  return depth < kNoHit ? depth : far;
}

double firstHit(const Scene& scene, const Vector3& o, const Vector3& d) {
  cv::Vec3f unused;
  const double lambda = nearest(scene, o, d, unused);
  return lambda < kNoHit ? lambda : 0.0;
}

}  // namespace

cv::Vec3f Texture::sample(double s, double t) const {
  return bilinear(image, s * image.cols - 0.5, t * image.rows - 0.5);
}

void HeightField::fitDepthRange() {
  double lo, hi;
  cv::minMaxLoc(depth, &lo, &hi);
  z_min = lo * 0.9;
  z_max = hi * 1.05;
}

float Texture::opacity(double s, double t) const {
  if (alpha.empty()) return 1.0f;
  return bilinearScalar(alpha, s * alpha.cols - 0.5, t * alpha.rows - 0.5);
}

Texture makeTexture(const TextureSpec& spec) {
  Texture tex;
  if (spec.kind == "image") {
    Frame f = readImageFile(spec.path);
    tex.image = f.image;
    if (!spec.colour && tex.image.channels() == 3)
      cv::cvtColor(tex.image, tex.image, cv::COLOR_BGR2GRAY);
    return tex;
  }
  std::mt19937_64 rng(spec.seed * 0x9e3779b97f4a7c15ULL + 17);
  const auto shaped = [&](const cv::Mat& unit) {
    return unit * spec.contrast + (spec.mean - 0.5 * spec.contrast);
  };
  if (!spec.colour) {
    tex.image = shaped(pattern(spec, rng));
  } else {
    // Colour: the pattern tinted by a second, coarse noise per channel.
    const cv::Mat base = pattern(spec, rng);
    std::vector<cv::Mat> channels;
    for (int c = 0; c < 3; ++c) {
      const cv::Mat tint = noise(spec.resolution, 0.25, rng);
      channels.push_back(shaped(base.mul(0.6 + 0.4 * tint)));
    }
    cv::merge(channels, tex.image);
  }
  cv::max(tex.image, 0.0, tex.image);
  cv::min(tex.image, 1.0, tex.image);
  return tex;
}

void Scene::addBox(const Vector3& center, const Vector3& size, const Vector3& rotation,
                   const std::shared_ptr<const Texture>& texture) {
  const Matrix3 R = expSO3(rotation).toRotationMatrix();
  for (int axis = 0; axis < 3; ++axis) {
    for (int sign : {-1, 1}) {
      const int a = (axis + 1) % 3, b = (axis + 2) % 3;
      rectangles.emplace_back(center + R.col(axis) * (sign * 0.5 * size[axis]), R.col(a), R.col(b),
                              size[a], size[b], texture);
    }
  }
}

std::vector<Vector3> sampleDirections(const Calibration& camera, int width, int height,
                                      int supersample) {
  const int ss = std::max(1, supersample);
  std::vector<Vector3> d(static_cast<size_t>(width) * height * ss * ss);
#pragma omp parallel for schedule(static)
  for (int y = 0; y < height; ++y) {
    size_t k = static_cast<size_t>(y) * width * ss * ss;
    for (int x = 0; x < width; ++x) {
      for (int sy = 0; sy < ss; ++sy) {
        for (int sx = 0; sx < ss; ++sx) {
          d[k++] = cameraDirection(camera, x + (sx + 0.5) / ss - 0.5, y + (sy + 0.5) / ss - 0.5);
        }
      }
    }
  }
  return d;
}

cv::Mat render(const Scene& scene, const Calibration& camera, int width, int height,
               const SE3& T_world_cam, const RenderOptions& options, cv::Mat* depth) {
  const int ss = std::max(1, options.supersample);
  if (options.directions &&
      options.directions->size() != static_cast<size_t>(width) * height * ss * ss)
    throw Error("render: RenderOptions::directions holds " +
                std::to_string(options.directions->size()) + " directions, not " +
                std::to_string(static_cast<size_t>(width) * height * ss * ss) +
                " (sampleDirections for this size and supersampling)");
  const int channels = scene.colour ? 3 : 1;
  cv::Mat out(height, width, CV_MAKETYPE(CV_32F, channels));
  if (depth) depth->create(height, width, CV_32F);
  const Matrix3 R = T_world_cam.rotationMatrix();
  const Vector3 o = T_world_cam.translation();
#pragma omp parallel for schedule(dynamic, 4)
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) {
      cv::Vec3f acc(0, 0, 0);
      for (int sy = 0; sy < ss; ++sy) {
        for (int sx = 0; sx < ss; ++sx) {
          // Sub-pixel sample positions centred on the pixel centre.
          const double u = x + (sx + 0.5) / ss - 0.5, v = y + (sy + 0.5) / ss - 0.5;
          const Vector3 d_cam =
              options.directions
                  ? (*options
                          .directions)[((static_cast<size_t>(y) * width + x) * ss + sy) * ss + sx]
                  : cameraDirection(camera, u, v);
          cv::Vec3f colour;
          nearest(scene, o, R * d_cam, colour);
          acc += colour;
        }
      }
      acc /= static_cast<float>(ss * ss);
      if (depth)
        depth->at<float>(y, x) =
            static_cast<float>(firstHit(scene, o, R * cameraDirection(camera, x, y)));
      if (channels == 1) {
        out.at<float>(y, x) = 0.114f * acc[0] + 0.587f * acc[1] +
                              0.299f * acc[2];  // BT.601 (equal channels: identity)
      } else {
        out.at<cv::Vec3f>(y, x) = acc;
      }
    }
  }
  return out;
}

}  // namespace evkit::synth
