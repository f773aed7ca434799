#!/usr/bin/env bash
# Fuzzes every reader with libFuzzer (clang, ASan + UBSan) for a given time each.
#
#   bash scripts/fuzz.sh [SECONDS_PER_READER=30] [READER ...]
#   EVKIT_FUZZ_SEED=7 bash scripts/fuzz.sh 600     # another random seed (default 1)
#
# Readers: text hdf5 aedat2 aedat3 aedat4 evt2 evt3 dat (default: all). Seed corpora come from the
# real fixtures in ../shared/fixtures/real (when present), from files the evkit binary writes, and
# from a few hand-made headers. A single allocation over 512 MB counts as a failure (no size field
# of a file may drive an allocation), as does a crash, a sanitizer report, or an input running
# longer than 10 s, a leaked allocation (LeakSanitizer) or a file descriptor left open after a read.
# Crashing inputs are left in build-fuzz/artifacts/; each reader's figures go to build-fuzz/work/.
set -euo pipefail
cd "$(dirname "$0")/.."

seconds=${1:-30}
shift || true
readers=("$@")
[ ${#readers[@]} -gt 0 ] || readers=(text hdf5 aedat2 aedat3 aedat4 evt2 evt3 dat)

CC=clang CXX=clang++ cmake -S . -B build-fuzz -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DEVKIT_FUZZ=ON \
  -DEVKIT_BUILD_TESTS=OFF -DEVKIT_BUILD_BENCHMARKS=OFF -DEVKIT_NATIVE=OFF -DCMAKE_UNITY_BUILD=ON >/dev/null
# The seeds are written by an evkit binary: the Release build's when there is one (scripts/test.sh
# builds it first), otherwise this build's. Only the readers need the fuzzing instrumentation, and
# the whole command-line program under it would take four times the fuzzers' own build.
evkit=build-test/cli/evkit
if [ ! -x "$evkit" ]; then
  evkit=build-fuzz/cli/evkit
  cmake --build build-fuzz -j "$(nproc)" --target evkit >/dev/null
fi
cmake --build build-fuzz -j "$(nproc)" --target evkit_fuzzers >/dev/null

# EVKIT_FUZZ_TAG keeps the work of runs side by side apart (two campaigns on two cores).
work=build-fuzz/work${EVKIT_FUZZ_TAG:+-$EVKIT_FUZZ_TAG}
seeds=build-fuzz/seeds${EVKIT_FUZZ_TAG:+-$EVKIT_FUZZ_TAG}
rm -rf "$work" "$seeds"
mkdir -p "$work" "$seeds" build-fuzz/artifacts
for r in "${readers[@]}"; do mkdir -p "$seeds/$r"; done

# Seeds written by evkit itself.
ASAN_OPTIONS=detect_leaks=0 "$evkit" demo --formats --events 300 --out "$work/demo" >/dev/null
cp "$work/demo/random.txt" "$seeds/text/" 2>/dev/null || true
[ -d "$seeds/hdf5" ] && ASAN_OPTIONS=detect_leaks=0 "$evkit" convert "$work/demo/random.txt" "$seeds/hdf5/a.h5" --compression deflate 2>/dev/null
[ -d "$seeds/hdf5" ] && ASAN_OPTIONS=detect_leaks=0 "$evkit" convert "$work/demo/random.txt" "$seeds/hdf5/b.h5" --compression blosc-lz4 2>/dev/null
# The other filters evkit decodes, as h5py writes them (the newest layouts and chunk indexes).
if [ -d "$seeds/hdf5" ] && /usr/bin/python3 -c 'import h5py' 2>/dev/null; then
  /usr/bin/python3 - "$seeds/hdf5/c.h5" "$seeds/hdf5/d.h5" <<'PY' || echo "fuzz: h5py could not write the seed files of other filters"
import sys
import h5py
import numpy as np
rng = np.random.default_rng(1)
n = 300
with h5py.File(sys.argv[1], "w", libver="latest") as f:
    g = f.create_group("events")
    g.create_dataset("t", data=np.sort(rng.integers(0, 10**5, n)), chunks=(100,), compression="gzip")
    g.create_dataset("x", data=rng.integers(0, 346, n).astype("u2"), chunks=(128,), compression="lzf")
    g.create_dataset("y", data=rng.integers(0, 260, n).astype("u2"), chunks=(n,), shuffle=True,
                     compression="gzip", fletcher32=True)
    g.create_dataset("p", data=rng.integers(0, 2, n).astype("i1") * 2 - 1)
with h5py.File(sys.argv[2], "w") as f:  # the plugins' filters (Debian's hdf5-filter-plugin)
    g = f.create_group("events")
    g.create_dataset("t", data=np.sort(rng.integers(0, 10**5, n)), chunks=(n,), compression=307)
    g.create_dataset("x", data=rng.integers(0, 346, n).astype("u2"), chunks=(n,), compression=32004,
                     compression_opts=(128,))
    g.create_dataset("y", data=rng.integers(0, 260, n).astype("u2"), chunks=(n,), compression=32001,
                     compression_opts=(0, 0, 0, 0, 5, 1, 5))
    g.create_dataset("p", data=rng.integers(0, 2, n).astype("i1") * 2 - 1, chunks=(n,),
                     compression=32004)
PY
fi
# Frames and attributes: evkit's layout with deflated frames chunked across frames and rows,
# event_utils' with times in seconds, polarities as h5py's bool (an enum) and timestamped images,
# and DSEC's (events without frames).
# Written to the work folder: the frames also seed the AEDAT 4.0 reader below.
if /usr/bin/python3 -c 'import h5py' 2>/dev/null; then
  /usr/bin/python3 - "$work/e.h5" "$work/f.h5" "$work/g.h5" <<'PY' || echo "fuzz: h5py could not write the seed files of frames"
import sys
import h5py
import numpy as np
rng = np.random.default_rng(2)
n = 200
with h5py.File(sys.argv[1], "w") as f:
    f.attrs["evkit_layout"] = 1
    f.attrs["sensor_width"] = 34
    f.attrs["sensor_height"] = 26
    g = f.create_group("events")
    g.create_dataset("t", data=np.sort(rng.integers(0, 10**5, n)))
    g.create_dataset("x", data=rng.integers(0, 34, n).astype("u2"))
    g.create_dataset("y", data=rng.integers(0, 26, n).astype("u2"))
    g.create_dataset("p", data=rng.integers(0, 2, n).astype("i1") * 2 - 1)
    fr = f.create_group("frames")
    fr.create_dataset("images", data=rng.integers(0, 255, (3, 26, 34)).astype("u1"),
                      chunks=(2, 13, 17), compression="gzip", shuffle=True)
    fr.create_dataset("exposure_start", data=np.array([0, 40000, 80000]))
    fr.create_dataset("exposure_end", data=np.array([10000, 50000, 90000]))
with h5py.File(sys.argv[2], "w") as f:
    f.attrs["sensor_resolution"] = np.array([26, 34])
    g = f.create_group("events")
    g.create_dataset("ts", data=np.sort(rng.random(n)) * 0.1)
    g.create_dataset("xs", data=rng.integers(0, 34, n).astype("u2"))
    g.create_dataset("ys", data=rng.integers(0, 26, n).astype("u2"))
    g.create_dataset("ps", data=rng.integers(0, 2, n).astype(bool))
    im = f.create_group("images")
    for i in range(2):
        d = im.create_dataset(f"image{i:09d}", data=rng.integers(0, 255, (26, 34)).astype("u1"),
                              chunks=(13, 34), compression="gzip" if i else None)
        d.attrs["timestamp"] = 0.03 + 0.05 * i
with h5py.File(sys.argv[3], "w") as f:  # DSEC's: times relative to a root t_offset, index at root
    t = np.sort(rng.integers(0, 9000, n)).astype("u4")
    g = f.create_group("events")
    g.create_dataset("t", data=t, chunks=(64,), compression="gzip")
    g.create_dataset("x", data=rng.integers(0, 34, n).astype("u2"), chunks=(64,), compression="gzip")
    g.create_dataset("y", data=rng.integers(0, 26, n).astype("u2"), chunks=(64,), compression="gzip")
    g.create_dataset("p", data=rng.integers(0, 2, n).astype("u1"), chunks=(64,), compression="gzip")
    f.create_dataset("ms_to_idx", data=np.searchsorted(t, np.arange(0, 10000, 1000)).astype("u8"))
    f.create_dataset("t_offset", data=np.int64(1_600_000_000_000_000))
PY
  [ -d "$seeds/hdf5" ] && cp "$work/e.h5" "$work/f.h5" "$work/g.h5" "$seeds/hdf5/" 2>/dev/null
fi
[ -d "$seeds/aedat4" ] && ASAN_OPTIONS=detect_leaks=0 "$evkit" convert "$work/demo/random.txt" "$seeds/aedat4/a.aedat4" 2>/dev/null
[ -d "$seeds/aedat4" ] && ASAN_OPTIONS=detect_leaks=0 "$evkit" convert "$work/demo/random.txt" "$seeds/aedat4/z.aedat4" --compression zstd 2>/dev/null
# Frames in AEDAT 4.0 (FRME packets, uncompressed so that mutations reach the FlatBuffers), from the
# HDF5 seed of frames.
if [ -d "$seeds/aedat4" ] && [ -f "$work/e.h5" ]; then
  ASAN_OPTIONS=detect_leaks=0 "$evkit" convert "$work/e.h5" "$seeds/aedat4/f.aedat4" --compression none >/dev/null 2>&1
fi

# Prefixes of the real recordings (the AEDAT 2.0 headers alone are ~175 kB).
fixtures=../shared/fixtures/real
if [ -d "$fixtures" ]; then
  [ -d "$seeds/aedat2" ] && head -c 180000 "$fixtures/davis240c_translboxes.aedat" > "$seeds/aedat2/translboxes.aedat"
  [ -d "$seeds/aedat2" ] && cp "$fixtures/davis346red_header_only.aedat" "$seeds/aedat2/"
  [ -d "$seeds/aedat4" ] && head -c 60000 "$fixtures/dvxplorer_sample.aedat4" > "$seeds/aedat4/dvxplorer.aedat4"
  [ -d "$seeds/evt2" ] && head -c 40000 "$fixtures/prophesee_gen3_evt2.raw" > "$seeds/evt2/gen3.raw"
  [ -d "$seeds/dat" ] && cp "$fixtures/atis_ncars_sample.dat" "$seeds/dat/"
else
  echo "fuzz: ../shared/fixtures/real absent; seeding from hand-made files only"
fi
# Hand-made seeds for formats without a public recording.
[ -d "$seeds/aedat3" ] && printf '#!AER-DAT3.1\r\n#Source 1: DAVIS240C\r\n#!END-HEADER\r\n\x01\x00\x01\x00\x08\x00\x00\x00\x04\x00\x00\x00\x00\x00\x00\x00\x01\x00\x00\x00\x01\x00\x00\x00\x01\x00\x00\x00\x07\x00\x02\x00\x10\x00\x00\x00' > "$seeds/aedat3/a.aedat"
[ -d "$seeds/evt3" ] && printf '%% evt 3.0\n%% format EVT3;height=720;width=1280\n%% end\n\x01\x80\x05\x60\x0a\x00\x03\x2a\x64\x30\x05\x40\x80\x50' > "$seeds/evt3/a.raw"
[ -d "$seeds/evt2" ] && printf '%% evt 2.0\n%% geometry 640x480\n\x0a\x00\x00\x80\x09\x38\x40\x11' > "$seeds/evt2/a.raw"
[ -d "$seeds/dat" ] && printf '%% Version 2\n%% Width 304\n%% Height 240\n\x0c\x08\x64\x00\x00\x00\x2c\x41\x04\x10' > "$seeds/dat/a.dat"

# One reader per core at a time: each fuzzer runs on one thread, so on 2 cores two at once take the
# time of one.
fuzz_one() {
  local r=$1 corpus="$work/corpus-$1"
  mkdir -p "$corpus"
  ASAN_OPTIONS=detect_leaks=1:allocator_may_return_null=0 LSAN_OPTIONS=suppressions=tests/fuzz/lsan.supp \
    EVKIT_FUZZ_DIR="$work" \
    "build-fuzz/tests/fuzz/fuzz_$r" "$corpus" "$seeds/$r" -max_total_time="$seconds" -timeout=10 \
    -malloc_limit_mb=512 -rss_limit_mb=3000 -max_len=262144 -seed="${EVKIT_FUZZ_SEED:-1}" -print_final_stats=1 \
    -artifact_prefix="build-fuzz/artifacts/$r-" > "$work/$r.log" 2>&1
}
slots=$(nproc)
declare -A pid_of
for r in "${readers[@]}"; do
  while [ "$(jobs -rp | wc -l)" -ge "$slots" ]; do wait -n || true; done
  echo "== fuzz $r for ${seconds}s"
  fuzz_one "$r" &
  pid_of[$r]=$!
done

failed=0
for r in "${readers[@]}"; do
  if ! wait "${pid_of[$r]}"; then
    echo "fuzz $r: FAILED (log: $work/$r.log)"
    tail -40 "$work/$r.log"
    failed=1
  else
    echo "fuzz $r:"
    grep -E "stat::number_of_executed_units|cov:" "$work/$r.log" | tail -2 | sed "s/^/  /"
    echo "  corpus: $(ls "$work/corpus-$r" | wc -l) inputs"
  fi
done
exit $failed
