"""DeePSD preview: outfits it never saw, animated without training. Left: held-out outfits of the
generator (one per family) at a held-out pose: LBS with nearest-body weights, DeePSD, and the drape
(the ground truth), with the error to the drape. Right column block: a garment not from the
generator (demos/garments/tube-dress.obj, an irregular triangulation): its template and DeePSD at
two held-out poses. Needs the DeePSD drapes (`recon garment train --model deepsd`).

    .venv/bin/python demos/deepsd_preview.py [--out FILE.jpg]
"""
from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np
import torch

from recon.body import default_body
from recon.garment import store
from recon.garment.data import posed_bodies
from recon.garment.deepsd.data import DeePSDDataConfig
from recon.garment.deepsd.eval import predict
from recon.garment.deepsd.model import DeePSD, OutfitGraph
from recon.garment.deepsd.train import load_samples
from recon.garment.templates import RestBody, make_outfit
from recon.viz import render_meshes

BODY_RGBA, CLOTH_RGBA = (0.85, 0.72, 0.62, 1.0), (0.35, 0.45, 0.8, 1.0)
SIZE = (190, 250)
TUBE = "demos/garments/tube-dress.obj"


def tile(body_v, bfaces, v, f, label, yaw=30.0):
    img = render_meshes([(body_v, bfaces, BODY_RGBA), (v, f, CLOTH_RGBA)], size=SIZE,
                        center=np.array([body_v[:, 0].mean(), body_v[:, 1].mean() - 0.1, body_v[:, 2].mean()]),
                        distance=2.5, yaw_deg=yaw)
    cv2.putText(img, label, (5, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    return img


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--pose", type=int, default=1, help="which of the test poses")
    ap.add_argument("--out", default="demos/previews/deepsd-held-out.jpg")
    a = ap.parse_args()
    torch.set_num_threads(2)
    body = default_body()
    bfaces = body.faces.numpy()
    model = DeePSD.load(store.deepsd_path())[0]
    samples = load_samples(body, "test", DeePSDDataConfig())
    seen, chosen = set(), []
    for s in samples:
        if s.family not in seen:
            seen.add(s.family)
            chosen.append(s)
    chosen = chosen[:4]
    k = a.pose
    rb = RestBody(body)
    tube = make_outfit(body, TUBE)
    tube_model = model.outfit(OutfitGraph.of(rb, tube))
    rest_v = body.rest_geometry(body.mean_shape[None])[0][0].detach().numpy()
    rows = []
    for r, s in enumerate(chosen):
        bv = s.body_v[k].numpy()
        row = []
        for method, name in (("lbs", "LBS"), ("ours", "DeePSD"), ("drape", "drape")):
            v = predict(method, s, {"ours": model}, {})[k]
            err = float((v - s.drapes[k]).norm(dim=-1).mean()) * 1000
            label = f"{s.family}: {name}" + ("" if method == "drape" else f" {err:.0f} mm")
            row.append(tile(bv, bfaces, v.numpy(), s.graph.faces, label))
        if r == 0:
            row.append(tile(rest_v, bfaces, tube.vertices, tube.faces, "tube dress (not generated)"))
        else:  # the other test poses
            rot = samples[0].rotmats[(k + r) % len(samples[0].rotmats)][None]
            pbv, _, pbt = posed_bodies(body, rot, body.mean_shape[None])
            v = tube_model.pose(rot, pbt)[0].numpy()
            row.append(tile(pbv[0].numpy(), bfaces, v, tube.faces, "tube dress: DeePSD"))
        rows.append(np.concatenate(row, 1))
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out), np.concatenate(rows, 0)[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, 85])
    print(out)


if __name__ == "__main__":
    main()
