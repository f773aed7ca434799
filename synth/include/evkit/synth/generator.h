// Scenes (presets and description files), camera shake, and the observation folder of DESIGN.md §6
// with ground truth: the input of every deblurring method.
//
// Scene description files are YAML or JSON (read with OpenCV's FileStorage), e.g.
//
//   %YAML:1.0
//   background: 0.1          # radiance where rays hit nothing
//   colour: 0                # 1 for a colour scene
//   objects:
//     - { type: plane, center: [0, 0, 5], size: [12, 9], right: [1, 0, 0], down: [0, 1, 0],
//         texture: { kind: noise, scale: 0.02, mean: 0.45, contrast: 0.7, seed: 1 } }
//     - { type: box, center: [0.3, 0.1, 2.5], size: [0.8, 0.8, 0.8], rotation: [0.2, 0.5, 0],
//         texture: { kind: checker, scale: 0.125 } }
//     - { type: rgbd, image: photo.png, depth: depth.png, depth_scale: 0.001, disparity: 0,
//         fx: 300, fy: 300, cx: 160, cy: 120 }
//
// Units are metres; the camera sits at the origin looking along +z (x right, y down) at
// mid-exposure. Plane: centre, size (width along `right`, height along `down`). Box: centre, size,
// rotation (axis-angle). Texture kinds: noise (scale = finest feature / texture size), stripes
// (scale = period, angle), checker (scale = cell), text (text), image (path); mean, contrast, seed,
// colour, resolution. rgbd: a colour image with a depth map (depth_scale converts the file's values
// to metres; disparity: 1 means the file holds disparity d and depth = fx * baseline / d, with
// `baseline`), seen from the origin with intrinsics fx fy cx cy (default: 0.9 width, centred).
#pragma once

#include <optional>
#include <string>
#include <vector>

#include "evkit/events/frame_source.h"
#include "evkit/spline/trajectory.h"
#include "evkit/synth/scene.h"

namespace evkit::synth {

struct SceneOptions {
  bool colour = false;
  uint64_t seed = 1;
  // For the rgbd preset: a colour image and a depth (or disparity) map; empty: procedural.
  std::string rgbd_image, rgbd_depth;
  double rgbd_depth_scale = 0.001;  // file units -> metres (16-bit PNG in mm)
  // For the natural scenes: the folder of the photographs (empty: defaultPhotoDir()).
  std::string photo_dir;
};

// Presets: planes (4 textured planes at 1.6-6 m), box (a box on a slanted ground plane before a
// wall), rgbd (a textured height field), ground (a slanted ground plane and a wall), text (a text
// plane before a noise wall), plain (a uniform wall with two small textured cards: texture-less
// regions over most of the image).
std::vector<std::string> presetNames();
// A preset or a natural scene by name.
Scene makePreset(const std::string& name, const SceneOptions& options);

// Natural scenes (synth/src/natural.cc): real photographs as depth-layered scenes, planes at 1-10 m
// with soft-edged cut-outs before full backdrops (occlusion boundaries), a slanted wall, a ground
// plane, planar ones, and the Middlebury motorcycle with its real depth map. Some are in colour.
// They read the data images of Debian's python3-skimage (CC0 or public domain).
std::vector<std::string> naturalSceneNames();
bool isNaturalScene(const std::string& name);
Scene makeNaturalScene(const std::string& name, const SceneOptions& options);
// $EVKIT_PHOTOS, else the folder where python3-skimage installs its data images.
std::string defaultPhotoDir();
Scene loadScene(const std::string& path, const SceneOptions& options);

// The default camera for an image size: fx = fy = 0.9 width, principal point at the centre.
Calibration defaultCamera(int width, int height);

struct ShakeOptions {
  double blur_px = 30;  // the longest image path of a scene point during the exposure
  int knots = 4;
  double rotation_share = 0.7;  // of the motion's blur coming from rotation (the rest translation)
  uint64_t seed = 1;
  // How rotation_share is read. false: as the knots' rotation (rad) against their translation (m),
  // so the image motion's split depends on the scene's depth and the draw. true: as image motion,
  // the rotation alone moving the image by rotation_share * blur_px and the translation adding the
  // rest at the point that moves most: a handheld shake whose parallax stays a share of the blur.
  bool share_of_image_motion = false;
};

// Random smooth camera shake over [t_begin, t_end]: a cubic B-spline on SE(3) with random knots,
// scaled so that blurLengthPx equals options.blur_px, and moved so that T(mid) = identity.
Trajectory makeShake(const Scene& scene, const Calibration& camera, int width, int height,
                     int64_t t_begin, int64_t t_end, const ShakeOptions& options);

// The longest image-space path (pixels) of the scene points seen on an 8x6 grid at mid-exposure.
double blurLengthPx(const Trajectory& trajectory, const Scene& scene, const Calibration& camera,
                    int width, int height);

struct SynthOptions {
  int width = 346, height = 260;
  int64_t t_begin_us = 1'600'000'000'000'000;  // absolute Unix µs
  int64_t exposure_us = 100'000;
  ShakeOptions shake;
  SimulatorOptions simulator;
  // Renders are spaced so that the image moves by at most this much between two (the simulator
  // interpolates log intensity linearly in between). ESIM's rejection rule (AdaptiveOptions) is
  // not used here: rendered occlusion edges are discontinuous in time and would drive it to its
  // minimum step.
  double max_motion_px = 0.1;
  int supersample = 2;
  int sharp_frames = 3;  // ground-truth sharp frames evenly over the exposure (start, ..., end)
  int poses = 101;       // ground-truth poses (TUM)
  // Radiance scale: below 1 a dark scene, above 1 saturated highlights. The frames (blurry and
  // ground truth) clip at 1 as a sensor's full well does; the events see the unclipped radiance.
  double gain = 1.0;
  // Writes an empty event file (an exposure whose events were lost): the blurry frame is unchanged.
  bool drop_events = false;
  // Events are simulated from this long before the exposure (the motion continued at its speed at
  // the exposure's start), so that each pixel's reference level when the exposure opens is where
  // its last event left it, as on a real camera, not the exposure's first frame. Only the events
  // inside the exposure are written.
  int64_t preroll_us = 0;
  // The camera that renders the scene (and is written to calib.txt): the lens a recording was
  // made with, radial-tangential distortion included. Unset: defaultCamera.
  std::optional<Calibration> camera;
};

// The camera options render with: options.camera, else defaultCamera.
Calibration cameraOf(const SynthOptions& options);

struct SynthReport {
  double blur_px = 0;
  int64_t events = 0;
  int64_t renders = 0;
  double max_fraction_over_c = 0;
};

// Renders over the exposure, simulates the events, and writes the observation folder:
// blurry.png (16-bit linear), exposure.txt, events.h5, calib.txt, contrast.txt, and gt/ with the
// sharp frames (<t_us>.png), poses.txt (TUM, T_world_cam), knots.txt (the spline's knots, TUM at
// the knot index), depth.npy (float32 metres at mid-exposure) and info.txt. The folder appears
// complete or not at all.
SynthReport writeObservation(const Scene& scene, const SynthOptions& options,
                             const std::string& dir);

// A recording of several blurry frames with the continuous events between them, as a DAVIS
// writes it: the camera shakes through the whole recording (a longer spline with more knots),
// `frames` exposures of options.exposure_us start every `frame_interval_us`, and each exposure
// has about options.shake.blur_px of blur. Writes, complete or not at all:
//   recording.aedat4 and recording.h5  events and the blurry frames (16-bit) with their exposures;
//   calib.txt, contrast.txt            the camera and the thresholds;
//   gt/<t_us>.png                      sharp frames at each exposure's start, middle and end;
//   gt/poses.txt                       the camera (TUM, T_world_cam), 101 poses per exposure.
struct RecordingOptions {
  int frames = 3;
  int64_t frame_interval_us = 150'000;  // exposure start to exposure start (> exposure_us)
  // With `drop_frame_events` >= 0, that frame's exposure has no events (lost in transfer).
  int drop_frame_events = -1;
};
struct RecordingReport {
  int frames = 0;
  int64_t events = 0;
  int64_t renders = 0;
};
RecordingReport writeSyntheticRecording(const Scene& scene, const SynthOptions& options,
                                        const RecordingOptions& recording, const std::string& dir);

// A named suite: observation folders <dir>/<name>.
//  - standard: the 5 presets x blur {15, 40} px, noiseless events, C = 0.2 (<scene>_blur<px>);
//  - noisy: the same 10 scenes with DAVIS-like event noise: per-pixel threshold mismatch 0.03,
//    shot noise 1 Hz, leak 0.1 Hz per pixel (<scene>_blur<px>_noisy);
//  - hard: one hard case each (hard_<case>): blur 70 px, blur 2 px, texture-less, saturated
//    highlights, a very dark scene, noisy events (mismatch, shot noise, leak), sparse events
//    (C = 0.5), dense events (C = 0.08), an exposure without events;
//  - natural: each natural scene twice, noiseless (shake seed 1) and with DAVIS-like noise (seed
//  2),
//    blur 15, 30 or 60 px in turn, rotation and translation in equal parts, a 30 ms pre-roll
//    (nat_<scene>_blur<px>[_noisy]);
//  - all: every one of them.
struct SuiteEntry {
  std::string name;   // folder name
  std::string group;  // "standard", "noisy", "hard" or "natural"
  std::string scene;  // preset
  double blur_px = 30;
  std::string what;  // what makes it hard or noisy (empty for standard entries)
  double gain = 1.0;
  double contrast = 0.2;
  double sigma = 0, shot_noise_hz = 0, leak_hz = 0;
  bool drop_events = false;
  uint64_t seed = 0;                   // of the shake; 0: the options' own
  double rotation_share = 0.7;         // ShakeOptions::rotation_share
  bool share_of_image_motion = false;  // ShakeOptions::share_of_image_motion
  int64_t preroll_us = 0;

  // Sets the blur, gain, thresholds, noise, shake and pre-roll of `options` (size, exposure stay).
  void apply(SynthOptions& options) const;
};
std::vector<std::string> suiteNames();
std::vector<SuiteEntry> suiteEntries(const std::string& suite);

}  // namespace evkit::synth
