"""NCS's training losses (stages 2-4 of ``recon.garment.ncs.train``), each a module-like callable
returning (loss, terms to log): the principal fields of the solved cloth and the coefficients on
them (``principal_fields``, ``project``, ``gram``), the fitting of the networks to the teacher
(``Fit``, with ``Contact``), and the physics steps' terms (``Physics``: the thesis' loss against the
solved past; ``StaticPoses``: PBNS's loss on the static part; ``FreeMotion``: the energies on
unsolved motion)."""
from __future__ import annotations

from collections.abc import Callable

import torch

from recon.body.base import BodyModel
from recon.garment import losses
from recon.garment.data import posed_bodies
from recon.garment.losses import candidates as pose_candidates
from recon.garment.mesh import nearest, nearest_among
from recon.garment.metrics import collision_pct, penetration
from recon.garment.ncs.config import NCSTrainConfig
from recon.garment.ncs.data import Teacher
from recon.garment.ncs.model import NCS, static_descriptors
from recon.garment.pbns.model import pose_features
from recon.garment.templates import Outfit


def principal_fields(du: torch.Tensor, masses: torch.Tensor, k: int, seed: int = 0) -> torch.Tensor:
    """The ``k`` principal components (k, n, 3) of displacements (..., n, 3) under the mass metric
    (``masses`` (n,)), each scaled so that its coefficients stay within +-0.5 on ``du`` (the GRU's
    codes are bounded by 1)."""
    w = (masses / masses.mean()).sqrt()[:, None]
    x = (du * w).reshape(-1, du.shape[-2] * 3)
    torch.manual_seed(seed)
    _, _, v = torch.svd_lowrank(x, q=k + 16, niter=4)
    fields = v.T[:k].reshape(k, -1, 3) / w
    scale = project(du, fields, masses).reshape(-1, k).abs().amax(0) / 0.5
    return fields * scale[:, None, None]


def project(du: torch.Tensor, fields: torch.Tensor, masses: torch.Tensor) -> torch.Tensor:
    """Least-squares coefficients (..., k) of displacements (..., n, 3) on ``fields`` (k, n, 3) in
    the mass metric."""
    m = masses / masses.mean()
    weighted = (fields * m[:, None]).reshape(len(fields), -1)  # a matmul: einsum would broadcast (..., k, n, 3)
    rhs = (du.reshape(*du.shape[:-2], -1) @ weighted.T) / len(m)
    return torch.linalg.solve(gram(fields.reshape(len(fields), -1), masses), rhs.unsqueeze(-1)).squeeze(-1)


def gram(rows: torch.Tensor, masses: torch.Tensor) -> torch.Tensor:
    """(E, E) mass-weighted Gram matrix of rest-pose fields (E, n * 3): code^T G code is the mean
    squared displacement."""
    w = (masses / masses.mean()).repeat_interleave(3)
    return (rows * w) @ rows.T / len(masses)


class Contact:
    """How far the predicted hanging part goes into the body, at frames ``frames`` (F,) of the
    train chunks: PBNS's posed drape ``static`` and the blended skinning rotations ``blend`` (C,
    F, n, 3[, 3]), the posed body ``body_v``, ``body_n`` (C, F, V, 3) and per cloth vertex the
    indices of the body vertices nearest the solved cloth, ``candidates`` (C, F, n, K): the
    prediction's nearest body vertex is searched among them, as the solver searches its own. The
    new rows' displacement (``fields()``: (k, n, 3) of the hanging part, read at each call, as the
    physics steps train them) is posed on PBNS's drape (the static code on PBNS's rows is PBNS's)."""

    def __init__(self, frames, static, blend, body_v, body_n, candidates, fields: Callable[[], torch.Tensor],
                 eps: float):
        self.frames, self.static, self.blend = frames, static, blend
        self.body_v, self.body_n, self.candidates = body_v, body_n, candidates
        self.fields, self.eps = fields, eps

    @staticmethod
    @torch.no_grad()
    def build(teacher: Teacher, chunk_motions, offsets: torch.Tensor, frames: torch.Tensor,
              fields: Callable[[], torch.Tensor], eps: float,
              k: int = 16) -> Contact:
        parts = []
        for (rot, tr), off in zip(chunk_motions, offsets):
            static, _, bv, bn, blend, _ = teacher.drapes(rot[frames], tr[frames])
            parts.append((static, blend, bv, bn, nearest(bv, static + off[frames], k).int()))
        return Contact(frames, *(torch.stack(x) for x in zip(*parts)), fields=fields, eps=eps)

    def __call__(self, i: torch.Tensor, j: torch.Tensor, z_new: torch.Tensor):
        """Chunks ``i`` (B,), their frame slots ``j`` (B, F') into ``frames``, the new rows' codes
        at every chunk frame (B, T, k) -> (mean squared penetration past eps (m^2), % inside)."""
        z = torch.gather(z_new, 1, self.frames[j][..., None].expand(-1, -1, z_new.shape[-1]))
        fields = self.fields()
        u = (z @ fields.reshape(len(fields), -1)).view(*z.shape[:2], -1, 3)
        ii = i[:, None].expand_as(j)
        x = (self.static[ii, j] + torch.einsum("bfnij,bfnj->bfni", self.blend[ii, j], u)).flatten(0, 1)
        bv, bn = self.body_v[ii, j].flatten(0, 1), self.body_n[ii, j].flatten(0, 1)
        p = penetration(x, bv, bn, nearest_among(bv, x, self.candidates[ii, j].flatten(0, 1)), self.eps)
        return p.pow(2).mean(), (p < -self.eps).float().mean() * 100  # inside: behind the surface itself


class Fit:
    """The fitting loss on a batch of chunks: the mass-weighted mean squared rest-pose displacement
    (m^2) between NCS's codes on the new rows (static + dynamic) and the teacher's, after the lead.
    ``inputs``: the chunks' static and dynamic descriptors and PBNS inputs (C, T, ...)."""

    def __init__(self, model: NCS, inputs, coef, gram_new, lead: int, contact: Contact | None = None,
                 contact_weight: float = 0.0, contact_frames: int = 8):
        self.model, self.inputs, self.coef, self.gram_new, self.lead = model, inputs, coef, gram_new, lead
        self.contact, self.contact_weight, self.contact_frames = contact, contact_weight, contact_frames

    def teacher_error(self, i: torch.Tensor, codes: torch.Tensor | None = None) -> torch.Tensor:
        """(B,) mean squared displacement error on the new rows, per chunk."""
        e = self.model.cfg.embedding
        if codes is None:
            zs, zd, _ = self.model.codes(*(x[i] for x in self.inputs))
            codes = zs + zd
        miss = codes[:, self.lead:, e:] - self.coef[i][:, self.lead:]
        return torch.einsum("btk,kl,btl->bt", miss, self.gram_new, miss).mean(1)

    def __call__(self, batch):
        """``batch``: train chunks (B,) and with ``contact`` the chunks' slots into its frames (B, F')."""
        i = batch[0]
        zs, zd, _ = self.model.codes(*(x[i] for x in self.inputs))
        teacher = self.teacher_error(i, zs + zd).mean()
        terms = {"teacher_mm": teacher.sqrt() * 1000}
        if self.contact is None or not self.contact_weight:
            return teacher, terms
        slots = batch[1]
        pen, inside = self.contact(i, slots, (zs + zd)[..., self.model.cfg.embedding:])
        return teacher + self.contact_weight * pen, {**terms, "contact_pct": inside}


def frame_codes(model: NCS, inputs, t: torch.Tensor) -> torch.Tensor:
    """NCS's codes (static + dynamic, (B * F, E)) of sequences ``inputs`` (static, dynamic
    descriptors, PBNS inputs (B, T, ...)) at their frames ``t`` (B, F): the network runs through
    every frame, the GRU needs the past."""
    zs, zd, _ = model.codes(*inputs)
    return torch.gather(zs + zd, 1, t[..., None].expand(-1, -1, zs.shape[-1])).flatten(0, 1)


class Physics:
    """The thesis' loss (eq. 6.8) on NCS's predictions at sampled frames of the chunks, with the
    previous states the solved ones: the PBNS energies of the predicted hanging part plus the
    inertia term against the projection of the teacher's two previous states. In units of a mean
    squared displacement (divided by the inertia term's factor), so that it adds to ``Fit``'s."""

    def __init__(self, model: NCS, teacher: Teacher, motions: list[tuple[torch.Tensor, torch.Tensor]],
                 offsets: torch.Tensor, inputs):
        self.model, self.teacher, self.motions, self.offsets, self.inputs = model, teacher, motions, offsets, inputs
        ic = teacher.inertia
        self.unit = ic.cfg.weight * 0.5 * ic.fps ** 2

    def __call__(self, i: torch.Tensor, t: torch.Tensor):
        """Chunks ``i`` (B,) and frames ``t`` (B, F), each >= 2 -> (loss, terms)."""
        z = frame_codes(self.model, [x[i] for x in self.inputs], t)
        return self.energy(i[:, None].expand_as(t).reshape(-1), t.reshape(-1), z)

    def energy(self, c: torch.Tensor, f: torch.Tensor, z: torch.Tensor):
        """The loss of codes ``z`` (n, E) at frames ``f`` (n,) of chunks ``c`` (n,): (mean, terms)."""
        tch = self.teacher
        n = len(f)
        frames = torch.stack([f - 2, f - 1, f], 1)  # (n, 3): the two solved frames, then the predicted one
        rot = torch.stack([self.motions[cc][0][ff] for cc, ff in zip(c.tolist(), frames)])
        tr = torch.stack([self.motions[cc][1][ff] for cc, ff in zip(c.tolist(), frames)])
        with torch.no_grad():  # the body's surface at the predicted frame only (a third of the cost)
            transforms = tch.body(rot.flatten(0, 1), tch.shape.expand(3 * n, -1), transl=tr.flatten(0, 1),
                                  points_only=True).transforms.view(n, 3, 24, 3, 4)
            bv, bn, _ = posed_bodies(tch.body, rot[:, 2], tch.shape, transl=tr[:, 2])
            static = tch.pbns.pose(rot[:, :2].flatten(0, 1), transforms[:, :2].flatten(0, 1))[:, tch.idx]
            carried = tch.pbns.skin(tch.pbns.rest, transforms[:, 1:].flatten(0, 1))[:, tch.idx]
        solved = static.view(n, 2, -1, 3) + self.offsets[c[:, None], frames[:, :2]]  # (n, 2, nh, 3)
        carried = carried.view(n, 2, -1, 3)
        proj = tch.inertia.projection(solved[:, 1], solved[:, 0], carried[:, 1] - carried[:, 0])
        dt = self.model.decode(z)
        x = self.model.skin(self.model.rest + dt, transforms[:, 2])[:, tch.idx]
        near = nearest(bv, x, 8)
        e = tch.crit(x, dt[:, tch.idx], bv, bn, near) + tch.inertia.to_projection(x, proj)
        # the nearest body vertex is the first of the 8: no second KD-tree query
        with torch.no_grad():
            terms = {"physics_edge_mm": tch.crit.edge.strain(x).abs().mean() * 1000,
                     "physics_collision_pct": collision_pct(x, bv, bn, near[..., 0]).mean()}
        return e.mean() / self.unit, terms


class StaticPoses:
    """PBNS's loss (eq. 5.3: the whole outfit's energies, its fabric) on NCS's static part, the
    prediction at motion control 0, at poses of the train split, in the units of ``Physics``: what
    PBNS minimised over thousands of poses, kept true of the static encoder fitted to a few chunks."""

    def __init__(self, model: NCS, outfit: Outfit, cfg: NCSTrainConfig, body: BodyModel, shape: torch.Tensor,
                 rotmats: torch.Tensor, unit: float, candidates: int = 8):
        self.model, self.unit = model, unit
        self.crit = losses.Criterion(outfit, model.rest, cfg)
        self.bv, self.bn, self.bt = posed_bodies(body, rotmats, shape)
        # the joint transforms' rotations are the joints' global rotations
        self.static = static_descriptors(rotmats, self.bt[..., :3]).flatten(1)
        self.pose = pose_features(rotmats)
        with torch.no_grad():  # the contacts' candidates around the static part as it is now (PBNS + the fit's)
            codes = model.static_code(self.static, self.pose)
        self.body_c, self.cloth_c = pose_candidates(model, self.crit, rotmats, self.bt, self.bv, candidates,
                                                    codes=codes)

    def __call__(self, i: torch.Tensor):
        """Poses ``i`` (B,) -> (loss, terms)."""
        dt = self.model.decode(self.model.static_code(self.static[i], self.pose[i]))
        v = self.model.skin(self.model.rest + dt, self.bt[i])
        e = self.crit(v, dt, self.bv[i], self.bn[i], self.body_c[i], [c[i] for c in self.cloth_c]).mean()
        with torch.no_grad():
            terms = {"static_edge_mm": self.crit.edge.strain(v).abs().mean() * 1000,
                     "static_collision_pct": collision_pct(v, self.bv[i], self.bn[i]).mean()}
        return e / self.unit, terms


class FreeMotion:
    """The energies every state of the cloth keeps low whatever its motion, collision, edge and
    pin (not gravity, which only inertia balances), on NCS's whole prediction of the hanging part at
    frames of motions no teacher solved, in the units of ``Physics``."""

    def __init__(self, model: NCS, teacher: Teacher, inputs, motions: list[tuple[torch.Tensor, torch.Tensor]],
                 unit: float):
        self.model, self.teacher, self.inputs, self.motions, self.unit = model, teacher, inputs, motions, unit

    def __call__(self, i: torch.Tensor, t: torch.Tensor):
        """Windows ``i`` (B,) and frames ``t`` (B, F) -> (loss, terms)."""
        tch, crit = self.teacher, self.teacher.crit
        z = frame_codes(self.model, [x[i] for x in self.inputs], t)
        rot = torch.cat([self.motions[w][0][f] for w, f in zip(i.tolist(), t)])
        tr = torch.cat([self.motions[w][1][f] for w, f in zip(i.tolist(), t)])
        bv, bn, transforms = posed_bodies(tch.body, rot, tch.shape, transl=tr)
        dt = self.model.decode(z)
        x = self.model.skin(self.model.rest + dt, transforms)[:, tch.idx]
        near = nearest(bv, x, 8)
        loss = crit.edge(x) + crit.collision(x, bv, bn, crit.faces, near) + crit.pin(dt[:, tch.idx])
        with torch.no_grad():
            terms = {"free_edge_mm": crit.edge.strain(x).abs().mean() * 1000,
                     "free_collision_pct": collision_pct(x, bv, bn, near[..., 0]).mean()}
        return loss.mean() / self.unit, terms
