"""The README's `recon animate` preview: a bundled photo's person, dressed, on a held-out walk.

    .venv/bin/python demos/animate_photo.py [--photo recon/data/examples/astronaut.jpg] [--out demos/previews]

Runs `recon animate` (animated .glb + full-size MP4 in OUT/animate-<photo>/) and writes a small
GIF preview beside it (every second frame, 15 fps).
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch

from recon.animate import Motion, animate, load_motion, on_the_ground, render_motion
from recon.body import default_body
from recon.demo import EXAMPLES
from recon.export.media import write_video
from recon.garment.dress import Dresser


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--photo", default=str(EXAMPLES / "astronaut.jpg"))
    ap.add_argument("--motion", default="walk")
    ap.add_argument("--outfit", default="tshirt-skirt")
    ap.add_argument("--seconds", type=float, default=4.0)
    ap.add_argument("--out", default="demos/previews")
    a = ap.parse_args()
    torch.set_num_threads(2)
    out = Path(a.out)
    work = Path("demos/out") / f"animate-{Path(a.photo).stem}"
    written = animate(a.photo, a.motion, work, outfit=a.outfit, max_seconds=a.seconds)
    info = json.loads(written["json"].read_text())
    person = json.loads(next((work / "reconstruction").glob("*/result.json")).read_text())
    body = default_body()
    shape = torch.tensor(list(person["shape"].values()), dtype=torch.float32)
    m = on_the_ground(load_motion(a.motion, body, shape), body, shape)
    m = Motion(m.rotmats[:info["frames"]], m.transl[:info["frames"]], m.fps, m.name)
    frames = render_motion(body, shape, m, Dresser(a.outfit), size=(240, 320), every=2)  # dressed at 30 fps
    print(write_video(out / f"animate-{Path(a.photo).stem}.gif", frames, m.fps / 2))
    for path in written.values():
        print(path)


if __name__ == "__main__":
    main()
