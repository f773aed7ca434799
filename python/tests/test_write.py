"""Writing from Python: round trips in every writable format, h5py on evkit's HDF5, the dtypes
callers have, and refusals with one clear message."""
import h5py
import numpy as np
import pytest

import evkit


@pytest.mark.parametrize("ext", ["txt", "h5", "aedat4"])
def test_round_trip(tmp_path, events, ext):
    path = tmp_path / f"out.{ext}"
    evkit.write(path, events, width=64, height=48)
    back = evkit.read(path)
    assert (back.width, back.height) == (64, 48)
    for name in "txyp":
        np.testing.assert_array_equal(getattr(back, name), events[name])


def test_hdf5_read_by_h5py(tmp_path, events):
    path = tmp_path / "out.h5"
    evkit.write(path, events, width=64, height=48, compression="deflate")
    with h5py.File(path, "r") as f:
        np.testing.assert_array_equal(f["events/t"][:], events["t"])
        np.testing.assert_array_equal(f["events/x"][:], events["x"])
        np.testing.assert_array_equal(f["events/y"][:], events["y"])
        # evkit's layout keeps p as 0/1 as DSEC does, or ±1: either way the same events.
        np.testing.assert_array_equal(np.where(f["events/p"][:] > 0, 1, -1), events["p"])


def test_frames_round_trip(tmp_path, events):
    rng = np.random.default_rng(3)
    image = rng.random((48, 64), dtype=np.float32)
    t0 = int(events["t"][0])
    frames = [evkit.Frame(image, t0, t0 + 10_000), (image[::-1].copy(), t0 + 20_000, t0 + 30_000)]
    for ext in ("h5", "aedat4"):
        path = tmp_path / f"framed.{ext}"
        evkit.write(path, events, frames=frames, width=64, height=48)
        back = evkit.read(path)
        assert len(back.frames) == 2
        f0 = back.frames[0]
        assert (f0.exposure_start, f0.exposure_end) == (t0, t0 + 10_000)
        assert f0.image.shape == (48, 64) and f0.image.dtype == np.float32
        np.testing.assert_allclose(f0.image, image, atol=1 / 255)  # 8-bit in the file
        np.testing.assert_allclose(np.asarray(back.frames[1]), image[::-1], atol=1 / 255)


def test_caller_dtypes_are_accepted(tmp_path, events):
    path = tmp_path / "dtypes.h5"
    columns = {
        "t": events["t"].astype(np.uint64),
        "x": events["x"].astype(np.int32),
        "y": events["y"].astype(np.float32),  # integral floats are pixels too
        "p": events["p"] > 0,  # bool
    }
    evkit.write(path, columns, width=64, height=48)
    back = evkit.read(path)
    np.testing.assert_array_equal(back.p, events["p"])
    evkit.write(path, (events["t"], events["x"], events["y"], (events["p"] > 0).astype(np.uint8)))
    back = evkit.read(path)
    np.testing.assert_array_equal(back.p, events["p"])
    assert (back.width, back.height) == (int(events["x"].max()) + 1, int(events["y"].max()) + 1)
    # evkit.Events from a read go back out without a conversion.
    evkit.write(tmp_path / "again.aedat4", back)
    np.testing.assert_array_equal(evkit.read(tmp_path / "again.aedat4").t, events["t"])


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda e: {**e, "t": e["t"] / 1e6}, r"t is float64.*precision"),
        (lambda e: {**e, "t": e["t"][::-1].copy()}, r"event 1: .*goes back in time"),
        (lambda e: {**e, "x": np.where(np.arange(len(e["x"])) == 5, 64, e["x"])},
         r"event 5: .*outside the 64x48 sensor"),
        (lambda e: {**e, "x": np.where(np.arange(len(e["x"])) == 3, -1, e["x"])},
         r"event 3: x = -1 is not a pixel"),
        (lambda e: {**e, "p": np.where(np.arange(len(e["p"])) == 9, 2, e["p"])},
         r"event 9: p = 2 is not a polarity"),
        (lambda e: {**e, "y": e["y"][:-1]}, r"columns of different lengths"),
        (lambda e: {**e, "x": e["x"] + 0.5}, r"is not a pixel"),
    ],
)
def test_bad_arrays_are_refused(tmp_path, events, change, message):
    columns = change({name: events[name] for name in "txyp"})
    path = tmp_path / "refused.h5"
    with pytest.raises(evkit.Error, match=message):
        evkit.write(path, columns, width=64, height=48)
    assert list(tmp_path.iterdir()) == []  # nothing under the final name, no temporary left


def test_wrong_kinds_are_refused(tmp_path):
    with pytest.raises(evkit.Error, match="expected evkit.Events"):
        evkit.write(tmp_path / "a.h5", 42)
    with pytest.raises(evkit.Error, match="one-dimensional"):
        evkit.write(tmp_path / "a.h5", {"t": np.zeros((2, 2), np.int64), "x": [0], "y": [0], "p": [1]})
    with pytest.raises(evkit.Error, match="cannot tell|extension|format"):
        evkit.write(tmp_path / "a.unknown", {"t": [1], "x": [0], "y": [0], "p": [1]})
    with pytest.raises(evkit.FileError):
        evkit.write(tmp_path / "no" / "such" / "dir.h5", {"t": [1], "x": [0], "y": [0], "p": [1]})
