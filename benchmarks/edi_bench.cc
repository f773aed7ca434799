// EDI at 346x260 with ~1e6 events in a 100 ms exposure: building the model (the events
// grouped by pixel), one latent frame, and the contrast search (grid + golden section).
//
//   EVKIT_BENCH_DIR=/tmp/evkit-bench ./build/benchmarks/evkit_edi_bench
// (writes edi_events.h5 and edi_blurry.npy there for benchmarks/reference_edi.py)

#include <benchmark/benchmark.h>
#include <omp.h>

#include <cstdlib>
#include <filesystem>

#include "bench_dir.h"
#include "evkit/deblur/edi.h"
#include "evkit/events/io.h"
#include "evkit/events/npy.h"
#include "evkit/events/random_events.h"

namespace evkit {
namespace {

struct Data {
  EventStore events;
  cv::Mat blurry;
  int64_t t0, t1;
};

const Data& data() {
  static const Data d = [] {
    RandomEventOptions o;
    o.count = 1'000'000;
    o.rate_hz = 1e7;  // 1e6 events in 100 ms
    Data d;
    d.events = randomEvents(o);
    d.t0 = d.events.t.front();
    d.t1 = d.t0 + 100000;
    d.blurry = cv::Mat(260, 346, CV_32F);
    cv::randu(d.blurry, 0.05, 0.95);
    Recording rec;
    rec.events = d.events;
    writeRecording(benchPath("edi_events.h5"), rec);
    writeNpy(benchPath("edi_blurry.npy"), d.blurry.ptr<float>(), {260, 346});
    return d;
  }();
  return d;
}

void BM_EdiModel(benchmark::State& state) {
  const Data& d = data();
  for (auto _ : state) benchmark::DoNotOptimize(EdiModel(d.events.view(), 346, 260, d.t0, d.t1));
}

void BM_EdiLatentFrame(benchmark::State& state) {
  omp_set_num_threads(static_cast<int>(state.range(0)));
  const Data& d = data();
  const EdiModel model(d.events.view(), 346, 260, d.t0, d.t1);
  int64_t t = d.t0;
  for (auto _ : state) {
    benchmark::DoNotOptimize(model.latent(d.blurry, t, 0.2, 0.2, EdiOptions{}));
    t = t + 7919 > d.t1 ? d.t0 : t + 7919;
  }
}

void BM_EdiContrastSearch(benchmark::State& state) {
  omp_set_num_threads(static_cast<int>(state.range(0)));
  const Data& d = data();
  const EdiModel model(d.events.view(), 346, 260, d.t0, d.t1);
  for (auto _ : state)
    benchmark::DoNotOptimize(model.searchContrast(d.blurry, (d.t0 + d.t1) / 2, 1.0, EdiOptions{}));
}

BENCHMARK(BM_EdiModel)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_EdiLatentFrame)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_EdiContrastSearch)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace
}  // namespace evkit

BENCHMARK_MAIN();
