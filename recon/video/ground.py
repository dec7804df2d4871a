"""Where a clip's people stand: the ground plane under their planted feet, and the world frame on it.

A track's ground (``ground_plane``) is the plane through its planted foot joints, held near the
torso's mean direction, the sole's height under them. Several tracks of one clip share one ground
(``common_ground``: their own grounds' mean normal, at their feet's median height); each is then
moved up or down until its own feet stand on it (``ground_height``), and all are written in one
world frame (``to_world``): +Y up from the ground, Z towards the camera, the origin on the ground
under the first track's start.
"""
from __future__ import annotations

import numpy as np
import torch

from recon.body import skeleton
from recon.body.base import BodyModel

FOOT_POINTS = {  # per foot: ankle, foot joint, toe tip landmark (J+ indices)
    "left": (skeleton.JOINT_NAMES.index("left_ankle"), skeleton.JOINT_NAMES.index("left_foot"),
             skeleton.NUM_JOINTS + skeleton.LANDMARK_NAMES.index("left_toe_tip")),
    "right": (skeleton.JOINT_NAMES.index("right_ankle"), skeleton.JOINT_NAMES.index("right_foot"),
              skeleton.NUM_JOINTS + skeleton.LANDMARK_NAMES.index("right_toe_tip")),
}
NECK = skeleton.JOINT_NAMES.index("neck")


def sole_height(body: BodyModel, shape: torch.Tensor) -> float:
    """How high the foot joint is above the sole in the rest pose (metres)."""
    with torch.no_grad():
        o = body(shape=shape)
    j = skeleton.JOINT_NAMES.index("left_foot")
    return float(o.joints[0, j, 1] - o.vertices[0, :, 1].min())


def torso_up(points: np.ndarray) -> np.ndarray:
    """The mean direction pelvis -> neck of J+ ``points`` (T, 42, 3): people hold the torso upright."""
    torso = points[:, NECK] - points[:, 0]
    return (torso / np.linalg.norm(torso, axis=1, keepdims=True)).mean(0)


def planted_feet(points: np.ndarray, planted: np.ndarray) -> np.ndarray:
    """(N, 3) the foot joints of J+ ``points`` (T, 42, 3) in the frames where ``planted`` (T, 2:
    left, right) says they are."""
    return np.concatenate([points[planted[:, s], FOOT_POINTS[side][1]] for s, side in enumerate(("left", "right"))])


def ground_plane(points: np.ndarray, up: np.ndarray, sole: float, stiffness: float = 0.05
                 ) -> tuple[np.ndarray, float]:
    """Plane n . x = d under planted foot joints ``points`` (N, 3): n is the direction of least
    spread, held near ``up`` (a line of footsteps does not fix the plane's tilt about it); d puts
    the sole ``sole`` metres under the points' median."""
    up = up / np.linalg.norm(up)
    if len(points) < 3:
        n = up
    else:
        c = points - points.mean(0)
        cov = c.T @ c / len(points) + stiffness * (np.eye(3) - np.outer(up, up))
        n = np.linalg.eigh(cov)[1][:, 0]
        n = n if n @ up > 0 else -n
    d = float(np.median(points @ n)) - sole if len(points) else 0.0
    return n, d


def lowest_plane(points: np.ndarray, up: np.ndarray) -> tuple[np.ndarray, float]:
    """Without planted feet: the plane normal to ``up`` under the lowest J+ of the track."""
    n = up / np.linalg.norm(up)
    return n, float(np.percentile(points.reshape(-1, 3) @ n, 1))


def common_ground(tracks: list[tuple[np.ndarray, np.ndarray, tuple[np.ndarray, float]]], soles: list[float]
                  ) -> tuple[np.ndarray, float] | None:
    """One ground for the tracks of a clip (``tracks``: per track its J+ and planted flags, as
    ``planted_feet`` takes them, and its own ground; ``soles``: its body's sole height): the mean
    of their own grounds' normals, weighted by their planted feet (a depth error moves a track's
    ground, it does not turn it: one plane through everyone's feet would tilt), at the median
    height of all those feet; None where fewer than 3 foot-frames were planted."""
    feet = [planted_feet(p, f) for p, f, _ in tracks]
    if sum(len(f) for f in feet) < 3:
        return None
    n = sum(len(f) * g[0] for f, (_, _, g) in zip(feet, tracks, strict=True))
    n = n / np.linalg.norm(n)
    return n, float(np.median(np.concatenate([f @ n - sole for f, sole in zip(feet, soles, strict=True)])))


def ground_height(points: np.ndarray, planted: np.ndarray, ground: tuple[np.ndarray, float], sole: float,
                  min_planted: int = 10) -> float:
    """How high a track's own ground (under its planted feet) lies over ``ground`` (metres, along its
    normal); 0 where fewer than ``min_planted`` foot-frames were planted."""
    feet = planted_feet(points, planted)
    n, d = ground
    return float(np.median(feet @ n)) - sole - d if len(feet) >= min_planted else 0.0


def to_world(ground: tuple[np.ndarray, float], origin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(R, o): X_world = R @ (X_cam - o). +Y the ground's normal, Z towards the camera (level),
    the origin on the ground under ``origin``."""
    n, d = ground
    fwd = np.array([0.0, 0.0, 1.0]) - n[2] * n
    z = -fwd / max(np.linalg.norm(fwd), 1e-9)
    x = np.cross(n, z)
    r = np.stack([x, n, z])
    return r, origin - (origin @ n - d) * n
