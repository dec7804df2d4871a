"""One track's motion as one optimisation over all its frames.

The per-frame estimates (SMPLR's pose and placement on each frame's keypoints) start it; the
body's joint rotations and pelvis positions of every frame then move together, with the track's
one body shape fixed, to minimise (``SmoothConfig`` weights):

* reprojection: the body's J+ projected against the frame's detected 2D J+ (frames where the
  person was seen, points inside the image);
* depth: the root-relative 3D J+ near the per-frame lifted ones (what 2D cannot fix);
* acceleration: the J+'s second differences in time, in the camera frame divided by their depth
  (units of the image, like the reprojection): the motion prior. Frames where the person was not
  seen have only this term and so are bridged smoothly;
* contact: a foot found planted in the image (its 2D keypoints still, and low: ``planted``) does
  not move in 3D between planted frames (ankle, foot joint and toe tip); where only the learned
  motion prior (``recon.video.prior``) finds it planted, its foot joint does not
  (``SmoothConfig.contact_from``);
* a small prior keeping the rotations near the per-frame ones; optionally (off by default) a pull
  towards the motion prior's J+ (``SmoothConfig.prior``).

A turning camera (``TrackInput.camera_rotations``: how each frame's camera turned from the clip's
first one, ``recon.video.camera_motion``) is taken out: the motion lives in the first frame's camera
(the reference frame), where the acceleration and contact terms hold, and each frame's body is
turned into that frame's camera for the reprojection and depth terms. Without rotations the
reference frame is the camera's.

A track longer than ``SmoothConfig.window`` frames is optimised window by window (overlapping by
``overlap`` frames, blended linearly there), so a long clip's memory stays bounded.

The track's ground is the plane through its planted feet (``recon.video.ground``).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import roma
import torch
from scipy.ndimage import gaussian_filter1d

from recon import camera
from recon.body.base import BodyModel
from recon.fit import linear_rest_geometry
from recon.video import prior as motion_prior
from recon.video.ground import FOOT_POINTS, ground_plane, lowest_plane, planted_feet, sole_height, torso_up

CONTACT_FROM = ("image", "prior", "either")


@dataclass
class SmoothConfig:
    steps: int = 400  # optimiser iterations over the whole track (0: the per-frame estimates, gaps interpolated)
    acceleration: float = 100.0  # of the root-relative J+
    # of the root-relative J+ along the line of sight (None: ``acceleration``): the depth is what the
    # frames fix least, while motion across the image is seen in 2D
    depth_acceleration: float | None = None
    root_acceleration: float = 30.0  # of the pelvis' path (its depth is the noisiest)
    contact: float = 30.0
    depth_prior: float = 20.0  # as ``recon.fit.FitConfig``'s
    pose_prior: float = 0.05
    pose_lr: float = 0.02  # Adam's step sizes: rotations (radians) ...
    translation_lr: float = 0.1  # ... and pelvis positions (metres)
    optimizer: str = "lbfgs"  # or "adam" (``pose_lr``, ``translation_lr``)
    planted_speed: float = 0.012  # a foot moving less than this (units of the box height a frame) in 2D ...
    planted_low: float = 0.06  # ... within this of the lowest foot point of the frame is planted
    # the learned motion prior (``recon.video.prior``): the body pulled towards its root-relative J+
    # and root path (units of the image, like the reprojection); 0: not used
    prior: float = 0.0
    prior_root: float = 0.0
    # where the target comes from: "learned" (the motion prior) or "gaussian" (the per-frame J+
    # filtered in time with ``gaussian_sigma`` frames: the prior's baseline)
    prior_kind: str = "learned"
    gaussian_sigma: float = 2.0
    # the acceleration terms penalise the body's acceleration itself ("zero") or its difference from
    # the target's ("target": the target's motion is kept, only what departs from it is damped)
    acceleration_about: str = "zero"
    # which feet are planted: "image" (2D keypoints still and low), "prior" (its planted flags) or "either"
    contact_from: str = "either"
    planted_probability: float = 0.5  # the prior's planted probability above which a foot is planted
    # a longer track is optimised in windows of this many frames, each overlapping the one before by
    # ``overlap`` frames and blended there: memory stays bounded on long clips
    window: int = 900
    overlap: int = 90


@dataclass
class TrackInput:
    """One track over frames first..last (T of them), from the per-frame estimates."""

    seen: np.ndarray  # (T,) bool: detected in that frame
    points2d: np.ndarray  # (T, 42, 2) pixels (anything where not seen)
    points3d: np.ndarray  # (T, 42, 3) root-relative lifted J+
    boxes: np.ndarray  # (T, 4)
    rotmats: np.ndarray  # (T, 24, 3, 3) per-frame local rotations, root into the camera frame
    translation: np.ndarray  # (T, 3) per-frame pelvis positions, camera frame
    shape: np.ndarray  # (S,) the track's body shape
    K: np.ndarray  # (3, 3)
    image_shape: tuple[int, int]
    # (T, 3, 3) each frame's camera turn from the reference camera (x_t = R_t x_ref); None: static
    camera_rotations: np.ndarray | None = None
    # (T, 3) and its move, where it travelled: X_t = R_t X_ref + t_t for a point; None: it did not
    camera_shifts: np.ndarray | None = None

    def frames(self, a: int, b: int) -> TrackInput:
        """The track over its frames a..b-1."""
        cut = lambda x: None if x is None else x[a:b]  # noqa: E731
        return TrackInput(self.seen[a:b], self.points2d[a:b], self.points3d[a:b], self.boxes[a:b], self.rotmats[a:b],
                          self.translation[a:b], self.shape, self.K, self.image_shape, cut(self.camera_rotations),
                          cut(self.camera_shifts))

    def in_reference(self) -> tuple[np.ndarray, np.ndarray]:
        """The per-frame root rotations and pelvis positions turned into the reference frame."""
        if self.camera_rotations is None:
            return self.rotmats, self.translation
        back = np.swapaxes(self.camera_rotations, 1, 2)
        rot = self.rotmats.copy()
        rot[:, 0] = back @ self.rotmats[:, 0]
        moved = self.translation if self.camera_shifts is None else self.translation - self.camera_shifts
        return rot, np.einsum("tij,tj->ti", back, moved)


@dataclass
class TrackMotion:
    """The track's motion in the reference frame (the camera's, the first frame's if it turned)."""

    rotmats: np.ndarray  # (T, 24, 3, 3), root into the reference frame
    translation: np.ndarray  # (T, 3)
    joints: np.ndarray  # (T, 24, 3)
    points: np.ndarray  # (T, 42, 3)
    planted: np.ndarray  # (T, 2) bool: left, right foot planted
    ground: tuple[np.ndarray, float]  # plane (n, d): n . x = d, n up
    sole: float  # how high the foot joint stands over the ground in the rest pose (metres)


def fill_gaps(seen: np.ndarray, rotmats: np.ndarray, translation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Frames not seen get rotations slerped and positions interpolated between the nearest seen
    frames (held beyond the first and last)."""
    seen_idx = np.flatnonzero(seen)
    if len(seen_idx) == 0:
        raise ValueError("a track needs at least one seen frame")
    rot, tr = rotmats.copy(), translation.copy()
    q = roma.rotmat_to_unitquat(torch.as_tensor(rotmats, dtype=torch.float64))
    for f in np.flatnonzero(~seen):
        after = seen_idx[seen_idx > f]
        before = seen_idx[seen_idx < f]
        if not len(before) or not len(after):
            g = after[0] if len(after) else before[-1]
            rot[f], tr[f] = rotmats[g], translation[g]
            continue
        a, b = before[-1], after[0]
        w = (f - a) / (b - a)
        rot[f] = roma.unitquat_to_rotmat(roma.unitquat_slerp(q[a], q[b], torch.tensor([w], dtype=torch.float64))[0])
        tr[f] = (1 - w) * translation[a] + w * translation[b]
    return rot, tr


def planted(inp: TrackInput, cfg: SmoothConfig) -> np.ndarray:
    """(T, 2) whether each foot (left, right) is planted: seen, its 2D points nearly still between
    the frames around, and near the lowest foot point of the frame (image y grows downwards)."""
    t = len(inp.seen)
    height = np.maximum(inp.boxes[:, 3] - inp.boxes[:, 1], 1.0)
    out = np.zeros((t, 2), bool)
    feet = [list(FOOT_POINTS[s]) for s in ("left", "right")]
    lowest = inp.points2d[:, sum(feet, []), 1].max(1)
    inside = camera.inside_image(inp.points2d.reshape(-1, 2), inp.image_shape).reshape(t, -1)
    for f in range(1, t - 1):
        if not (inp.seen[f - 1] and inp.seen[f] and inp.seen[f + 1]):
            continue
        for s, ids in enumerate(feet):
            speed = np.linalg.norm(inp.points2d[f + 1, ids] - inp.points2d[f - 1, ids], axis=1).mean() / 2
            low = inp.points2d[f, ids, 1].max() >= lowest[f] - cfg.planted_low * height[f]
            out[f, s] = inside[f, ids].all() and low and speed < cfg.planted_speed * height[f]
    return out


def smooth_track(body: BodyModel, inp: TrackInput, cfg: SmoothConfig | None = None) -> TrackMotion:
    """The track's motion (module doc) in the reference frame, and its ground plane."""
    cfg = cfg or SmoothConfig()
    if cfg.overlap < 2 or cfg.window <= cfg.overlap:
        raise ValueError("SmoothConfig needs overlap >= 2 and window > overlap")
    for name, allowed in (("contact_from", CONTACT_FROM), ("prior_kind", ("learned", "gaussian")),
                          ("acceleration_about", ("zero", "target"))):
        if getattr(cfg, name) not in allowed:
            raise ValueError(f"SmoothConfig.{name} must be one of {', '.join(allowed)}")
    rot0, tr0 = fill_gaps(inp.seen, *inp.in_reference())
    contact = image = planted(inp, cfg)
    t = len(rot0)
    shape = torch.tensor(inp.shape, dtype=torch.float32)[None]
    rest = linear_rest_geometry(body, shape, None, with_jacobian=False)[0]  # (1, ...): the track's one shape
    target = None
    pulled = bool(cfg.prior or cfg.prior_root or cfg.acceleration_about == "target")  # the objective uses target
    if pulled or cfg.contact_from != "image":
        with torch.no_grad():
            start = body(torch.tensor(rot0, dtype=torch.float32), transl=torch.tensor(tr0, dtype=torch.float32),
                         points_only=True, rest=tuple(x.expand(t, -1, -1) for x in rest)).points.numpy()
        target, feet = motion_prior.denoise(_prior(), start, inp.seen)
        if cfg.prior_kind == "gaussian":
            target = gaussian_filter1d(start.astype(np.float64), cfg.gaussian_sigma, axis=0, mode="nearest")
        flags = feet > cfg.planted_probability
        contact = {"image": image, "prior": flags, "either": image | flags}[cfg.contact_from]
    # the foot points pinned (ankle, foot joint, toe tip): all three where the image saw the foot
    # still, the foot joint alone where only the prior says planted (its flag is the foot joint's)
    edge = np.zeros_like(image) if cfg.contact_from == "prior" else image
    pinned = np.stack([edge, contact, edge], axis=2)
    delta, tr = np.zeros((t, 24, 3), np.float32), np.zeros((t, 3), np.float32)
    for a, b in windows(t, cfg.window, cfg.overlap):
        d, x = _optimise(body, inp.frames(a, b), cfg, rot0[a:b], tr0[a:b], pinned[a:b], rest,
                         target[a:b] if pulled else None)
        w = np.ones(b - a, np.float32)
        if a > 0:  # the overlap with the window before: from its answer to this one's, linearly
            n = min(cfg.overlap, b - a)
            w[:n] = np.arange(1, n + 1) / (n + 1)
        delta[a:b] = (1 - w[:, None, None]) * delta[a:b] + w[:, None, None] * d
        tr[a:b] = (1 - w[:, None]) * tr[a:b] + w[:, None] * x
    with torch.no_grad():
        r = torch.tensor(rot0, dtype=torch.float32) @ roma.rotvec_to_rotmat(torch.tensor(delta))
        out = body(r, transl=torch.tensor(tr), points_only=True, rest=tuple(x.expand(t, -1, -1) for x in rest))
    pts = out.points.numpy().astype(np.float64)
    rot = r.numpy().astype(np.float64)
    up = torso_up(pts)
    feet = planted_feet(pts, contact)
    sole = sole_height(body, shape)
    ground = ground_plane(feet, up, sole) if len(feet) else lowest_plane(pts, up)
    return TrackMotion(rot, tr.astype(np.float64), pts[:, :24], pts, contact, ground, sole)


def windows(frames: int, window: int, overlap: int) -> list[tuple[int, int]]:
    """(first, stop) of the windows covering ``frames`` frames: one where they fit, else windows
    of ``window`` frames, each starting ``overlap`` frames before the one before ends."""
    if frames <= window:
        return [(0, frames)]
    out, a = [], 0
    while True:
        b = min(a + window, frames)
        out.append((a, b))
        if b == frames:
            return out
        a = b - overlap


def _optimise(body: BodyModel, inp: TrackInput, cfg: SmoothConfig, rot0: np.ndarray, tr0: np.ndarray,
              contact: np.ndarray, rest: tuple[torch.Tensor, torch.Tensor], target: np.ndarray | None = None
              ) -> tuple[np.ndarray, np.ndarray]:
    """One window's optimisation (module doc), started from the per-frame ``rot0``, ``tr0``, with
    the body's ``rest`` geometry (1, ...), the foot points pinned (``contact``: (T, 2, 3), per foot
    its ``FOOT_POINTS``) and the motion prior's J+ ``target`` (T, 42, 3) or None: the rotation
    offsets (T, 24, 3) from ``rot0`` (axis-angle) and the pelvis positions (T, 3)."""
    t = len(rot0)
    dtype = torch.float32
    k = torch.tensor(inp.K, dtype=dtype)
    rest = tuple(x.expand(t, -1, -1) for x in rest)
    r0 = torch.tensor(rot0, dtype=dtype)
    uv = torch.tensor(inp.points2d, dtype=dtype)
    p3 = torch.tensor(inp.points3d, dtype=dtype)
    w = torch.tensor(camera.inside_image(inp.points2d.reshape(-1, 2), inp.image_shape).reshape(t, -1)
                     & inp.seen[:, None], dtype=dtype)
    seen = torch.tensor(inp.seen, dtype=dtype)
    delta = torch.zeros(t, 24, 3, requires_grad=True)
    tr = torch.tensor(tr0, dtype=dtype).requires_grad_(True)
    ids = [list(FOOT_POINTS[s]) for s in ("left", "right")]
    turn = None if inp.camera_rotations is None else torch.tensor(inp.camera_rotations, dtype=dtype)
    shift = None if inp.camera_shifts is None else torch.tensor(inp.camera_shifts, dtype=dtype)[:, None]
    both = torch.tensor(contact[1:] & contact[:-1], dtype=dtype)  # (T-1, 2, 3) pinned in f and f+1
    tgt = None if target is None else torch.tensor(target, dtype=dtype)

    def pose(d):
        return r0 @ roma.rotvec_to_rotmat(d)

    def objective():
        pts = body(pose(delta), transl=tr, points_only=True, rest=rest).points  # reference frame
        seen_pts = pts if turn is None else pts @ turn.transpose(1, 2)  # each frame's camera
        seen_pts = seen_pts if shift is None else seen_pts + shift
        depth = seen_pts[:, :1, 2:].detach().clamp_min(0.5)
        e2d = (((camera.project(seen_pts, k, min_depth=1e-3) - uv) / k[0, 0]) ** 2).sum(-1)
        loss = (w * e2d).sum() / w.sum().clamp_min(1)
        e3d = ((seen_pts - seen_pts[:, :1]) - p3).pow(2).sum(-1).mean(-1)
        loss = loss + cfg.depth_prior * 1e-3 * (seen * e3d).sum() / seen.sum().clamp_min(1)
        loss = loss + cfg.pose_prior * 1e-3 * delta.pow(2).sum() / t
        if tgt is not None:
            rel = ((pts - pts[:, :1]) - (tgt - tgt[:, :1])) / depth
            root = (pts[:, 0] - tgt[:, 0]) / depth[:, 0]
            loss = loss + cfg.prior * rel.pow(2).sum(-1).mean() + cfg.prior_root * root.pow(2).sum(-1).mean()
        if t >= 3:
            moving = pts if tgt is None or cfg.acceleration_about == "zero" else pts - tgt
            acc = (moving[2:] - 2 * moving[1:-1] + moving[:-2]) / depth[1:-1]
            root = acc[:, :1]
            rel = (acc - root).pow(2)
            if cfg.depth_acceleration is None:
                loss = loss + cfg.acceleration * rel.sum(-1).mean()
            else:
                loss = loss + cfg.acceleration * rel[..., :2].sum(-1).mean() \
                    + cfg.depth_acceleration * rel[..., 2].mean()
            loss = loss + cfg.root_acceleration * root.pow(2).sum(-1).mean()
        if t >= 2 and both.any():
            for s in range(2):
                step = (pts[1:, ids[s]] - pts[:-1, ids[s]]) / depth[1:]
                loss = loss + cfg.contact * (both[:, s] * step.pow(2).sum(-1)).sum() / both.sum()
        return loss

    if cfg.optimizer == "lbfgs":
        opt = torch.optim.LBFGS([delta, tr], lr=1.0, max_iter=cfg.steps, history_size=20,
                                line_search_fn="strong_wolfe")

        def closure():
            opt.zero_grad()
            loss = objective()
            loss.backward()
            return loss
        if cfg.steps:
            opt.step(closure)
    else:
        opt = torch.optim.Adam([{"params": [delta], "lr": cfg.pose_lr}, {"params": [tr], "lr": cfg.translation_lr}])
        for _ in range(cfg.steps):
            loss = objective()
            opt.zero_grad()
            loss.backward()
            opt.step()
    return delta.detach().numpy(), tr.detach().numpy()


@functools.lru_cache(maxsize=1)
def _prior() -> motion_prior.MotionPrior:
    return motion_prior.load()
