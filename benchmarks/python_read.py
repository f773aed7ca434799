#!/usr/bin/python3
"""Reading events into numpy from Python: evkit.read and evkit.open against h5py on the same
HDF5 files, in the same run (the files evkit_io_bench leaves in its folder; run it first).

    PYTHONPATH=build/python /usr/bin/python3 benchmarks/python_read.py /tmp/evkit-bench

evkit.read's columns (.t .x .y .p) are views of the C++ buffers, so its figure should be the C++
reader's (BM_Hdf5ReadWhole); .events builds the structured array (one copy) on top.
"""
import sys
import time

import h5py
import numpy as np

import evkit

folder = sys.argv[1] if len(sys.argv) > 1 else "/tmp/evkit-bench"


def best_of(fn, repeats=5):
    best, result = float("inf"), None
    for _ in range(repeats):
        start = time.perf_counter()
        result = fn()
        best = min(best, time.perf_counter() - start)
    return best, result


def report(name, seconds, n, reference=None):
    rate = n / seconds / 1e6
    ratio = f"  {rate / reference:5.2f}x h5py" if reference else ""
    print(f"{name:<40} {rate:8.1f} M events/s  ({seconds * 1e3:6.0f} ms){ratio}")
    return rate


for compression in ("none", "blosc-lz4", "deflate"):
    path = f"{folder}/events_{compression}.h5"

    def read_h5py():
        with h5py.File(path, "r") as f:
            e = f["events"]
            return e["t"][:], e["x"][:], e["y"][:], e["p"][:]

    def read_evkit():
        rec = evkit.read(path)
        return rec.t, rec.x, rec.y, rec.p

    def read_structured():
        return evkit.read(path).events

    def stream_evkit():
        return sum(len(chunk.t) for chunk in evkit.open(path, chunk=1 << 20))

    seconds, cols = best_of(read_h5py)
    n = len(cols[0])
    h5 = report(f"h5py, {compression}", seconds, n)
    seconds, cols = best_of(read_evkit)
    assert len(cols[0]) == n and cols[0].base is not None
    report(f"evkit.read columns, {compression}", seconds, n, h5)
    seconds, ev = best_of(read_structured)
    report(f"evkit.read .events, {compression}", seconds, len(ev), h5)
    seconds, count = best_of(stream_evkit)
    report(f"evkit.open 2^20 chunks, {compression}", seconds, count, h5)
