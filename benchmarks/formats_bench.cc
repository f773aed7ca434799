// Read throughput of the camera formats on 1e7 events (346x260, absolute Unix-µs timestamps).
// AEDAT 4 files are written by evkit; AEDAT 2.0, AEDAT 3.1, EVT 2.0 and DAT files are generated
// here byte by byte from their specifications (same events), since evkit does not write them.
//
//   EVKIT_BENCH_DIR=/tmp/evkit-bench ./build/benchmarks/evkit_formats_bench

#include <benchmark/benchmark.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>

#include "bench_dir.h"
#include "evkit/events/io.h"
#include "evkit/events/random_events.h"

namespace evkit {
namespace {

namespace fs = std::filesystem;

constexpr size_t kEvents = 10'000'000;

std::string pathFor(const std::string& name) { return benchPath(name); }

const EventStore& events() {
  static const EventStore ev = [] {
    RandomEventOptions o;
    o.count = kEvents;
    o.t_start_us = 1605537493718345;
    o.rate_hz = 5e6;
    o.sensor = SensorSize{240, 180};  // fits every format's address layout, DAVIS240 for AEDAT 2
    return randomEvents(o);
  }();
  return ev;
}

class Out {
 public:
  explicit Out(const std::string& path) : f_(path, std::ios::binary) {}
  void str(const std::string& s) { f_ << s; }
  void be32(uint32_t v) {
    for (int i = 3; i >= 0; --i) f_.put(static_cast<char>(v >> (8 * i)));
  }
  void le32(uint32_t v) {
    for (int i = 0; i < 4; ++i) f_.put(static_cast<char>(v >> (8 * i)));
  }
  void le16(uint16_t v) {
    for (int i = 0; i < 2; ++i) f_.put(static_cast<char>(v >> (8 * i)));
  }

 private:
  std::ofstream f_;
};

std::string makeFile(const std::string& format) {
  const EventStore& ev = events();
  const std::string path = pathFor("formats." + format);
  if (fs::exists(path)) return path;
  const int64_t t0 = ev.t.front();
  if (format == "aedat4" || format == "aedat4zstd") {
    Recording rec;
    rec.events = ev;
    WriterOptions o;
    o.compression = format == "aedat4" ? Compression::kLz4 : Compression::kZstd;
    writeRecording(path, rec, Format::kAedat4, o);
  } else if (format == "aedat2") {
    Out out(path);
    out.str("#!AER-DAT2.0\r\n# AEChip: eu.seebetter.ini.chips.davis.DAVIS240C\r\n");
    for (size_t i = 0; i < ev.size(); ++i) {
      out.be32((uint32_t(179 - ev.y[i]) << 22) | (uint32_t(239 - ev.x[i]) << 12) |
               (uint32_t(ev.p[i] > 0) << 11));
      out.be32(static_cast<uint32_t>(ev.t[i] - t0));
    }
  } else if (format == "aedat3") {
    Out out(path);
    out.str("#!AER-DAT3.1\r\n#Source 1: DAVIS240C\r\n#!END-HEADER\r\n");
    for (size_t b = 0; b < ev.size(); b += 8192) {
      const size_t n = std::min<size_t>(8192, ev.size() - b);
      out.le16(1), out.le16(1), out.le32(8), out.le32(4), out.le32(0), out.le32(uint32_t(n)),
          out.le32(uint32_t(n)), out.le32(uint32_t(n));
      for (size_t i = b; i < b + n; ++i) {
        out.le32((uint32_t(ev.x[i]) << 17) | (uint32_t(ev.y[i]) << 2) |
                 (uint32_t(ev.p[i] > 0) << 1) | 1u);
        out.le32(static_cast<uint32_t>(ev.t[i] - t0));
      }
    }
  } else if (format == "evt2") {
    Out out(path);
    out.str("% evt 2.0\n% geometry 240x180\n% end\n");
    int64_t high = -1;
    for (size_t i = 0; i < ev.size(); ++i) {
      const int64_t t = ev.t[i] - t0;
      if ((t >> 6) != high) {
        high = t >> 6;
        out.le32(0x80000000u | uint32_t(high & 0x0FFFFFFF));
      }
      out.le32((uint32_t(ev.p[i] > 0) << 28) | (uint32_t(t & 63) << 22) |
               (uint32_t(ev.x[i]) << 11) | ev.y[i]);
    }
  } else if (format == "dat") {
    Out out(path);
    out.str("% Version 2\n% Width 240\n% Height 180\n");
    out.str(std::string("\x0c\x08", 2));
    for (size_t i = 0; i < ev.size(); ++i) {
      out.le32(static_cast<uint32_t>(ev.t[i] - t0));
      out.le32((uint32_t(ev.p[i] > 0) << 28) | (uint32_t(ev.y[i]) << 14) | ev.x[i]);
    }
  }
  return path;
}

void BM_Read(benchmark::State& state, const std::string& format) {
  const std::string path = makeFile(format);
  size_t n = 0;
  for (auto _ : state) {
    auto reader = openReader(path);
    Chunk chunk;
    while (reader->next(chunk, size_t{1} << 20)) n += chunk.events.size();
  }
  if (n != state.iterations() * kEvents) state.SkipWithError("wrong event count");
  state.SetItemsProcessed(static_cast<int64_t>(n));
  state.counters["MB"] = static_cast<double>(fs::file_size(path)) / 1e6;
}

void BM_WriteAedat4(benchmark::State& state) {
  Recording rec;
  rec.events = events();
  for (auto _ : state) writeRecording(pathFor("write.aedat4"), rec);
  state.SetItemsProcessed(static_cast<int64_t>(state.iterations() * kEvents));
}

BENCHMARK_CAPTURE(BM_Read, aedat4_lz4, std::string("aedat4"))
    ->Unit(benchmark::kMillisecond)
    ->Iterations(3);
BENCHMARK_CAPTURE(BM_Read, aedat4_zstd, std::string("aedat4zstd"))
    ->Unit(benchmark::kMillisecond)
    ->Iterations(3);
BENCHMARK_CAPTURE(BM_Read, aedat2, std::string("aedat2"))
    ->Unit(benchmark::kMillisecond)
    ->Iterations(3);
BENCHMARK_CAPTURE(BM_Read, aedat3, std::string("aedat3"))
    ->Unit(benchmark::kMillisecond)
    ->Iterations(3);
BENCHMARK_CAPTURE(BM_Read, evt2, std::string("evt2"))->Unit(benchmark::kMillisecond)->Iterations(3);
BENCHMARK_CAPTURE(BM_Read, dat, std::string("dat"))->Unit(benchmark::kMillisecond)->Iterations(3);
BENCHMARK(BM_WriteAedat4)->Unit(benchmark::kMillisecond)->Iterations(1);

}  // namespace
}  // namespace evkit

BENCHMARK_MAIN();
