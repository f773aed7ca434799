// RPG dataset folder (Mueggler et al., "The Event-Camera Dataset and Simulator", IJRR 2017):
//   events.txt   "t x y p" (t in seconds)
//   images.txt   "t images/frame_00000000.png" (t in seconds, path relative to the folder)
//   calib.txt    "fx fy cx cy k1 k2 p1 p2 k3"
// The images carry one timestamp each; their exposure interval is not recorded, so a frame's
// exposure start and end are both that timestamp.

#include <filesystem>

#include "evkit/base/error.h"
#include "evkit/events/image_io.h"
#include "formats.h"
#include "timed_list.h"

namespace evkit::detail {
namespace fs = std::filesystem;

namespace {

class RpgFolderReader final : public EventReader {
 public:
  explicit RpgFolderReader(const std::string& dir) : dir_(dir) {
    events_ = openTextReader((fs::path(dir) / "events.txt").string());
    info_ = events_->info();
    info_.format = Format::kRpgFolder;
    info_.layout = "rpg-folder";
    const fs::path calib = fs::path(dir) / "calib.txt";
    if (fs::exists(calib)) info_.calibration = readCalibration(calib.string());
    const fs::path images = fs::path(dir) / "images.txt";
    if (fs::exists(images)) images_ = readTimedPathList(images.string(), true, false);
  }

 protected:
  bool readChunk(Chunk& chunk, size_t max_events) override {
    const bool got_events = events_->next(scratch_, max_events);
    chunk.events.setSensor(scratch_.events.sensor());
    chunk.events.append(scratch_.events.view());
    const int64_t last_t = chunk.events.empty() ? INT64_MIN : chunk.events.t.back();
    while (next_image_ < images_.size() && (!got_events || images_[next_image_].first <= last_t)) {
      Frame frame = readImageFile(images_[next_image_].second);
      frame.exposure_start_us = frame.exposure_end_us = images_[next_image_].first;
      if (info_.sensor.known() &&
          (frame.image.cols != info_.sensor.width || frame.image.rows != info_.sensor.height)) {
        throwInFile(images_[next_image_].second, "image size differs from the sensor size");
      }
      chunk.frames.push_back(std::move(frame));
      ++next_image_;
    }
    return got_events || !chunk.frames.empty();
  }

  void seek(int64_t t_begin) override {
    events_->setTimeWindow(t_begin, INT64_MAX);
    while (next_image_ < images_.size() && images_[next_image_].first < t_begin) ++next_image_;
  }

 private:
  std::string dir_;
  std::unique_ptr<EventReader> events_;
  Chunk scratch_;
  std::vector<std::pair<int64_t, std::string>> images_;
  size_t next_image_ = 0;
};

}  // namespace

std::unique_ptr<EventReader> openRpgFolderReader(const std::string& path) {
  return std::make_unique<RpgFolderReader>(path);
}

}  // namespace evkit::detail
