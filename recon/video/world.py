"""A clip's tracks as motions in its one world frame: each track's optimisation on its per-frame
detections (``fit_track``: ``recon.video.smooth``), then every track on one ground, in one frame
(``one_world``: ``recon.video.ground``), so that the people of a clip stand where they stood
towards each other in every file written.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from recon.body.base import BodyModel
from recon.video.ground import common_ground, ground_height, to_world
from recon.video.outputs import WorldMotion
from recon.video.perframe import Detections
from recon.video.smooth import SmoothConfig, TrackInput, TrackMotion, smooth_track
from recon.video.track import Track


@dataclass
class FittedTrack:
    """A track's optimised motion in the reference frame, before it is placed in the clip's world."""

    id: int
    first: int
    seen: np.ndarray
    shape: np.ndarray
    motion: TrackMotion
    turns: np.ndarray | None
    moves: np.ndarray | None


def fit_track(body: BodyModel, t: Track, dets: Detections, k: np.ndarray, size, cfg: SmoothConfig,
              rotations: np.ndarray | None = None, shifts: np.ndarray | None = None) -> FittedTrack:
    """The track's one optimisation (``smooth_track``); ``rotations``: (frames, 3, 3) each frame's
    camera turn from the first one's, or None (still); ``shifts``: (frames, 3) its move where it
    travelled (X_f = R_f X_ref + t_f), or None."""
    rows = np.array([d.index for d in t.detections])
    first, last = int(dets.frame[rows].min()), int(dets.frame[rows].max())
    n = last - first + 1
    pos = dets.frame[rows] - first
    seen = np.zeros(n, bool)
    seen[pos] = True

    def spread(a, fill=0.0):
        x = np.full((n, *a.shape[1:]), fill, np.float64)
        x[pos] = a[rows]
        return x
    rot = spread(dets.rotmats)
    rot[~seen] = np.eye(3)
    shape = np.median(dets.shape[rows], 0)
    turns = None if rotations is None else rotations[first:last + 1]
    moves = None if shifts is None else shifts[first:last + 1]
    inp = TrackInput(seen, spread(dets.points2d), spread(dets.points3d), spread(dets.box), rot,
                     spread(dets.translation), shape, k, tuple(size), turns, moves)
    return FittedTrack(t.id, first, seen, shape, smooth_track(body, inp, cfg), turns, moves)


def one_world(fitted: list[FittedTrack]) -> list[WorldMotion]:
    """Every track in the clip's one world frame (``recon.video.ground``): one ground under all
    their planted feet, each track moved up or down until its own feet stand on it (their depths
    as estimated: moving a body along the camera's rays until its feet touch would move it far
    for a few centimetres where the camera stands at the people's height), and the origin under
    the first track's start. A lone track keeps its own ground."""
    if not fitted:
        return []
    shared = common_ground([(f.motion.points, f.motion.planted, f.motion.ground) for f in fitted],
                           [f.motion.sole for f in fitted]) if len(fitted) > 1 else None
    ground = shared or fitted[0].motion.ground
    out = []
    for f in fitted:
        m = f.motion
        at = m.translation if shared is None else \
            m.translation - ground_height(m.points, m.planted, ground, m.sole) * ground[0]
        if not out:
            r, o = to_world(ground, at[np.flatnonzero(f.seen)[0]])
        rotw = m.rotmats.copy()
        rotw[:, 0] = r @ m.rotmats[:, 0]
        out.append(WorldMotion(f.id, f.first, rotw, (at - o) @ r.T, f.shape, f.seen, m.planted, (r, o), f.turns,
                               f.moves))
    return out
