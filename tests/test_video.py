"""H.264 video and PNG frames: exact sizes, frame counts, small coding error."""

import numpy as np
import pytest
from PIL import Image

from sim2real.errors import UserError
from sim2real.inference.video import read_video, read_video_frames, write_frames, write_video


def smooth_frames(n, h, w):
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    out = []
    for t in range(n):
        r = 128 + 90 * np.sin(xx / w * 2 * np.pi + 0.3 * t)
        g = 128 + 90 * np.cos(yy / h * 2 * np.pi - 0.2 * t)
        b = 60 + 100 * (xx + yy) / (h + w)
        out.append(np.clip(np.stack([r, g, b], -1), 0, 255).astype(np.uint8))
    return out


@pytest.mark.parametrize("backend", ["pyav", "imageio"])
@pytest.mark.parametrize("h,w", [(48, 80), (45, 77)])
def test_video_round_trip(tmp_path, backend, h, w):
    frames = smooth_frames(12, h, w)
    path = tmp_path / "video.mp4"
    assert write_video(iter(frames), path, fps=5.0, backend=backend) == 12
    assert [p.name for p in tmp_path.iterdir()] == ["video.mp4"]  # no temporary file left
    # Odd sides are padded by one pixel (bottom / right) for yuv420p; even sizes are exact.
    assert read_video(path) == (12, h + h % 2, w + w % 2)
    dec = read_video_frames(path)[:, :h, :w]
    err = np.abs(dec.astype(np.float64) - np.stack(frames)).mean()
    assert err < 6, err


def test_video_fps_and_errors(tmp_path):
    import av

    path = tmp_path / "v.mp4"
    write_video(smooth_frames(3, 16, 16), path, fps=5.0)
    with av.open(str(path)) as c:
        assert c.streams.video[0].average_rate == 5
    with pytest.raises(UserError):
        write_video([], tmp_path / "empty.mp4")
    with pytest.raises(ValueError):
        write_video([np.zeros((16, 16, 3), np.uint8), np.zeros((16, 18, 3), np.uint8)], tmp_path / "bad.mp4")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["v.mp4"]


def test_write_frames(tmp_path):
    frames = smooth_frames(3, 45, 77)
    names = write_frames(frames, tmp_path / "frames")
    assert names == ["000000.png", "000001.png", "000002.png"]
    for name, f in zip(names, frames):
        assert np.array_equal(np.array(Image.open(tmp_path / "frames" / name)), f)
    with pytest.raises(UserError):
        write_frames(frames, tmp_path / "frames")  # not empty any more


def test_background_writer_writes_frames_and_video(tmp_path):
    from sim2real.inference.video import BackgroundFrameWriter

    frames = [np.full((18, 30, 3), 40 * k, np.uint8) for k in range(5)]
    (tmp_path / "f").mkdir()
    with BackgroundFrameWriter(tmp_path / "f", tmp_path / "v.mp4", fps=5.0, depth=2) as w:
        for f in frames:
            w.put(f)
    assert w.count == 5 and read_video(tmp_path / "v.mp4") == (5, 18, 30)
    assert sorted(p.name for p in (tmp_path / "f").iterdir()) == [f"{k:06d}.png" for k in range(5)]
    assert np.array_equal(np.asarray(Image.open(tmp_path / "f" / "000003.png")), frames[3])


def test_background_writer_raises_the_writers_error_in_the_caller(tmp_path):
    from sim2real.inference.video import BackgroundFrameWriter

    (tmp_path / "f").mkdir()
    with pytest.raises(ValueError, match="frame 2"):
        with BackgroundFrameWriter(tmp_path / "f", tmp_path / "v.mp4", fps=5.0, depth=1) as w:
            for k in range(40):  # frame 2 has another size: the writer stops, the caller hears of it
                w.put(np.zeros((18, 30 if k != 2 else 32, 3), np.uint8))
    assert not (tmp_path / "v.mp4").exists()


def test_background_writer_encodes_pngs_in_several_threads(tmp_path, monkeypatch):
    """Frames go to the PNG threads (more than one at work), each file holds its own frame, and
    the video holds all of them in order."""
    import threading
    import time

    from sim2real.inference import video

    writers, write = set(), video.atomic_write_image

    def slow_write(path, image):
        writers.add(threading.current_thread().name)
        time.sleep(0.02)  # long enough that the next frame finds the first thread busy
        write(path, image)

    monkeypatch.setattr(video, "atomic_write_image", slow_write)
    frames = smooth_frames(9, 18, 30)
    (tmp_path / "f").mkdir()
    with video.BackgroundFrameWriter(tmp_path / "f", tmp_path / "v.mp4", fps=5.0, depth=4, png_threads=3) as w:
        for f in frames:
            w.put(f)
    assert w.count == 9 and len(writers) > 1 and all(n.startswith("png-writer") for n in writers)
    for k, f in enumerate(frames):
        assert np.array_equal(np.asarray(Image.open(tmp_path / "f" / f"{k:06d}.png")), f)
    dec = read_video_frames(tmp_path / "v.mp4").astype(float)
    dist = np.abs(dec[:, None] - np.stack(frames)[None]).mean(axis=(2, 3, 4))  # decoded x written
    assert np.array_equal(dist.argmin(axis=1), np.arange(9))  # each decoded frame is nearest its own


def test_background_writer_raises_a_failed_png_write_in_the_caller(tmp_path):
    from sim2real.inference.video import BackgroundFrameWriter

    (tmp_path / "f").write_text("a file where the frames folder should be")
    with pytest.raises(UserError, match=f"^cannot write {tmp_path / 'f'}/0000.*: {tmp_path / 'f'} is a file, not a folder$"):
        with BackgroundFrameWriter(tmp_path / "f", tmp_path / "v.mp4", fps=5.0, depth=1, png_threads=2) as w:
            for f in smooth_frames(40, 18, 30):
                w.put(f)
    assert not (tmp_path / "v.mp4").exists()
