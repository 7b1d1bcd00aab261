"""Sources of real footage and their frames: video files through PyAV (FFmpeg), folders of
frames through PIL.

A source is one video file or one clip of frames in a folder (a folder given as SRC is searched
recursively: each sub-folder with frames holds sources of its own, each video file in it is one).
The frames of a folder whose names differ only in their last number (``clip1_0008.jpg``,
``clip1_0016.jpg``) are one clip; frames of another name (``clip2_0008.jpg``) or of another size
form other sources. Frames of a folder are taken in file-name order, all of them (their rate is not
known); a video is sampled at ``fps`` frames per second of its timestamps (the first frame at or
after each multiple of ``1 / fps`` from the start of the range), within an optional time range
``SRC@START-END`` (seconds or [h:]mm:ss, either end may be left out).
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import av
import numpy as np
from PIL import Image

from sim2real.data.real import to_rgb
from sim2real.errors import UserError, reason

VIDEO_EXTENSIONS = (".mp4", ".avi", ".mkv", ".mov", ".m4v", ".webm", ".mpg", ".mpeg")
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


@dataclass
class Source:
    id: str
    path: Path
    kind: str
    """'video' or 'frames'."""
    files: list[Path] = field(default_factory=list)
    """Frame files (kind 'frames'), in name order."""
    root: Path | None = None
    """The SRC folder a frame folder was found under (labels mirror its layout)."""
    start: float = 0.0
    end: float = math.inf


@dataclass
class Frame:
    index: int
    time: float | None
    image: np.ndarray
    """uint8 (H, W, 3) RGB."""
    file: Path | None = None


def parse_time(text: str, src: str) -> float:
    """Seconds from '12.5', '1:05' or '1:02:03'."""
    try:
        parts = [float(p) for p in text.split(":")]
    except ValueError:
        raise UserError(f"bad time '{text}' in {src} (seconds or [h:]mm:ss)") from None
    if len(parts) > 3 or any(p < 0 or not math.isfinite(p) for p in parts):
        raise UserError(f"bad time '{text}' in {src} (seconds or [h:]mm:ss)")
    return sum(p * 60 ** i for i, p in enumerate(reversed(parts)))


def split_range(src: str) -> tuple[Path, float, float]:
    """``PATH@START-END`` -> (PATH, start, end); a path that exists as given is never split."""
    m = re.fullmatch(r"(.+)@([0-9:.]*)-([0-9:.]*)", src)
    if os.path.exists(src) or m is None:
        return Path(src), 0.0, math.inf
    start = parse_time(m.group(2), src) if m.group(2) else 0.0
    end = parse_time(m.group(3), src) if m.group(3) else math.inf
    if end <= start:
        raise UserError(f"empty time range in {src}: the end must come after the start")
    return Path(m.group(1)), start, end


def _clip_key(name: str) -> str:
    """A frame's clip: its file stem with the last run of digits (the frame number) left out, so
    that 'clip1_0008' and 'clip1_0016' are one clip, 'clip2_0008' another."""
    return re.sub(r"\d+(?=\D*$)", "#", Path(name).stem)


def _by_clip(files: list[Path]) -> dict[tuple[str, int, int], list[Path]]:
    """Frame files grouped by clip (:func:`_clip_key`) and size (w, h, from the image headers), in
    name order: each group is a source (a folder may mix clips, or crops of different sizes)."""
    groups: dict[tuple[str, int, int], list[Path]] = {}
    for f in files:
        try:
            with Image.open(f) as im:
                size = im.size
        except Exception as e:  # PIL raises many types for damaged files
            raise UserError(f"cannot read frame {f}: {e}") from None
        groups.setdefault((_clip_key(f.name), *size), []).append(f)
    return groups


def _source_id(path: Path, taken: set[str], suffix: str = "") -> str:
    parts = [p for p in (path.parent.name, path.stem if path.is_file() else path.name, suffix) if p]
    base = re.sub(r"[^A-Za-z0-9_.-]+", "_", "_".join(parts[-3:])).strip("._") or "source"
    sid, n = base, 2
    while sid in taken:
        sid, n = f"{base}-{n}", n + 1
    taken.add(sid)
    return sid


def find_sources(srcs: list[str]) -> list[Source]:
    """The sources of the SRC arguments (videos, frame folders; module docstring)."""
    sources: list[Source] = []
    taken: set[str] = set()
    for src in srcs:
        path, start, end = split_range(src)
        if not path.exists():
            raise UserError(f"source {src} does not exist")
        if path.is_file():
            ext = path.suffix.lower()
            if ext in VIDEO_EXTENSIONS:
                sources.append(Source(_source_id(path, taken), path, "video", start=start, end=end))
            elif ext in IMAGE_EXTENSIONS:
                if (start, end) != (0.0, math.inf):
                    raise UserError(f"a time range applies to videos only, not to the image {path}")
                sources.append(Source(_source_id(path, taken), path, "frames", files=[path], root=path.parent))
            else:
                raise UserError(f"source {path} is neither a video ({', '.join(VIDEO_EXTENSIONS)}) "
                                f"nor an image ({', '.join(IMAGE_EXTENSIONS)})")
            continue
        if (start, end) != (0.0, math.inf):
            raise UserError(f"a time range applies to videos only, not to the folder {path}")
        found = 0
        for d, _, names in sorted(os.walk(path)):
            names = sorted(names)
            frames = [Path(d) / n for n in names if Path(n).suffix.lower() in IMAGE_EXTENSIONS]
            groups = _by_clip(frames)
            clips = {k[0] for k in groups}
            for (clip, w, h), files in groups.items():
                suffix = "_".join(([clip.strip("#_-.")] if len(clips) > 1 else []) +
                                  ([f"{w}x{h}"] if len(groups) > len(clips) else []))
                sid = _source_id(Path(d), taken, suffix)
                sources.append(Source(sid, Path(d), "frames", files=files, root=path))
                found += 1
            for n in names:
                if Path(n).suffix.lower() in VIDEO_EXTENSIONS:
                    sources.append(Source(_source_id(Path(d) / n, taken), Path(d) / n, "video"))
                    found += 1
        if not found:
            raise UserError(f"the folder {path} holds no frames ({', '.join(IMAGE_EXTENSIONS)}) and no videos")
    return sources


def read_image(path: Path) -> np.ndarray:
    try:
        with Image.open(path) as im:
            im.load()
            return to_rgb(im)
    except Exception as e:  # PIL raises many types for damaged files
        raise UserError(f"cannot read frame {path}: {e}") from None


def expected_frames(source: Source, fps: float, max_frames: int | None = None) -> int | None:
    """How many frames :func:`iter_frames` will give, as far as the container tells (for progress);
    a video that cannot be opened raises :class:`UserError`."""
    if source.kind == "frames":
        n = len(source.files)
    else:
        # a container that cannot be opened fails here, before a progress bar is drawn for it
        with _open_video(source.path) as c:
            d = _duration(c, c.streams.video[0]) if c.streams.video else None
        if d is None:
            return None
        n = math.ceil((min(d, source.end) - source.start) * fps)
    return min(n, max_frames) if max_frames else n


def iter_frames(source: Source, fps: float, max_frames: int | None = None,
                pick: set[int] | None = None) -> Iterator[Frame]:
    """The sampled frames of ``source`` in order (``pick``: only these sample indices, read
    without decoding the others where the source allows it: frame folders)."""
    if source.kind == "frames":
        files = source.files[:max_frames] if max_frames else source.files
        for i, f in enumerate(files):
            if pick is None or i in pick:
                yield Frame(i, None, read_image(f), f)
        return
    yield from _video_frames(source, fps, max_frames)


def _open_video(path: Path):
    try:
        return av.open(str(path))
    except (av.FFmpegError, OSError, ValueError) as e:
        raise UserError(f"cannot open video {path}: {reason(e)}") from None


def _video_frames(source: Source, fps: float, max_frames: int | None) -> Iterator[Frame]:
    path = source.path
    with _open_video(path) as container:
        if not container.streams.video:
            raise UserError(f"{path} holds no video stream")
        stream = container.streams.video[0]
        stream.thread_type = "AUTO"
        if source.start > 0:
            try:  # to the key frame before the range's start; decoding then skips to it
                container.seek(int(source.start / stream.time_base), stream=stream, backward=True)
            except av.FFmpegError as e:
                raise UserError(f"cannot seek in video {path}: {reason(e)}") from None
        step, next_t, n, decoded, last_t, ended = 1.0 / fps, source.start, 0, 0, 0.0, True
        try:
            for frame in container.decode(stream):
                decoded += 1
                t = frame.time if frame.time is not None else decoded / float(stream.average_rate or fps)
                last_t = max(last_t, t)
                if t < source.start - 1e-6:
                    continue
                if t >= source.end or (max_frames and n >= max_frames):
                    ended = False
                    break
                if t + 1e-6 < next_t:
                    continue
                yield Frame(n, round(t, 6), frame.to_ndarray(format="rgb24"))
                n += 1
                next_t += step * max(1, math.floor((t + 1e-6 - next_t) / step) + 1)
        except av.FFmpegError as e:
            raise UserError(f"cannot decode video {path} (corrupt or truncated?): {reason(e)}") from None
        if decoded == 0:
            raise UserError(f"video {path} has no decodable frames")
        duration = _duration(container, stream)
        if ended and duration is not None and last_t < duration - max(TRUNCATED_S, TRUNCATED_SHARE * duration):
            raise UserError(f"video {path} is truncated: its frames end at {last_t:.2f} s of {duration:.2f} s")


TRUNCATED_S = 0.5
TRUNCATED_SHARE = 0.05
"""A video whose decodable frames end this long (seconds, or share of its length, the larger)
before the length its container declares is truncated."""


def _duration(container, stream) -> float | None:
    """The length the video stream (else the container: it may count a longer audio track)
    declares, in seconds, or None."""
    if stream.duration and stream.time_base:
        start = float(stream.start_time * stream.time_base) if stream.start_time else 0.0
        return float(stream.duration * stream.time_base) + start
    if container.duration:
        return container.duration / 1e6  # FFmpeg's AV_TIME_BASE
    return None
