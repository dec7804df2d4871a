"""A PBNS outfit animated on a held-out mocap clip: GIF (pyrender) + animated .glb.

    .venv/bin/python demos/outfit_on_mocap.py [--outfit tshirt-trousers] [--out demos/out]

The .glb carries the skeleton, the skinned body and outfit, and the outfit's PBNS blend shapes
with per-frame weights: it plays in Blender / three.js / model-viewer without our code.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import roma
import torch

from recon.body import default_body
from recon.demo import dressed_gif
from recon.export.glb import write_glb
from recon.garment.dress import Dresser
from recon.garment.morph import outfit_animation
from recon.poses.mocap import FPS, MocapPoses


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--outfit", default="tshirt-trousers")
    ap.add_argument("--out", default="demos/out")
    ap.add_argument("--frames", type=int, default=120)
    a = ap.parse_args()
    torch.set_num_threads(1)
    out = Path(a.out)
    print(dressed_gif(out, a.outfit))
    body = default_body()
    m = MocapPoses.load("test")
    sel = (m.clip == m.clip[0]).nonzero()[0][:a.frames]
    rot = roma.rotvec_to_rotmat(torch.from_numpy(m.rotvec[sel]).float())
    transl = torch.from_numpy(m.transl[sel]).float()
    dresser = Dresser(a.outfit)
    print(write_glb(out / f"{a.outfit}-mocap.glb", body, dresser.shape, rot, transl, FPS,
                    outfit_animation(body, dresser.shape, rot, transl, dresser, FPS)))


if __name__ == "__main__":
    main()
