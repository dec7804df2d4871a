"""Pick the 18 SMPLR surface landmarks as fixed vertices of any body model's rest mesh.

Each landmark is a rule on the rest mesh (body frame: +Y up, +Z forward, +X left), so the
same definitions apply to anny and to a user's SMPL-family file. Rules use the joints and
the dominant skinning joint of each vertex; they pick extreme points (most forward, highest,
...) within a region, which are stable and easy to check by eye.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from recon.body import skeleton

J = {n: i for i, n in enumerate(skeleton.JOINT_NAMES)}


def _pick(verts: np.ndarray, mask: np.ndarray, score: np.ndarray, name: str) -> int:
    if not mask.any():
        raise ValueError(f"landmark {name!r}: no vertex satisfies its rule on this body model")
    cand = np.flatnonzero(mask)
    return int(cand[np.argmax(score[cand])])


def select_landmarks(verts: np.ndarray, joints: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Return the vertex index of each landmark, in ``skeleton.LANDMARK_NAMES`` order."""
    dominant = weights.argmax(axis=1)
    # Body scale from the rest skeleton, so radii work for any size of model.
    height = joints[J["head"], 1] - min(joints[J["left_ankle"], 1], joints[J["right_ankle"], 1])
    r = 0.06 * height / 1.4

    def near(joint: str, radius: float) -> np.ndarray:
        return np.linalg.norm(verts - joints[J[joint]], axis=1) < radius

    def dom(*names: str) -> np.ndarray:
        return np.isin(dominant, [J[n] for n in names])

    # Left/right symmetry: right landmarks are the mirror vertices of left ones; midline
    # landmarks are self-mirrored vertices (exactly on X=0 for a symmetric mesh).
    mirror = cKDTree(verts).query(verts * np.array([-1.0, 1.0, 1.0]))[1]
    midline = mirror == np.arange(len(verts))
    if not midline.any():
        ax = np.abs(verts[:, 0])
        midline = ax <= max(0.25 * r, 1.01 * ax.min())
    x, y, z = verts[:, 0], verts[:, 1], verts[:, 2]
    out: dict[str, int] = {}
    out["head_top"] = _pick(verts, dom("head"), y, "head_top")
    out["nose"] = _pick(verts, dom("head") & midline, z, "nose")
    chest_band = np.abs(y - joints[J["spine3"], 1]) < r
    out["chest"] = _pick(verts, midline & chest_band, z, "chest")
    out["upper_back"] = _pick(verts, midline & chest_band, -z, "upper_back")
    belly_band = np.abs(y - joints[J["spine1"], 1]) < r
    out["belly"] = _pick(verts, midline & belly_band, z, "belly")
    out["sacrum"] = _pick(verts, midline & dom("pelvis", "spine1") & (y < joints[J["spine1"], 1]), -z, "sacrum")
    for side, sign in (("left", 1.0),):
        sh = joints[J[f"{side}_shoulder"]]
        above = dom(f"{side}_collar", f"{side}_shoulder") & (np.abs(x - sh[0]) < 0.5 * r)
        out[f"{side}_shoulder_top"] = _pick(verts, above, y, f"{side}_shoulder_top")
        out[f"{side}_elbow_back"] = _pick(verts, near(f"{side}_elbow", 1.2 * r), -z, f"{side}_elbow_back")
        hand = 0.5 * (joints[J[f"{side}_wrist"]] + joints[J[f"{side}_hand"]])
        near_hand = np.linalg.norm(verts - hand, axis=1) < 1.2 * r
        out[f"{side}_hand_outer"] = _pick(verts, near_hand, sign * x, f"{side}_hand_outer")
        hip_band = dom(f"{side}_hip") & (np.abs(y - joints[J[f"{side}_hip"], 1]) < 1.5 * r)
        out[f"{side}_hip_side"] = _pick(verts, hip_band, sign * x, f"{side}_hip_side")
        out[f"{side}_knee_front"] = _pick(verts, near(f"{side}_knee", 1.5 * r), z, f"{side}_knee_front")
        out[f"{side}_toe_tip"] = _pick(verts, dom(f"{side}_foot", f"{side}_ankle"), z, f"{side}_toe_tip")
    for name in list(out):
        if name.startswith("left_"):
            out["right_" + name[5:]] = int(mirror[out[name]])
    return np.array([out[n] for n in skeleton.LANDMARK_NAMES], dtype=np.int64)
