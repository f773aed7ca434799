// evkit demo: the built-in default job of the README's first command. It makes a small random
// recording (a rotating bar with noise, absolute Unix-µs timestamps), converts it text -> HDF5 ->
// text, checks the round trip is exact, prints `evkit info`, and writes an accumulated PNG.

#include <filesystem>
#include <iostream>

#include <opencv2/imgcodecs.hpp>

#include "common.h"
#include "evkit/events/accumulate.h"
#include "evkit/events/error.h"
#include "evkit/events/random_events.h"

namespace evkit::cli {

namespace fs = std::filesystem;

int runDemo(const Args& args) {
  po::options_description opts("options");
  opts.add_options()("out", po::value<std::string>()->default_value("evkit-demo"), "output folder")(
      "events", po::value<size_t>()->default_value(500000), "number of random events")(
      "seed", po::value<uint64_t>()->default_value(1), "random seed");
  po::positional_options_description pos;
  po::variables_map vm;
  if (!parseArgs(args, "usage: evkit demo [--out DIR] [--events N] [--seed S]", opts, pos, vm)) return kExitOk;
  const fs::path dir = vm["out"].as<std::string>();
  fs::create_directories(dir);

  RandomEventOptions random;
  random.count = vm["events"].as<size_t>();
  random.seed = vm["seed"].as<uint64_t>();
  Recording rec;
  rec.events = randomEvents(random);
  const std::string txt = (dir / "random.txt").string();
  const std::string h5 = (dir / "random.h5").string();
  const std::string back = (dir / "roundtrip.txt").string();
  writeRecording(txt, rec);
  std::cout << "1. wrote " << withThousands(static_cast<int64_t>(rec.events.size())) << " random events to " << txt << "\n";

  convertFile(txt, std::nullopt, h5, std::nullopt, {}, std::nullopt, std::nullopt);
  convertFile(h5, std::nullopt, back, std::nullopt, {}, std::nullopt, std::nullopt);
  const Recording again = readRecording(back);
  const bool exact = again.events.t == rec.events.t && again.events.x == rec.events.x &&
                     again.events.y == rec.events.y && again.events.p == rec.events.p;
  std::cout << "2. converted text -> " << h5 << " -> " << back << ": round trip "
            << (exact ? "exact" : "DIFFERS") << "\n";
  if (!exact) throw Error("round trip through HDF5 changed the events");

  std::cout << "3. evkit info " << h5 << "\n\n";
  printInfo(h5, std::nullopt);

  const int64_t t0 = rec.events.t.front();
  const EventSpan window = rec.events.sliceTime(t0, t0 + 50000);
  const std::string png = (dir / "accumulated.png").string();
  if (!cv::imwrite(png, renderPolarity(accumulateSigned(window)))) throwInFile(png, "cannot write image");
  std::cout << "\n4. accumulated the first 50 ms (" << withThousands(static_cast<int64_t>(window.size()))
            << " events) into " << png << " (ON red, OFF blue)\n";
  return kExitOk;
}

}  // namespace evkit::cli
