// The methods' settings tables: one declaration per key drives parsing, check(), the help text and
// the unknown-key message; the BeNeRF budget grammar is the same everywhere.

#include <gtest/gtest.h>

#include "evkit/base/error.h"
#include "evkit/deblur/benerf.h"
#include "evkit/deblur/deblurrer.h"
#include "evkit/deblur/edi.h"

namespace evkit {
namespace {

std::string errorOf(const std::function<void()>& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

TEST(Settings, BenerfDefaultsAreTheBalancedBudget) {
  const BenerfOptions defaults, balanced = benerfBudget("balanced");
  EXPECT_EQ(defaults.iterations, balanced.iterations);
  EXPECT_EQ(defaults.blur_rays, balanced.blur_rays);
  EXPECT_EQ(defaults.event_rays, balanced.event_rays);
  EXPECT_EQ(defaults.samples, balanced.samples);
  EXPECT_EQ(defaults.hash.grid.levels, balanced.hash.grid.levels);
  EXPECT_EQ(defaults.hash.grid.log2_table, balanced.hash.grid.log2_table);
  EXPECT_NO_THROW(defaults.check());
  EXPECT_NO_THROW(benerfOptions({}).check());
}

TEST(Settings, OneBudgetGrammar) {
  const BenerfBudget seconds = parseBenerfBudget("60s");
  EXPECT_EQ(seconds.label, "60 s");
  EXPECT_DOUBLE_EQ(seconds.options.budget_seconds, 60);
  const BenerfBudget steps = parseBenerfBudget("250");
  EXPECT_EQ(steps.label, "250 it");
  EXPECT_EQ(steps.options.iterations, 250);
  EXPECT_EQ(steps.options.hash.grid.log2_table, benerfBudget("fast").hash.grid.log2_table);
  EXPECT_EQ(parseBenerfBudget("quality").options.iterations, 4000);
  for (const char* bad : {"60x", "-5", "0", "slow", "", "2.5"})
    EXPECT_THROW(parseBenerfBudget(bad), Error) << bad;
  // --set budget= takes the same tokens.
  EXPECT_EQ(benerfOptions({{"budget", "250"}}).iterations, 250);
  EXPECT_DOUBLE_EQ(benerfOptions({{"budget", "1.5s"}}).budget_seconds, 1.5);
  EXPECT_EQ(benerfOptions({{"budget", "fast"}, {"iterations", "7"}}).iterations,
            7);  // keys over the budget
  // The pixel grid's stop where its loss no longer falls: looser at `fast`, none at `quality`, the
  // C++ defaults `balanced`'s.
  EXPECT_DOUBLE_EQ(benerfBudget("fast").converged, 3e-3);
  EXPECT_DOUBLE_EQ(benerfBudget("balanced").converged, 1e-3);
  EXPECT_DOUBLE_EQ(BenerfOptions{}.converged, benerfBudget("balanced").converged);
  EXPECT_DOUBLE_EQ(benerfBudget("quality").converged, 0);
  EXPECT_DOUBLE_EQ(benerfOptions({{"budget", "fast"}, {"converged", "0"}}).converged, 0);
  EXPECT_THROW(benerfOptions({{"converged", "-0.1"}}), Error);
}

TEST(Settings, CheckRefusesWhatParsingRefuses) {
  BenerfOptions o;
  o.alpha = 0;
  EXPECT_NE(errorOf([&] { o.check(); }).find("alpha=0 must be in (0, 1]"), std::string::npos);
  EXPECT_NE(errorOf([] {
              benerfOptions({{"alpha", "0"}});
            }).find("alpha=0 must be in (0, 1]"),
            std::string::npos);
  o = BenerfOptions{};
  o.samples = 1;
  EXPECT_NE(errorOf([&] { o.check(); }).find("samples=1 must be an integer >= 2"),
            std::string::npos);
  EdiOptions e;
  e.search_min = 0.6;
  EXPECT_NE(errorOf([&] { e.check(); }).find("c_min < c_max"), std::string::npos);
  EXPECT_NE(errorOf([] {
              ediOptions({{"c_min", "-1"}});
            }).find("c_min=-1 must be > 0"),
            std::string::npos);
}

TEST(Settings, UnknownKeysListTheTable) {
  const std::string benerf = errorOf([] { makeDeblurrer("benerf", {{"itertions", "5"}}); });
  EXPECT_NE(
      benerf.find("benerf: unknown setting 'itertions' (known: budget, preset, field, iterations,"),
      std::string::npos)
      << benerf;
  const std::string edi = errorOf([] { makeDeblurrer("edi", {{"contrasts", "0.2"}}); });
  EXPECT_NE(
      edi.find(
          "edi: unknown setting 'contrasts' (known: contrast, search, c_min, c_max, margin_us, "
          "levels)"),
      std::string::npos)
      << edi;
}

TEST(Settings, HelpShowsEveryKeyWithItsDefault) {
  const std::string help = deblurrerHelp("benerf");
  for (const std::string& key : benerfSettings().keys())
    EXPECT_NE(help.find("  " + key + " ("), std::string::npos) << key;
  EXPECT_NE(help.find("samples (integer, default 8)"), std::string::npos) << help;
  EXPECT_NE(help.find("depth_scale (number, default 0.02)"), std::string::npos) << help;
  EXPECT_NE(deblurrerHelp("edi").find("c_max (number, default 0.5)"), std::string::npos);
  EXPECT_THROW(deblurrerHelp("magic"), Error);
}

TEST(Settings, ChoicesRoundTripThroughTheirNames) {
  const BenerfOptions o = benerfOptions(
      {{"field", "mlp"}, {"trajectory", "split"}, {"init", "identity"}, {"normalise", "0"}});
  EXPECT_EQ(o.field, BenerfOptions::FieldKind::kMlp);
  EXPECT_DOUBLE_EQ(o.field_lr, 5e-4);  // the paper's rate for its MLP
  EXPECT_EQ(o.trajectory, TrajectoryKind::kCubicSplit);
  EXPECT_EQ(o.init, BenerfOptions::Init::kIdentity);
  EXPECT_EQ(o.event_form, BenerfOptions::EventForm::kDirect);
  EXPECT_NE(errorOf([] {
              benerfOptions({{"field", "voxels"}});
            }).find("field must be hash, mlp or pixels, not 'voxels'"),
            std::string::npos);
}

// threads: auto (the cores other programs leave idle; the default) or a count, shown back as it was
// given.
TEST(Settings, ThreadsAreACountOrAuto) {
  EXPECT_EQ(benerfOptions({}).threads, kThreadsFromLoad);
  EXPECT_EQ(benerfOptions({{"threads", "0"}}).threads, 0);
  EXPECT_EQ(benerfOptions({{"threads", "3"}}).threads, 3);
  EXPECT_EQ(benerfOptions({{"threads", "auto"}}).threads, kThreadsFromLoad);
  for (const char* bad : {"-1", "1.5", "many"}) {
    EXPECT_NE(errorOf([&] {
                benerfOptions({{"threads", bad}});
              }).find("must be an integer in [0, 4096] or auto"),
              std::string::npos)
        << bad;
  }
  EXPECT_NE(deblurrerHelp("benerf").find("threads (N|auto, default auto)"), std::string::npos);
}

}  // namespace
}  // namespace evkit
