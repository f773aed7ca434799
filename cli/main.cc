// evkit: one binary, git-style subcommands.

#include <cstdio>
#include <exception>
#include <iostream>
#include <map>
#include <opencv2/core/utils/logger.hpp>
#include <string>

#include "common.h"
#include "evkit/base/error.h"

namespace {

using evkit::cli::Args;

struct Command {
  int (*run)(const Args&);
  const char* summary;
};

const std::map<std::string, Command>& commands() {
  static const std::map<std::string, Command> table = {
      {"info",
       {evkit::cli::runInfo, "describe a recording: format, sensor, events, time span, frames"}},
      {"convert",
       {evkit::cli::runConvert, "convert a recording between formats, optionally a time window"}},
      {"accumulate",
       {evkit::cli::runAccumulate,
        "event frames, counts, time surfaces, voxel grids as PNG + .npy"}},
      {"frames",
       {evkit::cli::runFrames,
        "export a recording's frames as PNGs plus frames.csv of exposure times"}},
      {"simulate",
       {evkit::cli::runSimulate,
        "events and blurry frames from an image sequence or video (ESIM model)"}},
      {"synth",
       {evkit::cli::runSynth,
        "synthetic blurry frame + events + ground truth (an observation folder), or a suite"}},
      {"deblur",
       {evkit::cli::runDeblur,
        "sharp frames from a blurry frame and its events (blurry, edi, benerf), or every frame of "
        "a recording (--recording FILE --frames all)"}},
      {"video",
       {evkit::cli::runVideo,
        "merge a recording job's frames (evkit deblur --recording --frames) into frames.csv and "
        "one latent video"}},
      {"compare",
       {evkit::cli::runCompare,
        "run several deblurring methods on one observation: table + side-by-side PNG"}},
      {"bench",
       {evkit::cli::runBench,
        "speed against error of every method and budget on a synthetic suite: csv, table, plot"}},
      {"metrics",
       {evkit::cli::runMetrics,
        "PSNR and SSIM of an image against a reference, BRISQUE without one"}},
      {"demo",
       {evkit::cli::runDemo,
        "the built-in default job: random recording -> formats -> info -> PNG"}},
  };
  return table;
}

void printUsage() {
  std::cout << "evkit "
            << "0.1.0"
            << " — a toolkit for event cameras\n\n"
            << "usage: evkit <command> [options]   (evkit <command> --help for its "
               "options)\n\ncommands:\n";
  for (const auto& [name, cmd] : commands()) std::printf("  %-11s %s\n", name.c_str(), cmd.summary);
  std::cout << "\nexit codes: 0 success, 1 bad input or failed output, 2 bad command line, 3 "
               "internal error\n";
}

}  // namespace

int main(int argc, char** argv) {
  cv::utils::logging::setLogLevel(cv::utils::logging::LOG_LEVEL_ERROR);
  if (argc < 2) {
    printUsage();
    return evkit::cli::kExitUsage;
  }
  const std::string name = argv[1];
  if (name == "--help" || name == "-h" || name == "help") {
    printUsage();
    return evkit::cli::kExitOk;
  }
  if (name == "--version") {
    std::cout << "evkit 0.1.0\n";
    return evkit::cli::kExitOk;
  }
  const auto it = commands().find(name);
  if (it == commands().end()) {
    std::cerr << "evkit: unknown command '" << name << "' (see evkit --help)\n";
    return evkit::cli::kExitUsage;
  }
  const Args args(argv + 2, argv + argc);
  try {
    return it->second.run(args);
  } catch (const evkit::cli::UsageError& e) {
    std::cerr << "evkit " << name << ": " << e.what() << " (see evkit " << name << " --help)\n";
    return evkit::cli::kExitUsage;
  } catch (const evkit::Error& e) {
    std::cerr << "evkit " << name << ": " << e.what() << "\n";
    return evkit::cli::kExitInputError;
  } catch (const std::bad_alloc&) {
    std::cerr << "evkit " << name << ": out of memory\n";
    return evkit::cli::kExitInputError;
  } catch (const std::exception& e) {
    std::cerr << "evkit " << name << ": internal error: " << e.what() << "\n";
    return evkit::cli::kExitInternal;
  }
}
