"""Dress a posed body with a trained outfit: ``Dresser``, the one entry point, whatever the
garment family (``recon.garment.family``: PBNS with NCS for motions, Taylor, DeePSD, or one you
register).

The outfit was simulated on one body shape. For another shape its rest pose is resized the
CLOTH3D way (thesis 3.3.2): the rest-body displacement between the two shapes is transferred
to every cloth vertex from its nearest body vertex and Laplacian-smoothed, so body detail does
not print through; when the outfit has a trained resizer (``recon garment resize``, thesis
5.5.6) its correction is added and a tightness can be asked for. The family's model then poses
it; the post-step (recon.garment.collide: edge lengths restored, cloth pushed out of the body)
follows, the same for every family.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from recon.body.base import BodyModel
from recon.errors import ReconError
from recon.garment.collide import CollisionResolver
from recon.garment.family import GarmentModel, PostStep, family, family_names
from recon.poses.mocap import FPS  # motions' default frame rate: the pose set's (NCS learns at it)


@dataclass
class DressedOutfit:
    vertices: np.ndarray  # (B, N, 3) posed cloth, same frame as the body output
    faces: np.ndarray  # (F, 3)
    garment_id: np.ndarray  # (N,)
    names: list[str]


GARMENT_MODELS = family_names()  # the registered families (recon.garment.family)


class Dresser:
    """``Dresser("tshirt-trousers")(body, rotmats, shape, transl) -> DressedOutfit``."""

    def __init__(self, outfit: str = "tshirt-trousers", path: str | Path | None = None, resizer: bool = True,
                 resolve_collisions: bool = True, dynamics: bool | None = None, garment_model: str = "pbns", **options):
        """``path``: the outfit's weights file (default: its trained ones). ``resizer``: its trained
        resizer where it has one. ``resolve_collisions``: the post-step of recon.garment.collide:
        restore the edge lengths and push cloth the network leaves inside the body out of it (its
        cost: eval/results/bench-garment-1t.md). ``dynamics``: motions through a dynamic model
        (PBNS's: the outfit's NCS; None: when it has one; True: it must). ``garment_model``: a
        registered family (``GARMENT_MODELS``): "pbns" (PBNS, NCS for motions as ``dynamics``
        says), "taylor" (the example-based model; its database: ``recon garment train --model
        taylor``) or "deepsd" (any outfit animated without training; what a garment mesh with no
        PBNS weights of its own gets). ``options``: the family's own (Taylor: ``drape_iterations``)."""
        cls = family(garment_model)
        if cls.static and dynamics:
            raise ReconError(f"the {garment_model} garment model is quasi-static: no dynamics")
        if other := cls.instead(outfit, path):
            cls = family(other)
        self.garment: GarmentModel = cls(outfit, path, resizer=resizer, dynamics=dynamics, **options)
        self.garment_model = cls.name
        self.resolver = CollisionResolver(self.garment.model.faces.numpy(), self.garment.layer) \
            if resolve_collisions else None

    @property
    def model(self) -> torch.nn.Module:
        """The outfit's skinned blend-shape model (its rest, faces and skinning weights)."""
        return self.garment.model

    @property
    def outfit(self) -> str:
        """What ``Dresser(outfit)`` takes to load it again."""
        return self.garment.outfit

    @property
    def shape(self) -> torch.Tensor:
        """The body shape the outfit was made on."""
        return self.garment.shape

    @property
    def garment_id(self) -> np.ndarray:
        return self.garment.garment_id

    @property
    def names(self) -> list[str]:
        return self.garment.names

    @property
    def has_resizer(self) -> bool:
        """Whether the outfit has a trained resizer (needed for a ``tightness``)."""
        return self.garment.has_resizer

    @property
    def dynamic(self) -> bool:
        """Whether motions are dressed by a dynamic model (else frame by frame)."""
        return self.garment.dynamic

    def rest_for(self, body: BodyModel, shape: torch.Tensor, smooth: int = 10, tightness=None) -> torch.Tensor:
        """Outfit rest vertices resized to ``shape`` (1-D tensor); ``tightness`` (2,) needs a
        trained resizer (> 0 looser, see recon.garment.resize)."""
        return self.garment.rest_for(body, shape, smooth, tightness)

    def _post(self, body: BodyModel) -> PostStep | None:
        if self.resolver is None:
            return None
        return lambda v, body_vertices, rest: self.resolver(v, body_vertices, body.faces, rest=rest)

    def _points_only(self) -> bool:
        return self.resolver is None and not self.garment.needs_body_mesh

    @torch.no_grad()
    def __call__(self, body: BodyModel, rotmats: torch.Tensor, shape: torch.Tensor, transl: torch.Tensor | None = None,
                 up: torch.Tensor | None = None, tightness=None) -> DressedOutfit:
        """``up``: (3, 3) rotation from the frame of ``rotmats``' root to the gravity-aligned body
        frame (+Y up); e.g. diag(1, -1, -1) for poses in an upright OpenCV camera frame. The
        network sees the gravity-aligned pose; the cloth is posed in the input frame."""
        b = rotmats.shape[0]
        shape = shape.reshape(b, -1)
        out = body(rotmats, shape, transl=transl, points_only=self._points_only())
        r = rotmats.clone()
        if up is not None:
            r[:, 0] = up.to(r) @ r[:, 0]
        verts = self.garment.dress(body, out, r, shape, tightness, self._post(body))
        return DressedOutfit(verts.numpy(), self.model.faces.numpy(), self.garment_id, self.names)

    def sequence_codes(self, body: BodyModel, rotmats: torch.Tensor, shape: torch.Tensor,
                       transl: torch.Tensor | None = None,
                       fps: float = FPS, motion: float = 1.0) -> tuple[torch.Tensor, torch.Tensor]:
        """The blend-shape model dressing a motion and its codes per frame: (D (E, N*3), (T, E));
        ``motion`` scales a dynamic model's motion (0 = static). Poses in the gravity-aligned body
        frame (+Y up)."""
        return self.garment.sequence_codes(body, rotmats, shape, transl, fps, motion)

    @torch.no_grad()
    def animate(self, body: BodyModel, rotmats: torch.Tensor, shape: torch.Tensor, transl: torch.Tensor | None = None,
                fps: float = FPS, tightness=None, motion: float = 1.0) -> DressedOutfit:
        """Dress a motion (T, 24, 3, 3) local rotations, +Y up, at ``fps`` frames a second (NCS
        learnt its dynamics at 30), one shape (S,) and translation (T, 3): (T, N, 3) cloth."""
        shape = shape.reshape(-1)
        t = len(rotmats)
        out = body(rotmats, shape[None].expand(t, -1), transl=transl, points_only=self._points_only())
        rest = self.rest_for(body, shape, tightness=tightness)
        verts = self.garment.animate(body, out, rotmats, shape, transl, fps, rest, motion)
        if self.resolver is not None:
            verts = self.resolver(verts, out.vertices, body.faces, rest=rest)
        return DressedOutfit(verts.numpy(), self.garment.motion_model.faces.numpy(), self.garment_id, self.names)
