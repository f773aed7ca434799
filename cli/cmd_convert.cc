// evkit convert IN OUT: streams chunks from a reader into a writer (bounded memory).

#include <iostream>

#include "common.h"
#include "evkit/base/error.h"

namespace evkit::cli {

namespace {

// Resolves start/end (absolute or relative to the first event) into a window.
std::pair<int64_t, int64_t> resolveWindow(const std::string& in, std::optional<Format> in_format,
                                          std::optional<TimeValue> start,
                                          std::optional<TimeValue> end) {
  int64_t first = 0;
  if ((start && start->relative) || (end && end->relative)) {
    auto probe = openReader(in, in_format);
    Chunk chunk;
    if (!probe->next(chunk, 1) || chunk.events.empty())
      throwInFile(in, "no events, so no first event to count from");
    first = chunk.events.t.front();
  }
  const auto resolve = [&](const std::optional<TimeValue>& v, int64_t fallback) {
    if (!v) return fallback;
    return v->relative ? first + v->us : v->us;
  };
  return {resolve(start, INT64_MIN), resolve(end, INT64_MAX)};
}

}  // namespace

int64_t convertFile(const std::string& in, std::optional<Format> in_format, const std::string& out,
                    std::optional<Format> out_format, const WriterOptions& options,
                    std::optional<TimeValue> start, std::optional<TimeValue> end) {
  const auto [t_begin, t_end] = resolveWindow(in, in_format, start, end);
  auto reader = openReader(in, in_format);
  reader->setTimeWindow(t_begin, t_end);
  auto writer =
      openWriter(out, out_format ? *out_format : outputFormat(out), reader->info().sensor, options);
  Progress progress("convert", reader->info().event_count);
  int64_t written = 0;
  Chunk chunk;
  while (reader->next(chunk, size_t{1} << 20)) {
    writer->write(chunk.events.view());
    for (const Frame& f : chunk.frames) writer->writeFrame(f);
    written += static_cast<int64_t>(chunk.events.size());
    progress.update(written);
  }
  writer->close();
  for (const std::string& w : reader->info().warnings) std::cerr << "warning: " << w << "\n";
  return written;
}

int runConvert(const Args& args) {
  po::options_description opts("options");
  opts.add_options()("input", po::value<std::string>()->required(), "input recording")(
      "output", po::value<std::string>()->required(), "output file (.txt, .h5, .aedat4)")(
      "format", po::value<std::string>(),
      "input format (text, hdf5, rpg, aedat2, aedat3, aedat4, evt2, evt3, dat); default: from the "
      "name")("out-format", po::value<std::string>(),
              "output format (text, hdf5, aedat4); default: from the name")(
      "start", po::value<std::string>(),
      "keep events from this time: µs, 1.5s, or +10ms from the first event")(
      "end", po::value<std::string>(), "keep events before this time (same forms as --start)")(
      "compression", po::value<std::string>()->default_value("auto"),
      "HDF5: blosc-lz4 (fast; needs the Blosc plugin to read), deflate (readable everywhere), "
      "none; "
      "AEDAT 4: lz4, zstd, none; auto = blosc-lz4 (or deflate without the plugin) / lz4")(
      "level", po::value<int>()->default_value(1), "HDF5 compression level 0-9");
  po::positional_options_description pos;
  pos.add("input", 1).add("output", 1);
  po::variables_map vm;
  if (!parseArgs(args, "usage: evkit convert IN OUT [--start T] [--end T] [--compression C]", opts,
                 pos, vm)) {
    return kExitOk;
  }
  WriterOptions options;
  try {
    const std::string compression = vm["compression"].as<std::string>();
    if (compression != "auto") options.compression = parseCompression(compression);
  } catch (const Error& e) {
    throw UsageError(std::string("--compression: ") + e.what());
  }
  options.level = vm["level"].as<int>();
  if (options.level < 0 || options.level > 9) throw UsageError("--level: expected 0..9");
  std::optional<TimeValue> start, end;
  if (vm.count("start")) start = parseTimeValue(vm["start"].as<std::string>(), "start");
  if (vm.count("end")) end = parseTimeValue(vm["end"].as<std::string>(), "end");
  const std::string out = vm["output"].as<std::string>();
  const int64_t n = convertFile(vm["input"].as<std::string>(), optionalFormat(vm, "format"), out,
                                optionalFormat(vm, "out-format"), options, start, end);
  std::cerr << "wrote " << withThousands(n) << " events to " << out << "\n";
  return kExitOk;
}

}  // namespace evkit::cli
