"""NCS's dynamic reference: newton's VBD run on short held-out clips (``DYNAMIC_CLIPS``; the val
performers' ``VAL_CLIPS`` for choices), cached in ``<cache>/garment-dynamic/`` (minutes a clip),
and the hem measures ``recon garment eval --model ncs`` (``ncs.eval``) scores the models with.
"""
from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np
import roma
import torch

from recon import paths
from recon.body.base import BodyModel
from recon.errors import ReconError
from recon.garment import reference, store
from recon.garment.mesh import boundary_loops, faces_within
from recon.garment.ncs.model import hanging_part
from recon.garment.pbns.model import PBNS, trained_outfit
from recon.poses.mocap import MocapPoses


class DynamicClip(NamedTuple):
    """A scored slice of a test clip: ``frames`` frames from ``start``, its last pose held ``hold``
    more frames, after ``lead`` frames of the clip before it that the simulation and the models
    run through unscored (the cloth's swing, and NCS's recurrent state, come from the motion
    before the slice, not from a start at rest)."""
    name: str
    start: int
    frames: int
    hold: int
    lead: int
    motion: str
    split: str = "test"


# Held-out performers. The turn is the test split's fastest (root yaw rate); no test clip stops
# suddenly, so the run's last pose is held: the body stops dead and the cloth should swing on and
# settle (the run is 42 frames long, so its lead-in is short)
DYNAMIC_CLIPS = (DynamicClip("03_03", 975, 60, 0, 30, "turn (3.3 rad/s)"),
                 DynamicClip("09_11", 12, 30, 30, 12, "run, then a dead stop"),
                 DynamicClip("12_01", 30, 60, 0, 30, "walk"))
# The same kinds of motion from the val performers: what training choices are tuned on (the test
# clips above only report)
VAL_CLIPS = (DynamicClip("06_12", 210, 60, 0, 30, "turn (3.1 rad/s)", "val"),
             DynamicClip("02_03", 12, 30, 30, 12, "run, then a dead stop", "val"),
             DynamicClip("02_01", 30, 56, 0, 30, "walk", "val"))

def clip_motion(split_poses: MocapPoses, name: str, start: int = 0, frames: int | None = None, hold: int = 0):
    """Local rotations (T, 24, 3, 3) and translation (T, 3) of a clip (its first frame's pelvis
    above the origin), its last pose repeated ``hold`` more frames."""
    c = next((i for i, k in enumerate(split_poses.clips) if k["name"] == name), None)
    if c is None:
        raise ReconError(f"no clip {name} in the pose set")
    idx = np.nonzero(split_poses.clip == c)[0][start:None if frames is None else start + frames]
    idx = np.concatenate([idx, np.full(hold, idx[-1])])
    rot = roma.rotvec_to_rotmat(torch.from_numpy(split_poses.rotvec[idx]).float())
    tr = torch.from_numpy(split_poses.transl[idx]).float()
    return rot, tr - tr[:1] * torch.tensor([1.0, 0.0, 1.0])


def hem_vertices(rest: np.ndarray, faces: np.ndarray, band: float = 0.02) -> np.ndarray:
    """Boundary vertices within ``band`` m of the outfit's lowest point: the hem."""
    boundary = np.unique(np.concatenate(boundary_loops(faces)))
    return boundary[rest[boundary, 1] <= rest[boundary, 1].min() + band]


def dynamic_path(outfit: str, clip: DynamicClip) -> Path:
    c = clip
    return paths.cache_dir() / "garment-dynamic" / f"{outfit}-{c.name}-{c.start}-{c.frames}-{c.hold}-lead{c.lead}.npz"


def lead_in(clip: DynamicClip) -> tuple[torch.Tensor, torch.Tensor]:
    """The clip's rotations and translation from its lead-in's first frame."""
    return clip_motion(MocapPoses.load(clip.split), clip.name, clip.start - clip.lead, clip.lead + clip.frames,
                       clip.hold)


def dynamic_reference(body: BodyModel, outfit_name: str, pbns: PBNS, shape: torch.Tensor, clip: DynamicClip,
                      log=None) -> dict:
    """The newton simulation of ``clip`` from its lead-in (cached): {"vertices": (lead + T, n, 3),
    "subset": (N,) bool}; the cloth starts from its drape moving as the skinned outfit moves."""
    path = dynamic_path(outfit_name, clip)
    if path.exists():
        with np.load(path) as z:
            return {k: z[k] for k in z.files}
    if not reference.available():
        raise ReconError('the dynamic reference needs newton: pip install "recon[sim]" (docs/garments.md)')
    outfit, _, _ = trained_outfit(body, store.pbns_path(outfit_name))
    rot, tr = lead_in(clip)
    with torch.no_grad():
        o = body(rot, shape.expand(len(rot), -1), transl=tr)
        skinned = pbns.skin(pbns.rest, o.transforms).numpy()
    sub, held = hanging_part(outfit)
    faces = faces_within(outfit.faces, sub)
    pinned = held[sub]
    res = reference.simulate(o.vertices.numpy(), body.faces.numpy(), outfit.vertices[sub], skinned[0][sub], faces,
                             pinned, skinned[:, sub][:, pinned], reference.DynamicConfig(), skinned[:, sub], log)
    out = {"vertices": res["vertices"].astype(np.float32), "subset": sub, "seconds": np.array(res["seconds"]),
           "drape_settled": np.array(res["drape"]["settled"])}
    path.parent.mkdir(parents=True, exist_ok=True)
    def save(tmp):
        with open(tmp, "wb") as f:  # a file object: np.savez would append ".npz" to the temporary name
            np.savez(f, **out)
    paths.atomic_write(path, save)
    return out


def hem_twist(hem: torch.Tensor, skinned_hem: torch.Tensor) -> torch.Tensor:
    """(T,) the hem ring's mean rotation (rad) about the vertical through its skinned centroid, from
    where skinning puts it: > 0 counter-clockwise seen from above."""
    c = skinned_hem.mean(1, keepdim=True)
    a, b = (hem - c)[..., [2, 0]], (skinned_hem - c)[..., [2, 0]]  # (z, x): atan2 about +Y
    ang = torch.atan2(a[..., 1], a[..., 0]) - torch.atan2(b[..., 1], b[..., 0])
    return torch.atan2(torch.sin(ang), torch.cos(ang)).mean(1)
