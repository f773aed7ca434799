"""Whatever arrays a caller passes: an evkit.Error or a result, never a crash; nothing leaked
(memory, file descriptors) by reads, failed reads and failed writes."""
import os
import resource

import numpy as np
import pytest

import evkit

DTYPES = [np.int8, np.uint8, np.int16, np.uint16, np.int32, np.uint32, np.int64, np.uint64,
          np.float16, np.float32, np.float64, np.bool_, np.complex64]


def random_column(rng, n):
    dtype = DTYPES[rng.integers(len(DTYPES))]
    values = rng.integers(-5, 70_000, n) if rng.random() < 0.5 else rng.integers(-2, 3, n)
    if rng.random() < 0.3:
        values = np.sort(values)
    with np.errstate(all="ignore"):
        return values.astype(dtype)


def test_random_arrays_never_crash(tmp_path):
    rng = np.random.default_rng(11)
    outcomes = {"ok": 0, "refused": 0}
    for i in range(300):
        n = int(rng.integers(0, 50))
        columns = {  # valid events in random dtypes, then one column (or none) made random
            "t": np.sort(rng.integers(0, 10**6, n)).astype(DTYPES[rng.integers(4, 8)]),
            "x": rng.integers(0, 64, n).astype(DTYPES[rng.integers(1, 11)]),
            "y": rng.integers(0, 48, n).astype(DTYPES[rng.integers(1, 11)]),
            "p": rng.integers(0, 2, n).astype(DTYPES[rng.integers(0, 12)]),
        }
        spoilt = "txyp?"[rng.integers(5)]
        if spoilt != "?":
            columns[spoilt] = random_column(rng, n)
        if rng.random() < 0.1:
            columns["y"] = columns["y"][: max(0, n - 1)]
        if rng.random() < 0.05:
            columns["x"] = columns["x"].reshape(-1, 1)
        try:
            evkit.accumulate(columns, 64, 48)
            evkit.write(tmp_path / f"r{i}.h5", columns, width=64, height=48)
            outcomes["ok"] += 1
        except evkit.Error as e:
            assert str(e).startswith("events"), str(e)
            outcomes["refused"] += 1
    assert outcomes["ok"] > 50 and outcomes["refused"] > 50  # both paths were exercised
    written = {p.name for p in tmp_path.iterdir()}
    assert all(name.endswith(".h5") and "tmp" not in name for name in written)


def open_descriptors():
    return len(os.listdir("/proc/self/fd"))


@pytest.mark.skipif(not os.path.isdir("/proc/self/fd"), reason="needs /proc (Linux)")
def test_nothing_leaks(tmp_path, real):
    path = real("dvxplorer_sample.aedat4")
    bad = tmp_path / "bad.h5"
    bad.write_bytes(b"\x89HDF\r\n\x1a\n" + b"\0" * 100)
    evkit.read(path)  # warm up caches and lazily loaded libraries
    descriptors = open_descriptors()
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    for _ in range(30):
        rec = evkit.read(path)
        _ = rec.t, rec.events, evkit.accumulate(rec, repr="voxel")
        with pytest.raises(evkit.FileError):
            evkit.read(bad)
        with pytest.raises(evkit.Error):
            evkit.write(tmp_path / "x.h5", {"t": [2, 1], "x": [0, 0], "y": [0, 0], "p": [1, 1]})
        stream = evkit.open(path, chunk=10_000)
        next(stream)
        stream.close()
        del rec
    assert open_descriptors() == descriptors
    grown_mb = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - rss) / 1024
    assert grown_mb < 40, f"peak memory grew by {grown_mb:.0f} MB over 30 reads"
