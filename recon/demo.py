"""``recon demo``: the README's main command on the bundled example photos.

``photo_demo``: the bundled photos through ``recon run`` (dressed when the outfit is trained)
and a contact sheet (photo | overlay | side view). ``body_demo``: sampled bodies in held-out
mocap poses, one exported as .obj/.glb, and SMPLR's reconstructions of them from noisy joints +
landmarks. ``dressed_gif``: the outfit on a held-out mocap clip.
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import roma
import torch
from PIL import Image

from recon import paths
from recon.body import default_body
from recon.export.media import write_image
from recon.export.mesh import write_mesh
from recon.garment.dress import Dresser
from recon.poses.mocap import MocapPoses
from recon.poses.sampler import PoseSampler, ShapeSampler
from recon.run import RunOptions, run
from recon.smplr import SMPLR
from recon.smplr.model import WEIGHTS as SMPLR_WEIGHTS
from recon.smplr.noise import fixed_gaussian
from recon.viz import render_meshes

EXAMPLES = paths.DATA_DIR / "examples"


def body_demo(out: Path, seed: int = 0, n: int = 4) -> list[Path]:
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
    write_image(png, grid)
    write_mesh(obj, o.vertices[0].numpy(), faces)
    write_mesh(glb, o.vertices[0].numpy(), faces)
    written = [png, obj, glb]
    if SMPLR_WEIGHTS.exists():  # ground truth (grey) next to SMPLR from noisy J+ (blue)
        model = SMPLR.load(body)
        noisy = fixed_gaussian(o.points, 0.04, torch.Generator().manual_seed(seed))
        with torch.no_grad():
            rec = model(noisy).body
        tiles = []
        for i in range(n):
            gt_v, rec_v = o.vertices[i].numpy(), rec.vertices[i].numpy() + np.array([0.9, 0.0, 0.0])
            tiles.append(render_meshes([(gt_v, faces, (0.7, 0.7, 0.7, 1.0)), (rec_v, faces, (0.45, 0.6, 0.9, 1.0))],
                                       size=(480, 400)))
        sm = out / "smplr.png"
        write_image(sm, np.concatenate(tiles, 1))
        written.append(sm)
    return written


def example_photos() -> list[Path]:
    """The bundled example photos (recon/data/examples, see its SOURCES.md)."""
    return sorted(p for p in EXAMPLES.iterdir() if p.suffix.lower() in (".jpg", ".png"))


def photo_demo(out: Path, outfit: str | None = None) -> list[Path]:
    """``recon run`` on the bundled example photos + one contact sheet (photo | overlay | side)."""
    photos = example_photos()
    summary = run(photos, out / "photos", RunOptions(outfit=outfit), progress=False, log=lambda m: None,
                  page=False)  # the demo's own page (recon demo) shows them
    rows = []
    for p in photos:
        d = out / "photos" / p.stem
        if not (d / "result.json").exists():
            continue
        tiles = [cv2.imread(str(p))] + [cv2.imread(str(d / n)) for n in ("overlay.png", "side.png")]
        h = 320
        rows.append(np.concatenate([cv2.resize(t, (round(t.shape[1] * h / t.shape[0]), h)) for t in tiles], 1))
    if not rows:
        raise RuntimeError(f"no example photo was reconstructed: {summary.to_json()}")  # a bug: they all have a person
    w = max(r.shape[1] for r in rows)
    sheet = np.concatenate([np.pad(r, ((0, 0), (0, w - r.shape[1]), (0, 0)), constant_values=255) for r in rows], 0)
    path = out / "examples.png"
    write_image(path, sheet[..., ::-1])
    return [path, out / "photos"]


def dressed_gif(out: Path, outfit: str, frames: int = 60, size=(360, 480)) -> Path:
    """The outfit on a held-out mocap clip (first test clip), rendered with pyrender as a GIF."""
    body = default_body()
    m = MocapPoses.load("test")
    clip = m.clip[0]
    sel = np.nonzero(m.clip == clip)[0][:frames * 2:2]  # 15 fps
    rot = roma.rotvec_to_rotmat(torch.from_numpy(m.rotvec[sel]).float())
    rot[:, 0] = torch.eye(3)  # face the camera, keep the limbs' motion
    dresser = Dresser(outfit)
    shape = dresser.shape
    with torch.no_grad():
        bv = body(rot, shape[None].expand(len(rot), -1)).vertices.numpy()
    cloth = dresser(body, rot, shape.expand(len(rot), -1))
    images = []
    centre = bv.reshape(-1, 3).mean(0)
    for i in range(len(rot)):
        img = render_meshes([(bv[i] - centre, body.faces.numpy(), (0.85, 0.75, 0.68, 1.0)),
                             (cloth.vertices[i] - centre, cloth.faces, (0.35, 0.45, 0.8, 1.0))],
                            size=size, yaw_deg=25, distance=3.2, center=np.zeros(3))
        images.append(Image.fromarray(img))
    path = out / f"{outfit}-mocap.gif"
    out.mkdir(parents=True, exist_ok=True)
    paths.atomic_write(path, lambda t: images[0].save(t, format="GIF", save_all=True, append_images=images[1:],
                                                       duration=67, loop=0))
    return path
