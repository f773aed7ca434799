#include "binary_file.h"

#include <algorithm>
#include <cctype>
#include <filesystem>

#include "evkit/base/error.h"

namespace evkit::detail {

BinaryFile::BinaryFile(std::string path) : path_(std::move(path)) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path_, ec)) throwInFile(path_, "no such file");
  file_ = openFile(path_, "rb");
  if (!file_) throwInFile(path_, "cannot open for reading");
  size_ = static_cast<int64_t>(std::filesystem::file_size(path_, ec));
  std::setvbuf(file_.get(), nullptr, _IOFBF, 1 << 16);
}

size_t BinaryFile::read(void* out, size_t n) {
  const size_t got = std::fread(out, 1, n, file_.get());
  offset_ += static_cast<int64_t>(got);
  return got;
}

void BinaryFile::readExact(void* out, size_t n, const char* what) {
  const int64_t at = offset_;
  if (read(out, n) != n) failAt(at, std::string("truncated: expected ") + what);
}

void BinaryFile::seek(int64_t offset) {
  if (offset < 0 || offset > size_ ||
      std::fseek(file_.get(), static_cast<long>(offset), SEEK_SET) != 0) {
    failAt(offset, "seek outside the file");
  }
  offset_ = offset;
}

bool BinaryFile::readLine(std::string& line, size_t max_length) {
  line.clear();
  const int64_t start = offset_;
  int c;
  while ((c = std::fgetc(file_.get())) != EOF) {
    ++offset_;
    if (c == '\n') {
      if (!line.empty() && line.back() == '\r') line.pop_back();
      return true;
    }
    line += static_cast<char>(c);
    if (line.size() > max_length) failAt(start, "header line too long (not a text header?)");
  }
  if (line.empty()) return false;
  failAt(start, "truncated inside the header (its last line has no end)");
}

int BinaryFile::peek() {
  const int c = std::fgetc(file_.get());
  if (c == EOF) return -1;
  std::ungetc(c, file_.get());
  return c;
}

void BinaryFile::fail(const std::string& what) const { throwAtByte(path_, offset_, what); }
void BinaryFile::failAt(int64_t offset, const std::string& what) const {
  throwAtByte(path_, offset, what);
}

SensorSizeGuess sensorSizeForCamera(const std::string& name) {
  std::string n = name;
  std::transform(n.begin(), n.end(), n.begin(), [](unsigned char c) { return std::tolower(c); });
  const auto has = [&](const char* key) { return n.find(key) != std::string::npos; };
  if (has("davis240") || has("davis_240")) return {240, 180};
  if (has("davis346") || has("davis_346")) return {346, 260};
  if (has("davis640") || has("davis_640")) return {640, 480};
  if (has("dvs128") || has("dvs_128")) return {128, 128};
  if (has("dvxplorer_lite") || has("dvxplorer lite") || has("dvxplorerlite")) return {320, 240};
  if (has("dvxplorer")) return {640, 480};
  return {};
}

}  // namespace evkit::detail
