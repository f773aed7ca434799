#!/usr/bin/env python3
"""Converts a recording to evkit's HDF5 and reads it back with h5py, checking every event.

    python3 examples/python/convert_to_hdf5.py RECORDING OUT.h5

evkit's HDF5 layout is DSEC's: events/t (int64 µs), events/x, events/y, events/p, plus
ms_to_idx, readable by h5py (deflate here; Blosc-LZ4 needs `hdf5plugin` or Debian's
hdf5-filter-plugin).
"""
import argparse

import h5py
import numpy as np

import evkit


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording")
    parser.add_argument("out")
    args = parser.parse_args()

    rec = evkit.read(args.recording)
    evkit.write(args.out, rec, frames=rec.frames, compression="deflate")

    with h5py.File(args.out, "r") as f:
        t = f["events/t"][:]
        x = f["events/x"][:]
        y = f["events/y"][:]
        p = np.where(f["events/p"][:] > 0, 1, -1)
        print(f"{args.out}: datasets {sorted(f['events'].keys())}, {len(t):,} events")
    for name, column in (("t", t), ("x", x), ("y", y), ("p", p)):
        if not np.array_equal(column, getattr(rec, name)):
            raise SystemExit(f"{name} differs after the round trip")
    print(f"h5py reads back the same {len(t):,} events (t {t[0]} .. {t[-1]} us)")


if __name__ == "__main__":
    main()
