#include "evkit/harness/speed_error.h"

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <set>
#include <sstream>

#include "evkit/base/error.h"
#include "evkit/base/text.h"
#include "evkit/deblur/benerf.h"
#include "evkit/events/atomic_file.h"
#include "evkit/events/image_io.h"
#include "evkit/nerf/camera.h"
#include "evkit/spline/lie.h"

namespace evkit {

namespace fs = std::filesystem;

namespace {

// A budget token -> its label and the BeNeRF setting it stands for (parseBenerfBudget's grammar).
std::pair<std::string, MethodSettings> parseBudget(const std::string& token) {
  try {
    return {parseBenerfBudget(token).label, {{"budget", token}}};
  } catch (const Error& e) {
    throw Error(std::string("--budgets: ") + e.what());
  }
}

std::string csvField(const std::string& v) {
  if (v.find_first_of(",\"\n") == std::string::npos) return v;
  std::string out = "\"";
  for (char c : v) {
    if (c == '"') out += '"';
    out += c == '\n' ? ' ' : c;
  }
  return out + "\"";
}

std::vector<std::string> csvSplit(const std::string& line) {
  std::vector<std::string> fields(1);
  bool quoted = false;
  for (size_t i = 0; i < line.size(); ++i) {
    const char c = line[i];
    if (quoted) {
      if (c == '"' && i + 1 < line.size() && line[i + 1] == '"') {
        fields.back() += '"';
        ++i;
      } else if (c == '"') {
        quoted = false;
      } else {
        fields.back() += c;
      }
    } else if (c == '"') {
      quoted = true;
    } else if (c == ',') {
      fields.emplace_back();
    } else {
      fields.back() += c;
    }
  }
  return fields;
}

double csvNumber(const std::string& v) {
  if (v.empty()) return std::nan("");
  try {
    return std::stod(v);
  } catch (const std::exception&) {
    return std::nan("");
  }
}

constexpr const char* kCsvHeader =
    "group,scene,what,method,budget,status,wall_s,psnr_mid,ssim_mid,brisque_mid,psnr_mean,rotation_"
    "error_deg,"
    "rotation_truth_deg,iterations,nonfinite,rotation_estimated_deg,rotation_error_px,blur_truth_"
    "px,"
    "blur_estimated_px,motion_error_px";

std::string csvNumberField(double v) {
  if (!std::isfinite(v)) return "";
  std::ostringstream s;
  s.precision(8);
  s << v;
  return s.str();
}

std::string runName(const BenchRow& r) {
  return r.budget == "-" ? r.method : r.method + " " + r.budget;
}

// Rows of the group the summary and the plot speak for: "standard" when present, else all.
std::vector<BenchRow> summaryRows(const std::vector<BenchRow>& rows, std::string* group) {
  std::vector<BenchRow> standard;
  for (const BenchRow& r : rows) {
    if (r.group == "standard") standard.push_back(r);
  }
  if (group) *group = standard.empty() ? "every scene" : "the standard scenes";
  return standard.empty() ? rows : standard;
}

struct Summary {
  std::string method, budget;
  double psnr = 0, ssim = 0, brisque = 0, rotation = 0, rotation_px = 0, rotation_found = 0,
         motion_px = 0, wall = 0, psnr_exposure = 0;
  int n = 0, n_rotation = 0, n_rotation_px = 0, n_found = 0, n_motion = 0, n_brisque = 0,
      n_exposure = 0, failed = 0;
  int64_t nonfinite = 0;
  double first_seen = 0;  // order of appearance
};

// Mean per (method, budget) over the rows that succeeded, in the order the runs appear.
std::vector<Summary> summarise(const std::vector<BenchRow>& rows) {
  std::map<std::pair<std::string, std::string>, Summary> by;
  int order = 0;
  for (const BenchRow& r : rows) {
    auto [it, fresh] = by.try_emplace({r.method, r.budget});
    Summary& s = it->second;
    if (fresh) {
      s.method = r.method;
      s.budget = r.budget;
      s.first_seen = order++;
    }
    s.nonfinite += r.nonfinite;
    if (!r.ok()) {
      ++s.failed;
      continue;
    }
    ++s.n;
    s.psnr += r.psnr;
    s.ssim += r.ssim;
    s.wall += r.wall_s;
    if (std::isfinite(r.brisque)) s.brisque += r.brisque, ++s.n_brisque;
    if (std::isfinite(r.psnr_mean)) s.psnr_exposure += r.psnr_mean, ++s.n_exposure;
    if (std::isfinite(r.rotation_error_deg)) s.rotation += r.rotation_error_deg, ++s.n_rotation;
    if (std::isfinite(r.rotation_error_px)) s.rotation_px += r.rotation_error_px, ++s.n_rotation_px;
    if (std::isfinite(r.motion_error_px)) s.motion_px += r.motion_error_px, ++s.n_motion;
    if (std::isfinite(r.rotation_estimated_deg) && r.rotation_truth_deg > 0)
      s.rotation_found += r.rotation_estimated_deg / r.rotation_truth_deg, ++s.n_found;
  }
  std::vector<Summary> out;
  for (auto& [key, s] : by) {
    if (s.n > 0) {
      s.psnr /= s.n;
      s.ssim /= s.n;
      s.wall /= s.n;
    }
    s.brisque = s.n_brisque ? s.brisque / s.n_brisque : std::nan("");
    s.psnr_exposure = s.n_exposure ? s.psnr_exposure / s.n_exposure : std::nan("");
    s.rotation = s.n_rotation ? s.rotation / s.n_rotation : std::nan("");
    s.rotation_px = s.n_rotation_px ? s.rotation_px / s.n_rotation_px : std::nan("");
    s.rotation_found = s.n_found ? s.rotation_found / s.n_found : std::nan("");
    s.motion_px = s.n_motion ? s.motion_px / s.n_motion : std::nan("");
    out.push_back(s);
  }
  std::sort(out.begin(), out.end(),
            [](const Summary& a, const Summary& b) { return a.first_seen < b.first_seen; });
  return out;
}

std::string health(const BenchRow& r) {
  if (!r.ok()) return r.status;
  return r.nonfinite ? std::to_string(r.nonfinite) + " non-finite values" : "ok";
}

std::vector<std::string> groupsOf(const std::vector<BenchRow>& rows) {
  std::vector<std::string> groups;
  for (const BenchRow& r : rows) {
    if (std::find(groups.begin(), groups.end(), r.group) == groups.end()) groups.push_back(r.group);
  }
  return groups;
}

// The mean per method and budget over one group's scenes.
void writeGroupSummary(std::ostringstream& md, const std::vector<BenchRow>& rows,
                       const std::string& group) {
  std::vector<BenchRow> in_group;
  for (const BenchRow& r : rows) {
    if (r.group == group) in_group.push_back(r);
  }
  md << "\n## Speed against error: mean over the " << group << " scenes\n\n"
     << "| method | budget | PSNR (dB) | over the exposure | SSIM | BRISQUE | rotation error (°) | "
        "at the border (px) | rotation found | image motion error (px) | wall time (s) | scenes | "
        "failed | non-finite |\n"
     << "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n";
  for (const Summary& s : summarise(in_group)) {
    md << "| " << s.method << " | " << s.budget << " | " << fixedOrDash(s.n ? s.psnr : NAN, 2)
       << " | " << fixedOrDash(s.psnr_exposure, 2) << " | " << fixedOrDash(s.n ? s.ssim : NAN, 4)
       << " | " << fixedOrDash(s.brisque, 1) << " | " << fixedOrDash(s.rotation, 3) << " | "
       << fixedOrDash(s.rotation_px, 2) << " | " << fixedOrDash(s.rotation_found, 3) << " | "
       << fixedOrDash(s.motion_px, 2) << " | "
       << fixedOrDash(s.n ? s.wall : NAN, s.wall < 1 ? 3 : 1) << " | " << s.n << " | " << s.failed
       << " | " << s.nonfinite << " |\n";
  }
}

// One line per scene of a group, PSNR per run, and the numerical health.
void writePerScene(std::ostringstream& md, const std::vector<BenchRow>& rows,
                   const std::string& group) {
  std::vector<std::string> scenes, run_names;
  std::map<std::string, std::map<std::string, const BenchRow*>> by;
  for (const BenchRow& r : rows) {
    if (r.group != group) continue;
    if (!by.count(r.scene)) scenes.push_back(r.scene);
    if (std::find(run_names.begin(), run_names.end(), runName(r)) == run_names.end())
      run_names.push_back(runName(r));
    by[r.scene][runName(r)] = &r;
  }
  if (scenes.empty()) return;
  md << "\n## Per scene, " << group
     << " (PSNR of the mid frame, dB; health: failures and non-finite output values)\n\n"
     << "| scene | what |";
  for (const std::string& n : run_names) md << ' ' << n << " |";
  md << " health |\n|---|---|";
  for (size_t i = 0; i < run_names.size(); ++i) md << "---|";
  md << "---|\n";
  for (const std::string& c : scenes) {
    const auto& runs = by[c];
    md << "| " << c << " | " << runs.begin()->second->what << " |";
    std::string problems;
    for (const std::string& n : run_names) {
      const auto it = runs.find(n);
      md << ' '
         << (it == runs.end()   ? ""
             : it->second->ok() ? fixedOrDash(it->second->psnr, 2)
                                : "failed")
         << " |";
      if (it != runs.end() && health(*it->second) != "ok")
        problems += (problems.empty() ? "" : "; ") + n + ": " + health(*it->second);
    }
    md << ' ' << (problems.empty() ? "ok" : problems) << " |\n";
  }
}

// The pose at t_us, between the stamped poses around it (geodesic on SE(3)); clamped to the ends.
SE3 poseAtTime(const std::vector<StampedPose>& poses, int64_t t_us) {
  const auto after = std::lower_bound(poses.begin(), poses.end(), t_us,
                                      [](const StampedPose& p, int64_t t) { return p.t_us < t; });
  if (after == poses.begin()) return poses.front().pose;
  if (after == poses.end()) return poses.back().pose;
  const StampedPose& before = *(after - 1);
  const double s =
      static_cast<double>(t_us - before.t_us) / static_cast<double>(after->t_us - before.t_us);
  return before.pose * expSE3(s * logSE3(before.pose.inverse() * after->pose));
}

// R_a(start)^T R_a(end) against the same for b: the rotation between the two exposure rotations.
Quaternion exposureRotationError(const std::vector<StampedPose>& a,
                                 const std::vector<StampedPose>& b) {
  const Quaternion qa = a.front().pose.rotation().conjugate() * a.back().pose.rotation();
  const Quaternion qb = b.front().pose.rotation().conjugate() * b.back().pose.rotation();
  return Quaternion(qa.conjugate() * qb);
}

}  // namespace

std::vector<BenchRun> benchRuns(const std::vector<std::string>& methods,
                                const std::vector<std::string>& budgets,
                                const std::vector<std::string>& mlp_budgets,
                                const std::map<std::string, MethodSettings>& extra) {
  std::vector<BenchRun> runs;
  const auto with_extra = [&](const std::string& method, MethodSettings s) {
    if (const auto it = extra.find(method); it != extra.end()) {
      for (const auto& [k, v] : it->second) s[k] = v;
    }
    return s;
  };
  for (const std::string& m : methods) {
    if (m == "blurry" || m == "edi") {
      runs.push_back({m, "-", makeMethod(m, with_extra(m, {}))});
    } else if (m == "benerf" || m == "benerf-mlp") {
      const std::vector<std::string>& list = m == "benerf" ? budgets : mlp_budgets;
      if (list.empty()) throw Error("no budgets for " + m);
      for (const std::string& token : list) {
        auto [label, settings] = parseBudget(token);
        if (m == "benerf-mlp") settings["field"] = "mlp";
        runs.push_back({m, label, makeMethod("benerf", with_extra(m, settings))});
      }
    } else {
      throw Error("--methods: unknown method '" + m + "' (known: blurry, edi, benerf, benerf-mlp)");
    }
  }
  return runs;
}

double exposureRotationDeg(const std::vector<StampedPose>& poses) {
  if (poses.size() < 2) return std::nan("");
  return logSO3(
             Quaternion(poses.front().pose.rotation().conjugate() * poses.back().pose.rotation()))
             .norm() *
         180.0 / M_PI;
}

double exposureRotationErrorPx(const std::vector<StampedPose>& a, const std::vector<StampedPose>& b,
                               const PinholeCamera& camera) {
  if (a.size() < 2 || b.size() < 2 || camera.width <= 0) return std::nan("");
  const Eigen::Matrix3d error = exposureRotationError(a, b).toRotationMatrix();
  const double w = camera.width - 1, h = camera.height - 1;
  double largest = 0;
  for (const auto& [x, y] : {std::pair{0.0, 0.0},
                             {w / 2, 0.0},
                             {w, 0.0},
                             {0.0, h / 2},
                             {w, h / 2},
                             {0.0, h},
                             {w / 2, h},
                             {w, h}}) {
    const Vector3 ray((x - camera.cx) / camera.fx, (y - camera.cy) / camera.fy, 1.0);
    const Vector3 moved = error * ray;
    if (moved.z() <= 1e-6) return std::nan("");
    largest = std::max(largest, std::hypot(camera.fx * moved.x() / moved.z() + camera.cx - x,
                                           camera.fy * moved.y() / moved.z() + camera.cy - y));
  }
  return largest;
}

double exposureRotationErrorDeg(const std::vector<StampedPose>& a,
                                const std::vector<StampedPose>& b) {
  if (a.size() < 2 || b.size() < 2) return std::nan("");
  return logSO3(exposureRotationError(a, b)).norm() * 180.0 / M_PI;
}

double exposureMotionErrorPx(const std::vector<StampedPose>& estimate, const cv::Mat& inverse_depth,
                             const std::vector<StampedPose>& truth, const cv::Mat& depth,
                             const PinholeCamera& camera, int64_t start_us, int64_t end_us,
                             const cv::Mat& mask) {
  const cv::Size size(camera.width, camera.height);
  if (estimate.size() < 2 || truth.size() < 2 || size.area() <= 0 || inverse_depth.size() != size ||
      depth.size() != size || inverse_depth.type() != CV_32F || depth.type() != CV_32F ||
      (!mask.empty() && (mask.size() != size || mask.type() != CV_8U)))
    return std::nan("");
  const int64_t mid_us = start_us + (end_us - start_us) / 2;
  // From the mid-exposure camera into the camera at each end: a point of inverse depth rho on the
  // mid camera's ray x (z = 1) is seen along R x + rho p (rho = 0: at infinity).
  struct Relative {
    Matrix3 R;
    Vector3 p;
  };
  const auto relative = [&](const std::vector<StampedPose>& poses) {
    const SE3 mid = poseAtTime(poses, mid_us);
    std::array<Relative, 2> out;
    for (int e = 0; e < 2; ++e) {
      const SE3 to = poseAtTime(poses, e == 0 ? start_us : end_us).inverse() * mid;
      out[e] = {to.rotationMatrix(), to.translation()};
    }
    return out;
  };
  const std::array<Relative, 2> est = relative(estimate), tru = relative(truth);
  double sum = 0;
  int64_t n = 0;
  for (int y = 0; y < size.height; ++y) {
    for (int x = 0; x < size.width; ++x) {
      const double z = depth.at<float>(y, x), rho_est = inverse_depth.at<float>(y, x);
      if ((!mask.empty() && !mask.at<uint8_t>(y, x)) || !std::isfinite(rho_est)) continue;
      const double rho = std::isfinite(z) && z > 0 ? 1.0 / z : 0.0;
      const Vector3 ray = nerf::pixelDirection(camera, x, y);
      for (int e = 0; e < 2; ++e) {
        const Vector3 a = est[e].R * ray + rho_est * est[e].p, b = tru[e].R * ray + rho * tru[e].p;
        if (!(a.z() > 1e-9) || !(b.z() > 1e-9)) continue;  // behind the camera
        sum += (nerf::projectPoint(camera, a) - nerf::projectPoint(camera, b)).norm();
        ++n;
      }
    }
  }
  return n ? sum / static_cast<double>(n) : std::nan("");
}

BenchRow runBench(const Observation& obs, const std::string& group, const std::string& scene,
                  const std::string& what, const BenchRun& run, const std::string& out_dir,
                  MethodReport* report, const std::function<void(int, int, double)>& progress) {
  BenchRow row;
  row.group = group;
  row.scene = scene;
  row.what = what;
  row.method = run.method;
  row.budget = run.budget;
  row.rotation_truth_deg = exposureRotationDeg(obs.gt_poses);
  row.blur_truth_px = obs.gt_blur_px;
  try {
    DeblurRequest request = completeRequest(obs, {});
    request.progress = progress;
    MethodReport r = evaluateMethod(obs, run.deblurrer, request);
    if (!out_dir.empty()) writeMethodOutputs(out_dir, obs, run.deblurrer, r);
    row.wall_s = r.wall_s;
    row.psnr = r.psnr_mid;
    row.ssim = r.ssim_mid;
    row.brisque = r.brisque_mid;
    row.psnr_mean = r.psnr_mean;
    for (const Frame& f : r.result.frames) {
      cv::Mat values;
      f.image.convertTo(values, CV_32F);
      values = values.reshape(1, 1);
      for (int i = 0; i < values.cols; ++i) row.nonfinite += !std::isfinite(values.at<float>(0, i));
    }
    if (r.result.trajectory) {
      const PinholeCamera camera =
          obs.camera.withSize(obs.blurry.image.cols, obs.blurry.image.rows);
      row.rotation_error_deg = exposureRotationErrorDeg(*r.result.trajectory, obs.gt_poses);
      row.rotation_estimated_deg = exposureRotationDeg(*r.result.trajectory);
      row.rotation_error_px = exposureRotationErrorPx(*r.result.trajectory, obs.gt_poses, camera);
      row.motion_error_px = exposureMotionErrorPx(
          *r.result.trajectory, r.result.disparity, obs.gt_poses, obs.gt_depth, camera,
          obs.blurry.exposure_start_us, obs.blurry.exposure_end_us);
    }
    // The blur length the method worked with: from its motion where it has one (the pixel grid),
    // else as measured through EDI.
    for (const char* key : {"blur_px_measured", "blur_px_motion"}) {
      if (const auto it = r.result.parameters.find(key); it != r.result.parameters.end())
        row.blur_estimated_px = it->second;
    }
    if (const auto it = r.result.parameters.find("iterations"); it != r.result.parameters.end())
      row.iterations = it->second;
    if (report) *report = std::move(r);
  } catch (const Error& e) {
    row.status = std::string("failed: ") + e.what();
  }
  return row;
}

std::vector<BenchRow> readBenchCsv(const std::string& path) {
  std::vector<BenchRow> rows;
  std::ifstream in(path);
  if (!in) return rows;
  std::string line;
  if (!std::getline(in, line) || line != kCsvHeader) return rows;  // another layout: start afresh
  while (std::getline(in, line)) {
    const std::vector<std::string> f = csvSplit(line);
    if (f.size() != 20) continue;
    BenchRow r;
    r.group = f[0], r.scene = f[1], r.what = f[2], r.method = f[3], r.budget = f[4],
    r.status = f[5];
    r.wall_s = csvNumber(f[6]), r.psnr = csvNumber(f[7]), r.ssim = csvNumber(f[8]),
    r.brisque = csvNumber(f[9]);
    r.psnr_mean = csvNumber(f[10]), r.rotation_error_deg = csvNumber(f[11]),
    r.rotation_truth_deg = csvNumber(f[12]);
    r.iterations = csvNumber(f[13]);
    r.nonfinite = static_cast<int64_t>(csvNumber(f[14]));
    r.rotation_estimated_deg = csvNumber(f[15]), r.rotation_error_px = csvNumber(f[16]);
    r.blur_truth_px = csvNumber(f[17]), r.blur_estimated_px = csvNumber(f[18]);
    r.motion_error_px = csvNumber(f[19]);
    rows.push_back(r);
  }
  return rows;
}

void writeBenchResults(const std::string& dir, const std::vector<BenchRow>& rows,
                       const std::string& title) {
  fs::create_directories(dir);
  std::ostringstream csv;
  csv << kCsvHeader << "\n";
  for (const BenchRow& r : rows) {
    csv << csvField(r.group) << ',' << csvField(r.scene) << ',' << csvField(r.what) << ','
        << csvField(r.method) << ',' << csvField(r.budget) << ',' << csvField(r.status) << ','
        << csvNumberField(r.wall_s) << ',' << csvNumberField(r.psnr) << ','
        << csvNumberField(r.ssim) << ',' << csvNumberField(r.brisque) << ','
        << csvNumberField(r.psnr_mean) << ',' << csvNumberField(r.rotation_error_deg) << ','
        << csvNumberField(r.rotation_truth_deg) << ',' << csvNumberField(r.iterations) << ','
        << r.nonfinite << ',' << csvNumberField(r.rotation_estimated_deg) << ','
        << csvNumberField(r.rotation_error_px) << ',' << csvNumberField(r.blur_truth_px) << ','
        << csvNumberField(r.blur_estimated_px) << ',' << csvNumberField(r.motion_error_px) << "\n";
  }
  writeFileAtomically(dir + "/results.csv", csv.str());

  std::ostringstream md;
  md << "# " << title << "\n\n"
     << "PSNR, SSIM and BRISQUE of the mid-exposure frame; rotation error: the angle between the "
        "estimated and the true rotation over the exposure, and that error as image motion at the "
        "image border (px); rotation found: the estimated rotation over the true one; image motion "
        "error: the mean distance between where the estimate (its trajectory through its depths) "
        "and the truth move each pixel from mid-exposure to the exposure's ends, the part of the "
        "motion the data can tell apart (a rotation and a translation can move the image alike); "
        "over the exposure: the mean PSNR over every ground-truth time (the exposure's start, "
        "middle and end). Means over the scenes a run finished.\n";
  for (const std::string& group : groupsOf(rows)) writeGroupSummary(md, rows, group);
  for (const char* group : {"hard", "natural"}) writePerScene(md, rows, group);
  md << "\n## Every run\n\n| group | scene | method | budget | PSNR (dB) | SSIM | BRISQUE | "
        "rotation error (°) | at the border (px) | rotation found (°) | true rotation (°) | image "
        "motion error (px) | blur found (px) | true blur (px) | iterations | wall time (s) | "
        "health "
        "|\n|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n";
  for (const BenchRow& r : rows) {
    md << "| " << r.group << " | " << r.scene << " | " << r.method << " | " << r.budget << " | "
       << fixedOrDash(r.psnr, 2) << " | " << fixedOrDash(r.ssim, 4) << " | "
       << fixedOrDash(r.brisque, 1) << " | " << fixedOrDash(r.rotation_error_deg, 3) << " | "
       << fixedOrDash(r.rotation_error_px, 2) << " | " << fixedOrDash(r.rotation_estimated_deg, 3)
       << " | " << fixedOrDash(r.rotation_truth_deg, 3) << " | "
       << fixedOrDash(r.motion_error_px, 2) << " | " << fixedOrDash(r.blur_estimated_px, 1) << " | "
       << fixedOrDash(r.blur_truth_px, 1) << " | " << fixedOrDash(r.iterations, 0) << " | "
       << fixedOrDash(r.wall_s, r.wall_s < 1 ? 3 : 1) << " | " << health(r) << " |\n";
  }
  writeFileAtomically(dir + "/results.md", md.str());
  drawSpeedError(rows, title, dir + "/speed_vs_error.png");
}

void drawSpeedError(const std::vector<BenchRow>& all_rows, const std::string& title,
                    const std::string& png_path) {
  std::string group;
  const std::vector<BenchRow> rows = summaryRows(all_rows, &group);
  std::vector<Summary> points;
  for (const Summary& s : summarise(rows)) {
    if (s.n > 0 && std::isfinite(s.psnr) && std::isfinite(s.wall)) points.push_back(s);
  }
  constexpr int kWidth = 960, kHeight = 600, kLeft = 80, kRight = 210, kTop = 56, kBottom = 64;
  cv::Mat img(kHeight, kWidth, CV_8UC3, cv::Scalar(255, 255, 255));
  const cv::Scalar ink(40, 40, 40), grid(225, 225, 225);
  const auto font = cv::FONT_HERSHEY_SIMPLEX;
  const auto text = [&](const std::string& s, cv::Point p, double scale, const cv::Scalar& colour,
                        int thickness = 1) {
    cv::putText(img, s, p, font, scale, colour, thickness, cv::LINE_AA);
  };
  const auto width_of = [&](const std::string& s, double scale) {
    return cv::getTextSize(s, font, scale, 1, nullptr).width;
  };

  // Axes: x = log10(wall time) over whole decades, y = PSNR over whole dB with a margin.
  const double floor_s = 1e-4;  // the blurry "method" takes microseconds
  double x0 = -1, x1 = 1, y0 = 10, y1 = 40;
  if (!points.empty()) {
    x0 = 1e9, x1 = -1e9, y0 = 1e9, y1 = -1e9;
    for (const Summary& s : points) {
      const double lx = std::log10(std::max(s.wall, floor_s));
      x0 = std::min(x0, lx), x1 = std::max(x1, lx), y0 = std::min(y0, s.psnr),
      y1 = std::max(y1, s.psnr);
    }
    x0 = std::floor(x0), x1 = std::max(std::ceil(x1), x0 + 1);
    y0 = std::floor(y0 - 1), y1 = std::ceil(y1 + 1);
  }
  const int pw = kWidth - kLeft - kRight, ph = kHeight - kTop - kBottom;
  const auto px = [&](double wall) {
    return kLeft + static_cast<int>(
                       std::lround((std::log10(std::max(wall, floor_s)) - x0) / (x1 - x0) * pw));
  };
  const auto py = [&](double psnr) {
    return kTop + static_cast<int>(std::lround((y1 - psnr) / (y1 - y0) * ph));
  };
  for (int d = static_cast<int>(x0); d <= static_cast<int>(x1); ++d) {
    const int x = px(std::pow(10.0, d));
    cv::line(img, {x, kTop}, {x, kTop + ph}, grid);
    std::string label = d <= -3
                            ? fixedOrDash(std::pow(10.0, d + 3), d + 3 < 0 ? -(d + 3) : 0) + " ms"
                            : fixedOrDash(std::pow(10.0, d), d < 0 ? -d : 0) + " s";
    text(label, {x - width_of(label, 0.45) / 2, kTop + ph + 20}, 0.45, ink);
  }
  const double y_step = (y1 - y0) > 24 ? 5 : (y1 - y0) > 10 ? 2 : 1;
  for (double v = std::ceil(y0 / y_step) * y_step; v <= y1; v += y_step) {
    const int y = py(v);
    cv::line(img, {kLeft, y}, {kLeft + pw, y}, grid);
    const std::string label = fixedOrDash(v, 0);
    text(label, {kLeft - 8 - width_of(label, 0.45), y + 5}, 0.45, ink);
  }
  cv::rectangle(img, {kLeft, kTop}, {kLeft + pw, kTop + ph}, ink);
  text("wall time per frame (log scale)",
       {kLeft + pw / 2 - width_of("wall time per frame (log scale)", 0.5) / 2, kHeight - 18}, 0.5,
       ink);
  text("PSNR (dB)", {10, kTop - 12}, 0.5, ink);
  text(title + " - mean over " + group, {kLeft, 30}, 0.6, ink, 1);

  // One colour per method; points joined in order of wall time, labelled by budget.
  const std::vector<cv::Scalar> palette = {{120, 120, 120}, {180, 119, 31},  {40, 39, 214},
                                           {44, 160, 44},   {189, 103, 148}, {14, 127, 255}};
  std::vector<std::string> methods;
  for (const Summary& s : points) {
    if (std::find(methods.begin(), methods.end(), s.method) == methods.end())
      methods.push_back(s.method);
  }
  for (size_t m = 0; m < methods.size(); ++m) {
    const cv::Scalar colour = palette[m % palette.size()];
    std::vector<Summary> curve;
    for (const Summary& s : points) {
      if (s.method == methods[m]) curve.push_back(s);
    }
    std::sort(curve.begin(), curve.end(),
              [](const Summary& a, const Summary& b) { return a.wall < b.wall; });
    for (size_t i = 0; i < curve.size(); ++i) {
      const cv::Point p(px(curve[i].wall), py(curve[i].psnr));
      if (i > 0)
        cv::line(img, {px(curve[i - 1].wall), py(curve[i - 1].psnr)}, p, colour, 2, cv::LINE_AA);
      cv::circle(img, p, 5, colour, cv::FILLED, cv::LINE_AA);
      if (curve[i].budget != "-") text(curve[i].budget, {p.x + 7, p.y - 7}, 0.42, colour);
    }
    const int ly = kTop + 20 + static_cast<int>(m) * 26;
    cv::line(img, {kLeft + pw + 16, ly - 5}, {kLeft + pw + 44, ly - 5}, colour, 2, cv::LINE_AA);
    cv::circle(img, {kLeft + pw + 30, ly - 5}, 5, colour, cv::FILLED, cv::LINE_AA);
    text(methods[m], {kLeft + pw + 52, ly}, 0.5, ink);
  }
  if (points.empty()) text("no finished runs", {kLeft + 20, kTop + 40}, 0.6, ink);

  writeImageFile(png_path, img);
}

}  // namespace evkit
