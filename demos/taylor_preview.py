"""Taylor garment model preview: one outfit on five very different bodies (columns) at a held-out
pose; rows: PBNS + resizer (the default Dresser), the Taylor model as a motion's frame gets it
(the model and the post-step), as a photo gets it (drape iterations first), the quasi-static
drape (what all try to be). Needs the outfit's Taylor database (`recon garment train --model taylor`).

    .venv/bin/python demos/taylor_preview.py [--outfit tshirt-skirt] [--out demos/previews/taylor-tshirt-skirt.jpg]
"""
from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np
import torch

from recon.body import default_body
from recon.garment.dress import Dresser
from recon.garment.taylor.config import TaylorBuildConfig
from recon.garment.taylor.data import drape_poses
from recon.garment.taylor.eval import test_poses
from recon.viz import render_meshes

BODY_RGBA, CLOTH_RGBA = (0.85, 0.72, 0.62, 1.0), (0.35, 0.45, 0.8, 1.0)
# (gender, age, muscle, weight, height, proportions): none of them in the database
BODIES = ((1.0, 0.5, 0.3, 0.15, 0.15, 0.5), (0.0, 0.7, 0.6, 0.9, 0.85, 0.5), (1.0, 0.9, 0.4, 0.85, 0.4, 0.4),
          (0.0, 0.4, 0.8, 0.3, 0.9, 0.6), (0.5, 0.6, 0.5, 0.5, 0.5, 0.5))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--outfit", default="tshirt-skirt")
    ap.add_argument("--pose", type=int, default=3, help="which held-out test pose")
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    torch.set_num_threads(1)
    body = default_body()
    shapes = torch.tensor(BODIES, dtype=torch.float32)
    rot = test_poses(20)[a.pose:a.pose + 1]
    drapes = drape_poses(TaylorBuildConfig(outfit=a.outfit), rot, [shapes], desc="preview")[0]["posed"][1:]
    rows = {"PBNS + resizer": Dresser(a.outfit, dynamics=False),
            "Taylor, motion": Dresser(a.outfit, garment_model="taylor", drape_iterations=0),
            "Taylor, photo": Dresser(a.outfit, garment_model="taylor")}
    faces, tiles = body.faces.numpy(), {k: [] for k in (*rows, "drape")}
    for i, s in enumerate(shapes):
        with torch.no_grad():
            bv = body(rot, s[None]).vertices[0].numpy()
        centre = 0.5 * (bv.min(0) + bv.max(0))
        clothes = {k: d(body, rot, s[None]).vertices[0] for k, d in rows.items()} | {"drape": drapes[i]}
        for k, cloth in clothes.items():
            err = "" if k == "drape" else f" {1000 * np.linalg.norm(cloth - drapes[i], axis=1).mean():.1f} mm"
            cloth_faces = rows["Taylor, photo"].model.faces.numpy()
            img = render_meshes([(bv, faces, BODY_RGBA), (cloth, cloth_faces, CLOTH_RGBA)],
                                size=(260, 380), center=centre, distance=3.0)
            cv2.putText(img, k + err, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
            tiles[k].append(img)
    out = Path(a.out or f"demos/previews/taylor-{a.outfit}.jpg")
    out.parent.mkdir(parents=True, exist_ok=True)
    grid = np.concatenate([np.concatenate(t, 1) for t in tiles.values()], 0)
    cv2.imwrite(str(out), grid[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, 85])
    print(out)


if __name__ == "__main__":
    main()
