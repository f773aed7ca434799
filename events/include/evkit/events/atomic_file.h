// Output that never appears half-written under its final name: write to temporaryPath(), then
// commit() renames it into place. Destroyed uncommitted (an exception on the way), it removes the
// temporary file.
#pragma once

#include <string>

namespace evkit {

class AtomicPath {
 public:
  explicit AtomicPath(std::string final_path);
  ~AtomicPath();
  AtomicPath(const AtomicPath&) = delete;
  AtomicPath& operator=(const AtomicPath&) = delete;

  const std::string& temporaryPath() const { return temporary_; }
  const std::string& finalPath() const { return final_; }
  // Renames the temporary file (or folder) to the final path, replacing what was there.
  void commit();

 private:
  std::string final_;
  std::string temporary_;
  bool committed_ = false;
};

// Writes `bytes` to `path` atomically.
void writeFileAtomically(const std::string& path, const std::string& bytes);

}  // namespace evkit
