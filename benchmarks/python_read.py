#!/usr/bin/python3
"""Reading events into numpy from Python: evkit.read and evkit.open against h5py on the same
HDF5 files, in the same run (the files evkit_io_bench leaves in its folder; run it first).

    PYTHONPATH=build/python /usr/bin/python3 benchmarks/python_read.py /tmp/evkit-bench

evkit.read's columns (.t .x .y .p) are views of the C++ buffers, so its figure should be the C++
reader's (BM_Hdf5ReadWhole); .events builds the structured array (one copy) on top.
"""
import sys

import evkit
from timing import best_of, read_h5py_columns, report

folder = sys.argv[1] if len(sys.argv) > 1 else "/tmp/evkit-bench"


def read_columns(path):
    rec = evkit.read(path)
    return rec.t, rec.x, rec.y, rec.p


for compression in ("none", "blosc-lz4", "deflate"):
    path = f"{folder}/events_{compression}.h5"
    seconds, cols = best_of(lambda: read_h5py_columns(path), 5)
    n = len(cols[0])
    h5py_rate = report(f"h5py, {compression}", seconds, n, width=40)
    seconds, cols = best_of(lambda: read_columns(path), 5)
    assert len(cols[0]) == n and cols[0].base is not None  # views of the C++ store
    report(f"evkit.read columns, {compression}", seconds, n, h5py_rate, width=40)
    seconds, ev = best_of(lambda: evkit.read(path).events, 5)
    report(f"evkit.read .events, {compression}", seconds, len(ev), h5py_rate, width=40)
    seconds, count = best_of(lambda: sum(len(c.t) for c in evkit.open(path, chunk=1 << 20)), 5)
    report(f"evkit.open 2^20 chunks, {compression}", seconds, count, h5py_rate, width=40)
