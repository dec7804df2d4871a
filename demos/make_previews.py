"""Shrink the demo outputs into the README previews (demos/previews), after retraining weights.

    .venv/bin/recon demo --out /tmp/demo
    .venv/bin/python demos/turntable.py --out /tmp/demo
    .venv/bin/python demos/make_previews.py /tmp/demo

(`demos/resize_grid.py` writes its own preview.)
"""
from __future__ import annotations

import argparse
from pathlib import Path

from PIL import Image, ImageSequence

# source name -> (preview name, size, keep every n-th frame, frame ms)
GIFS = {"tshirt-trousers-mocap.gif": ("tshirt-trousers-mocap.gif", (240, 320), 2, 130),
        "astronaut-tshirt-trousers-turntable.gif": ("astronaut-turntable.gif", (240, 320), 3, 120)}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("src", type=Path, help="folder written by `recon demo` and demos/turntable.py")
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "previews")
    a = ap.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    Image.open(a.src / "examples.png").convert("RGB").resize((720, 720), Image.LANCZOS).save(
        a.out / "examples.jpg", quality=85)
    for src, (name, size, every, ms) in GIFS.items():
        frames = [f.convert("RGB").resize(size, Image.LANCZOS)  # convert while the iterator sits on the frame
                  for i, f in enumerate(ImageSequence.Iterator(Image.open(a.src / src))) if i % every == 0]
        frames[0].save(a.out / name, save_all=True, append_images=frames[1:], duration=ms, loop=0, optimize=True)
        print(a.out / name, len(frames), "frames")


if __name__ == "__main__":
    main()
