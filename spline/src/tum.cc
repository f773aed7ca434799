#include "evkit/spline/tum.h"

#include <unistd.h>

#include <charconv>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "evkit/base/error.h"

namespace evkit {

namespace {

// "1305031102.175304" -> 1305031102175304 µs, exactly (integer part and up to 9 decimals; digits
// beyond the µs round half up). False if malformed.
bool parseSeconds(const std::string& s, int64_t& us) {
  size_t i = 0;
  const bool negative = !s.empty() && s[0] == '-';
  if (negative) ++i;
  int64_t whole = 0;
  size_t digits = 0;
  for (; i < s.size() && std::isdigit(static_cast<unsigned char>(s[i])); ++i, ++digits) {
    if (whole > (INT64_MAX / 1000000 - 9) / 10) return false;
    whole = whole * 10 + (s[i] - '0');
  }
  int64_t frac = 0;
  int frac_digits = 0;
  bool round_up = false;
  if (i < s.size() && s[i] == '.') {
    for (++i; i < s.size() && std::isdigit(static_cast<unsigned char>(s[i])); ++i, ++digits) {
      if (frac_digits < 6) {
        frac = frac * 10 + (s[i] - '0');
        ++frac_digits;
      } else if (frac_digits == 6) {
        round_up = s[i] >= '5';
        ++frac_digits;
      }
    }
  }
  if (i != s.size() || digits == 0) return false;
  for (int k = std::min(frac_digits, 6); k < 6; ++k) frac *= 10;
  us = whole * 1000000 + frac + (round_up ? 1 : 0);
  if (negative) us = -us;
  return true;
}

std::string formatSeconds(int64_t us) {
  const bool negative = us < 0;
  const uint64_t m = negative ? static_cast<uint64_t>(-(us + 1)) + 1 : static_cast<uint64_t>(us);
  char buf[40];
  std::snprintf(buf, sizeof(buf), "%s%llu.%06llu", negative ? "-" : "",
                static_cast<unsigned long long>(m / 1000000),
                static_cast<unsigned long long>(m % 1000000));
  return buf;
}

}  // namespace

std::vector<StampedPose> readTum(const std::string& path) {
  std::ifstream file(path);
  if (!file) throwInFile(path, "cannot open trajectory file");
  std::vector<StampedPose> poses;
  std::string line;
  int64_t line_no = 0;
  while (std::getline(file, line)) {
    ++line_no;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    const size_t first = line.find_first_not_of(" \t");
    if (first == std::string::npos || line[first] == '#') continue;
    std::istringstream in(line);
    std::vector<std::string> fields;
    for (std::string f; in >> f;) fields.push_back(f);
    if (fields.size() != 8) {
      throwAtLine(
          path, line_no,
          "expected 8 fields 't tx ty tz qx qy qz qw', found " + std::to_string(fields.size()));
    }
    int64_t t;
    if (!parseSeconds(fields[0], t))
      throwAtLine(path, line_no, "cannot read the time '" + fields[0] + "' (seconds)");
    double v[7];
    for (int k = 0; k < 7; ++k) {
      const std::string& f = fields[static_cast<size_t>(k + 1)];
      const auto [ptr, ec] = std::from_chars(f.data(), f.data() + f.size(), v[k]);
      if (ec != std::errc() || ptr != f.data() + f.size() || !std::isfinite(v[k])) {
        throwAtLine(path, line_no,
                    "field " + std::to_string(k + 2) + " '" + f + "' is not a finite number");
      }
    }
    const Quaternion q(v[6], v[3], v[4], v[5]);
    if (std::abs(q.norm() - 1.0) > 1e-3) {
      throwAtLine(path, line_no,
                  "quaternion (qx qy qz qw) has norm " + std::to_string(q.norm()) + ", expected 1");
    }
    if (!poses.empty() && t < poses.back().t_us) throwAtLine(path, line_no, "time goes back");
    poses.push_back(StampedPose{t, SE3(q, Vector3(v[0], v[1], v[2]))});
  }
  return poses;
}

void writeTum(const std::string& path, const std::vector<StampedPose>& poses) {
  std::ostringstream out;
  out << "# t tx ty tz qx qy qz qw (T_world_cam, t in seconds)\n";
  char buf[256];
  for (const StampedPose& p : poses) {
    const Quaternion& q = p.pose.rotation();
    const Vector3& t = p.pose.translation();
    std::snprintf(buf, sizeof(buf), " %.17g %.17g %.17g %.17g %.17g %.17g %.17g\n", t.x(), t.y(),
                  t.z(), q.x(), q.y(), q.z(), q.w());
    out << formatSeconds(p.t_us) << buf;
  }
  const std::string tmp = path + ".tmp-" + std::to_string(::getpid());
  {
    std::ofstream f(tmp);
    f << out.str();
    f.close();
    if (!f) {
      std::filesystem::remove(tmp);
      throwInFile(path, "cannot write trajectory file");
    }
  }
  std::filesystem::rename(tmp, path);
}

std::vector<StampedPose> sampleTrajectory(const Trajectory& trajectory,
                                          const std::vector<int64_t>& times_us) {
  std::vector<StampedPose> out;
  out.reserve(times_us.size());
  for (int64_t t : times_us) out.push_back(StampedPose{t, trajectory.poseAt(t)});
  return out;
}

}  // namespace evkit
