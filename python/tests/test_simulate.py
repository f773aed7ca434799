"""The simulator, the scene generator and observations built from arrays."""
import numpy as np
import pytest

import evkit


def test_simulate_brightening_ramp():
    # log(I + eps) rises by 0.21 a frame: with C = 0.2, one ON event per pixel and frame.
    frames = [np.full((8, 10), 0.1 * np.exp(0.21 * k) - 1e-3, np.float32) for k in range(6)]
    times = np.arange(6, dtype=np.int64) * 1000
    ev = evkit.simulate(frames, times, contrast=0.2)
    assert (ev.width, ev.height) == (10, 8)
    assert len(ev) == 80 * 5 and np.all(ev.p == 1)
    assert np.all(np.diff(ev.t) >= 0) and ev.t[0] > 0 and ev.t[-1] <= 5000
    # The k-th level is crossed at 0.2 k / 0.21 of the ramp: interpolated µs, not frame times.
    np.testing.assert_allclose(ev.t[::80], 1000 * 0.2 * np.arange(1, 6) / 0.21, atol=1)
    again = evkit.simulate(np.stack(frames), times, contrast=0.2)
    np.testing.assert_array_equal(again.t, ev.t)


def test_simulate_refuses():
    frames = np.zeros((3, 4, 4), np.float32)
    with pytest.raises(evkit.Error, match="one timestamp per frame"):
        evkit.simulate(frames, [0, 1])
    with pytest.raises(evkit.Error, match="timestamps must increase"):
        evkit.simulate(frames, [0, 2, 1])
    with pytest.raises(evkit.Error, match="contrast"):
        evkit.simulate(frames, [0, 1, 2], contrast=-1)


def test_synth_observation_and_folder_round_trip(tmp_path):
    obs = evkit.synth("planes", blur_px=8, width=48, height=36, out=tmp_path / "obs")
    assert (obs.width, obs.height) == (48, 36) and obs.blurry.shape == (36, 48)
    start, end = obs.exposure
    assert end - start == 100_000
    assert obs.contrast == (0.2, 0.2)
    assert len(obs.events) > 1000 and np.all((obs.events.t >= start) & (obs.events.t <= end))
    assert len(obs.gt_frames) == 3 and obs.gt_poses.shape == (101, 8)
    q = obs.gt_poses[:, 4:]
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1, atol=1e-9)
    assert (tmp_path / "obs" / "blurry.png").exists()
    loaded = evkit.Observation.load(tmp_path / "obs")
    np.testing.assert_array_equal(loaded.events.t, obs.events.t)
    assert "planes" in evkit.scenes() and "planes_blur40" in evkit.suite("standard")


def test_observation_from_arrays(tmp_path):
    src = evkit.synth("planes", blur_px=8, width=48, height=36)
    ev = src.events.events  # a structured array
    obs = evkit.Observation(src.blurry, src.exposure, ev, calib=(43.2, 43.2, 23.5, 17.5), contrast=0.2)
    assert obs.calib["fx"] == 43.2 and obs.contrast == (0.2, 0.2) and obs.gt_poses is None
    assert not obs.blurry.flags.writeable  # a view of the observation's own frame
    np.testing.assert_array_equal(obs.events.x, src.events.x)
    obs.save(tmp_path / "saved")
    back = evkit.Observation.load(tmp_path / "saved")
    np.testing.assert_allclose(back.blurry, src.blurry, atol=1 / 65535)
    assert not obs.camera_assumed and not back.camera_assumed
    # No calibration: the camera is assumed, and a saved folder holds no calib.txt for it.
    bare = evkit.Observation(src.blurry, src.exposure, ev)
    assert bare.camera_assumed and bare.calib["fx"] == pytest.approx(0.9 * 48)
    bare.save(tmp_path / "bare")
    assert not (tmp_path / "bare" / "calib.txt").exists()
    assert evkit.Observation.load(tmp_path / "bare").camera_assumed
    with pytest.raises(evkit.Error, match="outside the 20x20 sensor"):
        evkit.Observation(np.zeros((20, 20), np.float32), src.exposure, ev)
    with pytest.raises(evkit.Error, match="end > start"):
        evkit.Observation(src.blurry, (5, 5), ev)
    with pytest.raises(evkit.Error, match="pixels must be float"):
        evkit.Observation(src.blurry.astype(np.int64), src.exposure, ev)
    with pytest.raises(evkit.FileError):
        evkit.Observation.load(tmp_path / "absent")
