"""Reading through Python: the real fixtures' facts, views without copies, streaming."""
import numpy as np
import pytest

import evkit


def test_dvxplorer_facts(real):
    rec = evkit.read(real("dvxplorer_sample.aedat4"))
    assert isinstance(rec, evkit.Recording)
    assert (rec.width, rec.height) == (320, 240)
    assert len(rec) == 111_954
    assert int((rec.p == 1).sum()) == 55_023 and int((rec.p == -1).sum()) == 56_931
    assert (rec.x.min(), rec.x.max(), rec.y.min(), rec.y.max()) == (0, 319, 0, 239)
    assert rec.t[0] == 1_605_537_493_718_345 and rec.t[-1] == 1_605_537_494_308_262
    assert (rec.x[0], rec.y[0], rec.p[0]) == (154, 204, -1)
    assert rec.info["camera"] == "DVXplorer_DXB00010"
    assert rec.info["counters"]["packets.EVTS"] == 59
    assert rec.info["counters"]["data_table_position"] == 945_243


def test_davis240_facts(real):
    rec = evkit.read(real("davis240c_translboxes.aedat"))
    assert (rec.width, rec.height) == (240, 180)
    assert len(rec) == 162_771
    assert int((rec.p > 0).sum()) == 82_944
    assert rec.t[0] == 294_976_755 and rec.t[-1] == 297_049_406
    # jAER's raw (x, y) = (156, 36), flipped to the top-left origin.
    assert (rec.x[0], rec.y[0], rec.p[0]) == (239 - 156, 179 - 36, -1)
    assert rec.info["counters"]["imu_words"] == 33_837  # a cut-off last IMU sample is tolerated
    rot = evkit.read(real("davis240c_rotdisk.aedat"))
    assert len(rot) == 374_296 and int((rot.p > 0).sum()) == 163_098
    assert (rot.t[0], rot.t[-1]) == (341_678, 3_508_437)


def test_columns_are_views_of_the_cpp_buffer(real):
    rec = evkit.read(real("dvxplorer_sample.aedat4"))
    t = rec.t
    assert t.dtype == np.int64 and rec.x.dtype == np.uint16 and rec.p.dtype == np.int8
    assert not t.flags.owndata  # numpy did not allocate it
    assert type(t.base).__name__ == "PyCapsule"  # its base holds the C++ store
    assert rec.t.ctypes.data == t.ctypes.data  # the same buffer every time: no copy
    assert not t.flags.writeable  # the store's order is an invariant
    with pytest.raises(ValueError):
        t[0] = 0
    del rec  # the view keeps the store alive
    assert t[0] == 1_605_537_493_718_345 and t[-1] == 1_605_537_494_308_262


def test_structured_array_matches_columns(real):
    rec = evkit.read(real("davis240c_rotdisk.aedat"))
    ev = rec.events
    assert ev.dtype.names == ("t", "x", "y", "p")
    assert ev.dtype == np.dtype([("t", "<i8"), ("x", "<u2"), ("y", "<u2"), ("p", "i1")])
    for name in "txyp":
        np.testing.assert_array_equal(ev[name], getattr(rec, name))
    assert rec.events is ev  # built once


def test_stream_in_chunks_equals_read(real):
    path = real("davis240c_translboxes.aedat")
    whole = evkit.read(path)
    sizes, parts = [], []
    with evkit.open(path, chunk=50_000) as stream:
        for chunk in stream:
            sizes.append(len(chunk))
            parts.append(chunk.t)
        assert stream.info["counters"]["dvs_events"] == 162_771
    assert max(sizes) <= 50_000 and sum(sizes) == len(whole)
    np.testing.assert_array_equal(np.concatenate(parts), whole.t)


def test_time_window(real):
    path = real("dvxplorer_sample.aedat4")
    whole = evkit.read(path)
    t0, t1 = int(whole.t[1000]), int(whole.t[50_000])
    part = evkit.read(path, start=t0, end=t1)
    expected = whole.t[(whole.t >= t0) & (whole.t < t1)]
    np.testing.assert_array_equal(part.t, expected)
    streamed = np.concatenate([c.t for c in evkit.open(path, chunk=7000, start=t0, end=t1)])
    np.testing.assert_array_equal(streamed, expected)


def test_prophesee_formats(real):
    dat = evkit.read(real("atis_ncars_sample.dat"))
    assert len(dat) > 0 and np.all(np.diff(dat.t) >= 0)
    evt2 = evkit.read(real("prophesee_gen3_evt2.raw"))
    assert len(evt2) > 0 and set(np.unique(evt2.p)) <= {-1, 1}


def test_bad_files_are_file_errors(tmp_path):
    with pytest.raises(evkit.FileError) as missing:
        evkit.read(tmp_path / "absent.h5")
    assert isinstance(missing.value, OSError) and isinstance(missing.value, ValueError)
    assert "absent.h5" in str(missing.value)
    bad = tmp_path / "bad.txt"
    bad.write_text("0.1 1 2 1\n0.2 3 x 0\n")
    with pytest.raises(evkit.FileError, match=r"bad.txt: line 2"):
        evkit.read(bad)
    with pytest.raises(evkit.FileError):
        list(evkit.open(bad))
    with pytest.raises(evkit.Error, match="unknown format|known"):
        evkit.read(bad, format="nope")
