"""Example-based clothing synthesis (Wu et al., "Example-based Real-time Clothing Synthesis for
Virtual Agents"): the body-shape dimension added to a clothing pose model by first-order Taylor
expansions at anchor poses, blended.

    f(beta, theta) = f(beta0, theta) + sum_s w^s [LBS_s->theta f(beta, theta_s) - LBS_s->theta f(beta0, theta_s)]

f(beta0, .) is the clothing pose model (PBNS on the body it was trained for, or a simulation);
f(., theta_s) is the clothing shape model of anchor s: the quasi-static drapes of the outfit on a
set of bodies at that pose (recon.garment.drape), reduced by PCA (5 components) with a ridge map
from (beta, beta^2, 1) to the coefficients (the paper's eq. 5-6). The model is of each drape's
departure from the outfit graded to its body (``resize.Transfer``, computed exactly for any body):
the PCA and its map then carry how the drape differs from the grading, not the body's size.

Here the anchors' drapes are kept unposed: each is taken back to the rest pose through the
outfit's skinning at its own pose and body (``integrate.unpose``), so "LBS from theta_s to theta"
is that inverse followed by the skinning at theta. The shape term of every anchor is then a rest
-pose displacement, computed once per body shape (``set_shape``); per frame the blended term is a
weighted sum of those displacements added to the pose model's rest-pose output before its one
skinning: the cost of the shape dimension is a blend, not one skinning per anchor.

The pose model: PBNS, trained further on the examples' drapes when the database was built
(``fitted``: its network and blend shapes stored with the database, its skinning PBNS's), and
corrected at example poses like the paper's SOR pose model (example poses blended): each example's
drape on PBNS's body minus the pose model's cloth there (``pose_residual``, unposed) is blended like
the shape terms, so the model meets the drape at an example. The examples are the
anchors and, when the database has them, more poses draped on PBNS's body alone
(``pose_examples``; one drape a pose where an anchor costs a drape per body), blended with weights
of their own (``correct_pose=False``: PBNS alone, the paper's formula with PBNS as f(beta0, .)).

Blending (the paper's eq. 7-8): the clothing is split into regions by bone groups (``REGIONS``);
per region the distance of the query pose to each anchor weighs each joint rotation difference
by the clothing's sensitivity to that joint in that region; the five nearest anchors get weights
1 / (D + eps)^k, normalised per region; a vertex takes its regions' weights by its skinning
weights. Over a motion the distances are damped from frame to frame (eq. 9). Penetrations are
pushed out along the normal of each cloth vertex's bound body vertex (eq. 10).
"""
from __future__ import annotations

import copy
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import roma
import torch
from scipy.spatial import cKDTree

from recon import paths
from recon.body import skeleton
from recon.body.base import BodyModel
from recon.garment.collide import CollisionResolver
from recon.garment.pbns.model import PBNS, mlp_of, pose_features, remove_yaw, rotate
from recon.garment.resize import Transfer

# bone groups of the clothing regions (the paper's N_g = 7)
REGIONS = (
    ("pelvis", "spine1", "spine2", "spine3", "neck", "head"),
    ("left_collar", "left_shoulder", "left_elbow", "left_wrist", "left_hand"),
    ("right_collar", "right_shoulder", "right_elbow", "right_wrist", "right_hand"),
    ("left_hip",),
    ("left_knee", "left_ankle", "left_foot"),
    ("right_hip",),
    ("right_knee", "right_ankle", "right_foot"),
)


@dataclass
class BlendConfig:
    nearest: int = 5  # anchors blended per region (the paper: the top five)
    power: float = 2.0  # k of 1 / (D + eps)^k: higher keeps an anchor's detail, lower smooths
    eps: float = 1e-4  # rad^2 (distances are sensitivity-weighted squared joint angle differences)
    damping: float = 0.5  # eta of eq. 9: share of the previous frame's distance kept over a motion
    margin: float = 0.005  # epsilon_p of eq. 10 (m): clearance restored at most


def region_weights(blend_weights: torch.Tensor) -> torch.Tensor:
    """(N, 24) skinning weights -> (N, G) share of each region per vertex (rows sum to 1)."""
    cols = [[skeleton.JOINT_NAMES.index(j) for j in group] for group in REGIONS]
    return torch.stack([blend_weights[:, c].sum(1) for c in cols], 1)


def pose_vector(rotmats: torch.Tensor) -> torch.Tensor:
    """(B, 24, 3, 3) local rotations -> (B, 72) joint rotation vectors, the root's heading removed
    (gravity acts on tilt, not on heading): the coordinates of the sensitivity distance."""
    r = torch.cat([remove_yaw(rotmats[:, :1]), rotmats[:, 1:]], 1)
    return roma.rotmat_to_rotvec(r).flatten(1)


def shape_features(shape: torch.Tensor) -> torch.Tensor:
    """(B, S) -> (B, 2S + 1): (beta, beta^2, 1), the inputs of the shape model's map (eq. 6)."""
    return torch.cat([shape, shape ** 2, torch.ones_like(shape[:, :1])], 1)


def blend_weights(distance: torch.Tensor, cfg: BlendConfig) -> torch.Tensor:
    """(..., G, A) region-to-anchor distances -> (..., G, A) weights: 1 / (D + eps)^k on the
    ``cfg.nearest`` nearest anchors of each region, 0 elsewhere, summing to 1 per region."""
    k = min(cfg.nearest, distance.shape[-1])
    d, idx = distance.topk(k, dim=-1, largest=False)
    w = (d + cfg.eps) ** -cfg.power
    w = w / w.sum(-1, keepdim=True)
    return torch.zeros_like(distance).scatter_(-1, idx, w)


def fit_shape_model(shapes: torch.Tensor, unposed: torch.Tensor, components: int = 5, ridge: float = 0.2
                    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """One anchor's clothing shape model from its drapes: ``unposed`` (K, N, 3) on bodies
    ``shapes`` (K, S). PCA of the vertex coordinates (eq. 5) and a ridge map (eq. 6, L2 weight
    ``ridge``): returns (mean (N, 3), basis (C, N, 3), map (C, 2S + 1)) with
    drape(beta) ~ mean + (map @ shape_features(beta)) . basis."""
    k = unposed.shape[0]
    flat = unposed.reshape(k, -1).double()
    mean = flat.mean(0)
    _, _, vh = torch.linalg.svd(flat - mean, full_matrices=False)
    c = min(components, k)
    basis = vh[:c]
    coeff = (flat - mean) @ basis.T  # (K, C), zero mean
    # the ridge acts on standardised features and spares the intercept: on raw phenotypes in [0, 1]
    # (not SMPL's betas of the paper) a weight of 0.2 shrinks every slope and misses the drapes by cm
    x = shape_features(shapes.double())[:, :-1]
    mu, sd = x.mean(0), x.std(0).clamp_min(1e-6)
    z = (x - mu) / sd
    w = torch.linalg.solve(z.T @ z + ridge * torch.eye(z.shape[1], dtype=z.dtype), z.T @ coeff).T  # (C, 2S)
    w = w / sd
    m = torch.cat([w, -(w @ mu)[:, None]], 1)  # (C, 2S + 1) on (beta, beta^2, 1)
    return mean.view(-1, 3).float(), basis.view(c, -1, 3).float(), m.float()


class TaylorGarment:
    """The Taylor model of one outfit: ``TaylorGarment.load(path, pbns)``; ``set_shape(body,
    shape)`` once per person, then ``pose(rotmats, transforms, body_v)`` per frame (or batch) and
    ``animate`` for motions (damped blending)."""

    def __init__(self, pbns: PBNS, anchors: torch.Tensor, sensitivity_q: torch.Tensor, basis: torch.Tensor,
                 maps: torch.Tensor, shape0: torch.Tensor, cfg: BlendConfig | None = None,
                 pose_residual: torch.Tensor | None = None, correct_pose: bool = True,
                 pose_examples: torch.Tensor | None = None, fitted: bool = False):
        self.pbns, self.cfg = pbns, cfg or BlendConfig()  # the pose model (a PBNS)
        self.fitted = fitted  # whether the pose model is PBNS trained further (stored with the database)
        self.anchors = anchors  # (A, 24, 3, 3) anchor poses
        self.anchor_vec = pose_vector(anchors)  # (A, 72)
        self.q = sensitivity_q  # (G, 72) per region, weight of each squared joint-angle difference
        self.basis = basis  # (A, C, N, 3) shape-model components (the means cancel in the Taylor term)
        self.maps = maps  # (A, C, 2S + 1)
        self.shape0 = shape0  # (S,) the body of the pose model
        # (E, 24, 3, 3) the poses of pose_residual, blended on their own; None: the anchors (E = A)
        self.pose_examples = pose_examples
        self.example_vec = None if pose_examples is None else pose_vector(pose_examples)
        # (E, N, 3) drape minus PBNS at each example on PBNS's body, unposed (None: zeros)
        self.pose_residual = pose_residual
        self.correct_pose = correct_pose
        self.regions = region_weights(pbns.weights.detach())  # (N, G)
        self.regions_t = self.regions.T.contiguous()  # (G, N): blending makes vertex rows, no transposed copy
        self.shape: torch.Tensor | None = None  # (S,) the body of set_shape
        # per-anchor shape terms beyond the grading, and with pose_residual (PBNS corrected as pose
        # model), stored coordinate-major (A, 3, N): blending them per vertex runs on contiguous rows
        self.delta_t: torch.Tensor | None = None
        self.corrected_t: torch.Tensor | None = None
        self.graded: torch.Tensor | None = None  # (N, 3) the template graded to the body of set_shape
        self.shift: torch.Tensor | None = None  # (N, 3) graded minus the pose model's rest
        self._transfer: Transfer | None = None
        self._body_inc = None  # the body's vertex-face incidence (its normals), made with _transfer

    @property
    def pose_residual(self) -> torch.Tensor | None:
        return self._residual

    @pose_residual.setter
    def pose_residual(self, residual: torch.Tensor | None) -> None:
        self._residual = residual
        self.residual_t = None if residual is None else residual.transpose(1, 2).contiguous()
        self.delta_t = None  # set_shape again
        self.shape = None

    @property
    def separate_examples(self) -> bool:
        """Whether the pose model's corrections are blended over examples of their own."""
        return self.example_vec is not None and self.residual_t is not None

    @contextmanager
    def corrections(self, on: bool):
        """Within the block the pose examples' corrections are on or off (``correct_pose``); after it
        as before."""
        before, self.correct_pose = self.correct_pose, on
        try:
            yield self
        finally:
            self.correct_pose = before

    # --- per body shape -------------------------------------------------------------------------
    @torch.no_grad()
    def shape_terms(self, shape: torch.Tensor) -> torch.Tensor:
        """(A, N, 3) the part of each anchor's rest-pose Taylor shape term f(beta, theta_s) -
        f(beta0, theta_s) (unposed) beyond the grading's, for ``shape`` (S,)."""
        dx = shape_features(shape.reshape(1, -1).float()) - shape_features(self.shape0.reshape(1, -1).float())
        coeff = self.maps @ dx[0]  # (A, C)
        return torch.einsum("ac,acnk->ank", coeff, self.basis.float())

    @torch.no_grad()
    def set_shape(self, body: BodyModel, shape: torch.Tensor) -> TaylorGarment:
        """Precompute the shape terms and the penetration binding for a body shape (S,) (nothing to do
        for the body it is set to already)."""
        shape = shape.detach().reshape(-1).float().cpu()
        if self.shape is not None and torch.equal(shape, self.shape):
            return self
        self.shape = shape
        bv = body.rest_geometry(self.shape[None].to(body.mean_shape))[0][0].float().numpy()
        if self._transfer is None:
            self._transfer = Transfer(body, self.pbns.rest.numpy(), self.pbns.faces.numpy(), self.shape0)
            self._body_inc = CollisionResolver.incidence(np.asarray(body.faces), len(bv))
        self.graded = torch.from_numpy(self._transfer.resize(self.shape[None], bv[None])[0])
        self.shift = self.graded - self.pbns.rest  # the grading's term, the same at every anchor
        self.delta_t = self.shape_terms(self.shape).transpose(1, 2).contiguous()
        self.corrected_t = self.delta_t if self.residual_t is None or self.separate_examples else (
            self.delta_t + self.residual_t)
        rest = self.graded + self.delta_t.mean(0).T  # the outfit on this body, at rest (a typical anchor's)
        bn = CollisionResolver.normals(bv, np.asarray(body.faces), self._body_inc)
        # a tree that builds faster (and queries alike) than the balanced, compact default
        _, bound = cKDTree(bv, balanced_tree=False, compact_nodes=False).query(rest.numpy())
        self.bound = torch.from_numpy(bound)
        self.bound_normal = torch.from_numpy(bn[bound]).float()  # rest normal of each cloth vertex's bound body vertex
        bv = torch.from_numpy(bv)
        clearance = ((rest - bv[self.bound]) * self.bound_normal).sum(-1)
        self.clearance = clearance.clamp(0.0, self.cfg.margin)  # d0 = min(h0, epsilon_p)
        return self

    # --- per frame ------------------------------------------------------------------------------
    def distances(self, rotmats: torch.Tensor, examples: bool = False, vec: torch.Tensor | None = None
                  ) -> torch.Tensor:
        """(B, G, A) sensitivity distance of each region of poses (B, 24, 3, 3) to each anchor (to
        each pose example: (B, G, E)); ``vec``: their ``pose_vector`` when known."""
        vec = pose_vector(rotmats) if vec is None else vec
        d = vec[:, None] - (self.example_vec if examples else self.anchor_vec)[None]
        return self.q @ (d ** 2).transpose(1, 2)

    def terms_t(self, pose_model: bool = True) -> torch.Tensor:
        """(A, 3, N) what each anchor adds: its shape term, and its pose-model correction when PBNS is
        the pose model, ``correct_pose`` and the anchors are the pose examples."""
        return self.corrected_t if pose_model and self.correct_pose else self.delta_t

    def terms(self, pose_model: bool = True) -> torch.Tensor:
        """``terms_t`` as (A, N, 3)."""
        return self.terms_t(pose_model).transpose(1, 2)

    def correction(self, weights: torch.Tensor, pose_model: bool = True) -> torch.Tensor:
        """(B, G, A) blend weights -> (B, N, 3) blended rest-pose terms (``terms``)."""
        return self.blend(weights, self.terms_t(pose_model))

    def blend(self, weights: torch.Tensor, terms_t: torch.Tensor) -> torch.Tensor:
        """(B, G, A) blend weights of terms (A, 3, N) -> (B, N, 3): each vertex blends with its
        regions' weights."""
        active = torch.nonzero(weights.sum((0, 1)) > 0)[:, 0]
        # (B, a, N): each active anchor's weight at every vertex, contiguous per anchor
        c = weights[:, :, active].transpose(1, 2) @ self.regions_t
        out = torch.zeros(c.shape[0], 3, c.shape[2], dtype=terms_t.dtype)
        for j, a in enumerate(active.tolist()):  # in place, no gathered copy of the active terms
            out.addcmul_(c[:, j, None], terms_t[a])
        return out.transpose(1, 2)

    @torch.no_grad()
    def pose(self, rotmats: torch.Tensor, transforms: torch.Tensor, body_v: torch.Tensor | None = None,
             pose_model: torch.Tensor | None = None, distance: torch.Tensor | None = None,
             weights: torch.Tensor | None = None, example_distance: torch.Tensor | None = None) -> torch.Tensor:
        """Cloth (B, N, 3) for poses (B, 24, 3, 3) (+Y up) on the body of ``set_shape``:
        ``transforms`` (B, 24, 3, 4) its joint transforms, ``body_v`` (B, V, 3) its posed vertices
        (penetration handling; None: none). ``pose_model`` (B, N, 3): the pose model's rest-pose
        output to use instead of PBNS's (an unposed simulation, for the upper bound). ``distance``
        (B, G, A): the blending's distances (``distances``; damped by ``animate``); ``weights``
        (B, G, A): blend weights to use instead; ``example_distance`` (B, G, E): the distances to
        the pose examples (``distances(rotmats, examples=True)``)."""
        if self.delta_t is None:
            raise RuntimeError("TaylorGarment.set_shape(body, shape) first")
        base = self.pbns.rest + self.pbns.deformation(rotmats) if pose_model is None else pose_model
        examples = pose_model is None and self.correct_pose and self.separate_examples
        vec = pose_vector(rotmats) if (weights is None and distance is None) or (
            examples and example_distance is None) else None  # once for both sets
        if weights is None:
            weights = blend_weights(self.distances(rotmats, vec=vec) if distance is None else distance, self.cfg)
        rest = base + self.shift + self.correction(weights, pose_model is None)
        if examples:
            if example_distance is None:
                example_distance = self.distances(rotmats, examples=True, vec=vec)
            rest = rest + self.blend(blend_weights(example_distance, self.cfg), self.residual_t)
        t = self.pbns.blend(transforms)  # for the skinning and the push-out alike
        x = self.pbns.apply_blend(rest, t)
        return x if body_v is None else self.push_out(x, t, body_v)

    def continued(self, x: torch.Tensor, solver, body_v: torch.Tensor, body_n: torch.Tensor,
                  transforms: torch.Tensor) -> torch.Tensor:
        """Cloth (1, N, 3) on the body of ``set_shape`` (posed: ``body_v``, ``body_n`` (1, V, 3),
        ``transforms`` (1, 24, 3, 4)) continued by ``solver`` (``DrapeSolver.continuation``): its
        rest the graded outfit, the tether's target that outfit skinned."""
        g = self.graded
        return solver(g, x[0], body_v[0], body_n[0], carried=self.pbns.skin(g[None], transforms)[0])[None]

    def push_out(self, x: torch.Tensor, rot: torch.Tensor, body_v: torch.Tensor) -> torch.Tensor:
        """Eq. 10: a cloth vertex closer to its bound body vertex (along that vertex's normal, posed
        by the cloth vertex's blended skinning rotation ``rot`` (B, N, 3, >= 3)) than its rest
        clearance (at most ``cfg.margin``) moves out to it."""
        n = rotate(rot, self.bound_normal)
        n = n / n.norm(dim=-1, keepdim=True).clamp_min(1e-9)
        h = torch.linalg.vecdot(x - body_v.index_select(1, self.bound), n)  # (index_select: a faster gather)
        return x.addcmul((self.clearance - h).clamp_min(0.0)[..., None], n)

    def damped_distances(self, rotmats: torch.Tensor, examples: bool = False) -> torch.Tensor:
        """(T, G, A) distances of a motion (to the pose examples: (T, G, E)), each frame's blended
        with the previous one's (eq. 9)."""
        d = self.distances(rotmats, examples)
        for t in range(1, len(d)):
            d[t] = self.cfg.damping * d[t - 1] + (1.0 - self.cfg.damping) * d[t]
        return d

    @torch.no_grad()
    def animate(self, rotmats: torch.Tensor, transforms: torch.Tensor, body_v: torch.Tensor | None = None
                ) -> torch.Tensor:
        """A motion (T, 24, 3, 3) frame by frame with the distances damped (eq. 9): (T, N, 3)."""
        d = self.damped_distances(rotmats)
        e = self.damped_distances(rotmats, examples=True) if self.separate_examples else None
        return torch.cat([self.pose(rotmats[i:i + 64], transforms[i:i + 64],
                                    None if body_v is None else body_v[i:i + 64], distance=d[i:i + 64],
                                    example_distance=None if e is None else e[i:i + 64])
                          for i in range(0, len(rotmats), 64)])

    @torch.no_grad()
    def sequence_codes(self, rotmats: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The model of a motion as blend shapes on the graded outfit (``graded``; an export's morph
        targets): PBNS's rows of D and, for every (region, anchor) pair the motion blends, that
        anchor's shape term on that region (and each pose example's correction likewise); and their
        weights per frame: (D (E + P, N * 3), codes (T, E + P)). Skinned like PBNS; without the
        penetration handling (not a blend shape)."""
        sets = [(self.damped_distances(rotmats), self.terms_t())]
        if self.correct_pose and self.separate_examples:
            sets.append((self.damped_distances(rotmats, examples=True), self.residual_t))
        rows, codes = [self.pbns.D.detach()], [self.pbns.mlp(pose_features(rotmats))]
        for distance, terms_t in sets:
            w = blend_weights(distance, self.cfg)  # (T, G, A)
            g, a = torch.nonzero(w.amax(0) > 0, as_tuple=True)
            targets = self.regions[:, g].T[:, None] * terms_t[a]  # (P, 3, N)
            rows.append(targets.transpose(1, 2).reshape(len(g), -1))
            codes.append(w[:, g, a])
        return torch.cat(rows), torch.cat(codes, 1)

    @property
    def example_poses(self) -> torch.Tensor:
        """(E, 24, 3, 3) the poses ``pose_residual`` corrects at: the pose examples, else the anchors."""
        return self.pose_examples if self.separate_examples else self.anchors

    @torch.no_grad()
    def example_drapes(self) -> torch.Tensor:
        """(E, N, 3) the unposed drapes at ``example_poses`` on the pose model's body: its cloth there
        plus its correction."""
        return self.pbns.rest + self.pbns.deformation(self.example_poses) + self.pose_residual

    @torch.no_grad()
    def with_pose_model(self, pose_model: PBNS, fitted: bool = False) -> TaylorGarment:
        """The same database on another pose model (e.g. PBNS as trained, for a fitted one): each
        example's correction re-expressed against it, so the model still meets the drapes there."""
        residual = self.pose_residual
        if residual is not None:
            residual = self.example_drapes() - pose_model.rest - pose_model.deformation(self.example_poses)
        return TaylorGarment(pose_model, self.anchors, self.q, self.basis, self.maps, self.shape0, self.cfg, residual,
                             self.correct_pose, self.pose_examples, fitted)

    # --- persistence ----------------------------------------------------------------------------
    def save(self, path: Path, meta_json: str) -> None:
        state = {"anchors": self.anchors, "q": self.q, "basis": self.basis.half(), "maps": self.maps,
                 "shape0": self.shape0, "blend": asdict(self.cfg), "meta_json": meta_json}
        if self.pose_residual is not None:
            state["pose_residual"] = self.pose_residual.half()
        if self.pose_examples is not None:
            state["pose_examples"] = self.pose_examples
        state["correct_pose"] = self.correct_pose
        if self.fitted:
            state["pose_model"] = {"mlp": self.pbns.mlp.state_dict(), "D": self.pbns.D.detach().half()}
        paths.atomic_write(Path(path), lambda t: torch.save(state, t))

    @classmethod
    def load(cls, path: Path, pbns: PBNS) -> tuple[TaylorGarment, dict]:
        """The model of a database file on ``pbns`` (the outfit's PBNS; with a fitted pose model, a copy
        of it with the stored network and blend shapes)."""
        ck = paths.load_checkpoint(path, "recon garment train --model taylor")
        if ck["basis"].shape[2] != pbns.rest.shape[0]:
            raise ValueError(f"{path} was built for another outfit ({ck['basis'].shape[2]} vertices)")
        fitted = "pose_model" in ck
        if fitted:
            pbns = copy.deepcopy(pbns)
            pbns.mlp = mlp_of(ck["pose_model"]["mlp"])  # PBNS's network, maybe widened
            pbns.D.data = ck["pose_model"]["D"].float()
            pbns.requires_grad_(False)
        res = ck.get("pose_residual")
        m = cls(pbns, ck["anchors"], ck["q"], ck["basis"].float(), ck["maps"], ck["shape0"], BlendConfig(**ck["blend"]),
                None if res is None else res.float(), ck.get("correct_pose", True), ck.get("pose_examples"), fitted)
        return m, ck
