#include "evkit/events/npy.h"

#include <cstring>
#include <fstream>
#include <iterator>
#include <numeric>
#include <sstream>

#include "evkit/base/error.h"
#include "evkit/events/atomic_file.h"

namespace evkit {

// Format: "\x93NUMPY", version 1.0, little-endian uint16 header length, then an ASCII dict padded
// with spaces and a newline so that the data starts at a multiple of 64 bytes (numpy's NEP 1).
void writeNpy(const std::string& path, const float* data, const std::vector<size_t>& shape) {
  std::string dict = "{'descr': '<f4', 'fortran_order': False, 'shape': (";
  for (size_t i = 0; i < shape.size(); ++i)
    dict += std::to_string(shape[i]) + (shape.size() == 1 || i + 1 < shape.size() ? ", " : "");
  dict += "), }";
  const size_t unpadded = 10 + dict.size() + 1;
  dict.append((64 - unpadded % 64) % 64, ' ');
  dict += '\n';
  std::string bytes = std::string("\x93NUMPY\x01\x00", 8);
  const uint16_t len = static_cast<uint16_t>(dict.size());
  bytes += static_cast<char>(len & 0xff);
  bytes += static_cast<char>(len >> 8);
  bytes += dict;
  const size_t count = std::accumulate(shape.begin(), shape.end(), size_t{1}, std::multiplies<>());
  bytes.append(reinterpret_cast<const char*>(data), count * sizeof(float));
  writeFileAtomically(path, bytes);
}

void writeNpy(const std::string& path, const std::vector<cv::Mat>& planes) {
  if (planes.empty()) {
    writeNpy(path, nullptr, {0});
    return;
  }
  const int h = planes[0].rows, w = planes[0].cols;
  std::vector<float> data;
  data.reserve(planes.size() * static_cast<size_t>(h * w));
  for (const cv::Mat& p : planes) {
    CV_Assert(p.type() == CV_32F && p.rows == h && p.cols == w);
    cv::Mat c = p.isContinuous() ? p : p.clone();
    data.insert(data.end(), c.ptr<float>(), c.ptr<float>() + h * w);
  }
  writeNpy(path, data.data(), {planes.size(), static_cast<size_t>(h), static_cast<size_t>(w)});
}

NpyArray readNpy(const std::string& path) {
  std::ifstream file(path, std::ios::binary);
  if (!file) throwInFile(path, "cannot open");
  const std::string bytes((std::istreambuf_iterator<char>(file)), std::istreambuf_iterator<char>());
  if (bytes.size() < 10 || bytes.compare(0, 6, "\x93NUMPY") != 0)
    throwAtByte(path, 0, "not a .npy file");
  const size_t len =
      static_cast<unsigned char>(bytes[8]) | (static_cast<unsigned char>(bytes[9]) << 8);
  if (bytes.size() < 10 + len) throwAtByte(path, 10, "truncated header");
  const std::string dict = bytes.substr(10, len);
  if (dict.find("'<f4'") == std::string::npos ||
      dict.find("'fortran_order': False") == std::string::npos) {
    throwAtByte(path, 10, "expected little-endian float32 in C order");
  }
  NpyArray out;
  const size_t open = dict.find("'shape': (");
  if (open == std::string::npos) throwAtByte(path, 10, "no shape in header");
  const size_t close = dict.find(')', open);
  if (close == std::string::npos) throwAtByte(path, 10, "the header's shape has no ')'");
  std::istringstream shape(dict.substr(open + 10, close - open - 10));
  // Each dimension a plain decimal count; their product is checked, so that no shape can wrap to
  // the size of the data that follows.
  size_t count = 1;
  for (std::string token; std::getline(shape, token, ',');) {
    const size_t first = token.find_first_not_of(' '), last = token.find_last_not_of(' ');
    if (first == std::string::npos) continue;
    const std::string digits = token.substr(first, last - first + 1);
    const bool decimal =
        digits.size() <= 12 && digits.find_first_not_of("0123456789") == std::string::npos;
    const size_t dim = decimal ? std::stoull(digits) : 0;
    if (!decimal || __builtin_mul_overflow(count, dim, &count) ||
        count > bytes.size() / sizeof(float)) {
      throwAtByte(path, static_cast<int64_t>(10 + open),
                  "the dimension '" + digits + "' is not a count that the file's data can hold");
    }
    out.shape.push_back(dim);
  }
  if (bytes.size() - 10 - len != count * sizeof(float))
    throwAtByte(path, static_cast<int64_t>(10 + len), "data size does not match the shape");
  out.data.resize(count);
  if (count) std::memcpy(out.data.data(), bytes.data() + 10 + len, count * sizeof(float));
  return out;
}

}  // namespace evkit
