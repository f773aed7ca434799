#pragma once

// How many threads a long run should take on a machine that other programs share. Every step of
// BeNeRF waits for its slowest thread, so a thread that shares its core with another program holds
// the others back: beside one busy process on 2 cores a frame took longer on both threads than on
// one (BENCHMARKS.md, "Beside another program").

#include <chrono>
#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <vector>

namespace evkit {

struct CoreLoad {
  int cores = 1;              // the CPUs this process may run on (its affinity mask)
  double busy_elsewhere = 0;  // how many of them other programs kept busy, on average
};

// One CPU's counters from /proc/stat, in clock ticks.
struct CpuTicks {
  uint64_t busy = 0, total = 0;
};
// The per-CPU lines ("cpuN ...") of a /proc/stat text by CPU index; the summed "cpu" line is left
// out. Busy is user + nice + system + irq + softirq + steal; total adds idle and iowait (guest time
// is already inside user).
std::map<int, CpuTicks> parseCpuTicks(const std::string& proc_stat);

// The load on `cpus` over a window from /proc/stat's counters at its two ends, less `own_ticks` of
// this process's own CPU time in it; nullopt where the window shows no ticks on them.
std::optional<CoreLoad> coreLoadBetween(const std::map<int, CpuTicks>& before,
                                        const std::map<int, CpuTicks>& after,
                                        const std::vector<int>& cpus, double own_ticks);

// The load on this process's CPUs over `window`: /proc/stat read at both ends, this process's own
// CPU time in between (getrusage) taken out. nullopt where /proc/stat or the mask cannot be read
// (not Linux).
std::optional<CoreLoad> measureCoreLoad(std::chrono::milliseconds window);

// The threads to run on: the cores that other programs leave idle, rounded to the nearest whole
// core, at least 1 and at most `max_threads`.
int threadsForLoad(const CoreLoad& load, int max_threads);

}  // namespace evkit
