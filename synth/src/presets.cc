#include <cmath>
#include <filesystem>
#include <opencv2/core/persistence.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "evkit/base/error.h"
#include "evkit/base/text.h"
#include "evkit/events/image_io.h"
#include "evkit/synth/generator.h"

namespace evkit::synth {

namespace fs = std::filesystem;

namespace {

std::shared_ptr<const Texture> texture(const std::string& kind, double scale, uint64_t seed,
                                       const SceneOptions& o, double mean = 0.45,
                                       double contrast = 0.7) {
  TextureSpec spec;
  spec.kind = kind;
  spec.scale = scale;
  spec.seed = seed * 7919 + o.seed;
  spec.colour = o.colour;
  spec.mean = mean;
  spec.contrast = contrast;
  return std::make_shared<Texture>(makeTexture(spec));
}

Rectangle plane(const Vector3& center, double width, double height,
                std::shared_ptr<const Texture> tex, const Vector3& right = Vector3::UnitX(),
                const Vector3& down = Vector3::UnitY()) {
  return Rectangle{center, right.normalized(), down.normalized(), width, height, std::move(tex)};
}

// A slanted ground plane below the camera: y = +1.2 m at the camera, rising away.
Rectangle ground(const SceneOptions& o, uint64_t seed) {
  const Vector3 along = Vector3(0, -0.25, 1).normalized();
  return plane(Vector3(0, 1.2 - 0.25 * 5, 5), 10, 10, texture("noise", 0.01, seed, o, 0.4, 0.6),
               Vector3::UnitX(), along);
}

HeightField proceduralHeightField(const SceneOptions& o) {
  HeightField hf;
  const int w = 480, h = 360;
  TextureSpec spec;
  spec.kind = "noise";
  spec.scale = 0.01;
  spec.resolution = 512;
  spec.colour = o.colour;
  spec.seed = o.seed + 101;
  cv::resize(makeTexture(spec).image, hf.image, cv::Size(w, h), 0, 0, cv::INTER_AREA);
  hf.depth.create(h, w, CV_32F);
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const double u = (x - w / 2.0) / w, v = (y - h / 2.0) / h;
      hf.depth.at<float>(y, x) = static_cast<float>(
          3.0 - 1.2 * std::exp(-((u + 0.15) * (u + 0.15) + v * v) / 0.02) -
          0.6 * std::exp(-((u - 0.25) * (u - 0.25) + (v + 0.1) * (v + 0.1)) / 0.01) + 0.8 * v);
    }
  }
  hf.intrinsics = defaultCamera(w, h);
  return hf;
}

HeightField heightFieldFromFiles(const std::string& image, const std::string& depth_path,
                                 double scale, bool disparity, double baseline,
                                 std::optional<Calibration> k, bool colour) {
  HeightField hf;
  hf.image = readImageFile(image).image;
  if (!colour && hf.image.channels() == 3) cv::cvtColor(hf.image, hf.image, cv::COLOR_BGR2GRAY);
  const cv::Mat raw = cv::imread(depth_path, cv::IMREAD_ANYDEPTH);
  if (raw.empty()) throwInFile(depth_path, "not a readable depth image (16-bit PNG expected)");
  if (raw.size() != hf.image.size()) throwInFile(depth_path, "depth map and image differ in size");
  raw.convertTo(hf.depth, CV_32F, scale);
  hf.intrinsics = k ? *k : defaultCamera(hf.image.cols, hf.image.rows);
  if (disparity) {
    for (int y = 0; y < hf.depth.rows; ++y) {
      for (int x = 0; x < hf.depth.cols; ++x) {
        float& d = hf.depth.at<float>(y, x);
        d = d > 0 ? static_cast<float>(hf.intrinsics.fx * baseline / d) : 0.0f;
      }
    }
  }
  // Holes (0) take the farthest valid depth.
  double zmin, zmax;
  cv::minMaxLoc(hf.depth, &zmin, &zmax, nullptr, nullptr, hf.depth > 0);
  if (!(zmax > 0)) throwInFile(depth_path, "no valid depth");
  hf.depth.setTo(zmax, hf.depth <= 0);
  return hf;
}

}  // namespace

Calibration defaultCamera(int width, int height) { return Calibration::assumed(width, height); }

std::vector<std::string> presetNames() {
  return {"planes", "box", "rgbd", "ground", "text", "plain"};
}

Scene makePreset(const std::string& name, const SceneOptions& o) {
  if (isNaturalScene(name)) return makeNaturalScene(name, o);
  Scene s;
  s.colour = o.colour;
  s.background = 0.1;
  if (name == "planes") {
    s.rectangles.push_back(plane(Vector3(0, 0, 6), 14, 11, texture("noise", 0.01, 1, o)));
    s.rectangles.push_back(
        plane(Vector3(-0.9, -0.3, 3.5), 2.4, 2.0, texture("text", 0.1, 2, o, 0.5, 0.8)));
    s.rectangles.push_back(
        plane(Vector3(0.8, 0.4, 2.2), 1.0, 1.4, texture("checker", 0.125, 3, o)));
    s.rectangles.push_back(plane(Vector3(0.1, -0.45, 1.6), 0.5, 0.35, texture("stripes", 0.1, 4, o),
                                 Vector3(1, 0.3, 0), Vector3(-0.3, 1, 0)));
  } else if (name == "box") {
    s.rectangles.push_back(plane(Vector3(0, 0, 5), 12, 9, texture("noise", 0.015, 1, o)));
    s.rectangles.push_back(ground(o, 2));
    s.addBox(Vector3(0.2, 0.1, 2.6), Vector3(0.9, 0.9, 0.9), Vector3(0.25, 0.6, 0.1),
             texture("checker", 0.1, 3, o, 0.5, 0.8));
    s.addBox(Vector3(-0.9, 0.4, 3.2), Vector3(0.5, 0.8, 0.5), Vector3(0, -0.4, 0),
             texture("noise", 0.05, 4, o));
  } else if (name == "rgbd") {
    if (o.rgbd_image.empty() != o.rgbd_depth.empty())
      throw Error("the rgbd preset needs both --image and --depth, or neither");
    s.height_field = o.rgbd_image.empty()
                         ? proceduralHeightField(o)
                         : heightFieldFromFiles(o.rgbd_image, o.rgbd_depth, o.rgbd_depth_scale,
                                                false, 0, std::nullopt, o.colour);
    s.height_field->fitDepthRange();
  } else if (name == "ground") {
    s.rectangles.push_back(plane(Vector3(0, -1, 7), 16, 8, texture("stripes", 0.05, 1, o)));
    s.rectangles.push_back(ground(o, 5));
  } else if (name == "text") {
    s.rectangles.push_back(
        plane(Vector3(0, 0, 4.5), 10, 8, texture("noise", 0.02, 1, o, 0.35, 0.5)));
    s.rectangles.push_back(
        plane(Vector3(0, 0, 2.0), 2.0, 1.5, texture("text", 0.1, 6, o, 0.5, 0.9)));
  } else if (name == "plain") {
    s.rectangles.push_back(plane(Vector3(0, 0, 5), 14, 11, texture("noise", 0.02, 1, o, 0.5, 0.0)));
    s.rectangles.push_back(
        plane(Vector3(-0.7, -0.2, 3.0), 0.8, 0.6, texture("checker", 0.125, 2, o, 0.5, 0.8)));
    s.rectangles.push_back(
        plane(Vector3(0.9, 0.5, 2.5), 0.7, 0.5, texture("text", 0.1, 3, o, 0.5, 0.9)));
  } else {
    throw Error("unknown preset '" + name + "' (known: " + joinNames(presetNames()) +
                "; natural scenes: " + joinNames(naturalSceneNames()) + ")");
  }
  return s;
}

Scene loadScene(const std::string& path, const SceneOptions& options) {
  if (!fs::is_regular_file(path)) throwInFile(path, "no such scene file");
  cv::FileStorage fsx;
  try {
    fsx.open(path, cv::FileStorage::READ);
  } catch (const cv::Exception& e) {
    throwInFile(path, std::string("not a readable YAML/JSON scene: ") + e.what());
  }
  if (!fsx.isOpened()) throwInFile(path, "not a readable YAML/JSON scene");
  Scene s;
  s.background = fsx["background"].empty() ? 0.1 : static_cast<double>(fsx["background"]);
  s.colour = fsx["colour"].empty() ? options.colour : static_cast<int>(fsx["colour"]) != 0;
  const auto vec3 = [&](const cv::FileNode& n, const char* key, Vector3 fallback) {
    const cv::FileNode v = n[key];
    if (v.empty()) return fallback;
    if (!v.isSeq() || v.size() != 3)
      throwInFile(path, std::string("'") + key + "' must be a list of 3 numbers");
    return Vector3(static_cast<double>(v[0]), static_cast<double>(v[1]), static_cast<double>(v[2]));
  };
  const auto num = [&](const cv::FileNode& n, const char* key, double fallback) {
    return n[key].empty() ? fallback : static_cast<double>(n[key]);
  };
  const auto str = [&](const cv::FileNode& n, const char* key, const std::string& fallback) {
    return n[key].empty() ? fallback : static_cast<std::string>(n[key]);
  };
  const auto resolve = [&](const std::string& p) {
    return fs::path(p).is_absolute() ? p : (fs::path(path).parent_path() / p).string();
  };
  const cv::FileNode objects = fsx["objects"];
  if (!objects.isSeq() || objects.size() == 0) throwInFile(path, "no 'objects' list");
  int index = 0;
  for (const cv::FileNode& obj : objects) {
    const std::string type = str(obj, "type", "");
    const std::string where = "object " + std::to_string(index++);
    TextureSpec spec;
    const cv::FileNode t = obj["texture"];
    if (!t.empty()) {
      spec.kind = str(t, "kind", spec.kind);
      spec.scale = num(t, "scale", spec.scale);
      spec.mean = num(t, "mean", spec.mean);
      spec.contrast = num(t, "contrast", spec.contrast);
      spec.angle = num(t, "angle", spec.angle);
      spec.text = str(t, "text", spec.text);
      spec.path = t["path"].empty() ? "" : resolve(str(t, "path", ""));
      spec.seed = static_cast<uint64_t>(num(t, "seed", static_cast<double>(index))) + options.seed;
      spec.resolution = static_cast<int>(num(t, "resolution", spec.resolution));
    }
    spec.colour = s.colour;
    try {
      if (type == "plane") {
        const cv::FileNode sz = obj["size"];
        if (!sz.isSeq() || sz.size() != 2)
          throwInFile(path, where + ": plane 'size' must be [width, height]");
        s.rectangles.push_back(
            plane(vec3(obj, "center", Vector3(0, 0, 5)), static_cast<double>(sz[0]),
                  static_cast<double>(sz[1]), std::make_shared<Texture>(makeTexture(spec)),
                  vec3(obj, "right", Vector3::UnitX()), vec3(obj, "down", Vector3::UnitY())));
      } else if (type == "box") {
        s.addBox(vec3(obj, "center", Vector3(0, 0, 3)), vec3(obj, "size", Vector3(1, 1, 1)),
                 vec3(obj, "rotation", Vector3::Zero()),
                 std::make_shared<Texture>(makeTexture(spec)));
      } else if (type == "rgbd") {
        std::optional<Calibration> k;
        if (!obj["fx"].empty())
          k = Calibration{
              num(obj, "fx", 0), num(obj, "fy", 0), num(obj, "cx", 0), num(obj, "cy", 0), {}};
        s.height_field =
            heightFieldFromFiles(resolve(str(obj, "image", "")), resolve(str(obj, "depth", "")),
                                 num(obj, "depth_scale", 0.001), num(obj, "disparity", 0) != 0,
                                 num(obj, "baseline", 0.1), k, s.colour);
        s.height_field->fitDepthRange();
      } else {
        throwInFile(path, where + ": unknown type '" + type + "' (known: plane, box, rgbd)");
      }
    } catch (const cv::Exception& e) {
      throwInFile(path, where + ": " + e.what());
    }
  }
  return s;
}

void SuiteEntry::apply(SynthOptions& o) const {
  o.shake.blur_px = blur_px;
  o.gain = gain;
  o.drop_events = drop_events;
  o.simulator.contrast_pos = o.simulator.contrast_neg = contrast;
  o.simulator.sigma = sigma;
  o.simulator.shot_noise_rate_hz = shot_noise_hz;
  o.simulator.leak_rate_hz = leak_hz;
  if (seed) o.shake.seed = seed;
  o.shake.rotation_share = rotation_share;
  o.shake.share_of_image_motion = share_of_image_motion;
  o.preroll_us = preroll_us;
}

namespace {

// The presets but `plain`, each at blur 15 and 40 px: <scene>_blur<px><suffix>.
std::vector<SuiteEntry> sceneGrid(const std::string& group, const std::string& suffix) {
  std::vector<SuiteEntry> entries;
  for (const std::string& scene : presetNames()) {
    if (scene == "plain") continue;
    for (double blur : {15.0, 40.0}) {
      SuiteEntry e;
      e.name = scene + "_blur" + std::to_string(static_cast<int>(blur)) + suffix;
      e.group = group;
      e.scene = scene;
      e.blur_px = blur;
      entries.push_back(e);
    }
  }
  return entries;
}

}  // namespace

std::vector<std::string> suiteNames() { return {"standard", "noisy", "hard", "natural", "all"}; }

std::vector<SuiteEntry> suiteEntries(const std::string& suite) {
  std::vector<SuiteEntry> entries;
  if (suite == "standard" || suite == "all") {
    for (const SuiteEntry& e : sceneGrid("standard", "")) entries.push_back(e);
  }
  if (suite == "noisy" || suite == "all") {
    // The standard scenes with DAVIS-like event noise (v2e's default threshold mismatch).
    for (SuiteEntry e : sceneGrid("noisy", "_noisy")) {
      e.what = "threshold mismatch 0.03, shot noise 1 Hz, leak 0.1 Hz per pixel";
      e.sigma = 0.03;
      e.shot_noise_hz = 1;
      e.leak_hz = 0.1;
      entries.push_back(e);
    }
  }
  if (suite == "hard" || suite == "all") {
    const auto hard = [&](const std::string& name, const std::string& scene, double blur,
                          const std::string& what) -> SuiteEntry& {
      SuiteEntry e;
      e.name = "hard_" + name;
      e.group = "hard";
      e.scene = scene;
      e.blur_px = blur;
      e.what = what;
      entries.push_back(e);
      return entries.back();
    };
    hard("blur70", "planes", 70, "large blur: 70 px");
    hard("blur2", "planes", 2, "tiny blur: 2 px");
    hard("textureless", "plain", 40, "texture-less: a uniform wall with two small cards");
    hard("saturated", "box", 40, "saturated highlights: radiance x3, frames clip at 1").gain = 3.0;
    hard("dark", "planes", 40, "very dark: radiance x0.02").gain = 0.02;
    SuiteEntry& noisy =
        hard("noisy", "planes", 40,
             "noisy events: threshold mismatch 0.04, shot noise 5 Hz, leak 1 Hz per pixel");
    noisy.sigma = 0.04;
    noisy.shot_noise_hz = 5;
    noisy.leak_hz = 1;
    hard("sparse", "planes", 40, "sparse events: C = 0.5").contrast = 0.5;
    hard("dense", "planes", 40, "dense events: C = 0.08").contrast = 0.08;
    hard("noevents", "planes", 40, "no events in the exposure").drop_events = true;
  }
  if (suite == "natural" || suite == "all") {
    // Each scene noiseless and with DAVIS-like noise, at two shake seeds and two blur lengths, so
    // that no figure rests on one draw; a handheld shake, 70% of the image motion from rotation
    // and the rest from translation (near layers move more than far ones); events from 30 ms
    // before the exposure.
    const std::vector<std::string> scenes = naturalSceneNames();
    const double blurs[3] = {15, 30, 60};
    for (size_t i = 0; i < scenes.size(); ++i) {
      for (int noisy = 0; noisy < 2; ++noisy) {
        SuiteEntry e;
        e.group = "natural";
        e.scene = scenes[i];
        e.blur_px = blurs[(i + noisy) % 3];
        e.name = "nat_" + scenes[i] + "_blur" + std::to_string(static_cast<int>(e.blur_px)) +
                 (noisy ? "_noisy" : "");
        e.seed = 1 + noisy;
        e.rotation_share = 0.7;
        e.share_of_image_motion = true;
        e.preroll_us = 30'000;
        if (noisy) {
          e.what = "threshold mismatch 0.03, shot noise 1 Hz, leak 0.1 Hz per pixel";
          e.sigma = 0.03;
          e.shot_noise_hz = 1;
          e.leak_hz = 0.1;
        }
        entries.push_back(e);
      }
    }
  }
  if (entries.empty())
    throw Error("unknown suite '" + suite + "' (known: standard, noisy, hard, natural, all)");
  return entries;
}

}  // namespace evkit::synth
