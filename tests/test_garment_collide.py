import numpy as np
import pytest
import torch
import trimesh
from scipy.spatial import cKDTree

from recon.body import default_body
from recon.garment.collide import CollisionResolver
from recon.garment.data import pose_set
from recon.garment.dress import Dresser
from recon.garment.mesh import vertex_normals
from recon.garment.metrics import physical_metrics


def _sphere(r):
    s = trimesh.creation.icosphere(subdivisions=3, radius=r)
    return torch.tensor(s.vertices, dtype=torch.float32), np.asarray(s.faces)


def _depth(v, surf, faces):
    """Signed distance along the normal of the nearest surface vertex (the collision metric)."""
    n = vertex_normals(surf[None], torch.as_tensor(faces))[0]
    idx = cKDTree(surf.numpy()).query(v.numpy())[1]
    return ((v - surf[idx]) * n[idx]).sum(-1)


def test_cloth_inside_the_body_is_pushed_out_and_far_cloth_stays():
    body, bf = _sphere(0.10)
    cloth, cf = _sphere(0.105)
    dent = cloth[:, 2] > 0.08  # a patch pressed 1 cm into the body
    cloth[dent] *= 0.09 / 0.105
    res = CollisionResolver(cf, eps=0.002)
    out = res(cloth[None], body[None], bf)[0]
    assert (_depth(cloth, body, bf) < 0).sum() == dent.sum()
    assert (_depth(out, body, bf) >= 0).all()  # nothing left inside
    assert out[dent].norm(dim=-1).min() >= 0.1  # on or outside the body's vertices
    far = cloth[:, 2] < 0.0
    assert torch.equal(out[far], cloth[far])  # the move stays local


def test_outer_layer_is_pushed_out_of_the_inner_one_which_stays_put():
    inner, f = _sphere(0.11)
    outer, _ = _sphere(0.12)
    cloth = torch.cat([inner, outer])
    faces = np.concatenate([f, f + len(inner)])
    layer = np.r_[np.zeros(len(inner)), np.ones(len(outer))].astype(np.int64)
    dent = torch.zeros(len(cloth), dtype=torch.bool)
    dent[len(inner):] = outer[:, 0] > 0.1
    cloth[dent] *= 0.105 / 0.12  # 5 mm inside the inner layer
    body, bf = _sphere(0.05)  # far inside: no body contact
    out = CollisionResolver(faces, layer, eps=0.002)(cloth[None], body[None], bf)[0]
    assert torch.equal(out[: len(inner)], cloth[: len(inner)])
    assert out[dent].norm(dim=-1).min() >= 0.11 - 1e-3


def test_nothing_to_resolve_is_identity_and_batches_are_independent():
    body, bf = _sphere(0.10)
    cloth, cf = _sphere(0.12)
    res = CollisionResolver(cf)
    bad = cloth.clone() * 0.8
    out = res(torch.stack([cloth, bad]), body.expand(2, -1, -1), bf)
    assert torch.equal(out[0], cloth)
    assert out[1].norm(dim=-1).min() == pytest.approx(0.10, abs=0.003)


def test_dresser_resolves_collisions_by_default():
    """The shipped outfit in held-out poses: its collision resolution leaves (almost) no cloth
    inside the body, the network's own output has some; the fix is local (a thigh under a hem
    lifts it by several cm, so the largest moves are not bounded here)."""
    body = default_body()
    rot = pose_set("test", 500, 0.5, seed=123)[:8]
    raw, fixed = Dresser("top-shorts", resolve_collisions=False), Dresser("top-shorts")
    shape = raw.shape.expand(len(rot), -1)
    a = raw(body, rot, shape)
    out = body(rot, shape)
    b = fixed.resolver(torch.from_numpy(a.vertices), out.vertices, body.faces).numpy()  # no rest: no strain step
    bn = vertex_normals(out.vertices, body.faces)
    rest = raw.model.rest
    m_raw = physical_metrics(torch.from_numpy(a.vertices), a.faces, rest, out.vertices, bn)
    m_fix = physical_metrics(torch.from_numpy(b), a.faces, rest, out.vertices, bn)
    assert m_raw["collision_pct"] > 0.2 and m_fix["collision_pct"] < 0.25 * m_raw["collision_pct"]
    assert m_fix["edge_mm"] < m_raw["edge_mm"] + 0.3
    move = np.linalg.norm(b - a.vertices, axis=-1)
    assert move.mean() < 0.003 and (move > 0.01).mean() < 0.05 and (move > 0.03).mean() < 0.01

def _grid(n=12, size=0.2):
    xs = np.linspace(0, size, n)
    x, y = np.meshgrid(xs, xs, indexing="ij")
    v = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], 1).astype(np.float32)
    i = np.arange(n * n).reshape(n, n)
    f = np.concatenate([np.stack([i[:-1, :-1].ravel(), i[1:, :-1].ravel(), i[1:, 1:].ravel()], 1),
                        np.stack([i[:-1, :-1].ravel(), i[1:, 1:].ravel(), i[:-1, 1:].ravel()], 1)])
    return torch.from_numpy(v), f


def _edge_error(v, rest, faces):
    return physical_metrics(v[None], faces, rest, v[None] - 10, torch.zeros(1, len(v), 3))["edge_mm"]


def test_strain_step_restores_edge_lengths_of_a_stretched_sheet():
    rest, f = _grid()
    stretched = rest * torch.tensor([1.1, 1.0, 1.0])  # 10 % along x
    body, bf = _sphere(0.02)
    body = body + torch.tensor([0.1, 0.1, -0.5])  # far below: no contact
    res = CollisionResolver(f)
    out = res(stretched[None], body[None], bf, rest=rest)[0]
    assert _edge_error(out, rest, f) < 0.3 * _edge_error(stretched, rest, f)
    assert torch.equal(res(stretched[None], body[None], bf)[0], stretched)  # no rest: no strain step
    no_strain = CollisionResolver(f, strain_iters=0)(stretched[None], body[None], bf, rest=rest)[0]
    assert torch.equal(no_strain, stretched)


def test_strain_step_keeps_cloth_at_its_rest_lengths_where_it_is():
    rest, f = _grid()
    rot = torch.from_numpy(trimesh.transformations.rotation_matrix(0.7, [1, 2, 3])[:3, :3]).float()
    moved = rest @ rot.T + torch.tensor([0.3, -0.1, 0.2])  # rigid: every edge at its rest length
    body, bf = _sphere(0.02)
    out = CollisionResolver(f)(moved[None], body[None] - 1.0, bf, rest=rest)[0]
    assert torch.allclose(out, moved, atol=1e-5)


def test_strain_step_leaves_no_cloth_inside_the_body():
    body, bf = _sphere(0.10)
    cloth, cf = _sphere(0.105)
    rest = cloth.clone()
    pulled = cloth * torch.where(cloth[:, 2:] > 0.05, 1.15, 1.0)  # the top stretched outwards
    dent = cloth[:, 2] < -0.08
    pulled[dent] *= 0.09 / 0.105  # and a patch pressed into the body
    out = CollisionResolver(cf, eps=0.002)(pulled[None], body[None], bf, rest=rest)[0]
    assert (_depth(out, body, bf) >= 0).all()
    assert _edge_error(out, rest, cf) < 0.5 * _edge_error(pulled, rest, cf)
    assert out.norm(dim=-1).max() < pulled.norm(dim=-1).max()  # the stretch pulled back in


def test_dresser_restores_edge_lengths_by_default():
    """The shipped outfit in held-out poses: the Dresser's default post-step leaves less edge error
    than the network's output and than collision resolution alone, and as few collisions."""
    body = default_body()
    rot = pose_set("test", 500, 0.5, seed=123)[:4]
    raw, dresser = Dresser("top-shorts", resolve_collisions=False), Dresser("top-shorts")
    shape = raw.shape.expand(len(rot), -1)
    out = body(rot, shape)
    bn = vertex_normals(out.vertices, body.faces)
    pv = torch.from_numpy(raw(body, rot, shape).vertices)
    rest = dresser.rest_for(body, shape[0])  # the outfit resized to the body: the lengths it restores
    collide_only = dresser.resolver(pv, out.vertices, body.faces)  # no rest: no strain step
    post = torch.from_numpy(dresser(body, rot, shape).vertices)
    m = {k: physical_metrics(v, raw.model.faces.numpy(), rest, out.vertices, bn)
         for k, v in (("raw", pv), ("collide", collide_only), ("post", post))}
    assert m["post"]["edge_mm"] < 0.9 * min(m["raw"]["edge_mm"], m["collide"]["edge_mm"])
    assert m["post"]["collision_pct"] < 0.25 * m["raw"]["collision_pct"]
