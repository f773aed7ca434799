#!/usr/bin/python3
"""Reference for the simulator figures: the same model (crossings counted from the reference,
interpolated timestamps, per-pixel thresholds, events sorted per interval) vectorised with numpy, on
the same kind of video as evkit_simulator_bench, in the same hour.

    /usr/bin/python3 benchmarks/reference_simulator.py
"""
import time

import numpy as np


def video(w, h, frames):
    rng = np.random.default_rng(1)
    phase = rng.uniform(0, 2 * np.pi, size=h * w).astype(np.float32)
    return [np.exp(-2.0 + np.sin(phase + 0.5 * f)).astype(np.float32) - 1e-3 for f in range(frames)]


def simulate(frames, c=0.2, sigma=0.03, dt=1000):
    rng = np.random.default_rng(2)
    n = frames[0].size
    c_pos = np.maximum(0.01, c + sigma * rng.standard_normal(n)).astype(np.float32)
    c_neg = np.maximum(0.01, c + sigma * rng.standard_normal(n)).astype(np.float32)
    prev = np.log(frames[0] + 1e-3)
    ref = prev.copy()
    total, t0 = 0, 0
    for frame in frames[1:]:
        cur = np.log(frame + 1e-3)
        d = cur - ref
        up = d >= 0
        step = np.where(up, c_pos, -c_neg)
        k = np.floor(np.abs(d) / np.abs(step)).astype(np.int64)
        pix = np.repeat(np.arange(n), k)
        j = np.arange(k.sum()) - np.repeat(np.cumsum(k) - k, k) + 1
        da, db = (prev - ref)[pix], d[pix]
        frac = (j * step[pix] - da) / (db - da)
        t = t0 + np.rint(np.clip(frac, 0, 1) * dt).astype(np.int64)
        order = np.argsort(t, kind="stable")
        events = (t[order], pix[order] % 346, pix[order] // 346, up[pix][order])
        ref = ref + k * step
        prev = cur
        t0 += dt
        total += len(events[0])
    return total


for w, h in ((346, 260), (1280, 720)):
    frames = video(w, h, 9)
    start = time.perf_counter()
    events = simulate(frames)
    seconds = time.perf_counter() - start
    print(f"numpy reference {w}x{h}: {events / seconds / 1e6:6.1f} M events/s, {8 / seconds:7.1f} frames/s")
