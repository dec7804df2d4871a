"""Samplers of plausible poses and body shapes for training data.

PoseSampler: a mocap frame (chosen split) -> optional left/right mirror -> Gaussian
perturbation of every joint -> clamp to per-joint limits -> reject self-intersections
(recon.poses.collision) and redraw. Joint limits are Euler-angle boxes (intrinsic XYZ, in
the joint's world-aligned rest axes) covering the training mocap's 0.1-99.9 percentiles
widened by ``margin_deg``: data-driven, so they follow the retargeted rig's conventions.

ShapeSampler: anny's shape prior (anny.shape_distribution.SimpleShapeDistribution,
calibrated on WHO height/weight data) with morphological age uniform in [18, 70] and gender
drawn as exactly 0 (male) or 1 (female); for SMPL-family files, betas ~ N(0, 1).
"""
from __future__ import annotations

import numpy as np
import torch
from anny.shape_distribution import SimpleShapeDistribution
from scipy.spatial.transform import Rotation

from recon.body import lbs, skeleton
from recon.body.base import BodyModel
from recon.errors import ReconError
from recon.poses.collision import SelfIntersection
from recon.poses.mocap import MocapPoses


class JointLimits:
    def __init__(self, lo: np.ndarray, hi: np.ndarray):
        self.lo, self.hi = lo, hi  # (24, 3) degrees, intrinsic XYZ

    @classmethod
    def from_poses(cls, rotvec: np.ndarray, margin_deg: float = 10.0, q: float = 0.1) -> JointLimits:
        e = Rotation.from_rotvec(rotvec.reshape(-1, 3)).as_euler("XYZ", degrees=True).reshape(-1, 24, 3)
        lo = np.percentile(e, q, axis=0) - margin_deg
        hi = np.percentile(e, 100 - q, axis=0) + margin_deg
        lo[0], hi[0] = -180.0, 180.0  # the root is the global orientation
        return cls(np.clip(lo, -180, 180), np.clip(hi, -180, 180))

    def euler(self, rotvec: np.ndarray) -> np.ndarray:
        return Rotation.from_rotvec(rotvec.reshape(-1, 3)).as_euler("XYZ", degrees=True).reshape(rotvec.shape)

    def inside(self, rotvec: np.ndarray, atol: float = 1e-3) -> np.ndarray:
        """(B, 24) True where each joint lies within its limits."""
        e = self.euler(rotvec)
        return ((e >= self.lo - atol) & (e <= self.hi + atol)).all(-1)

    def clamp(self, rotvec: np.ndarray) -> np.ndarray:
        e = np.clip(self.euler(rotvec), self.lo, self.hi)
        return Rotation.from_euler("XYZ", e.reshape(-1, 3), degrees=True).as_rotvec().reshape(rotvec.shape)


class PoseSampler:
    def __init__(self, body: BodyModel, split: str = "train", noise_deg: float = 8.0, mirror: bool = True,
                 random_yaw: bool = False, seed: int = 0, mocap: MocapPoses | None = None,
                 tol: float = 0.015, max_rounds: int = 20):
        mocap = mocap or MocapPoses.load()
        self.limits = JointLimits.from_poses(mocap.split("train").rotvec)
        self.poses = mocap.split(split)
        if len(self.poses) == 0:
            raise ReconError(f"mocap split {split!r} is empty")
        self.noise = np.radians(noise_deg)
        self.mirror, self.random_yaw = mirror, random_yaw
        self.collide = SelfIntersection(body, tol=tol)
        self.rng = np.random.default_rng(seed)
        self.max_rounds = max_rounds

    def _draw(self, n: int) -> np.ndarray:
        rv = self.poses.rotvec[self.rng.integers(0, len(self.poses), n)].astype(np.float64)
        if self.mirror:
            flip = self.rng.random(n) < 0.5
            if flip.any():
                r = torch.tensor(Rotation.from_rotvec(rv[flip].reshape(-1, 3)).as_matrix()).view(-1, 24, 3, 3)
                r = lbs.mirror_rotmats(r, skeleton.JOINT_MIRROR).numpy()
                rv[flip] = Rotation.from_matrix(r.reshape(-1, 3, 3)).as_rotvec().reshape(-1, 24, 3)
        if self.noise > 0:
            noise = self.rng.normal(0.0, self.noise, size=rv.shape)
            noise[:, 0] = 0.0
            r = Rotation.from_rotvec(rv.reshape(-1, 3)) * Rotation.from_rotvec(noise.reshape(-1, 3))
            rv = self.limits.clamp(r.as_rotvec().reshape(rv.shape))
        if self.random_yaw:
            yaw = Rotation.from_euler("y", self.rng.uniform(-np.pi, np.pi, n))
            rv[:, 0] = (yaw * Rotation.from_rotvec(rv[:, 0])).as_rotvec()
        return rv

    def sample(self, n: int) -> torch.Tensor:
        """(n, 24, 3) float32 axis-angle poses, inside the limits and free of self-intersection."""
        out = np.zeros((n, 24, 3))
        todo = np.arange(n)
        for _ in range(self.max_rounds):
            cand = self._draw(len(todo))
            ok = self.collide.check(torch.tensor(cand, dtype=torch.float64)).numpy()
            out[todo[ok]] = cand[ok]
            todo = todo[~ok]
            if len(todo) == 0:
                return torch.tensor(out, dtype=torch.float32)
        raise RuntimeError(f"{len(todo)} of {n} poses still self-intersect after {self.max_rounds} draws")


class ShapeSampler:
    def __init__(self, body: BodyModel, seed: int = 0, age_range: tuple[float, float] = (18.0, 70.0)):
        self.body = body
        self.gen = torch.Generator().manual_seed(seed)
        self.seed = seed
        self.age_range = age_range
        self._dist = None
        if hasattr(body, "anny"):
            a = body.anny
            self._dist = SimpleShapeDistribution(
                a, morphological_age_distribution=torch.distributions.Uniform(
                    torch.tensor(age_range[0], dtype=a.dtype), torch.tensor(age_range[1], dtype=a.dtype)))

    def sample(self, n: int) -> torch.Tensor:
        """(n, S) shape parameters in the body model's ``shape_names`` order."""
        seed = int(torch.randint(0, 2**31 - 1, (1,), generator=self.gen))
        with torch.random.fork_rng():
            torch.manual_seed(seed)
            if self._dist is None:
                return torch.randn(n, self.body.num_shape_params)
            _, ph = self._dist.sample(n)
            ph["gender"] = (torch.rand(n) < 0.5).to(ph["height"].dtype)
        shape = torch.stack([ph[k] for k in self.body.shape_names], dim=1).float()
        return shape.clamp(0.0, 1.0)
