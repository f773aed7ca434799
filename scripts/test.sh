#!/usr/bin/env bash
# The README's second command (and all that CI runs): install what is missing, build, run the whole
# test suite; fuzz every reader for 20 s (libFuzzer), one per core at a time; then the suite under
# AddressSanitizer + UndefinedBehaviorSanitizer, where the accuracy tests that train for hundreds of
# steps skip because shorter tests reach their code (scripts/sanitizer_coverage.sh measures it).
# EVKIT_SKIP_FUZZ=1 / EVKIT_SKIP_SANITIZE=1 skip those passes (quicker local runs);
# EVKIT_FUZZ_SECONDS changes the fuzzing time per reader.
set -euo pipefail
cd "$(dirname "$0")/.."

jobs=$(nproc)
# ctest runs $jobs tests at once, each with as many OpenMP threads as there are cores: threads that
# wait at a barrier sleep instead of spinning on a core another test needs (two BeNeRF tests under
# ASan side by side on 2 cores: 30.6 -> 22.1 s and 24.7 -> 21.1 s; alone, 17.4 -> 18.1 s).
export OMP_WAIT_POLICY=passive
bash scripts/install-deps.sh

echo "== Release build and tests"
cmake -S . -B build-test -G Ninja -DCMAKE_BUILD_TYPE=Release -DEVKIT_BUILD_TESTS=ON \
  -DEVKIT_BUILD_BENCHMARKS=OFF -DEVKIT_WERROR=ON -DCMAKE_UNITY_BUILD=ON
cmake --build build-test -j "$jobs"
ctest --test-dir build-test --output-on-failure -j "$jobs"

if [ "${EVKIT_SKIP_FUZZ:-0}" != "1" ]; then
  echo "== Fuzzing every reader (libFuzzer, ${EVKIT_FUZZ_SECONDS:-20} s each)"
  bash scripts/fuzz.sh "${EVKIT_FUZZ_SECONDS:-20}" text hdf5 aedat2 aedat3 aedat4 evt2 evt3 dat
fi

if [ "${EVKIT_SKIP_SANITIZE:-0}" != "1" ]; then
  echo "== AddressSanitizer + UBSan build and tests (not the Python module and its pytest suite: python3 is not instrumented)"
  cmake -S . -B build-asan -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DEVKIT_BUILD_TESTS=ON \
    -DEVKIT_BUILD_BENCHMARKS=OFF -DEVKIT_SANITIZE=ON -DEVKIT_WERROR=ON -DCMAKE_UNITY_BUILD=ON \
    -DCMAKE_CXX_FLAGS_RELWITHDEBINFO="-O2 -g1 -DNDEBUG -fno-sanitize-address-use-after-scope"
  # -g1: line tables for the reports, a quicker build. Use-after-scope off: it poisons and unpoisons
  # every small local array at each turn of the inner loops (the hash grid's corners and weights
  # among them), which made the BeNeRF tests 1.6 times slower (54 -> 34 s for the slowest alone);
  # overflows of those arrays, use after free, leaks and undefined behaviour are still caught.
  cmake --build build-asan -j "$jobs"
  # libhdf5 1.10.8 leaks on its own error paths for corrupt files (tests/fuzz/lsan.supp says why);
  # evkit's HDF5 leaks still show, as descriptors left open (tests/events/bad_files_test.cc).
  ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
    LSAN_OPTIONS="suppressions=$PWD/tests/fuzz/lsan.supp" \
    ctest --test-dir build-asan --output-on-failure -j "$jobs"
fi
