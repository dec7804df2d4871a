"""The example-based Taylor model as a garment model, quasi-static: PBNS's pose deformations
plus the body-shape dimension from drapes on many bodies at anchor poses (recon.garment.taylor.model).
It sizes the outfit to the body itself (no resizer, no tightness) and pushes penetrations out its
own way; the post-step follows, with the outfit graded to the body as its rest. A single pose (a
photo) is first continued by ``drape_iterations`` iterations of the drape solver the database was
built with (recon.garment.drape, one contact search, in the gravity-aligned frame): the model is
its warm start, and the cloth nears the drape at a fraction of a drape's cost. Motions are not
(frames refined apart would flicker)."""
from __future__ import annotations

from pathlib import Path

import torch

from recon.body.base import BodyModel
from recon.errors import MissingFile, ReconError
from recon.garment import store
from recon.garment.drape import DrapeSolver
from recon.garment.family import GarmentModel, PostStep
from recon.garment.mesh import vertex_normals
from recon.garment.pbns.garment_model import load_pbns
from recon.garment.pbns.model import trained_outfit
from recon.garment.taylor.model import TaylorGarment

# drape-solver iterations after the Taylor model on a single pose (chosen on val: garment-taylor.md)
DRAPE_ITERATIONS = 20


class TaylorGarmentModel(GarmentModel):
    """``path``: the outfit's PBNS weights (default: its trained ones; the database is found by
    the outfit's name); ``drape_iterations``: single poses continued by this many iterations of
    the drape solver (0: the model alone, real time)."""

    name = "taylor"
    static = True
    resizes = False

    def __init__(self, outfit: str, path: str | Path | None = None, resizer: bool = True,
                 dynamics: bool | None = None, drape_iterations: int = DRAPE_ITERATIONS):
        self.path, model, ck, name = load_pbns(outfit, path)
        self.outfit = name or str(self.path)
        self.take(model, ck)
        tp = store.taylor_path(self.outfit)
        if not tp.exists():
            raise MissingFile(f"{self.outfit} has no Taylor database {tp}: run "
                              f"`recon garment train --model taylor --outfit {self.outfit}` (its time: "
                              "recon/garment/weights/MODEL_CARD.md)")
        self.taylor, _ = TaylorGarment.load(tp, self.model)
        self.drape_iterations, self._solver = int(drape_iterations), None

    @property
    def label(self) -> str:
        return "Taylor"

    @property
    def needs_body_mesh(self) -> bool:
        return True

    def rest_for(self, body: BodyModel, shape: torch.Tensor, smooth: int = 10, tightness=None) -> torch.Tensor:
        """The graded template the Taylor blend shapes apply to."""
        if tightness is not None:
            raise ReconError("the Taylor garment model has no tightness (it has no resizer)")
        return self.taylor.set_shape(body, shape).graded

    def dress(self, body: BodyModel, out, rotmats: torch.Tensor, shape: torch.Tensor, tightness,
              post: PostStep | None) -> torch.Tensor:
        self.rest_for(body, shape[0], tightness=tightness)  # refuses a tightness
        posed = []
        for i, s in enumerate(shape):
            taylor = self.taylor.set_shape(body, s)
            if self.drape_iterations:
                v = self._draped(body, taylor, rotmats[i:i + 1], s, out.transforms[i:i + 1])
            else:
                v = taylor.pose(rotmats[i:i + 1], out.transforms[i:i + 1], out.vertices[i:i + 1])
            posed.append(v if post is None else post(v, out.vertices[i:i + 1], taylor.graded))
        return torch.cat(posed)

    def _draped(self, body: BodyModel, taylor: TaylorGarment, r: torch.Tensor, shape: torch.Tensor,
                transforms: torch.Tensor
                ) -> torch.Tensor:
        """One person's Taylor cloth (1, N, 3) continued by the drape solver: posed in the gravity
        -aligned frame (pose ``r``, no translation; the solver's gravity is -Y), then moved rigidly
        to the frame of ``transforms`` (1, 24, 3, 4) as the body's root moves between the two."""
        if self._solver is None:
            self._solver = DrapeSolver.continuation(trained_outfit(body, self.path)[0], self.drape_iterations)
        out = body(r, shape[None])
        bv, bn, bt = out.vertices, vertex_normals(out.vertices, body.faces), out.transforms
        v = taylor.continued(taylor.pose(r, bt, bv), self._solver, bv, bn, bt)
        a, g = transforms[0, 0], bt[0, 0]
        rot = a[:, :3] @ g[:, :3].T
        return v @ rot.T + (a[:, 3] - rot @ g[:, 3])

    def animate(self, body: BodyModel, out, rotmats: torch.Tensor, shape: torch.Tensor, transl: torch.Tensor | None,
                fps: float, rest: torch.Tensor, motion: float = 1.0) -> torch.Tensor:
        return self.taylor.set_shape(body, shape).animate(rotmats, out.transforms, out.vertices)

    def sequence_codes(self, body: BodyModel, rotmats: torch.Tensor, shape: torch.Tensor, transl: torch.Tensor | None,
                       fps: float, motion: float = 1.0) -> tuple[torch.Tensor, torch.Tensor]:
        with torch.no_grad():
            return self.taylor.set_shape(body, shape).sequence_codes(rotmats)
