"""PBNS as a garment model (thesis ch. 5): skinning plus pose-space deformations, the outfit
resized to each body (its trained resizer where it has one, else the CLOTH3D transfer); motions
through the outfit's NCS (ch. 6: the cloth swings, lags and settles) when it has one and
``dynamics`` is not False, else frame by frame. A garment mesh with no PBNS weights of its own is
dressed by DeePSD instead (``instead``)."""
from __future__ import annotations

import json
from pathlib import Path

import torch

from recon.body.base import BodyModel
from recon.errors import MissingFile
from recon.garment import store
from recon.garment.family import GarmentModel, PostStep
from recon.garment.ncs.model import NCS
from recon.garment.pbns.model import PBNS, pose_features
from recon.garment.resize import RestResizer
from recon.garment.templates import MESH_SUFFIXES


def untrained_mesh(outfit: str) -> bool:
    """Whether ``outfit`` is a garment mesh with no PBNS weights of its own."""
    return Path(outfit).suffix.lower() in MESH_SUFFIXES and not store.pbns_path(outfit).exists()


def load_pbns(outfit: str, path: str | Path | None = None) -> tuple[Path, PBNS, dict, str | None]:
    """The outfit's PBNS: ``path`` (default its trained weights: a preset's, your own garment's, a
    .pt file), the model, its checkpoint and the outfit's name in it (None: a weights file alone)."""
    path = Path(path) if path else store.trained_pbns(outfit)
    if not path.exists():
        raise MissingFile(f"no trained outfit {path}: run `recon garment train --outfit {outfit}`")
    model, ck = PBNS.load(path)
    return path, model, ck, json.loads(ck["meta_json"]).get("outfit")


class BlendGarment(GarmentModel):
    """A garment model that is one skinned blend-shape model (PBNS's form): the cloth of a pose is
    its skinning of the resized rest plus its pose-space deformations."""

    ncs: NCS | None = None

    def _take(self, model, ck: dict, resizer_path: Path | None) -> None:
        """The model, its checkpoint's outfit fields and the rest's resizing."""
        self.take(model, ck)
        self.resize = RestResizer(model.rest, model.faces, self.shape, resizer_path)

    @property
    def has_resizer(self) -> bool:
        return self.resize.path is not None

    @property
    def dynamic(self) -> bool:
        return self.ncs is not None

    @property
    def motion_model(self):
        return self.ncs or self.model

    def rest_for(self, body: BodyModel, shape: torch.Tensor, smooth: int = 10, tightness=None) -> torch.Tensor:
        return self.resize(body, shape, smooth, tightness)

    def dress(self, body: BodyModel, out, rotmats: torch.Tensor, shape: torch.Tensor, tightness,
              post: PostStep | None) -> torch.Tensor:
        rest = torch.stack([self.rest_for(body, s, tightness=tightness) for s in shape])
        verts = self.model.pose(rotmats, out.transforms, rest)
        return verts if post is None else post(verts, out.vertices, rest)

    def animate(self, body: BodyModel, out, rotmats: torch.Tensor, shape: torch.Tensor, transl: torch.Tensor | None,
                fps: float, rest: torch.Tensor, motion: float = 1.0) -> torch.Tensor:
        if self.ncs is None:
            return self.model.pose(rotmats, out.transforms, rest)
        _, codes = self.sequence_codes(body, rotmats, shape, transl, fps, motion)
        return self.ncs.pose_codes(codes, out.transforms, rest)

    @torch.no_grad()
    def pose_codes(self, rotmats: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """PBNS's morph targets D and its embedding of each pose: (D (E, N*3), (T, E))."""
        return self.model.D.detach(), self.model.mlp(pose_features(rotmats))

    def sequence_codes(self, body: BodyModel, rotmats: torch.Tensor, shape: torch.Tensor, transl: torch.Tensor | None,
                       fps: float, motion: float = 1.0) -> tuple[torch.Tensor, torch.Tensor]:
        """NCS's codes when dynamic (``motion`` scales its dynamic code: ``NCS.motion_codes``), else
        PBNS's embedding of each pose."""
        if self.ncs is None:
            return self.pose_codes(rotmats)
        with torch.no_grad():
            zs, zd = self.ncs.motion_codes(body, rotmats, shape, transl, fps)
            return self.ncs.D.detach(), zs + motion * zd

    def blend_codes(self, body: BodyModel, rotmats: torch.Tensor, shape: torch.Tensor, transl: torch.Tensor | None,
                    fps: float) -> tuple[torch.nn.Module, torch.Tensor, torch.Tensor]:
        """A motion as ``sequence_codes``; a single pose as PBNS's (NCS needs a motion)."""
        if len(rotmats) > 1:
            return super().blend_codes(body, rotmats, shape, transl, fps)
        return (self.model, *self.pose_codes(rotmats))


class PBNSGarment(BlendGarment):
    """``path``: a PBNS weights file (default: the outfit's trained one); ``resizer``: use the
    outfit's trained resizer where it has one; ``dynamics``: motions through its NCS (None: when
    it has one; True: it must)."""

    name = "pbns"

    def __init__(self, outfit: str, path: str | Path | None = None, resizer: bool = True,
                 dynamics: bool | None = None):
        self.path, model, ck, name = load_pbns(outfit, path)
        self.outfit = name or str(self.path)
        resizer_path = store.resizer_path(name, path) if resizer and name else None
        self._take(model, ck, resizer_path if resizer_path is not None and resizer_path.exists() else None)
        ncs_path = store.ncs_path(name) if name else None
        if dynamics is not False and ncs_path is not None and ncs_path.exists():
            self.ncs, _ = NCS.load(ncs_path)
        elif dynamics:
            raise MissingFile(f"{self.outfit} has no NCS (dynamic) weights: run "
                              f"`recon garment train --model ncs --outfit {self.outfit}`")

    @classmethod
    def instead(cls, outfit: str, path: str | Path | None) -> str | None:
        return "deepsd" if path is None and untrained_mesh(outfit) else None  # your mesh, no training: DeePSD

    @property
    def label(self) -> str:
        return "NCS" if self.dynamic else "PBNS"
