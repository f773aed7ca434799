"""Deblurring from Python: a tiny EDI and BeNeRF run, progress, errors, and Ctrl-C."""
import os
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

import evkit


@pytest.fixture(scope="module")
def obs():
    return evkit.synth("planes", blur_px=10, width=64, height=48)


def psnr(a, b):
    return 10 * np.log10(1 / np.mean((np.asarray(a, np.float64) - b) ** 2))


def test_edi_is_sharper_than_blurry(obs):
    result = evkit.deblur(obs, "edi")
    mid = (obs.exposure[0] + obs.exposure[1]) // 2
    assert mid in result.times and result.frames.shape == (len(result.times), 48, 64)
    truth = next(f.image for f in obs.gt_frames if f.exposure_start == mid)
    frame = result.frames[list(result.times).index(mid)]
    assert psnr(frame, truth) > psnr(obs.blurry, truth) + 3
    metrics = result.summary["metrics"]
    assert metrics["psnr_mid"] == pytest.approx(psnr(frame, truth), abs=0.05)
    assert result.trajectory is None and result.summary["method"] == "edi"
    assert result.summary["account"].startswith("thresholds ")  # given or searched, in words


def test_tiny_benerf_with_progress(obs):
    seen = []
    mid = (obs.exposure[0] + obs.exposure[1]) // 2
    result = evkit.deblur(obs, "benerf", times=[obs.exposure[0], mid], field="hash", iterations=75, seed=3, threads=1, progress=lambda *a: seen.append(a))
    assert [s[:2] for s in seen] == [(25, 75), (50, 75), (75, 75)]  # every 25 steps
    assert all(np.isfinite(s[2]) for s in seen)
    assert list(result.times) == [obs.exposure[0], mid]
    assert result.frames.shape == (2, 48, 64) and np.all(np.isfinite(result.frames))
    traj = result.trajectory
    assert traj.ndim == 2 and traj.shape[1] == 8
    np.testing.assert_allclose(np.linalg.norm(traj[:, 4:], axis=1), 1, atol=1e-9)
    assert traj[0, 0] == pytest.approx(obs.exposure[0] * 1e-6)
    assert result.summary["settings"]["iterations"] == "75"
    assert result.summary["account"].startswith("the hash field, its trajectory from ")


def test_progress_exception_stops_the_run(obs):
    def stop(done, total, loss):
        raise RuntimeError(f"stopped at {done}")

    with pytest.raises(RuntimeError, match="stopped at 25"):
        evkit.deblur(obs, "benerf", field="hash", iterations=100, progress=stop)


def test_deblur_refuses(obs):
    with pytest.raises(evkit.Error, match="unknown"):
        evkit.deblur(obs, "sharpen")
    with pytest.raises(evkit.Error, match="unknown setting 'itterations'"):
        evkit.deblur(obs, "benerf", itterations=10)
    with pytest.raises(evkit.Error, match="outside the exposure"):
        evkit.deblur(obs, "edi", times=[0])
    assert set(evkit.methods()) >= {"edi", "benerf", "blurry"}
    assert "budget" in evkit.method_help("benerf")


def test_ctrl_c_interrupts_a_long_run(tmp_path):
    script = textwrap.dedent("""
        import sys, evkit
        obs = evkit.synth("planes", blur_px=10, width=64, height=48)
        print("ready", flush=True)
        try:
            evkit.deblur(obs, "benerf", field="hash", iterations=200000)
        except KeyboardInterrupt:
            print("interrupted", flush=True)
            sys.exit(3)
    """)
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True,
                            env=dict(os.environ, OMP_NUM_THREADS="1"))
    try:
        assert proc.stdout.readline().strip() == "ready"
        time.sleep(1.0)
        sent = time.monotonic()
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=60)
        assert proc.returncode == 3 and "interrupted" in out
        assert time.monotonic() - sent < 30
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_deblur_recording_resumes(tmp_path):
    # A two-frame recording from two synthesised observations' frames and events.
    first = evkit.synth("planes", blur_px=6, width=48, height=36, seed=1)
    second = evkit.synth("planes", blur_px=6, width=48, height=36, seed=2)
    shift = 200_000
    ev = np.concatenate([first.events.events, second.events.events])
    ev["t"][len(first.events):] += shift
    frames = [evkit.Frame(first.blurry, *first.exposure),
              evkit.Frame(second.blurry, first.exposure[0] + shift, first.exposure[1] + shift)]
    path = tmp_path / "rec.h5"
    evkit.write(path, ev, frames=frames, width=48, height=36)
    seen = []
    summary = evkit.deblur_recording(path, tmp_path / "job", latent=3,
                                     progress=lambda *a: seen.append(a))
    assert summary == {"chosen": 2, "assigned": 2, "done": 2, "skipped": 0, "failed": 0, "merged": True}
    assert seen == [(1, 2, 0, "ok"), (2, 2, 1, "ok")]
    rows = (tmp_path / "job" / "frames.csv").read_text().splitlines()
    assert len(rows) == 3 and all(",ok," in r for r in rows[1:])
    again = evkit.deblur_recording(path, tmp_path / "job", latent=3)
    assert again["skipped"] == 2 and again["done"] == 0
    with pytest.raises(evkit.FileError, match="holds another job"):
        evkit.deblur_recording(path, tmp_path / "job", latent=4)
