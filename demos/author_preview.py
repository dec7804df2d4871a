"""Keyframe authoring preview: a held-out clip and a held-out fabric; two keyframes of the
simulation given (yellow labels), the rest of the clip propagated through the intrinsic garment
space. Rows: the simulation with the true parameters, ours from the two keyframes, linear
interpolation of the vertices between them, NCS (the default fabric, no keyframes). Columns: frames
across the clip. Needs the outfit's authoring model and simulations (`recon garment train --model
author`).

    .venv/bin/python demos/author_preview.py [--outfit tshirt-skirt] [--sim 0] [--out FILE.jpg]
"""
from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np
import torch

from recon.body import default_body
from recon.garment import store
from recon.garment.author.data import AuthorDataConfig, plan, sim_folder, teacher_config
from recon.garment.author.eval import interpolate, keyframes
from recon.garment.author.model import PELVIS, AuthorModel, Session, base_ncs, clip_inputs
from recon.garment.dress import Dresser
from recon.garment.ncs.data import Motions
from recon.garment.pbns.model import PBNS
from recon.viz import render_meshes

BODY_RGBA, CLOTH_RGBA = (0.85, 0.72, 0.62, 1.0), (0.35, 0.45, 0.8, 1.0)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--outfit", default="tshirt-skirt")
    ap.add_argument("--sim", type=int, default=0, help="which test simulation (parameter set x window)")
    ap.add_argument("--columns", type=int, default=7)
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    torch.set_num_threads(1)
    body = default_body()
    cfg = AuthorDataConfig(outfit=a.outfit)
    folder, sims = sim_folder(cfg), plan(cfg)
    sim = [s for s in sims if s.split == "test"][a.sim]
    model, _ = AuthorModel.load(store.author_path(a.outfit))
    pbns, ck = PBNS.load(store.trained_pbns(a.outfit))
    shape = ck["shape"]
    rot, transl = Motions(body, shape[None], teacher_config(a.outfit).smooth_motion).motion(sim.chunk)
    static, yaw, joints = clip_inputs(body, pbns, shape, rot, transl)
    ncs = base_ncs(a.outfit, model.cfg)
    base = clip_inputs(body, pbns, shape, rot, transl, ncs)[0] if ncs is not None else static
    truth = static.clone()
    truth[:, model.index] += torch.from_numpy(np.load(folder / f"{sim.name}.npy").astype(np.float32))
    t = len(truth)
    keys = keyframes(t, cfg.lead, 0.01)
    session = Session(model, base, yaw, joints)
    for k in keys:
        session.set_key(k, truth[k])
    pelvis = joints[:, PELVIS:PELVIS + 1]
    char = torch.einsum("kji,knj->kni", yaw[keys], truth[keys] - pelvis[keys])
    rows = {"simulation": truth, "ours (2 keyframes)": session.propagate(),
            "interpolation": torch.einsum("tij,tnj->tni", yaw, interpolate(char, keys, t)) + pelvis,
            "NCS (default fabric)": torch.from_numpy(Dresser(a.outfit).animate(body, rot, shape, transl).vertices)}
    shown = sorted(set(np.linspace(cfg.lead, t - 1, a.columns - len(keys)).astype(int).tolist()) | set(keys))
    faces, bfaces = pbns.faces.numpy(), body.faces.numpy()
    with torch.no_grad():
        bv = body(rot[shown], shape[None].expand(len(shown), -1), transl=transl[shown]).vertices.numpy()
    tiles = []
    for name, v in rows.items():
        row = []
        for i, f in enumerate(shown):
            centre = joints[f, PELVIS].numpy() + np.array([0.0, -0.3, 0.0])
            img = render_meshes([(bv[i], bfaces, BODY_RGBA), (v[f].numpy(), faces, CLOTH_RGBA)], size=(200, 260),
                                center=centre, distance=2.4, yaw_deg=70.0)
            err = float((v[f, model.index] - truth[f, model.index]).norm(dim=-1).mean()) * 1000
            label = f"{f}" + (" KEY" if f in keys else "") + ("" if name == "simulation" else f" {err:.0f} mm")
            cv2.putText(img, label, (5, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.42,
                        (200, 150, 0) if f in keys else (0, 0, 0), 1, cv2.LINE_AA)
            if i == 0:
                cv2.putText(img, name, (5, 250), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (0, 0, 0), 1, cv2.LINE_AA)
            row.append(img)
        tiles.append(np.concatenate(row, 1))
    out = Path(a.out or f"demos/previews/author-{a.outfit}.jpg")
    out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out), np.concatenate(tiles, 0)[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, 85])
    print(out, sim.name, sim.params)


if __name__ == "__main__":
    main()
