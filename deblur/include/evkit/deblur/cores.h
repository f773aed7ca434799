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

// The load on this process's CPUs followed through a long run without waiting: each measurement
// is of the time since the one before (or since the follower was made), /proc/stat's counters at
// both ends and this process's own CPU time in between (getrusage) taken out.
class LoadFollower {
 public:
  LoadFollower();  // the counters now
  // The load since the last measurement where at least `after` has passed since it (and the
  // counters then taken anew); nullopt before that, or where /proc/stat or the mask cannot be read
  // (not Linux).
  std::optional<CoreLoad> measure(std::chrono::milliseconds after = {});

 private:
  std::vector<int> cpus_;  // the affinity mask's
  double ticks_per_s_ = 0;
  std::chrono::steady_clock::time_point last_;
  std::optional<std::map<int, CpuTicks>> ticks_;
  double own_s_ = 0;
};

// The threads to run on: the cores that other programs leave idle, rounded to the nearest whole
// core, at least 1 and at most `max_threads`.
int threadsForLoad(const CoreLoad& load, int max_threads);

}  // namespace evkit
