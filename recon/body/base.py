"""The body-model interface every backend implements (smplx-style: one module, one forward)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from scipy.spatial import cKDTree
from torch import nn

from recon.body import lbs, skeleton
from recon.body.landmarks import select_landmarks


@dataclass
class BodyOutput:
    """Result of ``BodyModel.forward``. All positions in metres, in the body frame."""

    vertices: torch.Tensor  # (B, V, 3)
    joints: torch.Tensor  # (B, 24, 3)
    landmarks: torch.Tensor  # (B, 18, 3)
    transforms: torch.Tensor  # (B, 24, 3, 4): rest-pose point -> output point, per joint
    global_rotmats: torch.Tensor  # (B, 24, 3, 3)
    rest_vertices: torch.Tensor  # (B, V, 3), shaped but unposed

    @property
    def points(self) -> torch.Tensor:
        """J+ of SMPLR: joints then landmarks, (B, 42, 3)."""
        return torch.cat([self.joints, self.landmarks], dim=1)


class BodyModel(nn.Module):
    """A skinned parametric body: ``forward(pose, shape, transl) -> BodyOutput``.

    Subclasses register buffers ``faces`` (F, 3) long and ``weights`` (V, 24) and implement
    ``rest_geometry(shape, vertex_ids=None) -> (rest_vertices (B,V',3), rest_joints (B,24,3))``
    (V' = all vertices or the given subset); they may override ``pose_offsets(rotmats,
    vertex_ids)`` for pose-corrective blend shapes. See recon.body.skeleton for
    frames, units and joint order.
    """

    joint_names = skeleton.JOINT_NAMES
    parents = skeleton.JOINT_PARENTS
    landmark_names = skeleton.LANDMARK_NAMES
    shape_names: tuple[str, ...] = ()
    shape_range: tuple[float, float] | None = None  # valid interval of every shape parameter, if bounded

    faces: torch.Tensor
    weights: torch.Tensor
    landmark_indices: torch.Tensor
    mean_shape: torch.Tensor

    # --- to be provided by backends -------------------------------------------------
    def rest_geometry(self, shape: torch.Tensor, vertex_ids: torch.Tensor | None = None
                      ) -> tuple[torch.Tensor, torch.Tensor]:
        raise NotImplementedError

    def pose_offsets(self, rotmats: torch.Tensor, vertex_ids: torch.Tensor | None = None) -> torch.Tensor | None:
        return None

    # --- shared ---------------------------------------------------------------------
    @property
    def num_shape_params(self) -> int:
        return int(self.mean_shape.numel())

    @property
    def num_vertices(self) -> int:
        return int(self.weights.shape[0])

    def _finish_init(self) -> None:
        """Pick landmarks and the mirror map once the rest geometry is available."""
        with torch.no_grad():
            v, j = self.rest_geometry(self.mean_shape[None])
        idx = select_landmarks(v[0].cpu().numpy(), j[0].cpu().numpy(), self.weights.cpu().numpy())
        self.register_buffer("landmark_indices", torch.as_tensor(idx, dtype=torch.long), persistent=False)

    def mirror_vertex_map(self) -> np.ndarray:
        """For each vertex, its left/right mirror (nearest vertex of the X-reflected rest mesh)."""
        with torch.no_grad():
            v = self.rest_geometry(self.mean_shape[None])[0][0].cpu().numpy()
        mirrored = v * np.array([-1.0, 1.0, 1.0])
        return cKDTree(v).query(mirrored)[1]

    def _check_shape(self, shape: torch.Tensor | None, batch: int) -> torch.Tensor:
        if shape is None:
            return self.mean_shape.expand(batch, -1)
        if not torch.is_tensor(shape):
            raise TypeError(f"shape must be a torch.Tensor, got {type(shape).__name__}")
        if shape.ndim == 1:
            shape = shape.unsqueeze(0)
        if shape.ndim != 2 or shape.shape[1] != self.num_shape_params:
            raise ValueError(
                f"shape must have shape (B, {self.num_shape_params}) "
                f"[{', '.join(self.shape_names)}]; got {tuple(shape.shape)}"
            )
        if not torch.isfinite(shape).all():
            raise ValueError("shape contains NaN or infinite values")
        return shape.to(self.mean_shape.dtype)

    def identity_pose(self, batch: int = 1) -> torch.Tensor:
        eye = torch.eye(3, dtype=self.mean_shape.dtype, device=self.mean_shape.device)
        return eye.expand(batch, skeleton.NUM_JOINTS, 3, 3).clone()

    def forward(
        self,
        pose: torch.Tensor | None = None,
        shape: torch.Tensor | None = None,
        transl: torch.Tensor | None = None,
        points_only: bool = False,
        vertex_ids: torch.Tensor | None = None,
        rest: tuple[torch.Tensor, torch.Tensor] | None = None,
    ) -> BodyOutput:
        """Pose and shape the body.

        Args:
            pose: (B, 24, 3) axis-angle or (B, 24, 3, 3) local rotations; None = rest pose.
            shape: (B, S) shape parameters (see ``shape_names``); None = mean shape.
            transl: (B, 3) position of the pelvis joint; None = origin.
        A batch of 1 in pose or shape broadcasts against the other. ``points_only`` skins
        only the landmark vertices (``vertices`` then holds those 18): the cheap path for J+.
        ``vertex_ids`` skins only those vertices (``vertices`` then holds them, in that order;
        landmarks are still computed): e.g. a subset for silhouette fitting. ``rest`` = the
        ``rest_geometry`` of this call's vertices (landmarks first when ``vertex_ids`` is given),
        precomputed or linearised by a fitting loop; ``shape`` is then ignored.
        """
        dtype = self.mean_shape.dtype
        rot = None if pose is None else lbs.as_rotmats(pose, skeleton.NUM_JOINTS).to(dtype)
        shp = None if shape is None else self._check_shape(shape, 1)
        b = max(1 if rot is None else rot.shape[0], 1 if shp is None else shp.shape[0])
        for name, t in (("pose", rot), ("shape", shp)):
            if t is not None and t.shape[0] not in (1, b):
                raise ValueError(f"{name} batch size {t.shape[0]} does not match batch size {b}")
        rot = self.identity_pose(b) if rot is None else rot.expand(b, -1, -1, -1)
        shp = self._check_shape(shp, b).expand(b, -1)

        ids = self.landmark_indices if points_only else None
        if vertex_ids is not None and not points_only:
            ids = torch.cat([self.landmark_indices, torch.as_tensor(vertex_ids, device=self.landmark_indices.device)])
        rest_v, rest_j = self.rest_geometry(shp, ids) if rest is None else rest
        offsets = self.pose_offsets(rot, ids)
        posed_rest_v = rest_v if offsets is None else rest_v + offsets
        g_rot, joints, transforms = lbs.forward_kinematics(rot, rest_j, self.parents)

        # Move the pelvis to transl; fold the shift into the transforms so that skinning
        # any other rest-space mesh (a garment) with them lands in the same frame.
        shift = -joints[:, :1]
        if transl is not None:
            if not torch.is_tensor(transl) or transl.shape[-1] != 3 or transl.reshape(-1, 3).shape[0] not in (1, b):
                raise ValueError(f"transl must have shape (B, 3); got {tuple(getattr(transl, 'shape', ()))}")
            if not torch.isfinite(transl).all():
                raise ValueError("transl contains NaN or infinite values")
            shift = shift + transl.reshape(-1, 1, 3).to(dtype)
        transforms = torch.cat([transforms[..., :3], transforms[..., 3:] + shift.unsqueeze(-1)], dim=-1)
        weights = self.weights if ids is None else self.weights[ids]
        vertices = lbs.skin(posed_rest_v, weights, transforms)
        if points_only:
            landmarks = vertices
        elif ids is None:
            landmarks = vertices[:, self.landmark_indices]
        else:  # the landmarks were skinned first
            n = len(self.landmark_indices)
            landmarks, vertices, rest_v = vertices[:, :n], vertices[:, n:], rest_v[:, n:]
        return BodyOutput(
            vertices=vertices,
            joints=joints + shift,
            landmarks=landmarks,
            transforms=transforms,
            global_rotmats=g_rot,
            rest_vertices=rest_v,
        )
