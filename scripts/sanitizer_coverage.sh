#!/usr/bin/env bash
# What the sanitizer pass leaves unreached. The long accuracy tests skip there
# (kReachedByShorterTests in tests/test_util.h, and the 346 x 260 simulations) because shorter tests
# reach their code; this measures that claim. It builds the tests with gcov (build-coverage), runs
# the suite as the sanitizer pass runs it (EVKIT_TEST_AS_SANITIZED=1), then each test that skipped,
# alone, and prints for each the lines of evkit's libraries that only it reached. Not part of CI;
# about 25 minutes on 2 cores. Run it after adding a test that skips, or code that only such a test
# reaches.
set -euo pipefail
cd "$(dirname "$0")/.."

jobs=$(nproc)
build=build-coverage
# Counters without atomic updates: with them the OpenMP tests ran 4 times slower, and a lost
# increment between two threads still leaves a reached line above zero.
cmake -S . -B "$build" -G Ninja -DCMAKE_BUILD_TYPE=Release -DEVKIT_BUILD_TESTS=ON \
  -DEVKIT_BUILD_BENCHMARKS=OFF -DEVKIT_PYTHON=OFF -DCMAKE_UNITY_BUILD=ON \
  -DCMAKE_CXX_FLAGS="--coverage -fprofile-update=single" -DCMAKE_EXE_LINKER_FLAGS=--coverage >/dev/null
cmake --build "$build" -j "$jobs" >/dev/null
out=$build/sanitizer-coverage
rm -rf "$out"
mkdir -p "$out"

# The lines of evkit's libraries (not the tests') that the runs since the last reset reached.
reached() {
  find "$build/" -name '*.gcda' -not -path '*/tests/*' -print0 |
    xargs -0 -r -n 8 gcov --json-format --stdout 2>/dev/null |
    /usr/bin/python3 -c '
import json, sys
root = sys.argv[1] + "/"
for chunk in sys.stdin:
    if not chunk.strip():
        continue
    for f in json.loads(chunk)["files"]:
        name = f["file"]
        if name.startswith(root) and not name.startswith(root + "tests/"):
            for line in f["lines"]:
                if line["count"] > 0:
                    print(name[len(root):] + ":" + str(line["line_number"]))
' "$PWD" | sort -u
}
reset() { find "$build/" -name '*.gcda' -delete; }

# The sanitizer pass's tests: not Slurm, the installed package or Python, which it does not build.
reset
EVKIT_TEST_AS_SANITIZED=1 ctest --test-dir "$build" -j "$jobs" -E '^(Slurm|Install|Python)\.' \
  > "$out/pass.log" || { tail -30 "$out/pass.log"; exit 1; }
reached > "$out/pass.lines"
sed -n 's/.*Test *#[0-9]*: \([^ ]*\) .*\*\*\*Skipped.*/\1/p' "$out/pass.log" > "$out/skipped"
echo "The sanitizer pass reaches $(wc -l < "$out/pass.lines") lines of evkit's libraries;" \
  "$(wc -l < "$out/skipped") tests skip there."

left=0
while read -r name; do
  reset
  ctest --test-dir "$build" -R "^${name//./\\.}\$" > "$out/$name.log" || {
    echo "$name: failed alone (log: $out/$name.log)"
    exit 1
  }
  reached | comm -13 "$out/pass.lines" - > "$out/$name.lines"
  n=$(wc -l < "$out/$name.lines")
  left=$((left + n))
  # Consecutive lines of a file shown as one range.
  ranges=$(awk -F: '{ if ($1 == f && $2 == e + 1) e = $2; else { if (f != "") printf "%s:%s%s ", f, s, (e > s ? "-" e : ""); f = $1; s = e = $2 } }
                    END { if (f != "") printf "%s:%s%s", f, s, (e > s ? "-" e : "") }' \
             < <(sort -t: -k1,1 -k2,2n "$out/$name.lines"))
  echo "$name: $n lines only it reaches${ranges:+: $ranges}"
done < "$out/skipped"
echo "In all $left lines (with repeats) are reached only by tests that skip in the sanitizer pass."
