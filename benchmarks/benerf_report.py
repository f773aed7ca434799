"""Summarises benerf_suite.sh's output: a markdown table per scene and the mean per method.

The rotation error compares the rotation over the exposure, R(start)^T R(end), of the estimate
with the ground truth's (gt/poses.txt): the angle between the two, in degrees."""
import json
import math
import os
import sys

import numpy as np


def rotation(q):
    x, y, z, w = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def exposure_rotation(path):
    a = np.loadtxt(path)
    return rotation(a[0, 4:8]).T @ rotation(a[-1, 4:8])


def angle_deg(R):
    return math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(R) - 1) / 2))))


def main(suite, out):
    rows, means = [], {}
    for scene in sorted(os.listdir(out)):
        folder = os.path.join(out, scene)
        if not os.path.isdir(folder) or scene.endswith(".partial"):
            continue
        truth = exposure_rotation(os.path.join(suite, scene, "gt", "poses.txt"))
        for method in ("blurry", "edi", "benerf"):
            summary = os.path.join(folder, method, "summary.json")
            if not os.path.exists(summary):
                continue
            s = json.load(open(summary))
            m = s["metrics"]
            rot = ""
            trajectory = os.path.join(folder, method, "trajectory.txt")
            if os.path.exists(trajectory):
                rot = "%.2f" % angle_deg(exposure_rotation(trajectory).T @ truth)
            rows.append("| %s | %s | %.2f | %.4f | %s | %.1f |" % (scene, method, m["psnr_mid"], m["ssim_mid"], rot or "-", s["wall_time_s"]))
            acc = means.setdefault(method, [0.0, 0.0, 0.0, 0])
            acc[0] += m["psnr_mid"]
            acc[1] += m["ssim_mid"]
            acc[2] += s["wall_time_s"]
            acc[3] += 1
    print("| scene | method | PSNR (dB) | SSIM | rotation error (deg) | wall time (s) |")
    print("|---|---|---|---|---|---|")
    print("\n".join(rows))
    print()
    print("| method | mean PSNR (dB) | mean SSIM | mean wall time (s) | scenes |")
    print("|---|---|---|---|---|")
    for method, (p, s, t, n) in means.items():
        print("| %s | %.2f | %.4f | %.1f | %d |" % (method, p / n, s / n, t / n, n))


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
