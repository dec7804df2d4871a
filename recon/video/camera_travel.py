"""Where a travelling camera went: its turn and move frame by frame, from the ground and the far
background, at the people's scale.

A turn alone moves every background point the same way whatever its depth; a move does not, and
the turn fitted as if the camera only turned takes in part of a sideways move. Where the camera
moved (``TurnEstimate.travelled``), each measured match between frames a and b is fitted again
with both (six numbers, ``scipy.optimize.least_squares`` with a robust loss, started from the
turn): the points whose rays meet the ground plane (n . X = d in a's camera, within
``MAX_DISTANCE``) move by the plane's homography ``R_ab + t_ab n^T / d``, the others as the far
background, by the turn alone; points that are neither (a wall, a car) are left out by the loss.
The ground plane comes from the people: their foot joints, under their upright torsos, in the
first frame's camera (``ground_from_people``: the feet of the first frames through the turn
alone, then of every frame through the poses found, refitted ``ROUNDS`` times). Each match carries
the camera on from its key frame's pose; frames no match reached are interpolated.

``camera_poses(estimate, k, ground) -> (R (T, 3, 3), t (T, 3))``: ``X_f = R_f X_ref + t_f`` for a
point's coordinates in frame f's camera and in the first frame's.
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from recon.body import skeleton
from recon.video.camera_motion import TurnEstimate
from recon.video.ground import ground_plane

MAX_DISTANCE = 40.0  # m: ground points farther than this are taken as far background
FIRST_FRAMES = 10  # frames whose people give the first ground plane (the camera has moved little)
ROUNDS = 3  # plane from the poses, poses from the plane
FEET = [skeleton.JOINT_NAMES.index(n) for n in ("left_foot", "right_foot")]
NECK = skeleton.JOINT_NAMES.index("neck")


def travelling_camera(estimate: TurnEstimate, k: np.ndarray, frame: np.ndarray, points: np.ndarray,
                      sole: float) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, float]]:
    """The camera's poses (``camera_poses``) and the ground plane in the first frame's camera,
    from the people found: ``frame`` (N,) the frame of each, ``points`` (N, 42, 3) their J+ in
    that frame's camera; ``sole``: the foot joint's height above the sole (m)."""
    frames = len(estimate.rotations)
    r, t = estimate.rotations, np.zeros((frames, 3))
    ground = ground_from_people(frame, points, r, t, sole, np.arange(min(FIRST_FRAMES, frames)))
    for _ in range(ROUNDS):
        r, t = camera_poses(estimate, k, ground)
        ground = ground_from_people(frame, points, r, t, sole, np.arange(frames))
    return r, t, ground


def ground_from_people(frame: np.ndarray, points: np.ndarray, r: np.ndarray, t: np.ndarray, sole: float,
                       frames: np.ndarray) -> tuple[np.ndarray, float]:
    """The plane (n, d), n up, under the foot joints of the people of ``frames``, in the first
    frame's camera (each frame's points taken there by its pose: X_ref = R^T (X - t))."""
    sel = np.isin(frame, frames)
    if not sel.any():
        raise ValueError("no people in the frames the ground is taken from")
    f = frame[sel]
    ref = np.einsum("nji,nkj->nki", r[f], points[sel] - t[f][:, None])
    up = ref[:, NECK] - ref[:, 0]
    up = np.median(up / np.linalg.norm(up, axis=1, keepdims=True), 0)
    return ground_plane(ref[:, FEET].reshape(-1, 3), up, sole)


def camera_poses(estimate: TurnEstimate, k: np.ndarray, ground: tuple[np.ndarray, float],
                 px: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """(T, 3, 3), (T, 3): each frame's camera from the first one's (module doc)."""
    n_ref, d_ref = np.asarray(ground[0], float), float(ground[1])
    turn = estimate.rotations
    frames = len(turn)
    r, t = np.full((frames, 3, 3), np.nan), np.full((frames, 3), np.nan)
    r[0], t[0] = np.eye(3), 0.0
    k_inv = np.linalg.inv(k)
    for a, b, pa, pb in sorted(estimate.matches, key=lambda m: m[1]):
        if np.isnan(t[a, 0]) or len(pa) < 6:
            continue
        n_a = r[a] @ n_ref
        d_a = d_ref + n_a @ t[a]
        r_ab, t_ab = turn_and_move(pa, pb, k, k_inv, turn[b] @ turn[a].T, n_a, d_a, px)
        r[b], t[b] = r_ab @ r[a], r_ab @ t[a] + t_ab
    known = np.flatnonzero(~np.isnan(t[:, 0]))
    for f in np.flatnonzero(np.isnan(t[:, 0])):  # the turn of the nearest known frame before, carried on
        g = known[np.searchsorted(known, f) - 1]
        r[f] = turn[f] @ turn[g].T @ r[g]
    t = np.stack([np.interp(np.arange(frames), known, t[known, c]) for c in range(3)], 1)
    return r, t


def turn_and_move(pa: np.ndarray, pb: np.ndarray, k: np.ndarray, k_inv: np.ndarray, r0: np.ndarray,
                  n_a: np.ndarray, d_a: float, px: float) -> tuple[np.ndarray, np.ndarray]:
    """(R_ab, t_ab) with X_b = R_ab X_a + t_ab that best take the points ``pa`` (N, 2) of frame a
    to ``pb``: those on the ground plane (n_a . X = d_a) by its homography, the rest as far away;
    started from the turn ``r0`` and no move."""
    ra = np.concatenate([pa, np.ones((len(pa), 1))], 1) @ k_inv.T
    s = (ra @ n_a) / d_a  # 1 / the ray's length to the plane (units of ra): > 0 where it meets it ahead
    on = (s > 0) & (np.linalg.norm(ra, axis=1) < MAX_DISTANCE * np.maximum(s, 1e-9))
    lift = np.where(on, s, 0.0)[:, None]

    def residuals(x):
        y = ra @ Rotation.from_rotvec(x[:3]).as_matrix().T + lift * x[None, 3:]
        uv = y @ k.T
        return (uv[:, :2] / uv[:, 2:] - pb).ravel()
    x0 = np.concatenate([Rotation.from_matrix(r0).as_rotvec(), np.zeros(3)])
    x = least_squares(residuals, x0, loss="soft_l1", f_scale=px).x
    return Rotation.from_rotvec(x[:3]).as_matrix(), x[3:]
