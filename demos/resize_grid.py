"""Outfit resizing picture (thesis Fig. 5.9): one outfit on three body shapes (columns) at two
tightness values (rows), rest pose, with the trained resizer; plus the transfer-only version.

    .venv/bin/python demos/resize_grid.py [--outfit tshirt-trousers] [--out demos/previews/resize.jpg]
"""
from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np
import torch

from recon.body import default_body
from recon.garment.dress import Dresser
from recon.viz import render_meshes

BODY_RGBA, CLOTH_RGBA = (0.85, 0.72, 0.62, 1.0), (0.35, 0.45, 0.8, 1.0)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--outfit", default="tshirt-trousers")
    ap.add_argument("--out", default="demos/previews/resize.jpg")
    a = ap.parse_args()
    torch.set_num_threads(1)
    body = default_body()
    d = Dresser(a.outfit)
    if not d.has_resizer:
        raise SystemExit(f"no resizer for {a.outfit}: run `recon garment resize --outfit {a.outfit}`")
    names = list(body.shape_names)
    shapes = []
    for gender, weight, height in ((1.0, 0.25, 0.35), (0.5, 0.5, 0.5), (0.0, 0.8, 0.7)):
        s = body.mean_shape.clone()
        s[names.index("gender")], s[names.index("weight")], s[names.index("height")] = gender, weight, height
        shapes.append(s)
    faces = body.faces.numpy()
    rows = []
    for tight in ((0.0, 0.0), (0.25, 0.05)):
        tiles = []
        for s in shapes:
            with torch.no_grad():
                bv = body.rest_geometry(s[None])[0][0].numpy()
            cloth = d.rest_for(body, s, tightness=tight).numpy()
            img = render_meshes([(bv, faces, BODY_RGBA), (cloth, d.model.faces.numpy(), CLOTH_RGBA)], size=(300, 400),
                                center=np.array([0.0, 0.0, 0.0]) + 0.5 * (bv.min(0) + bv.max(0)), distance=3.1)
            cv2.putText(img, f"tightness {tight[0]:+.2f},{tight[1]:+.2f}", (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5,
                        (0, 0, 0), 1, cv2.LINE_AA)
            tiles.append(img)
        rows.append(np.concatenate(tiles, 1))
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out), np.concatenate(rows, 0)[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, 85])
    print(out)


if __name__ == "__main__":
    main()
