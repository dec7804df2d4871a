"""Body demo (the README's main command until the image pipeline lands).

Samples body shapes (anny prior, both genders) in poses from the held-out test mocap,
renders them with pyrender and exports one posed body as .obj and .glb.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from recon import paths


def body_demo(out: Path, seed: int = 0, n: int = 4) -> list[Path]:
    import cv2
    import trimesh

    from recon.body import default_body
    from recon.poses.sampler import PoseSampler, ShapeSampler
    from recon.viz import render_meshes

    body = default_body()
    poses = PoseSampler(body, split="test", noise_deg=0.0, mirror=False, seed=seed).sample(n)
    shapes = ShapeSampler(body, seed=seed).sample(n)
    shapes[:, 0] = torch.tensor([0.0, 1.0] * (n // 2) + [0.0] * (n % 2))
    with torch.no_grad():
        o = body(poses, shapes)
    faces = body.faces.numpy()
    tiles = []
    for i in range(n):
        v = o.vertices[i].numpy()
        colour = (0.55, 0.65, 0.85, 1.0) if shapes[i, 0] < 0.5 else (0.85, 0.6, 0.55, 1.0)
        tiles.append(np.concatenate([render_meshes([(v, faces, colour)], size=(320, 400)),
                                     render_meshes([(v, faces, colour)], size=(320, 400), yaw_deg=90)], 0))
    grid = np.concatenate(tiles, 1)
    out.mkdir(parents=True, exist_ok=True)
    png, obj, glb = out / "bodies.png", out / "body0.obj", out / "body0.glb"
    paths.atomic_write(png, lambda t: cv2.imwrite(t, grid[..., ::-1]) or (_ for _ in ()).throw(OSError(f"cannot write {t}")))
    mesh = trimesh.Trimesh(o.vertices[0].numpy(), faces, process=False)
    paths.atomic_write(obj, lambda t: mesh.export(t, file_type="obj"))
    paths.atomic_write(glb, lambda t: mesh.export(t, file_type="glb"))
    return [png, obj, glb]
