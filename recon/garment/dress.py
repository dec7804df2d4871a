"""Dress a posed body with a trained PBNS outfit.

The outfit was simulated on one body shape. For another shape its rest pose is resized the
CLOTH3D way (thesis 3.3.2): the rest-body displacement between the two shapes is transferred
to every cloth vertex from its nearest body vertex and Laplacian-smoothed, so body detail does
not print through; when the outfit has a trained resizer (``recon garment resize``, thesis
5.5.6) its correction is added and a tightness can be asked for. Pose-space deformations
(PBNS) and skinning then follow the new body.

A motion (``Dresser.animate``) is dressed by the outfit's NCS (thesis ch. 6: the cloth swings,
lags and settles) when the outfit has one and ``dynamics`` is not False, else by PBNS frame by
frame (quasi-static).

``garment_model="taylor"``: the example-based model (recon.garment.taylor.model) instead, quasi-static:
PBNS's pose deformations plus the body-shape dimension from drapes on many bodies at anchor poses;
it sizes the outfit to the body itself (no resizer, no tightness) and pushes penetrations out its
own way; the post-step follows, with the outfit graded to the body as its rest. A single pose (a
photo) is first continued by ``drape_iterations`` iterations of the drape solver the database was
built with (recon.garment.drape, one contact search, in the gravity-aligned frame): the model is
its warm start, and the cloth nears the drape at a fraction of a drape's cost. Motions are not
(frames refined apart would flicker).

``garment_model="deepsd"``: any outfit without training (recon.garment.deepsd.model, thesis ch. 4): its
blend weights and pose-space blend shapes predicted from the template mesh, then as PBNS
(resized by transfer, quasi-static). A garment mesh with no PBNS weights of its own gets it.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from recon.body import default_body
from recon.errors import MissingFile, ReconError
from recon.garment import store
from recon.garment.collide import CollisionResolver
from recon.garment.deepsd.model import animation_model
from recon.garment.drape import DrapeSolver
from recon.garment.mesh import vertex_normals
from recon.garment.ncs.model import FPS, NCS
from recon.garment.pbns.model import PBNS, pose_features, trained_outfit
from recon.garment.resize import OutfitResizer, Transfer
from recon.garment.taylor.model import TaylorGarment
from recon.garment.templates import MESH_SUFFIXES


@dataclass
class DressedOutfit:
    vertices: np.ndarray  # (B, N, 3) posed cloth, same frame as the body output
    faces: np.ndarray  # (F, 3)
    garment_id: np.ndarray  # (N,)
    names: list[str]


GARMENT_MODELS = ("pbns", "taylor", "deepsd")


def untrained_mesh(outfit: str) -> bool:
    """Whether ``outfit`` is a garment mesh with no PBNS weights of its own."""
    return Path(outfit).suffix.lower() in MESH_SUFFIXES and not store.pbns_path(outfit).exists()


# drape-solver iterations after the Taylor model on a single pose (chosen on val: garment-taylor.md)
DRAPE_ITERATIONS = 20


class Dresser:
    """``Dresser("tshirt-trousers")(body, rotmats, shape, transl) -> DressedOutfit``."""

    def __init__(self, outfit: str = "tshirt-trousers", path: str | Path | None = None, resizer: bool = True,
                 resolve_collisions: bool = True, dynamics: bool | None = None, garment_model: str = "pbns",
                 drape_iterations: int = DRAPE_ITERATIONS):
        """``resolve_collisions``: the post-step of recon.garment.collide: restore the edge lengths
        and push cloth the network leaves inside the body out of it (its cost:
        eval/results/bench-garment-1t.md).
        ``dynamics``: motions through the outfit's NCS (None: when it has one; True: it must).
        ``garment_model``: "pbns" (PBNS, NCS for motions as ``dynamics`` says), "taylor" (the
        example-based model; its database: ``recon garment train --model taylor``) or "deepsd" (any
        outfit animated without training, recon.garment.deepsd.model; what a garment mesh with no PBNS
        weights of its own gets).
        ``drape_iterations``: the Taylor model's single poses continued by this many iterations of
        the drape solver (0: the model alone, real time)."""
        if garment_model not in GARMENT_MODELS:
            raise ReconError(f"unknown garment model {garment_model!r}: {', '.join(GARMENT_MODELS)}")
        if garment_model in ("taylor", "deepsd") and dynamics:
            raise ReconError(f"the {garment_model} garment model is quasi-static: no dynamics")
        if garment_model == "pbns" and path is None and untrained_mesh(outfit):
            garment_model = "deepsd"  # your own garment without PBNS weights: DeePSD, no training
        self.garment_model = garment_model
        if garment_model == "deepsd":
            store.check_outfit(outfit)
            self.model, ck = animation_model(default_body(), outfit)
            name, dynamics = None, False
            self.outfit = str(Path(outfit).resolve()) if Path(outfit).is_file() else outfit  # found from anywhere
        else:
            path = Path(path) if path else store.trained_pbns(outfit)  # a preset, your own garment, a .pt file
            if not path.exists():
                raise MissingFile(f"no trained outfit {path}: run `recon garment train --outfit {outfit}`")
            self.model, ck = PBNS.load(path)
            name = json.loads(ck["meta_json"]).get("outfit")
            self.outfit = name or str(path)  # what Dresser(...) takes to load it again
        self.shape = ck["shape"]
        self.garment_id = ck["garment_id"].numpy()
        self.names = json.loads(ck["meta_json"])["garments"]
        self.resolver = None
        if resolve_collisions:
            self.resolver = CollisionResolver(self.model.faces.numpy(), ck["layer"].numpy())
        self._resized: dict[bytes, torch.Tensor] = {}
        self.resizer, self._resizer_path, self.transfer = None, None, None
        if resizer and name:
            p = store.resizer_path(name, path)
            self._resizer_path = p if p.exists() else None
        self.ncs = None
        ncs_path = store.ncs_path(name) if name else None
        self.taylor = None
        if garment_model == "taylor":
            tp = store.taylor_path(self.outfit)
            if not tp.exists():
                raise MissingFile(f"{self.outfit} has no Taylor database {tp}: run "
                                  f"`recon garment train --model taylor --outfit {self.outfit}` (its time: "
                                  "recon/garment/weights/MODEL_CARD.md)")
            self.taylor, _ = TaylorGarment.load(tp, self.model)
            self.drape_iterations, self._pbns_path, self._solver = int(drape_iterations), path, None
            dynamics = False  # quasi-static; the post-step follows its own penetration handling
        if dynamics is not False and ncs_path is not None and ncs_path.exists():
            self.ncs, _ = NCS.load(ncs_path)
        elif dynamics:
            raise MissingFile(f"{self.outfit} has no NCS (dynamic) weights: run "
                              f"`recon garment train --model ncs --outfit {self.outfit}`")

    @property
    def has_resizer(self) -> bool:
        """Whether the outfit has a trained resizer (needed for a ``tightness``)."""
        return self._resizer_path is not None

    def rest_for(self, body, shape: torch.Tensor, smooth: int = 10, tightness=None) -> torch.Tensor:
        """Outfit rest vertices resized to ``shape`` (1-D tensor); ``tightness`` (2,) needs a
        trained resizer (> 0 looser, see recon.garment.resize). The Taylor model's: the graded
        template its blend shapes apply to."""
        if self.taylor is not None:
            if tightness is not None:
                raise ReconError("the Taylor garment model has no tightness (it has no resizer)")
            return self.taylor.set_shape(body, shape).graded
        if self._resizer_path is not None:
            if self.resizer is None:
                self.resizer = OutfitResizer(body, self._resizer_path, self.model.rest.numpy(),
                                             self.model.faces.numpy())
            t = torch.zeros(2) if tightness is None else torch.as_tensor(tightness, dtype=torch.float32)
            key = shape.detach().cpu().numpy().tobytes() + t.numpy().tobytes()
            if key not in self._resized:
                self._resized[key] = self.resizer.rest(shape.detach().cpu(), t)[0]
            return self._resized[key]
        if tightness is not None:
            raise ReconError("tightness needs a trained resizer: run `recon garment resize`")
        key = shape.detach().cpu().numpy().tobytes()
        if key not in self._resized:
            if self.transfer is None or self.transfer.smooth != smooth:
                self.transfer = Transfer(body, self.model.rest.numpy(), self.model.faces.numpy(), self.shape, smooth)
            self._resized[key] = torch.from_numpy(self.transfer.resize(shape.detach().cpu().reshape(1, -1))[0])
        return self._resized[key]

    @torch.no_grad()
    def __call__(self, body, rotmats: torch.Tensor, shape: torch.Tensor, transl: torch.Tensor | None = None,
                 up: torch.Tensor | None = None, tightness=None) -> DressedOutfit:
        """``up``: (3, 3) rotation from the frame of ``rotmats``' root to the gravity-aligned body
        frame (+Y up); e.g. diag(1, -1, -1) for poses in an upright OpenCV camera frame. The
        network sees the gravity-aligned pose; the cloth is posed in the input frame."""
        b = rotmats.shape[0]
        shape = shape.reshape(b, -1)
        out = body(rotmats, shape, transl=transl, points_only=self.resolver is None and self.taylor is None)
        r = rotmats.clone()
        if up is not None:
            r[:, 0] = up.to(r) @ r[:, 0]
        if self.taylor is not None:
            self.rest_for(body, shape[0], tightness=tightness)  # refuses a tightness
            posed = []
            for i, s in enumerate(shape):
                taylor = self.taylor.set_shape(body, s)
                if self.drape_iterations:
                    v = self._draped(body, taylor, r[i:i + 1], s, out.transforms[i:i + 1])
                else:
                    v = taylor.pose(r[i:i + 1], out.transforms[i:i + 1], out.vertices[i:i + 1])
                if self.resolver is not None:
                    v = self.resolver(v, out.vertices[i:i + 1], body.faces, rest=taylor.graded)
                posed.append(v)
            return DressedOutfit(torch.cat(posed).numpy(), self.model.faces.numpy(), self.garment_id, self.names)
        rest = torch.stack([self.rest_for(body, s, tightness=tightness) for s in shape])
        verts = self.model.pose(r, out.transforms, rest)
        if self.resolver is not None:
            verts = self.resolver(verts, out.vertices, body.faces, rest=rest)
        return DressedOutfit(verts.numpy(), self.model.faces.numpy(), self.garment_id, self.names)

    def _draped(self, body, taylor: TaylorGarment, r: torch.Tensor, shape: torch.Tensor, transforms: torch.Tensor
                ) -> torch.Tensor:
        """One person's Taylor cloth (1, N, 3) continued by the drape solver: posed in the gravity
        -aligned frame (pose ``r``, no translation; the solver's gravity is -Y), then moved rigidly
        to the frame of ``transforms`` (1, 24, 3, 4) as the body's root moves between the two."""
        if self._solver is None:
            self._solver = DrapeSolver.continuation(trained_outfit(body, self._pbns_path)[0], self.drape_iterations)
        out = body(r, shape[None])
        bv, bn, bt = out.vertices, vertex_normals(out.vertices, body.faces), out.transforms
        v = taylor.continued(taylor.pose(r, bt, bv), self._solver, bv, bn, bt)
        a, g = transforms[0, 0], bt[0, 0]
        rot = a[:, :3] @ g[:, :3].T
        return v @ rot.T + (a[:, 3] - rot @ g[:, 3])

    @property
    def dynamic(self) -> bool:
        """Whether motions are dressed by NCS (else PBNS, frame by frame)."""
        return self.ncs is not None

    def sequence_codes(self, body, rotmats: torch.Tensor, shape: torch.Tensor, transl: torch.Tensor | None = None,
                       fps: float = FPS, motion: float = 1.0) -> tuple[torch.Tensor, torch.Tensor]:
        """The blend-shape model dressing a motion and its codes per frame: (D (E, N*3), (T, E)).
        NCS's when dynamic (``motion`` scales its dynamic code: 0 = static; ``NCS.motion_codes``),
        else PBNS's. Poses in the gravity-aligned body frame (+Y up)."""
        with torch.no_grad():
            if self.taylor is not None:
                return self.taylor.set_shape(body, shape).sequence_codes(rotmats)
            if self.ncs is None:
                return self.model.D.detach(), self.model.mlp(pose_features(rotmats))
            zs, zd = self.ncs.motion_codes(body, rotmats, shape, transl, fps)
            return self.ncs.D.detach(), zs + motion * zd

    @torch.no_grad()
    def animate(self, body, rotmats: torch.Tensor, shape: torch.Tensor, transl: torch.Tensor | None = None,
                fps: float = FPS, tightness=None, motion: float = 1.0) -> DressedOutfit:
        """Dress a motion (T, 24, 3, 3) local rotations, +Y up, at ``fps`` frames a second (NCS
        learnt its dynamics at 30), one shape (S,) and translation (T, 3): (T, N, 3) cloth."""
        shape = shape.reshape(-1)
        t = len(rotmats)
        shp = shape[None].expand(t, -1)
        out = body(rotmats, shp, transl=transl, points_only=self.resolver is None and self.taylor is None)
        rest = self.rest_for(body, shape, tightness=tightness)
        if self.taylor is not None:
            verts = self.taylor.set_shape(body, shape).animate(rotmats, out.transforms, out.vertices)
        elif self.ncs is None:
            verts = self.model.pose(rotmats, out.transforms, rest)
        else:
            _, codes = self.sequence_codes(body, rotmats, shape, transl, fps)
            verts = self.ncs.pose_codes(codes, out.transforms, rest)
        if self.resolver is not None:
            verts = self.resolver(verts, out.vertices, body.faces, rest=rest)
        model = self.ncs or self.model
        return DressedOutfit(verts.numpy(), model.faces.numpy(), self.garment_id, self.names)

