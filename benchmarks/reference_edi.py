#!/usr/bin/python3
"""Reference for the EDI figures: one latent frame by the same exact per-pixel sum, vectorised
with numpy, on the files evkit_edi_bench wrote (1e6 events, 346x260), in the same hour.

    /usr/bin/python3 benchmarks/reference_edi.py /tmp/evkit-bench
"""
import sys
import time

import h5py
import numpy as np

folder = sys.argv[1] if len(sys.argv) > 1 else "/tmp/evkit-bench"
with h5py.File(f"{folder}/edi_events.h5", "r") as f:
    t, x, y, p = (f["events"][k][:] for k in "txyp")
blurry = np.load(f"{folder}/edi_blurry.npy")
h, w = blurry.shape
t0, t1, c = int(t[0]), int(t[0]) + 100000, 0.2


def latent(f_time):
    pix = y.astype(np.int64) * w + x
    order = np.lexsort((t, pix))  # events grouped by pixel, in time order
    pix_s, t_s, p_s = pix[order], t[order], p[order].astype(np.int64)
    level = np.cumsum(p_s)  # running level, reset per pixel below
    first = np.r_[0, np.flatnonzero(np.diff(pix_s)) + 1]
    level -= np.repeat(np.r_[0, level[first[1:] - 1]], np.diff(np.r_[first, len(pix_s)]))
    # Segment k of a pixel: from its event k-1 (or t0) to event k (or t1), at the level before event k.
    start = t_s.copy()
    start[first] = t0
    start[np.setdiff1d(np.arange(len(t_s)), first)] = t_s[np.setdiff1d(np.arange(len(t_s)), first) - 1]
    before = level - p_s
    integral = np.bincount(pix_s, weights=(t_s - start) * np.exp(c * before), minlength=h * w)
    last = np.r_[first[1:] - 1, len(pix_s) - 1]
    integral[pix_s[last]] += (t1 - t_s[last]) * np.exp(c * level[last])
    has = np.bincount(pix_s, minlength=h * w) > 0
    integral[~has] = t1 - t0
    at_f = np.bincount(pix_s, weights=np.where(t_s <= f_time, p_s, 0), minlength=h * w)
    return (blurry.ravel() * np.exp(c * at_f) * (t1 - t0) / integral).reshape(h, w)


best = float("inf")
for _ in range(3):
    start = time.perf_counter()
    latent(t0 + 50000)
    best = min(best, time.perf_counter() - start)
print(f"numpy EDI latent frame (346x260, {len(t)} events): {best * 1e3:.1f} ms")
