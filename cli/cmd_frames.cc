// evkit frames FILE --out DIR: every frame of a recording as a linear PNG at its bit depth, plus
// frames.csv with each frame's exposure start and end (µs). Streams: frames are written as read.

#include <iostream>

#include "common.h"
#include "evkit/base/error.h"
#include "evkit/events/image_io.h"

namespace evkit::cli {

int runFrames(const Args& args) {
  po::options_description opts("options");
  opts.add_options()("input", po::value<std::string>()->required(), "recording with frames")(
      "out", po::value<std::string>()->required(), "output folder")(
      "format", po::value<std::string>(), "input format; default: from the name");
  po::positional_options_description pos;
  pos.add("input", 1);
  po::variables_map vm;
  if (!parseArgs(args, "usage: evkit frames FILE --out DIR", opts, pos, vm)) return kExitOk;
  const std::string in = vm["input"].as<std::string>();
  auto reader = openReader(in, optionalFormat(vm, "format"));
  FrameFolderWriter writer(vm["out"].as<std::string>());
  Progress progress("frames", reader->info().event_count);
  int64_t events = 0;
  Chunk chunk;
  while (reader->next(chunk, size_t{1} << 20)) {
    for (const Frame& f : chunk.frames) writer.add(f);
    events += static_cast<int64_t>(chunk.events.size());
    progress.update(events);
  }
  progress.finish();
  if (writer.count() == 0) throwInFile(in, "the recording holds no frames");
  writer.close();
  std::cerr << "wrote " << writer.count() << " frame" << (writer.count() == 1 ? "" : "s") << " to "
            << vm["out"].as<std::string>() << "/\n";
  return kExitOk;
}

}  // namespace evkit::cli
