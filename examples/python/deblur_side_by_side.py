#!/usr/bin/env python3
"""Deblurs an observation with EDI and BeNeRF and shows blurry | EDI | BeNeRF | ground truth.

    python3 examples/python/deblur_side_by_side.py [OBSERVATION_FOLDER] [--budget fast] [--out cmp.png]

Without a folder it synthesises one (evkit.synth: the 'planes' scene, 40 px of blur). A progress
bar shows BeNeRF's training (tqdm when installed); Ctrl-C stops it cleanly.
"""
import argparse
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

import evkit


def progress_printer():
    try:
        import tqdm

        return evkit.tqdm_progress(tqdm.tqdm(unit="step", desc="benerf"))
    except ImportError:

        def show(done, total, loss):
            print(f"\rbenerf {done}/{total} steps, loss {loss:.4g}", end="", file=sys.stderr)
            if done == total:
                print(file=sys.stderr)

        return show


def srgb(linear):
    c = np.clip(linear, 0, 1)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * c ** (1 / 2.4) - 0.055)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("observation", nargs="?")
    parser.add_argument("--budget", default="fast", help="BeNeRF budget: fast, balanced, 60s, 500")
    parser.add_argument("--size", type=int, nargs=2, default=(346, 260), metavar=("W", "H"),
                        help="size of the synthesised observation")
    parser.add_argument("--out", default="side_by_side.png")
    args = parser.parse_args()

    if args.observation:
        obs = evkit.Observation.load(args.observation)
    else:
        obs = evkit.synth("planes", blur_px=40, width=args.size[0], height=args.size[1])
    print(obs)
    mid = (obs.exposure[0] + obs.exposure[1]) // 2

    edi = evkit.deblur(obs, "edi", times=[mid])
    benerf = evkit.deblur(obs, "benerf", times=[mid], budget=args.budget,
                          progress=progress_printer())
    tiles = [("blurry", obs.blurry, None), ("EDI", edi.frames[0], edi.summary),
             ("BeNeRF", benerf.frames[0], benerf.summary)]
    truth = [f.image for f in obs.gt_frames if f.exposure_start == mid]
    if truth:
        tiles.append(("ground truth", truth[0], None))

    fig, axes = plt.subplots(1, len(tiles), figsize=(4 * len(tiles), 3.8))
    for ax, (name, image, summary) in zip(axes, tiles):
        ax.imshow(srgb(image), cmap="gray", vmin=0, vmax=1)
        if summary is not None and truth:
            name += f"\n{summary['metrics']['psnr_mid']:.2f} dB, {summary['wall_time_s']:.1f} s"
        ax.set_title(name)
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(args.out, dpi=100)
    for label, result in (("EDI", edi), ("BeNeRF", benerf)):
        m = result.summary["metrics"]
        print(f"{label:7s} PSNR {m['psnr_mid']:.2f} dB  SSIM {m['ssim_mid']:.4f}  "
              f"{result.summary['wall_time_s']:.2f} s")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
