// Read/write throughput of the text and HDF5 formats and accumulation throughput, on 1e7 random
// events with absolute Unix-µs timestamps (generated on the fly, never committed).
//
//   EVKIT_BENCH_DIR=/tmp/evkit-bench ./build/benchmarks/evkit_io_bench
//
// The files stay in EVKIT_BENCH_DIR so that benchmarks/reference_h5py.py can read the very same
// files with h5py/numpy in the same hour (the ratio goes into BENCHMARKS.md).

#include <benchmark/benchmark.h>

#include <cstdlib>
#include <filesystem>

#include "bench_dir.h"
#include "evkit/events/accumulate.h"
#include "evkit/events/io.h"
#include "evkit/events/random_events.h"

namespace evkit {
namespace {

namespace fs = std::filesystem;

constexpr size_t kEvents = 10'000'000;

const Recording& recording() {
  static const Recording rec = [] {
    RandomEventOptions o;
    o.count = kEvents;
    o.t_start_us = 1605537493718345;
    o.rate_hz = 5e6;
    Recording r;
    r.events = randomEvents(o);
    return r;
  }();
  return rec;
}

std::string pathFor(const std::string& name) { return benchPath(name); }

const Compression kCompressions[] = {Compression::kNone, Compression::kDeflate,
                                     Compression::kBloscLz4};

std::string hdf5Name(int compression) {
  return "events_" + compressionName(kCompressions[compression]) + ".h5";
}

void BM_TextWrite(benchmark::State& state) {
  const Recording& rec = recording();
  for (auto _ : state) writeRecording(pathFor("events.txt"), rec);
  state.SetItemsProcessed(static_cast<int64_t>(state.iterations() * rec.events.size()));
  state.counters["MB"] = static_cast<double>(fs::file_size(pathFor("events.txt"))) / 1e6;
}

void BM_TextRead(benchmark::State& state) {
  if (!fs::exists(pathFor("events.txt"))) writeRecording(pathFor("events.txt"), recording());
  size_t n = 0;
  for (auto _ : state) {
    auto reader = openReader(pathFor("events.txt"));
    Chunk chunk;
    while (reader->next(chunk, size_t{1} << 20)) n += chunk.events.size();
  }
  state.SetItemsProcessed(static_cast<int64_t>(n));
}

void BM_Hdf5Write(benchmark::State& state) {
  const Recording& rec = recording();
  WriterOptions options;
  options.compression = kCompressions[state.range(0)];
  for (auto _ : state)
    writeRecording(pathFor(hdf5Name(static_cast<int>(state.range(0)))), rec, std::nullopt, options);
  state.SetItemsProcessed(static_cast<int64_t>(state.iterations() * rec.events.size()));
  state.SetLabel(compressionName(kCompressions[state.range(0)]));
  state.counters["MB"] =
      static_cast<double>(fs::file_size(pathFor(hdf5Name(static_cast<int>(state.range(0)))))) / 1e6;
}

// The HDF5 file of a compression (range(0)), written on first use.
std::string hdf5File(const benchmark::State& state) {
  const std::string path = pathFor(hdf5Name(static_cast<int>(state.range(0))));
  if (!fs::exists(path)) {
    WriterOptions options;
    options.compression = kCompressions[state.range(0)];
    writeRecording(path, recording(), std::nullopt, options);
  }
  return path;
}

void BM_Hdf5Read(benchmark::State& state) {
  const std::string path = hdf5File(state);
  size_t n = 0;
  for (auto _ : state) {
    auto reader = openReader(path);
    Chunk chunk;
    while (reader->next(chunk, size_t{1} << 20)) n += chunk.events.size();
  }
  state.SetItemsProcessed(static_cast<int64_t>(n));
  state.SetLabel(compressionName(kCompressions[state.range(0)]));
}

// The whole file into one store, as readRecording (and so evkit.read in Python) does.
void BM_Hdf5ReadWhole(benchmark::State& state) {
  const std::string path = hdf5File(state);
  size_t n = 0;
  for (auto _ : state) n += readRecording(path).events.size();
  state.SetItemsProcessed(static_cast<int64_t>(n));
  state.SetLabel(compressionName(kCompressions[state.range(0)]));
}

// The check every reader makes of what it read (time order, sensor, polarity).
void BM_Validate(benchmark::State& state) {
  const EventSpan ev = recording().events.view();
  for (auto _ : state) validate(ev, "bench");
  state.SetItemsProcessed(static_cast<int64_t>(state.iterations() * ev.size()));
}

void BM_AccumulateSigned(benchmark::State& state) {
  const EventSpan ev = recording().events.view();
  for (auto _ : state) benchmark::DoNotOptimize(accumulateSigned(ev));
  state.SetItemsProcessed(static_cast<int64_t>(state.iterations() * ev.size()));
}

void BM_AccumulateSignedContrast(benchmark::State& state) {
  const EventSpan ev = recording().events.view();
  for (auto _ : state) benchmark::DoNotOptimize(accumulateSigned(ev, 0.2f, 0.25f));
  state.SetItemsProcessed(static_cast<int64_t>(state.iterations() * ev.size()));
}

void BM_AccumulateCounts(benchmark::State& state) {
  const EventSpan ev = recording().events.view();
  for (auto _ : state) benchmark::DoNotOptimize(accumulateCounts(ev));
  state.SetItemsProcessed(static_cast<int64_t>(state.iterations() * ev.size()));
}

void BM_VoxelGrid(benchmark::State& state) {
  const EventSpan ev = recording().events.view();
  for (auto _ : state) benchmark::DoNotOptimize(voxelGrid(ev, 5, ev.t.front(), ev.t.back()));
  state.SetItemsProcessed(static_cast<int64_t>(state.iterations() * ev.size()));
}

void BM_TimeSurface(benchmark::State& state) {
  const EventSpan ev = recording().events.view();
  for (auto _ : state) benchmark::DoNotOptimize(timeSurface(ev, ev.t.back(), 10000.0));
  state.SetItemsProcessed(static_cast<int64_t>(state.iterations() * ev.size()));
}

BENCHMARK(BM_TextWrite)->Unit(benchmark::kMillisecond)->Iterations(1);
BENCHMARK(BM_TextRead)->Unit(benchmark::kMillisecond)->Iterations(3);
BENCHMARK(BM_Hdf5Write)->DenseRange(0, 2)->Unit(benchmark::kMillisecond)->Iterations(1);
BENCHMARK(BM_Hdf5Read)->DenseRange(0, 2)->Unit(benchmark::kMillisecond)->Iterations(3);
BENCHMARK(BM_Hdf5ReadWhole)->DenseRange(0, 2)->Unit(benchmark::kMillisecond)->Iterations(3);
BENCHMARK(BM_Validate)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_AccumulateSigned)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_AccumulateSignedContrast)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_AccumulateCounts)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_VoxelGrid)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_TimeSurface)->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace evkit

BENCHMARK_MAIN();
