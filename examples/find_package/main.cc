// evkit as a library: write events to HDF5 and read them back, then deblur a frame with EDI.
//   evkit_example OUT_DIR
#include <cstdio>
#include <exception>

#include "evkit/base/error.h"
#include "evkit/deblur/deblurrer.h"
#include "evkit/events/io.h"
#include "evkit/events/random_events.h"

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: evkit_example OUT_DIR\n");
    return 2;
  }
  try {
    evkit::RandomEventOptions random;
    random.count = 50000;
    evkit::Recording recording;
    recording.events = evkit::randomEvents(random);
    const std::string path = std::string(argv[1]) + "/events.h5";
    evkit::writeRecording(path, recording);
    const evkit::Recording back = evkit::readRecording(path);
    std::printf("read %zu events from %s\n", back.events.size(), path.c_str());

    // An observation: a grey frame exposed over the first 20 ms, and the events of that window.
    evkit::Observation obs;
    obs.blurry.image = cv::Mat(random.sensor.height, random.sensor.width, CV_32F, cv::Scalar(0.3));
    obs.blurry.exposure_start_us = back.events.t.front();
    obs.blurry.exposure_end_us = obs.blurry.exposure_start_us + 20000;
    obs.events = evkit::EventStore(random.sensor);
    obs.events.append(
        back.events.sliceTime(obs.blurry.exposure_start_us, obs.blurry.exposure_end_us + 1));
    obs.camera = {0.9 * random.sensor.width,
                  0.9 * random.sensor.width,
                  random.sensor.width / 2.0,
                  random.sensor.height / 2.0,
                  {}};
    obs.contrast = {{0.2, 0.2}};
    const auto edi = evkit::makeDeblurrer("edi");
    const evkit::DeblurResult result = edi->run(obs, evkit::defaultRequest(obs, 3));
    std::printf("edi: %zu sharp frames of %dx%d\n", result.frames.size(),
                result.frames.front().image.cols, result.frames.front().image.rows);
  } catch (const evkit::Error& e) {
    std::fprintf(stderr, "evkit_example: %s\n", e.what());
    return 1;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "evkit_example: internal error: %s\n", e.what());
    return 3;
  }
  return 0;
}
