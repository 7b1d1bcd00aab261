"""Frames -> H.264 video (and PNG frames), at the frames' exact size.

:func:`write_video` encodes with libx264 (crf 18, yuv420p: the pixel format every player
reads) through PyAV; only when PyAV or its libx264 is missing does it use the ffmpeg binary that
imageio-ffmpeg ships, with ``macro_block_size=1`` so that nothing is resized to multiples of 16.

yuv420p needs an even width and height. A frame with an odd side is padded by one pixel at the
bottom and/or right edge (repeating the last row / column), so a 45x77 sequence becomes a
46x78 video whose top-left 45x77 pixels are the frames; the PNG frames (:func:`write_frames`)
keep the exact size. The video is written under a temporary name and renamed when complete.

:class:`BackgroundFrameWriter` writes the PNG frames (in threads) and encodes the video (in one)
while ``sim2real translate`` translates the next frames (PNG's zlib and libx264 release the GIL).
"""

from __future__ import annotations

import collections
import os
import queue
import threading
from concurrent.futures import ThreadPoolExecutor
from fractions import Fraction
from pathlib import Path
from typing import Iterable, Iterator

import av
import numpy as np

from sim2real.errors import UserError, reason
from sim2real.fileio import atomic_path, atomic_write_image, staged_output_dir
from sim2real.threads import worker_count

CRF = 18


def _check_frame(frame: np.ndarray, size: tuple[int, int] | None, index: int) -> np.ndarray:
    a = np.asarray(frame)
    if a.dtype != np.uint8 or a.ndim != 3 or a.shape[2] != 3:
        raise ValueError(f"frame {index}: expected uint8 (H, W, 3) RGB, got {a.dtype} {a.shape}")
    if size is not None and a.shape[:2] != size:
        raise ValueError(f"frame {index} is {a.shape[0]}x{a.shape[1]}, frame 0 is {size[0]}x{size[1]}")
    return a


def pad_even(frame: np.ndarray) -> np.ndarray:
    """Pad an (H, W, 3) frame by one edge pixel at the bottom / right where H / W is odd."""
    h, w = frame.shape[:2]
    if h % 2 == 0 and w % 2 == 0:
        return np.ascontiguousarray(frame)
    return np.pad(frame, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")


def pyav_has_libx264() -> bool:
    """Whether PyAV brings the libx264 encoder (else :func:`write_video` uses the ffmpeg binary)."""
    return "libx264" in av.codecs_available


def _rate(fps: float) -> Fraction:
    if not (np.isfinite(fps) and 0 < fps <= 1000):
        raise UserError(f"fps must be in (0, 1000], got {fps}")
    return Fraction(fps).limit_denominator(1001)


def _encode_pyav(frames: Iterator[np.ndarray], first: np.ndarray, tmp: Path, fps: float, crf: int) -> int:
    size = first.shape[:2]
    container = av.open(str(tmp), mode="w")
    try:
        stream = container.add_stream("libx264", rate=_rate(fps))
        stream.width, stream.height = pad_even(first).shape[1], pad_even(first).shape[0]
        stream.pix_fmt = "yuv420p"
        stream.options = {"crf": str(crf)}
        n = 0
        frame = first
        while frame is not None:
            vf = av.VideoFrame.from_ndarray(pad_even(_check_frame(frame, size, n)), format="rgb24")
            for packet in stream.encode(vf):
                container.mux(packet)
            n += 1
            frame = next(frames, None)
        for packet in stream.encode():
            container.mux(packet)
    finally:
        container.close()
    return n


def _encode_imageio(frames: Iterator[np.ndarray], first: np.ndarray, tmp: Path, fps: float, crf: int) -> int:
    import imageio_ffmpeg  # the fallback only: PyAV's own wheels bring libx264

    size = first.shape[:2]
    hp, wp = pad_even(first).shape[:2]
    writer = imageio_ffmpeg.write_frames(
        str(tmp), (wp, hp), fps=float(_rate(fps)), codec="libx264", pix_fmt_in="rgb24", pix_fmt_out="yuv420p",
        quality=None, macro_block_size=1, output_params=["-crf", str(crf)], ffmpeg_log_level="error",
    )
    writer.send(None)  # start ffmpeg
    n = 0
    try:
        frame = first
        while frame is not None:
            writer.send(pad_even(_check_frame(frame, size, n)))
            n += 1
            frame = next(frames, None)
    finally:
        writer.close()
    return n


def write_video(frames: Iterable[np.ndarray], path: str | os.PathLike, fps: float = 5.0, crf: int = CRF,
                backend: str = "auto") -> int:
    """Encode uint8 (H, W, 3) RGB frames as H.264 (libx264, ``crf``, yuv420p) into ``path``
    (.mp4, .mkv or .mov); returns the number of frames. ``backend``: ``"auto"`` (PyAV, else
    imageio-ffmpeg), ``"pyav"`` or ``"imageio"``. Odd sizes are padded (module docstring)."""
    path = Path(path)
    if backend not in ("auto", "pyav", "imageio"):
        raise ValueError(f"backend must be 'auto', 'pyav' or 'imageio', got {backend!r}")
    if backend == "auto":
        backend = "pyav" if pyav_has_libx264() else "imageio"
    if backend == "pyav" and not pyav_has_libx264():
        raise UserError("PyAV with libx264 is not available; install 'av' or use backend='imageio'")
    _rate(fps)
    it = iter(frames)
    first = next(it, None)
    if first is None:
        raise UserError(f"no frames to write to {path}")
    first = _check_frame(first, None, 0)
    encode = _encode_pyav if backend == "pyav" else _encode_imageio
    with atomic_path(path, suffix=".tmp" + (path.suffix or ".mp4")) as tmp:
        n = encode(it, first, tmp, fps, crf)
    return n


def read_video_frames(path: str | os.PathLike) -> np.ndarray:
    """Decode every frame of a video -> uint8 (N, H, W, 3) RGB (for tests and checks)."""
    try:
        with av.open(str(path)) as container:
            frames = [f.to_ndarray(format="rgb24") for f in container.decode(video=0)]
    except (OSError, av.error.FFmpegError) as e:
        raise UserError(f"cannot decode video {path}: {reason(e)}") from None
    if not frames:
        return np.zeros((0, 0, 0, 3), np.uint8)
    return np.stack(frames)


def read_video(path: str | os.PathLike) -> tuple[int, int, int]:
    """(number of decoded frames, height, width) of a video."""
    try:
        with av.open(str(path)) as container:
            n, h, w = 0, 0, 0
            for f in container.decode(video=0):
                n, h, w = n + 1, f.height, f.width
    except (OSError, av.error.FFmpegError) as e:
        raise UserError(f"cannot decode video {path}: {reason(e)}") from None
    return n, h, w


def write_frames(frames: Iterable[np.ndarray], out_dir: str | os.PathLike) -> list[str]:
    """Write uint8 (H, W, 3) RGB frames as ``out_dir/000000.png, 000001.png, ...`` (exact size,
    the folder appears when all are written). ``out_dir`` must be new or empty. Returns the file
    names."""
    names, size = [], None
    with staged_output_dir(out_dir) as out:
        for i, frame in enumerate(frames):
            a = _check_frame(frame, size, i)
            size = a.shape[:2]
            name = f"{i:06d}.png"
            atomic_write_image(out / name, a)
            names.append(name)
    return names


class BackgroundFrameWriter:
    """PNG frames ``frames_dir/000000.png ...`` and an H.264 video of them, written while the
    caller produces the next frames::

        with BackgroundFrameWriter(frames_dir, video_path, fps) as w:
            for frame in frames:
                w.put(frame)
        count = w.count

    One thread encodes the video; the PNG frames are encoded by ``png_threads`` more (default:
    the worker rule, :func:`sim2real.threads.worker_count`), since PNG's zlib costs three times
    libx264 per frame (12.2 against 4.1 ms at 256x512): one thread for both wrote 55 frames/s,
    this writer 97 on two cores (benchmarks/bench_export.py), the ceiling of a translation
    whose network is fast.

    At most ``depth`` frames wait in the queue and ``2 * png_threads`` in the PNG threads
    (memory stays bounded). An error of the writer (an odd frame, a full disk) is raised in the
    caller at its next :meth:`put` or at the end of the block; an error of the caller stops the
    writer, leaving the video unfinished (its temporary file removed)."""

    def __init__(self, frames_dir: str | os.PathLike, video: str | os.PathLike, fps: float, depth: int = 16,
                 png_threads: int | None = None):
        self.frames_dir, self.video, self.fps = Path(frames_dir), Path(video), float(fps)
        self._queue: queue.Queue = queue.Queue(maxsize=max(1, int(depth)))
        self._png_threads = worker_count() if png_threads is None else max(1, int(png_threads))
        self._error: BaseException | None = None
        self._abort = False
        self.count = 0
        self._thread = threading.Thread(target=self._run, name="frame-writer", daemon=True)

    def _frames(self) -> Iterator[np.ndarray]:
        with ThreadPoolExecutor(self._png_threads, thread_name_prefix="png-writer") as pool:
            pending: collections.deque = collections.deque()
            i = 0
            while True:
                frame = self._queue.get()
                if frame is None:
                    break
                if self._abort:
                    raise RuntimeError("frame writer stopped")
                pending.append(pool.submit(atomic_write_image, self.frames_dir / f"{i:06d}.png", frame))
                while pending and (len(pending) > 2 * self._png_threads or pending[0].done()):
                    pending.popleft().result()  # in order; a failed write raises here
                i += 1
                yield frame
            for f in pending:
                f.result()

    def _run(self) -> None:
        try:
            self.count = write_video(self._frames(), self.video, fps=self.fps)
        except BaseException as e:  # handed to the caller
            self._error = e
            while True:  # unblock a caller waiting on a full queue
                try:
                    if self._queue.get(timeout=0.1) is None:
                        break
                except queue.Empty:
                    if self._abort:
                        break

    def __enter__(self) -> "BackgroundFrameWriter":
        self._thread.start()
        return self

    def put(self, frame: np.ndarray) -> None:
        if self._error is not None:
            raise self._error
        self._queue.put(frame)

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None:
            self._abort = True
        try:
            self._queue.put(None, timeout=60)
        except queue.Full:
            self._abort = True
        self._thread.join()
        if exc_type is None and self._error is not None:
            raise self._error
