#include "evkit/deblur/cores.h"

#include <gtest/gtest.h>

#include <chrono>
#include <fstream>
#include <optional>
#include <thread>

#include "test_util.h"

namespace evkit {
namespace {

// The per-CPU lines only, each field where /proc/stat puts it; a line cut short is left out.
TEST(Cores, ParsesEachCpusTicks) {
  const std::map<int, CpuTicks> cpus = parseCpuTicks(
      "cpu  100 5 50 800 10 1 2 3 0 0\n"
      "cpu0 60 0 30 400 5 0 0 0 0 0\n"
      "cpu1 40 5 20 400 5 1 2 3 7 0\n"
      "intr 12345 0 0\n"
      "cpu2 1 2 3\n"
      "ctxt 987\n");
  ASSERT_EQ(cpus.size(), 2u);
  EXPECT_EQ(cpus.at(0).busy, 90u);
  EXPECT_EQ(cpus.at(0).total, 495u);
  EXPECT_EQ(cpus.at(1).busy, 71u);  // user nice system irq softirq steal; guest is within user
  EXPECT_EQ(cpus.at(1).total, 476u);
}

// Over a window of 100 ticks on each of two CPUs in the mask (a third outside it is busy
// throughout), 150 busy ticks of which 60 are this process's own: 0.9 of a core elsewhere.
TEST(Cores, TakesThisProcesssOwnTimeOutOfTheLoad) {
  const std::map<int, CpuTicks> before{{0, {10, 100}}, {1, {20, 100}}, {2, {0, 100}}};
  const std::map<int, CpuTicks> after{{0, {110, 200}}, {1, {70, 200}}, {2, {100, 200}}};
  const std::optional<CoreLoad> load = coreLoadBetween(before, after, {0, 1}, 60);
  ASSERT_TRUE(load);
  EXPECT_EQ(load->cores, 2);
  EXPECT_NEAR(load->busy_elsewhere, 0.9, 1e-12);
  EXPECT_EQ(threadsForLoad(*load, 2), 1);
  // Only its own: nothing elsewhere, both threads.
  EXPECT_NEAR(coreLoadBetween(before, after, {0, 1}, 150)->busy_elsewhere, 0.0, 1e-12);
  EXPECT_FALSE(coreLoadBetween(before, before, {0, 1}, 0));  // no ticks
  EXPECT_FALSE(coreLoadBetween(before, after, {5}, 0));      // no such CPU
}

TEST(Cores, ThreadsAreTheIdleCoresRounded) {
  EXPECT_EQ(threadsForLoad({2, 0.3}, 2), 2);
  EXPECT_EQ(threadsForLoad({2, 0.7}, 2), 1);
  EXPECT_EQ(threadsForLoad({2, 2.0}, 2), 1);  // never none
  EXPECT_EQ(threadsForLoad({8, 1.2}, 8), 7);
  EXPECT_EQ(threadsForLoad({8, 0.0}, 4), 4);  // no more than asked
}

// The follower measures without waiting: nothing until `after` has passed since its last
// measurement, then the load since it, where a child process that spins on one core is another
// program's (other tests running beside this one can only add to it); the next measurement is
// again of the time since that one.
TEST(Cores, FollowsTheLoadWithoutWaiting) {
  if (!std::ifstream("/proc/stat")) GTEST_SKIP() << "no /proc/stat on this system";
  LoadFollower follower;
  EXPECT_FALSE(follower.measure(std::chrono::seconds(60)));
  std::optional<CoreLoad> load;
  {
    const test::SpinningProcess busy;
    ASSERT_GT(busy.pid(), 0) << "fork failed";
    std::this_thread::sleep_for(std::chrono::milliseconds(300));
    load = follower.measure(std::chrono::milliseconds(250));
  }
  ASSERT_TRUE(load);
  EXPECT_GE(load->cores, 1);
  EXPECT_GE(load->busy_elsewhere, 0.7) << "on " << load->cores << " cores";
  EXPECT_FALSE(follower.measure(std::chrono::seconds(60)));
}

}  // namespace
}  // namespace evkit
