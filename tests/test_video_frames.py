"""Frames of a video file or a folder of images: order, range, rate, and bad frames said, not fatal."""
import cv2
import numpy as np
import pytest

from recon.video import FrameRange, FrameSource, VideoError
from recon.video.frames import natural_key


def _frame(i: int, size=(48, 64)) -> np.ndarray:
    """An RGB frame whose red channel holds its number (survives lossless and MJPG coding)."""
    rgb = np.zeros((*size, 3), np.uint8)
    rgb[..., 0] = 8 * i
    rgb[: size[0] // 2, :, 2] = 200
    return rgb


def _video(path, n=30, fps=10.0, fourcc="MJPG"):
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), fps, (64, 48))
    assert w.isOpened()
    for i in range(n):
        w.write(cv2.cvtColor(_frame(i), cv2.COLOR_RGB2BGR))
    w.release()
    return path


def _number(rgb: np.ndarray) -> int:
    return int(round(float(rgb[..., 0].mean()) / 8))


@pytest.mark.parametrize("suffix,fourcc", [(".avi", "MJPG"), (".mp4", "mp4v")])
def test_a_video_gives_its_frames_in_order_as_rgb(tmp_path, suffix, fourcc):
    src = FrameSource(_video(tmp_path / f"clip{suffix}", fourcc=fourcc))
    assert src.fps == pytest.approx(10.0) and src.count == 30 and src.size == (48, 64)
    frames = list(src)
    assert [f.index for f in frames] == list(range(30))
    assert [f.time for f in frames] == pytest.approx([i / 10 for i in range(30)])
    assert all(f.rgb.shape == (48, 64, 3) and f.rgb.dtype == np.uint8 and not f.error for f in frames)
    assert [_number(f.rgb) for f in frames] == list(range(30))
    assert frames[0].rgb[:24, :, 2].mean() > 150 and frames[0].rgb[24:, :, 2].mean() < 50  # RGB, upright


def test_the_range_picks_start_end_every_and_rate(tmp_path):
    path = _video(tmp_path / "clip.avi")  # 30 frames at 10 fps: 3 s
    pick = lambda **kw: [f.index for f in FrameSource(path, FrameRange(**kw))]  # noqa: E731
    assert pick(start=1.0) == list(range(10, 30))
    assert pick(start=0.5, end=1.2) == [5, 6, 7, 8, 9, 10, 11]
    assert pick(every=4) == [0, 4, 8, 12, 16, 20, 24, 28]
    assert pick(start=0.5, every=3, end=2.0) == [5, 8, 11, 14, 17]
    assert pick(fps=4.0) == [0, 3, 5, 8, 10, 13, 15, 18, 20, 23, 25, 28]  # first frame of each 0.25 s
    assert pick(fps=25.0) == list(range(30))  # no faster than the source
    frames = list(FrameSource(path, FrameRange(start=2.0)))
    assert [_number(f.rgb) for f in frames] == list(range(20, 30))  # the pixels follow the indices


def test_a_folder_is_read_in_natural_order_and_bad_frames_are_said(tmp_path):
    for i in range(12):
        cv2.imwrite(str(tmp_path / f"frame{i}.png"), cv2.cvtColor(_frame(i), cv2.COLOR_RGB2BGR))
    (tmp_path / "frame5.png").write_bytes(b"not an image")
    cv2.imwrite(str(tmp_path / "frame7.png"), np.zeros((20, 30, 3), np.uint8))  # another size
    (tmp_path / ".hidden").write_text("x")
    src = FrameSource(tmp_path, FrameRange(folder_fps=24.0))
    assert src.count == 12 and src.fps == 24.0 and src.size == (48, 64)
    frames = list(src)
    assert [f.index for f in frames] == list(range(12))
    bad = {f.index: f.error for f in frames if f.rgb is None}
    assert set(bad) == {5, 7} and "frame5.png" in bad[5] and "30x20" in bad[7]
    assert [_number(f.rgb) for f in frames if f.rgb is not None] == [0, 1, 2, 3, 4, 6, 8, 9, 10, 11]
    assert natural_key("frame2.png") < natural_key("frame10.png")


def test_a_corrupt_video_frame_is_said_and_the_rest_still_come(tmp_path):
    path = _video(tmp_path / "clip.avi")
    data = bytearray(path.read_bytes())
    starts = [i for i in range(len(data) - 1) if data[i] == 0xFF and data[i + 1] == 0xD8]  # the JPEG frames
    assert len(starts) == 30
    data[starts[10]:starts[10] + 400] = bytes(400)
    path.write_bytes(bytes(data))
    frames = list(FrameSource(path))
    bad = [f.index for f in frames if f.rgb is None]
    assert bad == [10] and "decoder" in frames[10].error
    assert [_number(f.rgb) for f in frames[:10]] == list(range(10))
    good = [_number(f.rgb) for f in frames[11:]]
    assert len(good) >= 17 and good == sorted(good) and good[-1] == 29  # in order, to the last frame


def test_what_cannot_be_read_is_a_clear_error(tmp_path):
    with pytest.raises(VideoError, match="no such file"):
        FrameSource(tmp_path / "missing.mp4")
    (tmp_path / "notes.mp4").write_text("not a video")
    with pytest.raises(VideoError, match="not a video"):
        FrameSource(tmp_path / "notes.mp4")
    (tmp_path / "empty").mkdir()
    with pytest.raises(VideoError, match="empty folder"):
        FrameSource(tmp_path / "empty")
    for bad in ({"start": 2.0, "end": 1.0}, {"every": 0}, {"fps": 0.0}, {"start": -1.0}):
        with pytest.raises(VideoError):
            FrameRange(**bad)
