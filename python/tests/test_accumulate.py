"""Representations and the slicer against numpy references."""
import numpy as np
import pytest

import evkit


def signed_reference(ev, w, h, c_on=1.0, c_off=1.0):
    out = np.zeros((h, w), np.float64)
    np.add.at(out, (ev["y"], ev["x"]), np.where(ev["p"] > 0, c_on, -c_off))
    return out


def test_frame_counts_normalized(events):
    frame = evkit.accumulate(events, 64, 48, repr="frame", c_on=0.2, c_off=0.3)
    assert frame.shape == (48, 64) and frame.dtype == np.float32
    np.testing.assert_allclose(frame, signed_reference(events, 64, 48, 0.2, 0.3), atol=1e-5)
    counts = evkit.accumulate(events, 64, 48, repr="counts")
    assert counts.shape == (2, 48, 64)
    on = np.zeros((48, 64))
    np.add.at(on, (events["y"][events["p"] > 0], events["x"][events["p"] > 0]), 1)
    np.testing.assert_array_equal(counts[0], on)
    assert counts.sum() == len(events)
    norm = evkit.accumulate(events, 64, 48, repr="normalized")
    ref = signed_reference(events, 64, 48)
    np.testing.assert_allclose(norm, ref / np.linalg.norm(ref), atol=1e-6)


def test_timesurface_and_voxel(events):
    t_ref = int(events["t"][-1])
    ts = evkit.accumulate(events, 64, 48, repr="timesurface", tau_us=10_000.0)
    assert ts.shape == (2, 48, 64)
    last = {}
    for t, x, y, p in events:
        last[(0 if p > 0 else 1, y, x)] = t
    for (c, y, x), t in list(last.items())[:50]:
        assert ts[c, y, x] == pytest.approx(np.exp(-(t_ref - t) / 10_000.0), rel=1e-5)
    vox = evkit.accumulate(events, 64, 48, repr="voxel", bins=4)
    assert vox.shape == (4, 48, 64)
    # Bilinear in time: the bins together hold each event's polarity once.
    np.testing.assert_allclose(vox.sum(axis=0), signed_reference(events, 64, 48), atol=1e-4)


def test_accumulate_refuses(events):
    with pytest.raises(evkit.Error, match="repr must be"):
        evkit.accumulate(events, 64, 48, repr="histogram")
    with pytest.raises(evkit.Error, match="both width and height"):
        evkit.accumulate(events, 64)
    with pytest.raises(evkit.Error, match="outside the 32x32 sensor"):
        evkit.accumulate(events, 32, 32)


def test_slicer_by_time_and_count(events):
    t0 = int(events["t"][0])
    windows = list(evkit.slices(events, by_time=10_000))
    assert [w.index for w in windows] == list(range(len(windows)))
    assert sum(len(w.events) for w in windows) == len(events)
    for w in windows:
        assert w.t_begin == t0 + 10_000 * w.index and w.t_end == w.t_begin + 10_000
        inside = events["t"][(events["t"] >= w.t_begin) & (events["t"] < w.t_end)]
        np.testing.assert_array_equal(w.events.t, inside)
    counted = list(evkit.slices(events, by_count=300))
    assert [len(w.events) for w in counted] == [300, 300, 300, 100]
    # Fed in pieces, the slicer gives the same windows.
    slicer = evkit.EventSlicer.by_count(300)
    pieces = []
    for part in np.array_split(events, 7):
        pieces += slicer.accept(part)
    pieces += slicer.finish()
    assert [len(w.events) for w in pieces] == [300, 300, 300, 100]
    np.testing.assert_array_equal(pieces[2].events.t, counted[2].events.t)


def test_slices_of_a_file(real):
    path = real("dvxplorer_sample.aedat4")
    rec = evkit.read(path)
    windows = list(evkit.slices(path, by_time=50_000, chunk=9_999))
    assert sum(len(w.events) for w in windows) == len(rec)
    assert windows[0].t_begin == rec.t[0]
