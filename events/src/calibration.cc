#include "evkit/events/calibration.h"

#include <cmath>
#include <fstream>
#include <sstream>

#include "evkit/base/error.h"
#include "evkit/events/atomic_file.h"

namespace evkit {

Calibration readCalibration(const std::string& path) {
  std::ifstream file(path);
  if (!file) throwInFile(path, "cannot open calibration file");
  std::string line;
  int64_t line_no = 0;
  while (std::getline(file, line)) {
    ++line_no;
    const size_t first = line.find_first_not_of(" \t\r");
    if (first == std::string::npos || line[first] == '#') continue;
    std::istringstream in(line);
    std::vector<double> v;
    std::string token;
    while (in >> token) {
      try {
        size_t used = 0;
        v.push_back(std::stod(token, &used));
        if (used != token.size()) throw std::invalid_argument(token);
      } catch (const std::exception&) {
        throwAtLine(path, line_no,
                    "'" + token + "' is not a number (expected fx fy cx cy [k1 k2 p1 p2 [k3]])");
      }
    }
    if (v.size() != 4 && v.size() != 8 && v.size() != 9) {
      throwAtLine(path, line_no,
                  "expected 4, 8 or 9 numbers 'fx fy cx cy [k1 k2 p1 p2 [k3]]', found " +
                      std::to_string(v.size()));
    }
    for (double x : v) {
      if (!std::isfinite(x)) throwAtLine(path, line_no, "non-finite value");
    }
    if (v[0] <= 0 || v[1] <= 0) throwAtLine(path, line_no, "focal lengths fx, fy must be positive");
    Calibration calib{v[0], v[1], v[2], v[3], std::vector<double>(v.begin() + 4, v.end())};
    return calib;
  }
  throwInFile(path, "no calibration line (expected fx fy cx cy [k1 k2 p1 p2 [k3]])");
}

void writeCalibration(const std::string& path, const Calibration& calib) {
  std::ostringstream out;
  out.precision(17);
  out << calib.fx << ' ' << calib.fy << ' ' << calib.cx << ' ' << calib.cy;
  for (double k : calib.distortion) out << ' ' << k;
  out << '\n';
  writeFileAtomically(path, out.str());
}

}  // namespace evkit
