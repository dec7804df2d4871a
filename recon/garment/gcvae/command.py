"""``recon garment sample --type dress -n 8 --out DIR``: garments drawn from the GCVAE's latent space
(recon.garment.gcvae.sample) written as ``sample_NN.obj`` (rest pose, body frame: what ``--outfit``
takes) and shown in ``samples.jpg``, each on the rest body and animated by DeePSD (thesis ch. 4) at
a pose of the test performers, with no training."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import torch

from recon import paths
from recon.body import default_body
from recon.body.base import BodyModel
from recon.export.mesh import write_mesh
from recon.export.records import write_json
from recon.garment import store
from recon.garment.data import pose_set, posed_bodies
from recon.garment.deepsd.model import DeePSD, OutfitGraph
from recon.garment.gcvae.sample import load_model, sample
from recon.garment.templates import Garment, Outfit, RestBody
from recon.viz import render_meshes

BODY_RGBA, CLOTH_RGBA = (0.85, 0.72, 0.62, 1.0), (0.35, 0.45, 0.8, 1.0)


def dressed_sheet(body: BodyModel, rb: RestBody, meshes: list[tuple[np.ndarray, np.ndarray]], pose: torch.Tensor,
                  labels: list[str], size=(180, 240)) -> np.ndarray:
    """Two rows: each garment on the rest body, and animated by DeePSD at ``pose`` (24, 3, 3)."""
    deepsd = DeePSD.load(store.deepsd_path())[0]
    with torch.no_grad():
        rest_v = body.rest_geometry(body.mean_shape[None])[0][0].numpy()
    bv, _, bt = posed_bodies(body, pose[None], body.mean_shape[None])
    faces = body.faces.numpy()
    top, bottom = [], []
    for (v, f), label in zip(meshes, labels):
        outfit = Outfit([Garment("sample", v.astype(np.float32), f, 0, np.zeros(len(v), bool))])
        model = deepsd.outfit(OutfitGraph.of(rb, outfit))
        posed = model.pose(pose[None], bt)[0].numpy()
        for row, body_v, cloth in ((top, rest_v, v), (bottom, bv[0].numpy(), posed)):
            img = render_meshes([(body_v, faces, BODY_RGBA), (cloth, f, CLOTH_RGBA)], size=size,
                                center=np.array([0.0, -0.25, 0.0]), distance=2.6, yaw_deg=25.0)
            cv2.putText(img, label, (5, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (0, 0, 0), 1, cv2.LINE_AA)
            row.append(img)
    return np.concatenate([np.concatenate(top, 1), np.concatenate(bottom, 1)], 0)


def sample_command(kind: str, n: int, out: str | Path, seed: int = 0, sheet: bool = True) -> dict:
    body = default_body()
    rb = RestBody(body)
    model = load_model(rb)
    meshes = sample(model, kind, n, seed)
    out = Path(out)
    written = []
    for i, (v, f) in enumerate(meshes):
        p = out / f"sample_{i:02d}.obj"
        write_mesh(p, v, f)
        written.append(p.name)
    info = {"type": kind, "n": n, "seed": seed, "files": written,
            "vertices": [int(len(v)) for v, _ in meshes]}
    if sheet:
        pose = pose_set("test", 64, 0.3, 0)[seed % 64]
        img = dressed_sheet(body, rb, meshes, pose, [f"{kind} {i}" for i in range(n)])
        paths.atomic_write(out / "samples.jpg", lambda t: cv2.imwrite(t, img[..., ::-1]))
        info["sheet"] = "samples.jpg"
    write_json(out / "samples.json", info)
    return info
