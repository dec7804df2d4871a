"""The README's `recon video` preview: a clip, the track's body over it, and the captured motion on
that body dressed with an NCS outfit, side by side, as a GIF (the clip cropped around the
person's path; the renderer's sensor noise smoothed a little, which GIF compresses badly).

    .venv/bin/python demos/video_preview.py [--clip walk-03_03] [--outfit tshirt-skirt]
    -> demos/previews/video-<clip>.gif
    .venv/bin/python demos/video_preview.py --real --every 1 --height 240 [--start 0 --end 6 --max-people 4]
    -> demos/previews/video-vtest.gif

The synthetic clip is one of synth-video-test's (eval/video.py renders it). ``--real`` takes real
footage instead: OpenCV's ``vtest.avi`` (Debian's opencv-doc, which scripts/setup.sh extracts; a
static camera over a square with pedestrians), and shows ``recon video``'s overlay as it is: the
bodies over the frame beside the 3D view of them on the ground.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np
import torch
from PIL import Image

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "eval"))
from video import clips  # noqa: E402 - eval/video.py renders and caches the benchmark clips

from recon import camera  # noqa: E402
from recon.animate import Motion, render_motion  # noqa: E402
from recon.body import default_body  # noqa: E402
from recon.garment.dress import Dresser  # noqa: E402
from recon.pipeline import ReconstructorConfig  # noqa: E402
from recon.synth.photos import photo_path  # noqa: E402
from recon.synth.video import SIZE  # noqa: E402
from recon.video import FrameRange, FrameSource, VideoOptions, video  # noqa: E402

OUT = Path(__file__).resolve().parent / "previews"
VTEST = ("opencv-doc", "usr/share/doc/opencv-doc/examples/data", "vtest.avi")


def save_gif(frames: list[np.ndarray], out: Path, seconds_per_frame: float, colours: int = 64) -> None:
    """One palette for all frames, no dithering: a tenth of the file of per-frame dithered palettes."""
    palette = Image.fromarray(np.concatenate(frames[::4], 0)).quantize(colours, dither=Image.Dither.NONE)
    images = [Image.fromarray(f).quantize(palette=palette, dither=Image.Dither.NONE) for f in frames]
    images[0].save(out, save_all=True, append_images=images[1:], duration=round(1000 * seconds_per_frame), loop=0,
                   optimize=True)
    print(out)


def real(a) -> None:
    """``recon video`` on vtest.avi: its overlay (bodies over the frame, the 3D view) as a GIF."""
    path = photo_path(*VTEST)
    if not path.is_file():
        raise SystemExit(f"{path} not found: scripts/setup.sh extracts Debian's opencv-doc there")
    with tempfile.TemporaryDirectory() as tmp:
        res = video(path, Path(tmp) / "out", VideoOptions(frames=FrameRange(start=a.start, end=a.end),
                                                          max_people=a.max_people))
        overlay = [f.rgb for f in FrameSource(Path(tmp) / "out" / "overlay.mp4")]
    h, w = overlay[0].shape[:2]
    size = (round(a.height * w / h), a.height)
    frames = [cv2.resize(f, size, interpolation=cv2.INTER_AREA) for f in overlay[::a.every]]
    save_gif(frames, OUT / "video-vtest.gif", a.every / res.fps, colours=128)  # the bodies over real colours


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--clip", default="walk-03_03")
    ap.add_argument("--outfit", default="tshirt-skirt")
    ap.add_argument("--height", type=int, default=200, help="GIF height in pixels (three square panels)")
    ap.add_argument("--every", type=int, default=3, help="every n-th frame")
    ap.add_argument("--real", action="store_true", help="OpenCV's vtest.avi instead of a synthetic clip")
    ap.add_argument("--start", type=float, default=0.0, help="with --real: first second")
    ap.add_argument("--end", type=float, default=6.0, help="with --real: last second")
    ap.add_argument("--max-people", type=int, default=4, help="with --real: people followed")
    a = ap.parse_args()
    torch.set_num_threads(1)
    if a.real:
        return real(a)
    name, path, truth = next(c for c in clips("synth-video-test") if c[0] == a.clip)
    body = default_body()
    with tempfile.TemporaryDirectory() as tmp:
        cfg = ReconstructorConfig(focal_factor=float(truth.K[0, 0]) / max(SIZE))
        res = video(path, Path(tmp) / "out", VideoOptions(), cfg)
        overlay = [f.rgb[:, :SIZE[1]] for f in FrameSource(Path(tmp) / "out" / "overlay.mp4")]
    clip = [f.rgb for f in FrameSource(path)]
    m = res.tracks[0]
    # a fixed square crop around where the person goes
    boxes = np.concatenate([camera.project(m.to_camera(m.translation), truth.K)])
    (x0, y0), (x1, y1) = boxes.min(0), boxes.max(0)
    side = int(min(max(x1 - x0, y1 - y0) + 0.6 * SIZE[0], SIZE[0]))
    cx, cy = int((x0 + x1) / 2), int((y0 + y1) / 2)
    left, top = int(np.clip(cx - side // 2, 0, SIZE[1] - side)), int(np.clip(cy - side // 2, 0, SIZE[0] - side))

    def crop(rgb):
        return cv2.medianBlur(np.ascontiguousarray(rgb[top:top + side, left:left + side]), 5)
    motion = Motion(torch.tensor(m.rotmats, dtype=torch.float32), torch.tensor(m.translation, dtype=torch.float32),
                    res.fps, name)
    dressed = render_motion(body, torch.tensor(m.shape, dtype=torch.float32), motion, Dresser(a.outfit),
                            size=(a.height, a.height), yaw_deg=30.0)
    frames = []
    for f in range(0, len(overlay), a.every):
        k = f - m.first
        panels = [crop(clip[f]), crop(overlay[f]), dressed[min(max(k, 0), len(dressed) - 1)]]
        frames.append(np.concatenate([cv2.resize(p, (a.height, a.height), interpolation=cv2.INTER_AREA)
                                      for p in panels], 1))
    save_gif(frames, OUT / f"video-{name}.gif", a.every / res.fps)


if __name__ == "__main__":
    main()
