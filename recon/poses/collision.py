"""Self-intersection test for posed bodies with inscribed spheres (cheap, conservative).

Each of the 24 body parts carries a few spheres centred on its bone and inscribed in the
rest mesh (radius = 0.9 x distance to the nearest surface vertex), so two spheres of
different parts can only overlap when the surfaces interpenetrate. Pairs that overlap in
the rest pose, or belong to parts adjacent in the kinematic tree, are ignored. The score is
the deepest sphere overlap in metres; ``SelfIntersection.check`` rejects poses above ``tol``.
Computed in float64, so that a pose near ``tol`` is accepted or rejected alike on every CPU.
"""
from __future__ import annotations

import numpy as np
import torch
from scipy.spatial import cKDTree

from recon.body import lbs, skeleton
from recon.body.base import BodyModel

FRACTIONS = (0.15, 0.5, 0.85)


class SelfIntersection:
    def __init__(self, body: BodyModel, tol: float = 0.015):
        self.body, self.tol = body, tol
        with torch.no_grad():
            v, j = body.rest_geometry(body.mean_shape[None])
        v, j = v[0].double().numpy(), j[0].double().numpy()
        lm = v[body.landmark_indices.numpy()]
        ends = {}
        children = {k: [c for c, p in enumerate(skeleton.JOINT_PARENTS) if p == k] for k in range(24)}
        li = skeleton.LANDMARK_NAMES.index
        for k, name in enumerate(skeleton.JOINT_NAMES):
            if name == "head":
                ends[k] = lm[li("head_top")]
            elif name.endswith("_foot"):
                ends[k] = lm[li(name.replace("_foot", "_toe_tip"))]
            elif name.endswith("_hand"):
                ends[k] = j[k] + (j[k] - j[k - 2])  # as long again as wrist->hand
            elif name == "spine3":
                ends[k] = j[skeleton.JOINT_NAMES.index("neck")]
            elif name == "pelvis":
                ends[k] = j[skeleton.JOINT_NAMES.index("spine1")]
            else:
                ends[k] = j[children[k]].mean(0)
        tree = cKDTree(v)
        centers, owner = [], []
        for k in range(24):
            for t in FRACTIONS:
                centers.append((1 - t) * j[k] + t * ends[k])
                owner.append(k)
        centers = np.array(centers)
        radii = 0.9 * tree.query(centers)[0]
        owner = np.array(owner)
        parents = np.array(skeleton.JOINT_PARENTS)
        same = owner[:, None] == owner[None]
        parent_child = (parents[owner][:, None] == owner[None]) | (owner[:, None] == parents[owner][None])
        # siblings around the pelvis (hips, spine1) and spine3 (neck, collars) touch at rest
        siblings = (parents[owner][:, None] == parents[owner][None]) & np.isin(parents[owner], [0, 9])[:, None]
        adjacent = same | parent_child | siblings
        d = np.linalg.norm(centers[:, None] - centers[None], axis=-1)
        rest_overlap = radii[:, None] + radii[None] - d > 0
        pairs = np.argwhere(np.triu(~adjacent & ~rest_overlap, 1))
        self.centers = torch.tensor(centers, dtype=torch.float64)
        self.radii = torch.tensor(radii, dtype=torch.float64)
        self.owner = torch.tensor(owner)
        self.pairs = torch.tensor(pairs)
        self.rest_joints = torch.tensor(j, dtype=torch.float64)

    def penetration(self, pose: torch.Tensor) -> torch.Tensor:
        """Deepest overlap (m) between non-adjacent parts, per pose: (B, 24, 3[,3]) -> (B,)."""
        rot = lbs.as_rotmats(pose.double(), 24)
        _, _, tf = lbs.forward_kinematics(rot, self.rest_joints.expand(rot.shape[0], -1, -1), skeleton.JOINT_PARENTS)
        t = tf[:, self.owner]  # (B, S, 3, 4)
        c = (t[..., :3] @ self.centers.unsqueeze(-1)).squeeze(-1) + t[..., 3]
        a, b = self.pairs[:, 0], self.pairs[:, 1]
        depth = self.radii[a] + self.radii[b] - (c[:, a] - c[:, b]).norm(dim=-1)
        return depth.clamp(min=0).amax(dim=1) if len(a) else torch.zeros(rot.shape[0])

    def check(self, pose: torch.Tensor) -> torch.Tensor:
        """True where the pose is free of self-intersection (within ``tol``)."""
        return self.penetration(pose) <= self.tol
