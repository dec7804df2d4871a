"""Retarget a source skeleton's motion onto the canonical 24-joint body (recon.body.skeleton).

Method (per frame, vectorised):
1. Normalise the source: axes snapped so the rest pose has +Y up, +X the subject's left,
   +Z forward; root translation rescaled by the ratio of leg lengths (unit-free).
2. Each canonical joint j is a source point (a node, or a blend of two nodes). Its global
   rotation G_j is the source segment's rotation since its rest pose, S_j, times a constant
   rest alignment A_j (minimal rotation from our rest bone direction to the source's), then
   corrected by the smallest swing that makes our bone j->child point exactly along the
   source bone (twist kept from the source). Pelvis and spine3 use a two-vector frame
   (bone direction + left/right axis of hips or shoulders).
3. Local rotations R_j = G_parent^T G_j.
So every single-child bone reproduces the source bone direction up to round-off; bones that
leave a branching joint (pelvis->hips, spine3->collars) follow proportions and are reported.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from recon.body import skeleton
from recon.errors import ReconError
from recon.poses.motion import SourceMotion, local_rotations

N = skeleton.JOINT_NAMES
JI = {n: i for i, n in enumerate(N)}

# Primary child of each canonical joint (bone used for direction matching). "head_top" and
# "*_toe_tip" are landmarks; hands have none and follow the wrist.
PRIMARY_CHILD = {
    "pelvis": "spine1", "spine1": "spine2", "spine2": "spine3", "spine3": "neck", "neck": "head",
    "head": "head_top",
}
for _s in ("left", "right"):
    PRIMARY_CHILD.update({
        f"{_s}_hip": f"{_s}_knee", f"{_s}_knee": f"{_s}_ankle", f"{_s}_ankle": f"{_s}_foot",
        f"{_s}_foot": f"{_s}_toe_tip", f"{_s}_collar": f"{_s}_shoulder",
        f"{_s}_shoulder": f"{_s}_elbow", f"{_s}_elbow": f"{_s}_wrist", f"{_s}_wrist": f"{_s}_hand",
    })
FRAME_JOINTS = {"pelvis": ("left_hip", "right_hip"), "spine3": ("left_shoulder", "right_shoulder")}


def _sided(table: dict[str, object], left: str, right: str) -> dict[str, object]:
    """Expand {'left_x': 'L...'} templates written with {s} into both sides."""
    out = {}
    for k, v in table.items():
        if "{s}" in k:
            for side, code in (("left", left), ("right", right)):
                kw = {"s": code, "h": code[0].lower(), "f": code[0].upper()}
                fill = (lambda x, kw=kw: x.format(**kw)) if isinstance(v, str) else (
                    lambda x, kw=kw: tuple(e.format(**kw) if isinstance(e, str) else e for e in x))
                out[k.format(s=side)] = fill(v)
        else:
            out[k] = v
    return out


# Canonical point -> source node, or ("lerp", node_a, node_b, t). Rotation comes from node_a.
SKELETON_MAPS: dict[str, dict[str, object]] = {
    "cmu_asf": _sided({
        "pelvis": "root", "spine1": "upperback", "spine2": "thorax", "spine3": "lowerneck",
        "neck": "upperneck", "head": "head", "head_top": "head_end",
        "{s}_hip": "{s}femur", "{s}_knee": "{s}tibia", "{s}_ankle": "{s}foot", "{s}_foot": "{s}toes",
        "{s}_toe_tip": "{s}toes_end", "{s}_collar": "{s}clavicle", "{s}_shoulder": "{s}humerus",
        "{s}_elbow": "{s}radius", "{s}_wrist": "{s}wrist", "{s}_hand": "{s}hand",
    }, "l", "r"),
    "cmu_bvh": _sided({
        # Joint X sits at the start of the segment it rotates; Chest2->lowerneck and
        # Wrist->hand have zero length, so spine2 is mid-Chest and the wrist turns with lhand.
        "pelvis": "Hips", "spine1": "Chest", "spine2": ("lerp", "Chest", "Chest2", 0.5),
        "spine3": "lowerneck", "neck": "Neck", "head": "Head", "head_top": "Head_end",
        "{s}_hip": "{s}Hip", "{s}_knee": "{s}Knee", "{s}_ankle": "{s}Ankle", "{s}_foot": "{s}Toe",
        "{s}_toe_tip": "{s}Toe_end", "{s}_collar": "{s}Collar", "{s}_shoulder": "{s}Shoulder",
        "{s}_elbow": "{s}Elbow", "{s}_wrist": ("lerp", "{h}hand", "{s}Wrist", 0.0),
        "{s}_hand": "{f}Fingers",
    }, "Left", "Right"),
    "daz": _sided({
        "pelvis": "hip", "spine1": "abdomen", "spine2": "chest", "spine3": ("lerp", "chest", "neck", 0.5),
        "neck": "neck", "head": "head", "head_top": ("lerp", "leftEye", "rightEye", 0.5),
        "{s}_hip": "{s}Thigh", "{s}_knee": "{s}Shin", "{s}_ankle": "{s}Foot",
        "{s}_foot": ("lerp", "{s}Foot", "{s}Foot_end", 0.7), "{s}_toe_tip": "{s}Foot_end",
        "{s}_collar": "{s}Collar", "{s}_shoulder": "{s}Shldr", "{s}_elbow": "{s}ForeArm",
        "{s}_wrist": "{s}Hand", "{s}_hand": "{s}Mid1",
    }, "l", "r"),
    "mixamo": _sided({
        "pelvis": "Hips", "spine1": "Spine1", "spine2": "Spine2", "spine3": "Spine3",
        "neck": "Neck", "head": "Head", "head_top": "Head_end",
        "{s}_hip": "{s}UpLeg", "{s}_knee": "{s}Leg", "{s}_ankle": "{s}Foot", "{s}_foot": "{s}ToeBase",
        "{s}_toe_tip": "{s}ToeBase_end", "{s}_collar": "{s}Shoulder", "{s}_shoulder": "{s}Arm",
        "{s}_elbow": "{s}ForeArm", "{s}_wrist": "{s}Hand", "{s}_hand": "{s}HandEnd",
    }, "Left", "Right"),
}
# Daz has no head end site: the eyes' midpoint is rigid with the head, which is all that
# the rest alignment A_head needs.


def detect_skeleton(names: list[str]) -> str:
    s = set(names)
    if "lowerback" in s and "lfemur" in s:
        return "cmu_asf"
    if "LHipJoint" in s and "LeftHip" in s:
        return "cmu_bvh"
    if "abdomen" in s and "lThigh" in s:
        return "daz"
    if "Spine3" in s and "LeftUpLeg" in s:
        return "mixamo"
    raise ReconError(f"unsupported source skeleton (joints: {', '.join(names[:12])}, ...)")


def _swing(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Smallest rotation taking unit vectors a to b, (..., 3) -> (..., 3, 3)."""
    a, b = np.broadcast_arrays(a, b)
    v = np.cross(a, b)
    c = np.einsum("...i,...i->...", a, b)
    vx = np.zeros(a.shape[:-1] + (3, 3))
    vx[..., 0, 1], vx[..., 0, 2], vx[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    vx[..., 1, 0], vx[..., 2, 0], vx[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    k = 1.0 / np.maximum(1.0 + c, 1e-8)
    r = np.eye(3) + vx + (vx @ vx) * k[..., None, None]
    flip = c < -1 + 1e-6  # antiparallel: half turn about any axis orthogonal to a
    if flip.any():
        axis = np.cross(a[flip], np.array([1.0, 0.0, 0.0]))
        bad = np.linalg.norm(axis, axis=-1) < 1e-6
        axis[bad] = np.cross(a[flip][bad], np.array([0.0, 1.0, 0.0]))
        r[flip] = Rotation.from_rotvec(np.pi * _unit(axis)).as_matrix()
    return r


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def _frame(primary: np.ndarray, lateral: np.ndarray) -> np.ndarray:
    """Orthonormal frame with columns (lateral', primary, lateral' x primary)."""
    y = _unit(primary)
    x = _unit(lateral - np.einsum("...i,...i->...", lateral, y)[..., None] * y)
    return np.stack([x, y, np.cross(x, y)], axis=-1)


def snap_to_joint(v: np.ndarray) -> np.ndarray:
    out = np.zeros(3)
    k = int(np.argmax(np.abs(v)))
    out[k] = np.sign(v[k])
    return out


@dataclass
class Retargeted:
    rotmats: np.ndarray  # (F, 24, 3, 3) local rotations, body frame
    transl: np.ndarray  # (F, 3) pelvis position, metres, body frame
    errors_deg: dict[str, np.ndarray]  # bone "a->b" -> (F,) angle to the source bone


class Retargeter:
    """Holds the target rest skeleton; call ``retarget(motion)`` per clip."""

    def __init__(self, rest_joints: np.ndarray, rest_landmarks: np.ndarray):
        self.rest = {n: rest_joints[i] for i, n in enumerate(N)}
        for name in ("head_top", "left_toe_tip", "right_toe_tip"):
            self.rest[name] = rest_landmarks[skeleton.LANDMARK_NAMES.index(name)]
        legs = [np.linalg.norm(self.rest[a] - self.rest[b]) for a, b in
                (("left_hip", "left_knee"), ("left_knee", "left_ankle"))]
        self.leg_length = float(sum(legs))

    @staticmethod
    def _points(m: SourceMotion, spec, rest: bool):
        pos = m.rest_positions if rest else m.positions
        rot = m.rest_rotations if rest else m.rotations
        if isinstance(spec, str):
            k = m.index(spec)
            return pos[..., k, :], rot[..., k, :, :]
        _, a, b, t = spec
        ka, kb = m.index(a), m.index(b)
        return (1 - t) * pos[..., ka, :] + t * pos[..., kb, :], rot[..., ka, :, :]

    def retarget(self, m: SourceMotion, skeleton_kind: str | None = None) -> Retargeted:
        kind = skeleton_kind or detect_skeleton(m.names)
        table = SKELETON_MAPS[kind]
        # Axis normalisation from the rest pose (rows: left, up, forward).
        rp = {n: self._points(m, s, True)[0] for n, s in table.items()}
        up = snap_to_joint(rp["head"] - rp["pelvis"])
        left = snap_to_joint(rp["left_hip"] - rp["right_hip"])
        if abs(up @ left) > 0.5:
            raise ReconError("could not infer the source's up and left axes from its rest pose")
        align = np.stack([left, up, np.cross(left, up)])
        P, Pr, S = {}, {}, {}
        for n, s in table.items():
            p, r = self._points(m, s, False)
            p0, r0 = self._points(m, s, True)
            P[n], Pr[n] = p @ align.T, p0 @ align.T
            S[n] = align @ r @ np.swapaxes(r0, -1, -2) @ align.T
        f = m.num_frames
        src_leg = np.linalg.norm(Pr["left_hip"] - Pr["left_knee"]) + np.linalg.norm(Pr["left_knee"] - Pr["left_ankle"])

        G = np.zeros((f, 24, 3, 3))
        A: dict[str, np.ndarray] = {}
        errors: dict[str, np.ndarray] = {}
        for j, name in enumerate(N):
            child = PRIMARY_CHILD.get(name)
            parent = skeleton.JOINT_PARENTS[j]
            if child is None or child not in P:
                G[:, j] = G[:, parent] if parent >= 0 else np.eye(3)
                continue
            d_t = _unit(self.rest[child] - self.rest[name])
            d_s = _unit(P[child] - P[name])
            if name in FRAME_JOINTS:
                lj, rj = FRAME_JOINTS[name]
                f_t = _frame(d_t, self.rest[lj] - self.rest[rj])
                f_s = _frame(d_s, P[lj] - P[rj])
                G[:, j] = f_s @ f_t.T
            else:
                d_s0 = _unit(Pr[child] - Pr[name])
                A[name] = _swing(d_t, d_s0)
                g0 = S[name] @ A[name]
                G[:, j] = _swing(g0 @ d_t, d_s) @ g0
            errors[f"{name}->{child}"] = _angle(G[:, j] @ d_t, d_s)
            for other in skeleton.JOINT_NAMES:  # secondary bones leaving branching joints
                if skeleton.JOINT_PARENTS[JI[other]] == j and other != child and other in P:
                    d_t2 = _unit(self.rest[other] - self.rest[name])
                    d_s2 = P[other] - P[name]
                    ok = np.linalg.norm(d_s2, axis=-1) > 1e-6
                    errors[f"{name}->{other}"] = np.where(ok, _angle(G[:, j] @ d_t2, _unit(d_s2)), 0.0)
        local = local_rotations(G, skeleton.JOINT_PARENTS)
        transl = P["pelvis"] * (self.leg_length / src_leg)
        return Retargeted(local.astype(np.float32), transl.astype(np.float32), errors)


def _angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    c = np.clip(np.einsum("...i,...i->...", _unit(a), _unit(b)), -1.0, 1.0)
    return np.degrees(np.arccos(c))
