"""Turntable GIF of a reconstructed, dressed human from one photo.

    .venv/bin/python demos/turntable.py [photo] [--outfit tshirt-trousers] [--out demos/out]

Reconstructs the photo (default: the bundled astronaut), dresses the body with a trained PBNS
outfit (resized to the reconstructed shape), puts it upright and renders 36 views with pyrender.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import torch
from PIL import Image

from recon import camera, io, paths
from recon.demo import EXAMPLES
from recon.garment.dress import Dresser
from recon.garment.pbns.model import remove_yaw
from recon.pipeline import Reconstructor
from recon.viz import render_meshes


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("photo", nargs="?", default=str(EXAMPLES / "astronaut.jpg"))
    ap.add_argument("--outfit", default="tshirt-trousers")
    ap.add_argument("--out", default="demos/out")
    ap.add_argument("--views", type=int, default=36)
    a = ap.parse_args()
    torch.set_num_threads(1)
    rec_model = Reconstructor()  # recon run's defaults
    rec = rec_model(io.load_image(a.photo))
    body = rec_model.body
    rot = torch.tensor(rec.rotmats[None], dtype=torch.float32)
    # into the gravity frame (camera assumed upright: the view frame), heading removed
    rot[0, 0] = remove_yaw(camera.rotation_to_view(rot[0, 0]))
    shape = torch.tensor(rec.shape[None], dtype=torch.float32)
    with torch.no_grad():
        bv = body(rot, shape).vertices[0].numpy()
    cloth = Dresser(a.outfit)(body, rot, shape)
    meshes = [(bv, body.faces.numpy(), (0.85, 0.75, 0.68, 1.0)),
              (cloth.vertices[0], cloth.faces, (0.35, 0.45, 0.8, 1.0))]
    centre = 0.5 * (bv.min(0) + bv.max(0))
    frames = [Image.fromarray(render_meshes(meshes, size=(360, 480), yaw_deg=360.0 * i / a.views, distance=3.0,
                                            center=centre)) for i in range(a.views)]
    out = Path(a.out) / f"{Path(a.photo).stem}-{a.outfit}-turntable.gif"
    out.parent.mkdir(parents=True, exist_ok=True)
    paths.atomic_write(out, lambda t: frames[0].save(t, format="GIF", save_all=True, append_images=frames[1:],
                                                     duration=80, loop=0))
    print(out)


if __name__ == "__main__":
    main()
