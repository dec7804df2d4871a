"""Implicit integration of NCS's training loss (thesis eq. 6.8): per frame, the cloth state that
minimises the PBNS energies plus the inertia term against the two previous states, which are
constants (the thesis' point against SNUG). It is the fixed point NCS's training aims at; solved
frame after frame over free vertices it gives the trajectories NCS's dynamic branch learns
(recon.garment.ncs.train), from nothing but the body's motion and the energies.

The state is the static model's drape (PBNS) plus a displacement u of the free vertices; the held
vertices (a skirt's pinned waist, a dress's top band: ``ncs.hanging_part``) stay with the static
drape. Damping (``InertiaConfig.keep_velocity``) acts on the cloth's velocity relative to where the
body carries it (the skinned outfit): the air moves with the body.

Solver: L-BFGS whose initial inverse Hessian is the factorised quadratic part of the energy (the
inertia's mass term plus the edge springs as a graph Laplacian, as projective dynamics builds it),
the quasi-Newton scheme of Liu et al. 2017 ("Quasi-Newton methods for real-time simulation of
hyperelastic materials"); a backtracking line search. The stiff springs make plain L-BFGS slow to
converge, and stopping it early is not harmless: at 30 iterations a frame a stop flings the hem
too far (eval/results/ncs-teacher-tshirt-skirt.md).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import torch
from scipy.sparse.linalg import splu

from recon.garment.losses import Criterion, InertiaLoss
from recon.garment.mesh import nearest


@dataclass
class IntegrateConfig:
    iterations: int = 60  # quasi-Newton iterations per frame at most
    history: int = 10
    # converged when no vertex moved more than this in the last iteration (metres)
    step_tol: float = 1e-6
    candidates: int = 16  # nearest body vertices per cloth vertex, searched once a frame
    # the preconditioner's stiffness across each edge, at least this share of its stiffness along
    # it: the bending and the collisions, left out of it, stiffen those directions (0 makes the
    # line search halve its steps ~5 times a iteration, 0.5 about once). 1: every edge as stiff
    # across as along, a matrix that depends on no state (projective dynamics' own), factorised once
    # for all frames, one coordinate at a time (eval/results/ncs-teacher-tshirt-skirt.md)
    across: float = 0.5


class Preconditioner:
    """The inverse of the energy's Hessian at a state, for the parts that make the problem stiff: the
    inertia's masses and the edge springs (each edge's exact Hessian, its tension's geometric part
    clamped at zero for compressed edges so that it stays positive definite: a projected Newton
    step), over the free vertices; factorised once per frame (``at``), or once for good with
    ``across`` >= 1, where the Hessian is a graph Laplacian in each coordinate alike. ``solve``
    applies it to (n, 3) vectors, zero at the held vertices."""

    def __init__(self, crit: Criterion, inertia: InertiaLoss, held: np.ndarray, across: float = 0.5):
        n = len(held)
        self.across = across
        self.e = crit.edge.edges.numpy()
        self.rest = crit.edge.rest_len.double().numpy()
        self.k = 2.0 * crit.edge.scale * crit.edge.cfg.weight * crit.edge.w.double().numpy() / len(self.e)
        self.m = np.repeat(inertia.cfg.weight * inertia.fps ** 2 * inertia.m.double().numpy() / n, 3)
        self.free = np.nonzero(np.repeat(~held, 3))[0]
        self.n = n
        i, j = self.e[:, 0], self.e[:, 1]
        self.lu = self.constant = None
        if across >= 1.0:  # k (I) per edge whatever its direction: one n x n Laplacian for x, y and z
            ii, jj = np.concatenate([i, j, i, j]), np.concatenate([i, j, j, i])
            lap = sp.coo_matrix((np.concatenate([self.k, self.k, -self.k, -self.k]), (ii, jj)), shape=(n, n)).tocsr()
            self.free_v = np.nonzero(~held)[0]
            h = (lap + sp.diags(self.m[0::3]))[self.free_v][:, self.free_v]
            self.constant = splu(h.tocsc(), permc_spec="MMD_AT_PLUS_A", options={"SymmetricMode": True})
            return
        # the per-frame path's (3n x 3n) sparsity pattern, built once
        rows = np.stack([3 * a[:, None] + np.arange(3) for a in (i, i, j, j)])  # (4, E, 3) dof ids per block
        cols = np.stack([3 * a[:, None] + np.arange(3) for a in (i, j, i, j)])
        self._r = np.broadcast_to(rows[:, :, :, None], (4, len(i), 3, 3)).ravel()
        self._c = np.broadcast_to(cols[:, :, None, :], (4, len(i), 3, 3)).ravel()
        self._sign = np.array([1.0, -1.0, -1.0, 1.0])[:, None, None, None]

    def at(self, x: torch.Tensor) -> Preconditioner:
        """Factorise the Hessian at the state ``x`` (n, 3) (nothing to do when it is constant)."""
        if self.constant is not None:
            return self
        v = x.detach().double().numpy()
        d = v[self.e[:, 1]] - v[self.e[:, 0]]
        length = np.linalg.norm(d, axis=1)
        u = d / np.maximum(length, 1e-12)[:, None]
        uu = u[:, :, None] * u[:, None, :]
        geo = np.clip(1.0 - self.rest / np.maximum(length, 1e-12), self.across, None)
        block = self.k[:, None, None] * (uu + geo[:, None, None] * (np.eye(3) - uu))
        vals = (self._sign * block[None]).ravel()
        h = sp.coo_matrix((vals, (self._r, self._c)), shape=(3 * self.n, 3 * self.n)).tocsr() + sp.diags(self.m)
        # minimum degree on A + A^T, symmetric mode: the faster ordering to factorise and to solve
        # than SuperLU's default (COLAMD) on a 5k-vertex skirt (fewer fill-ins: 2.4M against 4.1M)
        self.lu = splu(h[self.free][:, self.free].tocsc(), permc_spec="MMD_AT_PLUS_A",
                       options={"SymmetricMode": True})
        return self

    def solve(self, g: torch.Tensor) -> torch.Tensor:
        if self.constant is not None:
            out = np.zeros((self.n, 3))
            out[self.free_v] = self.constant.solve(np.ascontiguousarray(g.detach().double().numpy()[self.free_v]))
            return torch.from_numpy(out).to(g)
        out = np.zeros(3 * self.n)
        out[self.free] = self.lu.solve(g.detach().double().numpy().ravel()[self.free])
        return torch.from_numpy(out.reshape(-1, 3)).to(g)


def minimise(energy, u: torch.Tensor, precond: Preconditioner, cfg: IntegrateConfig) -> torch.Tensor:
    """L-BFGS from ``u`` (n, 3) on ``energy(u) -> scalar`` with the initial inverse Hessian
    ``precond.solve``; Armijo backtracking from the full step. A trial step the line search
    rejects costs the energy alone: the gradient is taken at accepted steps only."""
    def f_of(x):
        x = x.detach().requires_grad_(True)
        return energy(x), x

    def grad(f, x):
        g, = torch.autograd.grad(f, x)
        return g

    f, x = f_of(u)
    g, f = grad(f, x), f.detach()
    s_hist: list[torch.Tensor] = []
    y_hist: list[torch.Tensor] = []
    for _ in range(cfg.iterations):
        q, alphas = g.clone(), []
        for s, y in zip(reversed(s_hist), reversed(y_hist)):
            a = (s * q).sum() / (y * s).sum()
            q -= a * y
            alphas.append(a)
        r = precond.solve(q)
        for (s, y), a in zip(zip(s_hist, y_hist), reversed(alphas)):
            r += s * (a - (y * r).sum() / (y * s).sum())
        d = -r
        slope = (g * d).sum()
        if slope >= 0:  # not a descent direction: restart from the preconditioned gradient
            s_hist, y_hist = [], []
            d = -precond.solve(g)
            slope = (g * d).sum()
        t = 1.0
        while True:
            un = u + t * d
            fn, xn = f_of(un)
            if fn <= f + 1e-4 * t * slope or t < 1e-4:
                break
            t *= 0.5
        gn, fn = grad(fn, xn), fn.detach()
        s, y = un - u, gn - g
        if (s * y).sum() > 1e-12:
            s_hist.append(s)
            y_hist.append(y)
            if len(s_hist) > cfg.history:
                s_hist.pop(0)
                y_hist.pop(0)
        u, f, g = un, fn, gn
        if s.abs().max() < cfg.step_tol:
            break
    return u.detach()


def integrate(crit: Criterion, inertia: InertiaLoss, held: torch.Tensor, static: torch.Tensor,
              carried: torch.Tensor, body_v: torch.Tensor, body_n: torch.Tensor,
              cfg: IntegrateConfig | None = None, precond: Preconditioner | None = None,
              start: torch.Tensor | None = None,
              solve: Callable[[Callable, torch.Tensor], torch.Tensor] | None = None,
              friction: float = 0.0) -> torch.Tensor:
    """The cloth trajectory (T, n, 3) of a motion of ``T`` frames: ``static`` (T, n, 3), the
    static model's drape; ``carried`` (T, n, 3), the skinned outfit (where the body carries the
    cloth); the posed body ``body_v``, ``body_n`` (T, V, 3); ``held`` (n,) bool. The cloth starts
    at ``start`` (n, 3; default the static drape), moving as ``carried`` moves. ``solve(energy,
    u0) -> u``: another minimiser of each frame's energy than ``minimise`` (a comparison's).
    ``friction`` > 0: the share of a touching vertex's velocity along the body surface, relative
    to the carried cloth, that contact takes each frame (``contact_friction``)."""
    cfg = cfg or IntegrateConfig()
    if solve is None:
        precond = precond or Preconditioner(crit, inertia, held.numpy(), cfg.across)
    free = (~held).to(static.dtype)[:, None]
    v0 = carried[1] - carried[0] if len(carried) > 1 else torch.zeros_like(carried[0])
    x0 = static[0] if start is None else start
    prev = (x0 - 2 * v0, x0 - v0)
    out = []
    zero = torch.zeros_like(static[:1])
    for t in range(static.shape[0]):
        carry = carried[t] - carried[t - 1] if t else v0
        proj = inertia.projection(prev[1], prev[0], carry)
        if friction > 0:
            proj = contact_friction(proj, prev[1], body_v[t], body_n[t], crit.collision.cfg.eps, friction)
        cand = nearest(body_v[t:t + 1], proj[None], cfg.candidates)
        s_t, bv, bn = static[t], body_v[t:t + 1], body_n[t:t + 1]

        def energy(u, s_t=s_t, bv=bv, bn=bn, cand=cand, proj=proj):
            x = (s_t + u * free)[None]
            return (crit(x, zero, bv, bn, cand) + inertia.to_projection(x, proj[None])).sum()

        u0 = (proj - s_t) * free
        u = solve(energy, u0) if solve is not None else minimise(energy, u0, precond.at(s_t + u0), cfg)
        x = s_t + u * free
        out.append(x)
        prev = (prev[1], x)
    return torch.stack(out)


def contact_friction(proj: torch.Tensor, x_prev: torch.Tensor, body_v: torch.Tensor, body_n: torch.Tensor,
                     eps: float, friction: float, reach: float = 0.005) -> torch.Tensor:
    """Kinetic friction as a velocity filter: the projection ``proj`` (n, 3) of the vertices whose
    previous state ``x_prev`` lies within ``eps`` + ``reach`` (m) of the body surface (nearest body
    vertex, along its normal) keeps 1 - ``friction`` of its motion along the body surface."""
    idx = nearest(body_v[None], x_prev[None])[0]
    n = body_n[idx]
    touching = ((x_prev - body_v[idx]) * n).sum(-1, keepdim=True) < eps + reach
    step = proj - x_prev
    along = step - (step * n).sum(-1, keepdim=True) * n
    return torch.where(touching, proj - friction * along, proj)


def settle(crit: Criterion, inertia: InertiaLoss, held: torch.Tensor, static: torch.Tensor, carried: torch.Tensor,
           body_v: torch.Tensor, body_n: torch.Tensor, frames: int, cfg: IntegrateConfig | None = None,
           precond: Preconditioner | None = None) -> torch.Tensor:
    """The cloth (n, 3) after ``frames`` frames on the body held still in one pose (``static``,
    ``carried`` (n, 3), ``body_v``, ``body_n`` (V, 3)), from the static drape at rest: near the
    energies' own equilibrium there, which the static model only approximates."""
    rep = lambda x: x[None].expand(frames, *x.shape)  # noqa: E731
    return integrate(crit, inertia, held, rep(static), rep(carried), rep(body_v), rep(body_n), cfg, precond)[-1]


def unpose(blend: torch.Tensor, offset: torch.Tensor, min_singular: float = 0.0) -> torch.Tensor:
    """Posed offsets (..., n, 3) -> rest-pose displacements under the blended skinning rotations
    ``blend`` (..., n, 3, 3): the inverse of ``BlendShapeGarment.skin``'s linear part. Blends
    between far-apart joint rotations (a skirt's cloth between the legs) are near singular and
    their inverse flings a few centimetres of posed offset kilometres away in the rest pose;
    ``min_singular`` > 0 clamps the blend's singular values from below, so that such offsets
    stay within 1 / ``min_singular`` of their size (the rest inverts exactly)."""
    if min_singular <= 0:
        return torch.linalg.solve(blend, offset[..., None])[..., 0]
    u, s, vh = torch.linalg.svd(blend)
    return torch.einsum("...ji,...j,...kj,...k->...i", vh, 1.0 / s.clamp_min(min_singular), u, offset)
