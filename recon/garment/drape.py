"""Quasi-static drape of an outfit on a posed body of any shape: the state that minimises the PBNS
energies (edge, bending, body and layer collision, gravity) with the pinned vertices held where
the body carries them. The ground truth of the example-based (Taylor) garment model: its database
and its evaluation (recon.garment.taylor.model, recon.garment.taylor.eval).

The garment on a body of shape beta is the template graded to that body (``resize.Transfer``, as
``Dresser`` sizes it): its rest edge lengths are those of the transferred rest outfit, and the
drape starts from that rest outfit skinned to the pose (no network's output: the drape owes
nothing to PBNS).

Solver: rounds of preconditioned L-BFGS (``integrate.minimise``, the edge springs' graph Laplacian
factorised once per outfit) with the contact correspondences fixed within a round (nearest body
vertex and normal, nearest inner-layer vertex), searched again between rounds, as an ICP loop
does: a KD-tree search per energy evaluation would cost more than the energy. Contacts here are
frictionless, so a shirt could slide round the torso at no cost; a weak tether to where the body
carries each vertex (``tether``) stands for friction and makes the minimum unique.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from recon.garment import losses, mesh
from recon.garment.integrate import IntegrateConfig, Preconditioner, minimise
from recon.garment.losses import FABRIC

# the preconditioner's least mass term (per mean vertex, like the energies): below it the line search
# halves most steps; inertia's 5 / 9.81 at 30 fps
PRECOND_MASS = 460.0  # the fabric PBNS trains with: the drape minimises the same energies


@dataclass
class DrapeSolverConfig:
    rounds: int = 4  # contact searches; L-BFGS runs between them
    iterations: int = 40  # L-BFGS iterations per round at most
    step_tol: float = 2e-5  # a round ends when no vertex moved more than this (m) in an iteration
    # pull towards the skinned rest outfit (the body's carrying), per mean squared metre: friction's
    # stand-in (frictionless contacts leave sliding modes without a minimum)
    tether: float = 100.0
    edge: losses.EdgeConfig = field(default_factory=lambda: FABRIC.edge)
    bend: losses.BendConfig = field(default_factory=lambda: FABRIC.bend)
    collision: losses.CollisionConfig = field(default_factory=lambda: FABRIC.collision)
    gravity: losses.GravityConfig = field(default_factory=lambda: FABRIC.gravity)
    pin: losses.PinConfig = field(default_factory=lambda: FABRIC.pin)


class DrapeSolver:
    """``DrapeSolver(outfit, cfg)(rest, start, body_v, body_n) -> (N, 3)``: the drape of the
    outfit (its faces, layers, pins) whose rest shape is ``rest`` (N, 3), from ``start`` (N, 3; the
    skinned rest outfit, also the pinned vertices' place and the tether's target, unless ``carried``
    is given), on the posed body ``body_v``, ``body_n`` (V, 3)."""

    def __init__(self, outfit, cfg: DrapeSolverConfig | None = None):
        self.cfg = cfg = cfg or DrapeSolverConfig()
        rest = torch.from_numpy(np.asarray(outfit.vertices, np.float32))
        self.crit = losses.Criterion(outfit, rest, cfg)
        self.faces = self.crit.faces
        # the preconditioner: the edge springs' Laplacian plus the tether's Hessian as its mass term
        # (the Laplacian alone is singular for an unpinned top)
        fps = 30.0
        mass = losses.InertiaConfig(weight=max(2.0 * cfg.tether, PRECOND_MASS) / fps ** 2)
        inertia = losses.InertiaLoss(torch.ones(len(rest)), fps, mass)
        self.held = torch.from_numpy(np.asarray(outfit.pinned, bool))
        self.precond = Preconditioner(self.crit, inertia, self.held.numpy(), across=1.0)
        self.pairs = self.crit.collision.pairs()

    def contacts(self, x: torch.Tensor, body_v: torch.Tensor, body_n: torch.Tensor):
        """The fixed correspondences of a round: (body vertex, its normal) per cloth vertex, and per
        outer layer (inner vertex ids, their normals, a mask of pairs close enough to touch)."""
        idx = mesh.nearest(body_v[None], x[None])[0]
        layers = []
        if self.pairs:
            n = mesh.vertex_normals(x[None], self.faces)[0]
            for inner, outer in self.pairs:
                j = inner[mesh.nearest(x[None, inner], x[None, outer])[0]]
                near = (x[outer] - x[j]).norm(dim=-1) < self.cfg.collision.cloth_reach
                layers.append((outer, j, n[j], near))
        return body_v[idx], body_n[idx], layers

    def energy(self, x: torch.Tensor, rest_len: torch.Tensor, contact, carried: torch.Tensor) -> torch.Tensor:
        """The energies of the state ``x`` (N, 3) with a round's contacts."""
        cv, cn, layers = contact
        c = self.crit
        e = c.edge(x[None], rest_len[None])[0] + c.bend(x[None])[0] + c.gravity(x[None])[0]
        eps = self.cfg.collision.eps
        pen = torch.clamp(((x - cv) * cn).sum(-1) - eps, max=0.0)
        total = (pen ** 2).mean()
        for outer, j, nj, near in layers:
            p = torch.clamp(((x[outer] - x[j]) * nj).sum(-1) - eps, max=0.0) * near
            total = total + (p ** 2).sum() / len(x)
        e = e + self.cfg.collision.weight * total
        return e + self.cfg.tether * ((x - carried) ** 2).sum(-1).mean()

    @classmethod
    def continuation(cls, outfit, iterations: int) -> DrapeSolver:
        """A solver that continues a predicted cloth towards its drape: one contact search and at most
        ``iterations`` L-BFGS iterations, the rest as the default (the Taylor database's) solver."""
        return cls(outfit, DrapeSolverConfig(rounds=1, iterations=iterations))

    def __call__(self, rest: torch.Tensor, start: torch.Tensor, body_v: torch.Tensor, body_n: torch.Tensor,
                 carried: torch.Tensor | None = None) -> torch.Tensor:
        carried = start if carried is None else carried
        e = self.crit.edge.edges
        rest_len = (rest[e[:, 0]] - rest[e[:, 1]]).norm(dim=-1)
        free = (~self.held).to(start.dtype)[:, None]
        base = torch.where(self.held[:, None], carried, start)
        u = torch.zeros_like(start)
        inner = IntegrateConfig(iterations=self.cfg.iterations, step_tol=self.cfg.step_tol)
        for _ in range(self.cfg.rounds):
            with torch.no_grad():
                contact = self.contacts(base + u * free, body_v, body_n)
            with torch.enable_grad():
                u = minimise(lambda d, contact=contact: self.energy(base + d * free, rest_len, contact, carried),
                             u, self.precond, inner)
        return (base + u * free).detach()

