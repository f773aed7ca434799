// Simulator throughput: output events/s and input frames/s at 346x260 and 1280x720, on a video
// whose every pixel's log intensity oscillates (about 1.3 events per pixel per frame at C = 0.2),
// frames generated beforehand.
//
//   ./build/benchmarks/evkit_simulator_bench            (all cores; --benchmark_filter=... to pick)

#include <benchmark/benchmark.h>
#include <omp.h>

#include <cmath>
#include <random>

#include "evkit/events/simulator.h"

namespace evkit {
namespace {

std::vector<cv::Mat> makeVideo(int w, int h, int frames) {
  std::mt19937_64 rng(1);
  std::uniform_real_distribution<float> u(0.0f, 6.2831853f);
  std::vector<float> phase(static_cast<size_t>(w) * static_cast<size_t>(h));
  for (float& p : phase) p = u(rng);
  std::vector<cv::Mat> video;
  const LogMapping log;
  for (int f = 0; f < frames; ++f) {
    cv::Mat img(h, w, CV_32F);
    float* d = img.ptr<float>();
    for (size_t i = 0; i < phase.size(); ++i)
      d[i] = log.fromLog(-2.0f + 1.0f * std::sin(phase[i] + 0.5f * static_cast<float>(f)));
    video.push_back(img);
  }
  return video;
}

void BM_Simulate(benchmark::State& state) {
  const int w = static_cast<int>(state.range(0)), h = static_cast<int>(state.range(1));
  const int threads = static_cast<int>(state.range(2));
  omp_set_num_threads(threads);
  const std::vector<cv::Mat> video = makeVideo(w, h, 16);
  SimulatorOptions o;
  o.sigma = 0.03;
  EventSimulator sim(SensorSize{w, h}, o);
  EventStore out(SensorSize{w, h});
  sim.addFrame(video[0], 0, out);
  int64_t t = 0;
  size_t f = 1, events = 0, frames = 0;
  for (auto _ : state) {
    out.clear();
    t += 1000;
    sim.addFrame(video[f], t, out);
    f = f % (video.size() - 1) + 1;
    events += out.size();
    ++frames;
  }
  state.counters["Mev/s"] =
      benchmark::Counter(static_cast<double>(events) / 1e6, benchmark::Counter::kIsRate);
  state.counters["frames/s"] =
      benchmark::Counter(static_cast<double>(frames), benchmark::Counter::kIsRate);
  state.counters["ev/frame"] = static_cast<double>(events) / static_cast<double>(frames);
}

BENCHMARK(BM_Simulate)
    ->Args({346, 260, 1})
    ->Args({346, 260, 2})
    ->Args({1280, 720, 1})
    ->Args({1280, 720, 2})
    ->UseRealTime()
    ->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace evkit

BENCHMARK_MAIN();
