"""The README's cloth-dynamics preview: skinning | PBNS | NCS on a held-out clip with a fast turn
and a dead stop (the test performer's turn, then its last pose held).

    .venv/bin/python demos/ncs_side_by_side.py [--outfit tshirt-skirt] [--out demos/previews]

The three models run on every frame at 30 fps (no collision resolution: the networks as they
are); the GIF keeps every second frame (15 fps).
"""
from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np
import torch

from recon.animate import BODY_RGBA, OUTFIT_RGBA
from recon.body import default_body
from recon.export.media import write_video
from recon.garment import store
from recon.garment.ncs.eval import MODELS, run_models
from recon.garment.ncs.model import NCS
from recon.garment.ncs.reference_eval import clip_motion
from recon.garment.pbns.model import PBNS
from recon.poses.mocap import MocapPoses
from recon.viz import SequenceRenderer

CLIP = ("03_03", 975, 60, 24)  # test performer 3: the split's fastest turn, then a dead stop
LABELS = ("skinning", "PBNS", "NCS")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--outfit", default="tshirt-skirt")
    ap.add_argument("--ncs", default=None, help="NCS weights (default: the outfit's shipped ones)")
    ap.add_argument("--out", default="demos/previews")
    ap.add_argument("--size", type=int, nargs=2, default=(200, 260), metavar=("W", "H"))
    a = ap.parse_args()
    torch.set_num_threads(2)
    body = default_body()
    pbns, ck = PBNS.load(store.pbns_path(a.outfit))
    ncs, _ = NCS.load(Path(a.ncs) if a.ncs else store.ncs_path(a.outfit))
    shape = ck["shape"][None]
    rot, tr = clip_motion(MocapPoses.load("test"), *CLIP)
    cloth = run_models(pbns, ncs, body, shape, rot, tr)
    with torch.no_grad():
        bv = body(rot, shape.expand(len(rot), -1), transl=tr).vertices.numpy()
    ground = float(bv[..., 1].min())
    height = float(bv[0, :, 1].max() - ground)
    renderer = SequenceRenderer(size=tuple(a.size), yaw_deg=30.0, distance=1.6 * height + 0.8)
    frames = []
    try:
        for t in range(0, len(rot), 2):
            centre = np.array([tr[t, 0].item(), ground + 0.5 * height, tr[t, 2].item()])
            panels = []
            for label, model in zip(LABELS, MODELS, strict=True):
                img = renderer([(bv[t], body.faces.numpy(), BODY_RGBA),
                                (cloth[model][t].numpy(), pbns.faces.numpy(), OUTFIT_RGBA)], centre, ground)
                img = np.ascontiguousarray(img)
                cv2.putText(img, label, (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (20, 20, 20), 1, cv2.LINE_AA)
                panels.append(img)
            strip = np.concatenate(panels, 1)
            if t >= CLIP[2]:
                cv2.putText(strip, "stop", (strip.shape[1] - 60, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (160, 20, 20), 1,
                            cv2.LINE_AA)
            frames.append(strip)
    finally:
        renderer.close()
    print(write_video(Path(a.out) / f"ncs-{a.outfit}-turn-stop.gif", frames, 15.0))


if __name__ == "__main__":
    main()
