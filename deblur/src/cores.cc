#include "evkit/deblur/cores.h"

#include <sched.h>
#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <fstream>
#include <sstream>

namespace evkit {

std::map<int, CpuTicks> parseCpuTicks(const std::string& proc_stat) {
  std::map<int, CpuTicks> cpus;
  std::istringstream lines(proc_stat);
  std::string line;
  while (std::getline(lines, line)) {
    if (line.rfind("cpu", 0) != 0 || line.size() < 4 || !std::isdigit(line[3])) continue;
    std::istringstream fields(line.substr(3));
    int index = 0;
    uint64_t user = 0, nice = 0, system = 0, idle = 0, iowait = 0, irq = 0, softirq = 0, steal = 0;
    fields >> index >> user >> nice >> system >> idle >> iowait >> irq >> softirq;
    if (!fields) continue;
    if (!(fields >> steal)) steal = 0;  // kernels before 2.6.11 have no steal column
    CpuTicks& t = cpus[index];
    t.busy = user + nice + system + irq + softirq + steal;
    t.total = t.busy + idle + iowait;
  }
  return cpus;
}

namespace {

std::optional<std::map<int, CpuTicks>> readCpuTicks() {
  std::ifstream in("/proc/stat");
  if (!in) return std::nullopt;
  std::ostringstream text;
  text << in.rdbuf();
  return parseCpuTicks(text.str());
}

// This process's CPU time so far, in seconds.
double ownCpuSeconds() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  const auto seconds = [](const timeval& t) { return t.tv_sec + t.tv_usec * 1e-6; };
  return seconds(usage.ru_utime) + seconds(usage.ru_stime);
}

}  // namespace

std::optional<CoreLoad> coreLoadBetween(const std::map<int, CpuTicks>& before,
                                        const std::map<int, CpuTicks>& after,
                                        const std::vector<int>& cpus, double own_ticks) {
  CoreLoad load;
  load.cores = 0;
  uint64_t busy = 0, total = 0;
  for (const int cpu : cpus) {
    const auto start = before.find(cpu), end = after.find(cpu);
    if (start == before.end() || end == after.end()) continue;
    ++load.cores;
    busy += end->second.busy - start->second.busy;
    total += end->second.total - start->second.total;
  }
  if (load.cores == 0 || total == 0) return std::nullopt;
  // Each CPU's counters advance by the window's ticks: total / cores of them.
  const double window_ticks = static_cast<double>(total) / load.cores;
  load.busy_elsewhere = std::clamp((static_cast<double>(busy) - own_ticks) / window_ticks, 0.0,
                                   static_cast<double>(load.cores));
  return load;
}

LoadFollower::LoadFollower() : last_(std::chrono::steady_clock::now()) {
  cpu_set_t mask;
  CPU_ZERO(&mask);
  const long ticks_per_s = sysconf(_SC_CLK_TCK);
  if (sched_getaffinity(0, sizeof(mask), &mask) != 0 || ticks_per_s <= 0) return;
  for (int cpu = 0; cpu < CPU_SETSIZE; ++cpu)
    if (CPU_ISSET(cpu, &mask)) cpus_.push_back(cpu);
  ticks_per_s_ = static_cast<double>(ticks_per_s);
  ticks_ = readCpuTicks();
  own_s_ = ownCpuSeconds();
}

std::optional<CoreLoad> LoadFollower::measure(std::chrono::milliseconds after) {
  const auto now = std::chrono::steady_clock::now();
  if (!ticks_ || now - last_ < after) return std::nullopt;
  auto ticks = readCpuTicks();
  const double own_s = ownCpuSeconds();
  if (!ticks) return std::nullopt;
  const std::optional<CoreLoad> load =
      coreLoadBetween(*ticks_, *ticks, cpus_, (own_s - own_s_) * ticks_per_s_);
  ticks_ = std::move(ticks);
  own_s_ = own_s;
  last_ = now;
  return load;
}

int threadsForLoad(const CoreLoad& load, int max_threads) {
  const long idle = std::lround(load.cores - load.busy_elsewhere);
  return static_cast<int>(std::clamp<long>(idle, 1, std::max(1, max_threads)));
}

}  // namespace evkit
