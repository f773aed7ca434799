"""What the reference scripts share: the best of a few timed runs, and one report line."""
import time


def best_of(fn, repeats=3):
    """(seconds of the fastest run, the last run's result)."""
    best, result = float("inf"), None
    for _ in range(repeats):
        start = time.perf_counter()
        result = fn()
        best = min(best, time.perf_counter() - start)
    return best, result


def report(name, seconds, n, reference=None, width=34):
    """Prints M events/s (and the ratio against `reference`, in M events/s); returns the rate."""
    rate = n / seconds / 1e6
    ratio = f"  {rate / reference:5.2f}x h5py" if reference else ""
    print(f"{name:<{width}} {rate:8.1f} M events/s  ({seconds * 1e3:7.0f} ms){ratio}")
    return rate


def read_h5py_columns(path):
    """The four event columns of an HDF5 file, read whole with h5py."""
    import h5py

    with h5py.File(path, "r") as f:
        e = f["events"]
        return e["t"][:], e["x"][:], e["y"][:], e["p"][:]
