# Type stubs of evkit (the compiled core evkit._evkit plus the Python front). Checked against the
# module by python/tests/test_api.py: every public name has a stub and every stub a name.
import os
from typing import Any, Callable, Iterator, Literal, Mapping, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

__version__: str

# Events as the functions take them: evkit.Events (shared, no copy), a structured array or a
# mapping with fields t, x, y, p, or a tuple (t, x, y, p). t integer µs; p ±1, 0/1 or bool.
EventsLike = Union["Events", npt.NDArray[Any], Mapping[str, npt.ArrayLike], Sequence[npt.ArrayLike]]
ImageLike = npt.ArrayLike
PathLike = Union[str, os.PathLike[str]]

class Error(ValueError):
    """A problem with evkit's input; the message names the file, the position and what was expected."""

class FileError(Error, OSError):
    """A bad or unreadable file (evkit.Error, OSError)."""

class Events:
    """Events in memory, shared with numpy without a copy."""
    @property
    def t(self) -> npt.NDArray[np.int64]: """Timestamps, int64 µs (a read-only view, no copy)."""
    @property
    def x(self) -> npt.NDArray[np.uint16]: """Columns, uint16 pixels (a view)."""
    @property
    def y(self) -> npt.NDArray[np.uint16]: """Rows, uint16 pixels (a view)."""
    @property
    def p(self) -> npt.NDArray[np.int8]: """Polarity, int8 +1 ON / -1 OFF (a view)."""
    @property
    def events(self) -> npt.NDArray[np.void]:
        """Structured array with fields t (<i8), x (<u2), y (<u2), p (i1): one copy, cached."""
    @property
    def width(self) -> int: ...
    @property
    def height(self) -> int: ...
    def __len__(self) -> int: ...

class Frame:
    """An intensity frame with its exposure interval."""
    def __init__(self, image: npt.NDArray[np.float32], exposure_start: int, exposure_end: int,
                 bit_depth: int = 8) -> None: ...
    @property
    def image(self) -> npt.NDArray[np.float32]:
        """float32 linear [0, 1]; (height, width) or (height, width, 3) RGB."""
    @property
    def exposure_start(self) -> int: """µs"""
    @property
    def exposure_end(self) -> int: """µs"""
    @property
    def bit_depth(self) -> int: """8 or 16: the source's depth."""
    def __array__(self, dtype: Any = None) -> npt.NDArray[np.float32]: ...

class Recording(Events):
    """Events with their frames and what the file says of itself."""
    @property
    def frames(self) -> list[Frame]: ...
    @property
    def info(self) -> dict[str, Any]:
        """format, layout, camera, counters, warnings[, event_count, calibration]."""

class Stream:
    """Chunks of a file in bounded memory (from evkit.open)."""
    def __iter__(self) -> Iterator[Recording]: ...
    def __next__(self) -> Recording: ...
    def __enter__(self) -> "Stream": ...
    def __exit__(self, *args: Any) -> None: ...
    def close(self) -> None: ...
    @property
    def info(self) -> dict[str, Any]: ...

class Window:
    """One window of an EventSlicer."""
    @property
    def index(self) -> int: ...
    @property
    def t_begin(self) -> int: """µs, included"""
    @property
    def t_end(self) -> int: """µs, excluded"""
    @property
    def events(self) -> Events: ...

class EventSlicer:
    """Cuts a stream into windows by time or by count, in bounded memory."""
    @staticmethod
    def by_time(length_us: int, width: int = 0, height: int = 0) -> "EventSlicer": ...
    @staticmethod
    def by_count(count: int, width: int = 0, height: int = 0) -> "EventSlicer": ...
    def set_origin(self, t_us: int) -> None: ...
    def set_end(self, t_us: int) -> None: ...
    def accept(self, events: EventsLike) -> list[Window]: ...
    def finish(self) -> list[Window]: ...

class Observation:
    """One blurry frame, its exposure, the events and the camera (with ground truth if any)."""
    def __init__(self, blurry: ImageLike, exposure: Tuple[int, int], events: EventsLike,
                 calib: Union[Mapping[str, Any], Sequence[float], None] = None,
                 contrast: Union[float, Tuple[float, float], None] = None) -> None: ...
    @staticmethod
    def load(folder: PathLike) -> "Observation": ...
    def save(self, folder: PathLike) -> None: ...
    @property
    def blurry(self) -> npt.NDArray[np.float32]: ...
    @property
    def exposure(self) -> Tuple[int, int]: """(start_us, end_us)"""
    @property
    def events(self) -> Events: ...
    @property
    def calib(self) -> dict[str, Any]: """fx, fy, cx, cy, distortion, width, height"""
    @property
    def contrast(self) -> Union[Tuple[float, float], None]: ...
    @property
    def gt_frames(self) -> list[Frame]: ...
    @property
    def gt_poses(self) -> Union[npt.NDArray[np.float64], None]: """N x 8 TUM rows"""
    @property
    def width(self) -> int: ...
    @property
    def height(self) -> int: ...
    @property
    def source(self) -> str: ...

class DeblurResult:
    """What evkit.deblur returns."""
    @property
    def frames(self) -> npt.NDArray[np.float32]: """(N, H, W) or (N, H, W, 3) RGB, linear [0, 1]"""
    @property
    def times(self) -> npt.NDArray[np.int64]: """µs, one per frame"""
    @property
    def trajectory(self) -> Union[npt.NDArray[np.float64], None]:
        """N x 8 TUM rows (t s, tx ty tz, qx qy qz qw; T_world_cam)"""
    @property
    def disparity(self) -> Union[npt.NDArray[np.float32], None]: ...
    @property
    def summary(self) -> dict[str, Any]:
        """As summary.json: method, settings, account (what the method did, in words), parameters,
        wall_time_s, timings_s, metrics, curves"""

def read(path: PathLike, start: Union[int, None] = None, end: Union[int, None] = None,
         format: Union[str, None] = None) -> Recording:
    """Reads a whole recording (events and frames); start/end (µs) keep t in [start, end)."""

def open(path: PathLike, chunk: int = 1 << 20, start: Union[int, None] = None,
         end: Union[int, None] = None, format: Union[str, None] = None) -> Stream:
    """Streams a file in chunks of at most `chunk` events (bounded memory)."""

def write(path: PathLike, events: EventsLike,
          frames: Union[Sequence[Union[Frame, Tuple[ImageLike, int, int]]], None] = None,
          width: Union[int, None] = None, height: Union[int, None] = None,
          format: Union[str, None] = None, compression: Union[str, None] = None,
          level: int = 1) -> None:
    """Writes events (and frames): .txt, .h5 or .aedat4; the file appears whole or not at all."""

def accumulate(events: EventsLike, width: Union[int, None] = None, height: Union[int, None] = None,
               repr: Literal["frame", "counts", "normalized", "timesurface", "voxel"] = "frame",
               c_on: float = 1.0, c_off: float = 1.0, t_ref: Union[int, None] = None,
               tau_us: float = 50000.0, bins: int = 5, t0: Union[int, None] = None,
               t1: Union[int, None] = None) -> npt.NDArray[np.float32]:
    """An event representation: (H, W) for frame/normalized, (2, H, W) for counts/timesurface,
    (bins, H, W) for voxel."""

def slices(source: Union[PathLike, EventsLike], *, by_time: Union[int, None] = None,
           by_count: Union[int, None] = None, chunk: int = 1 << 20, start: Union[int, None] = None,
           end: Union[int, None] = None) -> Iterator[Window]:
    """Windows of a file or of events, by time (µs) or by count, in bounded memory."""

def simulate(frames: Union[Sequence[ImageLike], npt.NDArray[Any]], timestamps_us: npt.ArrayLike,
             contrast: float = 0.2, contrast_off: Union[float, None] = None, sigma: float = 0.0,
             refractory_us: int = 0, shot_noise_hz: float = 0.0, leak_hz: float = 0.0,
             seed: int = 1, lin_log: bool = False, eps: float = 1e-3,
             bayer_rggb: bool = False) -> Events:
    """Events from video frames (ESIM-like, with v2e's noise)."""

def synth(scene: str = "planes", out: Union[PathLike, None] = None, blur_px: float = 30.0,
          width: int = 346, height: int = 260, exposure_us: int = 100000, contrast: float = 0.2,
          sigma: float = 0.0, shot_noise_hz: float = 0.0, leak_hz: float = 0.0, seed: int = 1,
          colour: bool = False, preroll_us: int = 0, rotation_share: float = 0.7,
          photos: Union[PathLike, None] = None) -> Observation:
    """A synthetic observation with ground truth (a scene, a camera shake, its blur and events)."""

def scenes() -> list[str]:
    """The scenes evkit.synth knows (presets, then natural scenes)."""

def suite(name: str) -> list[str]:
    """The entries of a suite (standard, noisy, hard, natural, all)."""

def deblur(observation: Observation, method: str = "edi",
           times: Union[Sequence[int], None] = None,
           progress: Union[Callable[[int, int, float], Any], None] = None,
           **settings: Any) -> DeblurResult:
    """Deblurs an observation with 'edi', 'benerf' or 'blurry'; settings as evkit.method_help."""

def deblur_recording(recording: PathLike, out: PathLike, frames: str = "all", method: str = "edi",
                     shard: str = "0/1", latent: int = 10, calib: Union[PathLike, None] = None,
                     ground_truth: Union[PathLike, None] = None, filter_hot_pixels: bool = False,
                     seed: int = 1, merge: bool = True, video: str = "latent.avi",
                     video_fps: float = 30.0,
                     progress: Union[Callable[[int, int, int, str], Any], None] = None,
                     **settings: Any) -> dict[str, Any]:
    """Deblurs every chosen frame of a recording into `out` (evkit deblur --recording); resumable."""

def methods() -> list[str]:
    """The deblurring methods' names."""

def method_help(method: str) -> str:
    """Each setting of a method with its type, default and help, one per line."""

def tqdm_progress(bar: Any) -> Callable[[int, int, float], None]:
    """A deblur progress callback that drives a tqdm bar."""
