"""GCVAE preview: per garment type, three garments drawn from the latent space (z ~ N(0, I)) on the
rest body, then the same three animated by DeePSD at a held-out pose (no training for any of
them). Needs the GCVAE (`recon garment train --model gcvae`) and the shipped DeePSD.

    .venv/bin/python demos/gcvae_preview.py [--n 3] [--out FILE.jpg]
"""
from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np
import torch

from recon.body import default_body
from recon.garment.data import pose_set
from recon.garment.gcvae.command import dressed_sheet
from recon.garment.gcvae.model import TYPES
from recon.garment.gcvae.sample import load_model, sample
from recon.garment.templates import RestBody

SIZE = (150, 200)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="demos/previews/gcvae-samples.jpg")
    a = ap.parse_args()
    torch.set_num_threads(2)
    body = default_body()
    rb = RestBody(body)
    model = load_model(rb)
    pose = pose_set("test", 64, 0.3, 0)[5]
    rows = []
    for kind in TYPES:
        sheet = dressed_sheet(body, rb, sample(model, kind, a.n, a.seed), pose, [kind] * a.n, size=SIZE)
        rest, posed = sheet[:SIZE[1]], sheet[SIZE[1]:]
        rows.append(np.concatenate([rest, np.full((SIZE[1], 8, 3), 255, np.uint8), posed], 1))
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out), np.concatenate(rows, 0)[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, 85])
    print(out)


if __name__ == "__main__":
    main()
