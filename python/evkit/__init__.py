"""evkit: event cameras in Python, on evkit's C++ core.

Read, stream, write and convert recordings (numpy without copies), accumulate event
representations, simulate events from video, synthesise observations with ground truth, and
deblur a blurry frame with its events (EDI or BeNeRF).

    import evkit
    rec = evkit.read("recording.aedat4")       # rec.t, rec.x, rec.y, rec.p: views, no copy
    frame = evkit.accumulate(rec, repr="frame")
    obs = evkit.synth("planes_blur40")
    result = evkit.deblur(obs, "benerf", budget="fast")

Conventions: t int64 microseconds, x right and y down from the top-left, p +1 ON / -1 OFF,
images float32 linear in [0, 1] (colour as RGB). Errors raise evkit.Error (a ValueError) with the
message the command line prints; problems with files raise evkit.FileError (also an OSError).
"""

from ._evkit import (  # noqa: F401  (the public API)
    DeblurResult,
    Error,
    EventSlicer,
    Events,
    FileError,
    Frame,
    Observation,
    Recording,
    Stream,
    Window,
    accumulate,
    deblur,
    deblur_recording,
    method_help,
    methods,
    open,
    read,
    scenes,
    simulate,
    suite,
    synth,
    write,
)

__version__ = "0.1.0"

for _cls in (DeblurResult, EventSlicer, Events, Frame, Observation, Recording, Stream, Window):
    _cls.__module__ = __name__  # help() and repr() say evkit.X, not evkit._evkit.X
del _cls


def slices(source, *, by_time=None, by_count=None, chunk=1 << 20, start=None, end=None):
    """Windows (evkit.Window) of a file or of events, by time (µs) or by count, in bounded memory.

    source: a path (streamed with evkit.open) or events as evkit.write takes them. Exactly one of
    by_time and by_count. With a path, start/end (µs) restrict the stream.
    """
    if (by_time is None) == (by_count is None):
        raise Error("slices: give exactly one of by_time and by_count")
    slicer = EventSlicer.by_time(by_time) if by_time is not None else EventSlicer.by_count(by_count)
    if isinstance(source, str) or hasattr(source, "__fspath__"):
        with open(str(source), chunk=chunk, start=start, end=end) as stream:
            for part in stream:
                yield from slicer.accept(part)
    else:
        yield from slicer.accept(source)
    yield from slicer.finish()


def tqdm_progress(bar):
    """A deblur progress callback that drives a tqdm bar: evkit.deblur(obs, "benerf",
    progress=evkit.tqdm_progress(tqdm.tqdm()))."""

    def update(done, total, loss):
        bar.total = total
        bar.n = done
        bar.set_postfix(loss=f"{loss:.4g}", refresh=False)
        bar.refresh()

    return update
