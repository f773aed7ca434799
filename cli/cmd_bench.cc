// evkit bench: speed against error of every deblurring method at several budgets on a synthetic
// suite (generated here, or reused), with results.csv, results.md and a speed-against-error plot.

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <set>

#include "common.h"
#include "deblur_runner.h"
#include "evkit/base/error.h"
#include "evkit/deblur/observation.h"
#include "evkit/harness/speed_error.h"
#include "evkit/synth/generator.h"

namespace evkit::cli {

namespace fs = std::filesystem;

namespace {

std::string runFolder(const BenchRun& run) {
  std::string name = run.method;
  if (run.budget == "-") return name;
  name += "_";
  for (char c : run.budget) {
    if (c != ' ') name += c;
  }
  return name;
}

// The entry's observation folder under data_dir, generated when it is not there yet.
Observation suiteObservation(const synth::SuiteEntry& e, const std::string& data_dir, int width,
                             int height) {
  const std::string dir = data_dir + "/" + e.name;
  if (!fs::exists(dir + "/exposure.txt")) {
    synth::SynthOptions o;
    o.width = width;
    o.height = height;
    e.apply(o);
    std::fprintf(stderr, "generating %s (%s) ...\n", e.name.c_str(),
                 e.what.empty() ? e.scene.c_str() : e.what.c_str());
    synth::writeObservation(synth::makePreset(e.scene, {}), o, dir);
  }
  Observation obs = loadObservation(dir);
  if (obs.blurry.image.cols != width || obs.blurry.image.rows != height) {
    throwInFile(dir, "exists at " + std::to_string(obs.blurry.image.cols) + "x" +
                         std::to_string(obs.blurry.image.rows) +
                         ", not the --size asked for; give another --data folder");
  }
  return obs;
}

}  // namespace

int runBench(const Args& args) {
  po::options_description opts("options");
  opts.add_options()("out", po::value<std::string>()->required(),
                     "output folder: results.csv, results.md, speed_vs_error.png, runs/")(
      "suite", po::value<std::string>()->default_value("standard"),
      "standard (10 scenes), noisy (the same 10 with DAVIS-like event noise), hard (9 hard cases), "
      "natural (24: photographs at several depths) "
      "or all")("scenes", po::value<std::string>(),
                "only these entries of the suite (comma-separated names)")(
      "data", po::value<std::string>(),
      "where the suite's observation folders are (made when missing); default OUT/suite")(
      "size", po::value<std::string>()->default_value("346x260"),
      "image size of generated scenes WxH")(
      "methods", po::value<std::string>()->default_value("blurry,edi,benerf,benerf-mlp"),
      "blurry, edi, benerf, benerf-mlp")(
      "budgets", po::value<std::string>()->default_value("250,500,1000"),
      "BeNeRF budgets: N iterations of the fast budget, fast|balanced|quality, or seconds (60s)")(
      "mlp-budgets", po::value<std::string>()->default_value("60s"),
      "budgets of BeNeRF with the paper's MLP (benerf-mlp)")(
      "set", po::value<std::vector<std::string>>()->composing(),
      "METHOD.KEY=VALUE added to every run of METHOD (e.g. benerf.seed=2)")(
      "threads", po::value<int>(), "BeNeRF threads (default: the cores other programs leave idle)")(
      "unknown-contrast", po::bool_switch(),
      "the methods are not given the thresholds (contrast.txt), as with real data: EDI searches c, "
      "BeNeRF estimates them the same way")("rerun", po::bool_switch(),
                                            "run again what OUT/results.csv already holds");
  po::positional_options_description pos;
  po::variables_map vm;
  if (!parseArgs(
          args,
          "usage: evkit bench [--suite standard|noisy|hard|natural|all] [--methods ...] [--budgets "
          "...] --out DIR",
          opts, pos, vm)) {
    return kExitOk;
  }
  const auto [width, height] = parseImageSize(vm["size"].as<std::string>(), "size", 16, 4096);
  std::vector<synth::SuiteEntry> entries;
  try {
    entries = synth::suiteEntries(vm["suite"].as<std::string>());
  } catch (const Error& e) {
    throw UsageError(std::string("--suite: ") + e.what());
  }
  if (vm.count("scenes")) {
    const std::vector<std::string> wanted = splitList(vm["scenes"].as<std::string>());
    for (const std::string& w : wanted) {
      if (std::none_of(entries.begin(), entries.end(),
                       [&](const synth::SuiteEntry& e) { return e.name == w; })) {
        throw UsageError("--scenes: no entry '" + w + "' in suite " +
                         vm["suite"].as<std::string>());
      }
    }
    std::erase_if(entries, [&](const synth::SuiteEntry& e) {
      return std::find(wanted.begin(), wanted.end(), e.name) == wanted.end();
    });
  }
  std::map<std::string, MethodSettings> extra;
  if (vm.count("set")) {
    for (const std::string& kv : vm["set"].as<std::vector<std::string>>()) {
      const size_t eq = kv.find('='), dot = kv.find('.');
      if (eq == std::string::npos || dot == std::string::npos || dot > eq)
        throw UsageError("--set: expected METHOD.KEY=VALUE, got '" + kv + "'");
      extra[kv.substr(0, dot)][kv.substr(dot + 1, eq - dot - 1)] = kv.substr(eq + 1);
    }
  }
  if (vm.count("threads")) {
    if (vm["threads"].as<int>() < 1) throw UsageError("--threads must be at least 1");
    for (const char* m : {"benerf", "benerf-mlp"})
      extra[m]["threads"] = std::to_string(vm["threads"].as<int>());
  }
  std::vector<BenchRun> runs;
  try {
    runs = benchRuns(splitList(vm["methods"].as<std::string>()),
                     splitList(vm["budgets"].as<std::string>()),
                     splitList(vm["mlp-budgets"].as<std::string>()), extra);
  } catch (const Error& e) {
    throw UsageError(e.what());
  }
  const std::string out = vm["out"].as<std::string>();
  const std::string data = vm.count("data") ? vm["data"].as<std::string>() : out + "/suite";
  const bool unknown_contrast = vm["unknown-contrast"].as<bool>();
  const std::string title = "evkit bench: suite " + vm["suite"].as<std::string>() + " at " +
                            vm["size"].as<std::string>() +
                            (unknown_contrast ? ", thresholds not given to the methods" : "");

  // Finished runs of an earlier call are kept (and not run again unless --rerun).
  std::vector<BenchRow> rows;
  std::set<std::string> done;
  if (!vm["rerun"].as<bool>()) {
    for (const BenchRow& r : readBenchCsv(out + "/results.csv")) {
      if (r.ok()) rows.push_back(r), done.insert(r.key());
    }
  }
  size_t total = 0, step = 0;
  for (const synth::SuiteEntry& e : entries) {
    for (const BenchRun& run : runs)
      total += !done.count(e.name + "|" + run.method + "|" + run.budget);
  }
  std::fprintf(stderr, "%zu scenes x %zu runs: %zu to run, %zu kept from %s/results.csv\n",
               entries.size(), runs.size(), total, entries.size() * runs.size() - total,
               out.c_str());
  int failures = 0;
  for (const synth::SuiteEntry& e : entries) {
    std::optional<Observation> obs;
    for (const BenchRun& run : runs) {
      const std::string key = e.name + "|" + run.method + "|" + run.budget;
      if (done.count(key)) continue;
      if (!obs) {
        obs = suiteObservation(e, data, width, height);
        if (unknown_contrast) obs->contrast.reset();
      }
      ++step;
      std::fprintf(stderr, "[%zu/%zu] %-18s %-10s %-8s ...\n", step, total, e.name.c_str(),
                   run.method.c_str(), run.budget.c_str());
      TrainingProgress progress(run.method + " training");
      BenchRow row = evkit::runBench(*obs, e.group, e.name, e.what, run,
                                     out + "/runs/" + e.name + "/" + runFolder(run), nullptr,
                                     progress.callback());
      progress.finish();
      std::erase_if(rows, [&](const BenchRow& r) { return r.key() == key; });
      rows.push_back(row);
      if (row.ok()) {
        std::fprintf(
            stderr, "[%zu/%zu] %-18s %-10s %-8s PSNR %6.2f dB  SSIM %.4f  %8.3f s%s\n", step, total,
            e.name.c_str(), run.method.c_str(), run.budget.c_str(), row.psnr, row.ssim, row.wall_s,
            row.nonfinite ? ("  " + std::to_string(row.nonfinite) + " non-finite values").c_str()
                          : "");
      } else {
        ++failures;
        std::fprintf(stderr, "[%zu/%zu] %-18s %-10s %-8s %s\n", step, total, e.name.c_str(),
                     run.method.c_str(), run.budget.c_str(), row.status.c_str());
      }
      writeBenchResults(out, rows,
                        title);  // after every run: a later failure or a kill loses nothing
    }
  }
  writeBenchResults(out, rows, title);
  std::fprintf(stderr, "wrote %s/results.csv, results.md, speed_vs_error.png\n", out.c_str());
  if (failures > 0) {
    std::fprintf(stderr,
                 "evkit bench: %d run%s failed (see the health column of %s/results.md); the other "
                 "results are kept\n",
                 failures, failures == 1 ? "" : "s", out.c_str());
    return kExitInputError;
  }
  return kExitOk;
}

}  // namespace evkit::cli
