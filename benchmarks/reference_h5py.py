#!/usr/bin/python3
"""Reference figures for BENCHMARKS.md: reads the files that evkit_io_bench left in a folder with
h5py / numpy (Debian's python3-h5py, python3-numpy), in the same hour, so that evkit's
throughput can be given as a ratio against it.

    /usr/bin/python3 benchmarks/reference_h5py.py /tmp/evkit-bench
"""
import sys

import h5py
import numpy as np

from timing import best_of, read_h5py_columns, report

folder = sys.argv[1] if len(sys.argv) > 1 else "/tmp/evkit-bench"

for compression in ("none", "deflate", "blosc-lz4"):
    path = f"{folder}/events_{compression}.h5"
    seconds, cols = best_of(lambda: read_h5py_columns(path), 3)
    report(f"h5py read ({compression})", seconds, len(cols[0]))

with h5py.File(f"{folder}/events_none.h5", "r") as f:
    t, x, y, p = (f["events"][k][:] for k in "txyp")
    width, height = int(f.attrs["sensor_width"]), int(f.attrs["sensor_height"])


# Signed event frame the fast numpy way (bincount over linear pixel indices).
def accumulate():
    index = y.astype(np.int64) * width + x
    return np.bincount(index, weights=p, minlength=width * height).reshape(height, width)


seconds, _ = best_of(accumulate, 5)
report("numpy bincount signed frame", seconds, len(t))

# Text: numpy.loadtxt (C parser since numpy 1.23), one run: it is slow.
seconds, rows = best_of(lambda: np.loadtxt(f"{folder}/events.txt", skiprows=1), 1)
report("numpy.loadtxt text read", seconds, len(rows))
