#!/usr/bin/env python3
"""Reads a recording and plots an accumulated event frame with matplotlib.

    python3 examples/python/plot_recording.py RECORDING [--window-us 50000] [--out frame.png]

Any format evkit reads (AEDAT 2/3.1/4, HDF5, text, RPG folder, EVT 2/3, DAT). The columns
rec.t, rec.x, rec.y, rec.p are numpy views of evkit's buffers: no copy is made.
"""
import argparse

import matplotlib

matplotlib.use("Agg")  # files, no display needed
import matplotlib.pyplot as plt
import numpy as np

import evkit


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording")
    parser.add_argument("--window-us", type=int, default=50_000, help="events after the first one")
    parser.add_argument("--out", default="frame.png")
    args = parser.parse_args()

    rec = evkit.read(args.recording)
    print(f"{args.recording}: {len(rec):,} events, {rec.width}x{rec.height}, "
          f"{int((rec.p > 0).sum()):,} ON, t {rec.t[0]} .. {rec.t[-1]} us, {len(rec.frames)} frames")

    # A time window by binary search on the int64 µs column (no float seconds anywhere).
    begin = np.searchsorted(rec.t, rec.t[0])
    end = np.searchsorted(rec.t, rec.t[0] + args.window_us)
    window = rec.events[begin:end]
    frame = evkit.accumulate(window, rec.width, rec.height, repr="frame")
    surface = evkit.accumulate(window, rec.width, rec.height, repr="timesurface", tau_us=10_000.0)

    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    limit = max(1.0, float(np.percentile(np.abs(frame), 99)))
    axes[0].imshow(frame, cmap="bwr", vmin=-limit, vmax=limit)
    axes[0].set_title(f"signed count, {end - begin:,} events")
    axes[1].imshow(surface.max(axis=0), cmap="viridis")
    axes[1].set_title("time surface (tau 10 ms)")
    for ax in axes:
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(args.out, dpi=100)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
