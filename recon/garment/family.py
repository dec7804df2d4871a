"""The garment-model interface and its registry: what a model family (PBNS with NCS, Taylor,
DeePSD, or yours) must offer for ``recon.garment.dress.Dresser`` to dress a body in a pose or a
motion and for a .glb to hold it as skinning plus morph targets.

Families register themselves: a package names its ``GarmentModel`` class under the entry-point
group ``recon.garment_models`` (recon's own in pyproject.toml), or code calls ``register`` at
run time. The core imports no family: ``family(name)`` loads one on first use.
"""
from __future__ import annotations

import json
from abc import ABC, abstractmethod
from collections.abc import Callable
from importlib.metadata import entry_points
from pathlib import Path
from typing import ClassVar

import numpy as np
import torch

from recon.body.base import BodyModel
from recon.errors import ReconError

GROUP = "recon.garment_models"
# the post-step a Dresser applies: (cloth (B, N, 3), posed body vertices (B, V, 3), rest (B or 1, N, 3)) -> cloth
PostStep = Callable[[torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor]


class GarmentModel(ABC):
    """One outfit in one family, loaded: ``family(name)(outfit, path, resizer=..., dynamics=...,
    **options)``. Poses are local joint rotations (B or T, 24, 3, 3) whose root is in the
    gravity-aligned body frame (+Y up); ``out`` is the body model's output for them."""

    name: ClassVar[str]  # the registry's key, what ``--garment-model`` takes
    static: ClassVar[bool] = False  # quasi-static: refuses ``dynamics``
    resizes: ClassVar[bool] = True  # takes a tightness where the outfit has a trained resizer

    outfit: str  # what ``Dresser(outfit)`` takes to load it again
    model: torch.nn.Module  # the skinned blend-shape model (rest, faces, weights, D, blend, apply_blend)
    shape: torch.Tensor  # the body shape the outfit was made on
    garment_id: np.ndarray  # (N,) which garment each cloth vertex belongs to
    names: list[str]  # the garments
    layer: np.ndarray  # (N,) collision layer of each cloth vertex (the post-step's)

    def take(self, model: torch.nn.Module, ck: dict) -> None:
        """``model`` and the outfit fields of its checkpoint ``ck`` (shape, garment ids, names, layers)."""
        self.model = model
        self.shape, self.garment_id = ck["shape"], ck["garment_id"].numpy()
        self.names = json.loads(ck["meta_json"])["garments"]
        self.layer = ck["layer"].numpy()

    @classmethod
    def instead(cls, outfit: str, path: str | Path | None) -> str | None:
        """Another family that should dress ``outfit`` when this one is asked for (e.g. a garment
        mesh with no trained weights); None: this one."""
        return None

    @property
    def label(self) -> str:
        """The model's name for people (records, pages)."""
        return self.name

    @property
    def dynamic(self) -> bool:
        """Whether motions swing (a dynamic model), else each frame is dressed on its own."""
        return False

    @property
    def has_resizer(self) -> bool:
        """Whether ``rest_for`` takes a tightness."""
        return False

    @property
    def needs_body_mesh(self) -> bool:
        """Whether dressing needs the posed body's vertices besides its joint transforms."""
        return False

    @property
    def motion_model(self) -> torch.nn.Module:
        """The skinned blend-shape model a motion's cloth and codes belong to."""
        return self.model

    @abstractmethod
    def rest_for(self, body: BodyModel, shape: torch.Tensor, smooth: int = 10, tightness=None) -> torch.Tensor:
        """The outfit's rest vertices (N, 3) for the body shape ``shape`` (S,)."""

    @abstractmethod
    def dress(self, body: BodyModel, out, rotmats: torch.Tensor, shape: torch.Tensor, tightness,
              post: PostStep | None) -> torch.Tensor:
        """The cloth (B, N, 3) on B posed bodies, each frame on its own, ``post`` applied."""

    @abstractmethod
    def animate(self, body: BodyModel, out, rotmats: torch.Tensor, shape: torch.Tensor, transl: torch.Tensor | None,
                fps: float, rest: torch.Tensor, motion: float = 1.0) -> torch.Tensor:
        """The cloth (T, N, 3) of a motion of one body shape (S,) from the rest ``rest``, before the
        post-step; ``motion`` scales a dynamic model's motion (0: static)."""

    @abstractmethod
    def sequence_codes(self, body: BodyModel, rotmats: torch.Tensor, shape: torch.Tensor, transl: torch.Tensor | None,
                       fps: float, motion: float = 1.0) -> tuple[torch.Tensor, torch.Tensor]:
        """A motion as ``motion_model``'s morph targets and their weights per frame: (D (E, N*3), (T, E))."""

    def blend_codes(self, body: BodyModel, rotmats: torch.Tensor, shape: torch.Tensor, transl: torch.Tensor | None,
                    fps: float) -> tuple[torch.nn.Module, torch.Tensor, torch.Tensor]:
        """The frames (one pose, or a motion) as a skinned model, its morph targets and their
        weights per frame (what a .glb holds)."""
        return (self.motion_model, *self.sequence_codes(body, rotmats, shape, transl, fps))


_RUNTIME: dict[str, type[GarmentModel]] = {}


def register(cls: type[GarmentModel]) -> type[GarmentModel]:
    """Add a family at run time (a class decorator); entry points need no call."""
    _RUNTIME[cls.name] = cls
    return cls


def family_names() -> tuple[str, ...]:
    """Every registered family, the installed ones first (read from metadata: nothing is imported)."""
    installed = tuple(dict.fromkeys(ep.name for ep in entry_points(group=GROUP)))
    return installed + tuple(n for n in _RUNTIME if n not in installed)


def family(name: str) -> type[GarmentModel]:
    """The family registered as ``name``."""
    if name in _RUNTIME:
        return _RUNTIME[name]
    found = [ep for ep in entry_points(group=GROUP) if ep.name == name]
    if not found:
        known = family_names()
        if not known:
            raise ReconError(f"no garment model is registered: install recon (`pip install -e .`) so that its "
                             f"entry points ({GROUP}) are known")
        raise ReconError(f"unknown garment model {name!r}: {', '.join(known)}")
    cls = found[0].load()
    if not (isinstance(cls, type) and issubclass(cls, GarmentModel)) or cls.name != name:
        raise ReconError(f"the entry point {name} = {found[0].value} is not a GarmentModel named {name!r}")
    return cls
