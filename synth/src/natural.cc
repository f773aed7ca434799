// Natural scenes: real photographs as depth-layered scenes (planes at 1-10 m, cut-outs with soft
// alpha edges in front of full backdrops, a slanted wall, a ground plane) and one real depth map,
// the Middlebury 2014 "motorcycle" disparity. The photographs are the data images that Debian's
// python3-skimage ships, each CC0 or public domain (skimage/data/_fetchers.py says which);
// the disparity map is the Middlebury benchmark's (Scharstein et al., GCPR 2014), downsampled 4x
// as skimage ships it.
#include <zlib.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <opencv2/imgproc.hpp>
#include <opencv2/photo.hpp>
#include <random>

#include "evkit/base/error.h"
#include "evkit/base/text.h"
#include "evkit/events/image_io.h"
#include "evkit/synth/generator.h"

namespace evkit::synth {

namespace fs = std::filesystem;

namespace {

// Half the field of view of defaultCamera (fx = 0.9 width): tan = 0.5 / 0.9 across, 0.5 * (3 / 4) /
// 0.9 down for 4:3; backdrops cover it with a margin for the shake.
constexpr double kHalfWidth = 0.5 / 0.9, kHalfHeight = 0.42 / 0.9, kMargin = 1.5;

std::string photoPath(const SceneOptions& o, const std::string& file) {
  return (fs::path(o.photo_dir.empty() ? defaultPhotoDir() : o.photo_dir) / file).string();
}

// sRGB-encoded 8-bit photograph -> linear radiance in [0.03, 0.88] (no pure black: the log mapping
// of a real sensor never sees zero either).
cv::Mat photo(const SceneOptions& o, const std::string& file, bool colour) {
  const std::string path = photoPath(o, file);
  if (!fs::is_regular_file(path))
    throwInFile(path,
                "photograph not found: natural scenes use the data images of Debian's "
                "python3-skimage (bash scripts/install-deps.sh installs it; $EVKIT_PHOTOS names "
                "another folder)");
  cv::Mat image = readImageFile(path).image;
  if (image.channels() == 3 && !colour) cv::cvtColor(image, image, cv::COLOR_BGR2GRAY);
  if (image.channels() == 1 && colour) cv::cvtColor(image, image, cv::COLOR_GRAY2BGR);
  cv::Mat linear = image.clone();
  float* p = linear.ptr<float>();
  for (size_t i = 0; i < linear.total() * static_cast<size_t>(linear.channels()); ++i) {
    const float c = p[i];
    p[i] = 0.03f + 0.85f * (c <= 0.04045f ? c / 12.92f : std::pow((c + 0.055f) / 1.055f, 2.4f));
  }
  return linear;
}

// The photograph cropped to the aspect width:height and resampled to `texels` across (about twice
// the pixels it covers on screen, so that the renderer's bilinear lookups do not alias).
cv::Mat fitted(const cv::Mat& image, double width, double height, int texels) {
  const double aspect = width / height;
  cv::Rect crop(0, 0, image.cols, image.rows);
  if (image.cols > aspect * image.rows) {
    crop.width = static_cast<int>(aspect * image.rows);
    crop.x = (image.cols - crop.width) / 2;
  } else {
    crop.height = static_cast<int>(image.cols / aspect);
    crop.y = (image.rows - crop.height) / 2;
  }
  cv::Mat out;
  const int tw = std::max(8, texels), th = std::max(8, static_cast<int>(texels / aspect));
  cv::resize(image(crop), out, cv::Size(tw, th), 0, 0, cv::INTER_AREA);
  return out;
}

// A soft-edged blob covering most of a w x h matte: a few random bumps, thresholded, feathered over
// `soft` texels. An occlusion boundary of irregular shape.
cv::Mat blobMatte(int w, int h, uint64_t seed, double soft) {
  std::mt19937_64 rng(seed * 0x9e3779b97f4a7c15ULL + 3);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  cv::Mat field(h, w, CV_32F);
  double cx[5], cy[5], r[5];
  for (int k = 0; k < 5; ++k) cx[k] = 0.3 * u(rng), cy[k] = 0.3 * u(rng), r[k] = 0.4 + 0.1 * u(rng);
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const double sx = 2.0 * x / w - 1, sy = 2.0 * y / h - 1;
      double v = 0;
      for (int k = 0; k < 5; ++k)
        v += std::exp(-((sx - cx[k]) * (sx - cx[k]) + (sy - cy[k]) * (sy - cy[k])) / (r[k] * r[k]));
      field.at<float>(y, x) = static_cast<float>(v);
    }
  }
  cv::Mat matte = (field > 0.5) / 255;
  matte.convertTo(matte, CV_32F);
  cv::GaussianBlur(matte, matte, cv::Size(0, 0), soft);
  return matte;
}

struct Layers {
  const SceneOptions& o;
  bool colour;
  Scene scene;

  // A fronto-parallel backdrop at depth z filling the view (with a margin for the shake).
  void backdrop(const std::string& file, double z, double tilt = 0) {
    const double w = 2 * kMargin * kHalfWidth * z, h = 2 * kMargin * kHalfHeight * z;
    add(file, Vector3(0, 0, z), w, h, 0, tilt);
  }
  // A cut-out: the photograph inside a soft-edged blob, centred at (x, y) (as fractions of the
  // view's half-width and half-height) at depth z, `size` of the view's width across.
  void cutout(const std::string& file, double x, double y, double z, double size, uint64_t seed) {
    const double w = 2 * kHalfWidth * z * size, h = w * 0.8;
    add(file, Vector3(x * kHalfWidth * z, y * kHalfHeight * z, z), w, h, seed, 0);
  }
  // seed 0: opaque. yaw: a rotation about the vertical axis (a slanted wall).
  void add(const std::string& file, const Vector3& centre, double w, double h, uint64_t seed,
           double yaw) {
    const double on_screen = 0.9 * 346 * w / centre.z();  // pixels across at 346 wide
    auto tex = std::make_shared<Texture>();
    tex->image = fitted(photo(o, file, colour), w, h, static_cast<int>(2 * on_screen));
    if (seed) {
      const double soft = 1.2 * tex->image.cols / on_screen;  // about 0.6 px on screen
      tex->alpha = blobMatte(tex->image.cols, tex->image.rows, seed + o.seed, soft);
    }
    const Vector3 right(std::cos(yaw), 0, std::sin(yaw));
    scene.rectangles.push_back(Rectangle(centre, right, Vector3::UnitY(), w, h, tex));
  }
};

// The first array of a NumPy .npz archive (zip; stored or deflated): float32, C order.
cv::Mat readNpz(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throwInFile(path, "cannot open");
  std::vector<unsigned char> zip((std::istreambuf_iterator<char>(in)), {});
  const auto u16 = [&](size_t at) { return static_cast<uint32_t>(zip[at] | zip[at + 1] << 8); };
  const auto u32 = [&](size_t at) { return u16(at) | u16(at + 2) << 16; };
  if (zip.size() < 30 || u32(0) != 0x04034b50) throwAtByte(path, 0, "not a zip archive");
  const uint32_t method = u16(8), packed = u32(18), size = u32(22);
  const size_t data = 30 + u16(26) + u16(28);
  if ((u16(6) & 8) || data + packed > zip.size() || size > (1u << 30))
    throwAtByte(path, 18, "unsupported or damaged zip entry");
  std::vector<unsigned char> npy(size);
  if (method == 0) {
    std::memcpy(npy.data(), zip.data() + data, size);
  } else if (method == 8) {
    z_stream z{};
    if (inflateInit2(&z, -15) != Z_OK) throwInFile(path, "zlib failed");
    z.next_in = zip.data() + data;
    z.avail_in = packed;
    z.next_out = npy.data();
    z.avail_out = size;
    const int rc = inflate(&z, Z_FINISH);
    inflateEnd(&z);
    if (rc != Z_STREAM_END || z.total_out != size) throwAtByte(path, data, "damaged deflate data");
  } else {
    throwAtByte(path, 8, "zip compression method " + std::to_string(method) + " not supported");
  }
  if (npy.size() < 10 || std::memcmp(npy.data(), "\x93NUMPY", 6) != 0)
    throwInFile(path, "the archive's first entry is not a .npy array");
  const size_t header_len = npy[8] | npy[9] << 8;
  const std::string header(npy.begin() + 10,
                           npy.begin() + 10 + std::min(header_len, npy.size() - 10));
  int rows = 0, cols = 0;
  const size_t shape = header.find("'shape': (");
  if (header.find("'<f4'") == std::string::npos ||
      header.find("'fortran_order': False") == std::string::npos || shape == std::string::npos ||
      std::sscanf(header.c_str() + shape + 10, "%d, %d", &rows, &cols) != 2 || rows <= 0 ||
      cols <= 0 || 10 + header_len + size_t(rows) * cols * 4 > npy.size())
    throwInFile(path, "expected a 2-D little-endian float32 array in C order");
  cv::Mat out(rows, cols, CV_32F);
  std::memcpy(out.data, npy.data() + 10 + header_len, out.total() * 4);
  return out;
}

// The Middlebury motorcycle: the left image over its ground-truth depth, Z = f B / (d + doffs)
// with the calibration skimage documents for its 4x-downsampled copy (f 994.978 px, baseline
// 193.001 mm, doffs 31.086 px); pixels without ground truth are inpainted from their neighbours.
// Seen through a wider lens than it was taken with (f 500 px), so that it fills defaultCamera's
// view.
HeightField motorcycle(const SceneOptions& o, bool colour) {
  HeightField hf;
  hf.image = photo(o, "motorcycle_left.png", colour);
  const std::string archive = photoPath(o, "motorcycle_disp.npz");
  const cv::Mat disparity = readNpz(archive);
  if (disparity.size() != hf.image.size())
    throwInFile(archive, "disparity and image differ in size");
  hf.depth.create(disparity.size(), CV_32F);
  cv::Mat holes(disparity.size(), CV_8U, cv::Scalar(0));
  for (int y = 0; y < disparity.rows; ++y) {
    for (int x = 0; x < disparity.cols; ++x) {
      const float d = disparity.at<float>(y, x);
      const bool ok = std::isfinite(d) && d > 0;
      hf.depth.at<float>(y, x) = ok ? static_cast<float>(994.978 * 0.193001 / (d + 31.086)) : 0.f;
      holes.at<uint8_t>(y, x) = ok ? 0 : 255;
    }
  }
  cv::inpaint(hf.depth, holes, hf.depth, 5, cv::INPAINT_TELEA);
  hf.intrinsics = Calibration{500, 500, (hf.image.cols - 1) / 2.0, (hf.image.rows - 1) / 2.0, {}};
  hf.fitDepthRange();
  return hf;
}

}  // namespace

std::string defaultPhotoDir() {
  const char* env = std::getenv("EVKIT_PHOTOS");
  return env && *env ? env : "/usr/lib/python3/dist-packages/skimage/data";
}

std::vector<std::string> naturalSceneNames() {
  return {"coffee_astronaut", "cat_bricks",      "cameraman_grass", "rocket_layers",
          "four_layers",      "slanted_bricks",  "gravel_ground",   "motorcycle",
          "coffee_plane",     "astronaut_plane", "hubble_rocket",   "text_coins"};
}

bool isNaturalScene(const std::string& name) {
  for (const std::string& n : naturalSceneNames()) {
    if (n == name) return true;
  }
  return false;
}

Scene makeNaturalScene(const std::string& name, const SceneOptions& o) {
  const bool colour =
      o.colour || name == "coffee_astronaut" || name == "cat_bricks" || name == "motorcycle";
  Layers l{o, colour, {}};
  l.scene.colour = colour;
  l.scene.background = 0.1;
  if (name == "coffee_astronaut") {  // two photographs at two depths
    l.backdrop("astronaut.png", 4.5);
    l.cutout("coffee.png", -0.35, 0.1, 1.2, 0.55, 1);
  } else if (name == "cat_bricks") {
    l.backdrop("brick.png", 2.5);
    l.cutout("chelsea.png", 0.3, 0.05, 1.0, 0.6, 2);
  } else if (name == "cameraman_grass") {
    l.backdrop("grass.png", 6.0);
    l.cutout("camera.png", -0.1, -0.1, 1.6, 0.5, 3);
  } else if (name == "rocket_layers") {  // three depths
    l.backdrop("gravel.png", 8.0);
    l.cutout("rocket.jpg", 0.35, -0.2, 3.0, 0.45, 4);
    l.cutout("coffee.png", -0.45, 0.3, 1.1, 0.45, 5);
  } else if (name == "four_layers") {
    l.backdrop("grass.png", 7.0);
    l.cutout("brick.png", 0.4, -0.3, 4.0, 0.5, 6);
    l.cutout("chelsea.png", -0.4, 0.0, 2.0, 0.45, 7);
    l.cutout("camera.png", 0.2, 0.45, 1.1, 0.35, 8);
  } else if (name == "slanted_bricks") {  // a wall at 55 degrees, from 1.3 m to beyond 4 m
    l.backdrop("astronaut.png", 7.0);
    l.add("brick.png", Vector3(-0.9, 0, 2.6), 4.0, 2.6, 0, 0.96);
  } else if (name == "gravel_ground") {  // a ground plane below the camera, a wall, a cut-out
    l.backdrop("hubble_deep_field.jpg", 9.0);
    auto ground = std::make_shared<Texture>();
    ground->image = fitted(photo(o, "gravel.png", colour), 1, 1, 1024);
    l.scene.rectangles.emplace_back(Vector3(0, 0.9 - 0.12 * 4.5, 5.5), Vector3::UnitX(),
                                    Vector3(0, -0.12, 1).normalized(), 9, 9, ground);
    l.cutout("chelsea.png", 0.35, -0.5, 2.5, 0.45, 9);
  } else if (name == "motorcycle") {  // a real depth map
    l.scene.height_field = motorcycle(o, colour);
  } else if (name == "coffee_plane") {  // planar: one photograph
    l.backdrop("coffee.png", 1.5);
  } else if (name == "astronaut_plane") {  // planar, slightly slanted
    l.backdrop("astronaut.png", 3.5, 0.2);
  } else if (name == "hubble_rocket") {
    l.backdrop("hubble_deep_field.jpg", 10.0);
    l.cutout("rocket.jpg", 0.0, 0.0, 2.0, 0.6, 10);
  } else if (name == "text_coins") {
    l.backdrop("coins.png", 3.0);
    l.cutout("text.png", -0.2, 0.2, 1.3, 0.55, 11);
  } else {
    throw Error("unknown natural scene '" + name + "' (known: " + joinNames(naturalSceneNames()) +
                ")");
  }
  return l.scene;
}

}  // namespace evkit::synth
