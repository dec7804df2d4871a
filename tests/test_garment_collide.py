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
    """The shipped outfit in held-out poses: the Dresser's output has (almost) no cloth inside the
    body, the network's own output has some; the fix is local (a thigh under a hem lifts it by
    several cm, so the largest moves are not bounded here)."""
    body = default_body()
    rot = pose_set("test", 500, 0.5, seed=123)[:8]
    raw, fixed = Dresser("top-shorts", resolve_collisions=False), Dresser("top-shorts")
    shape = raw.shape.expand(len(rot), -1)
    a, b = raw(body, rot, shape), fixed(body, rot, shape)
    out = body(rot, shape)
    bn = vertex_normals(out.vertices, body.faces)
    rest = raw.model.rest
    m_raw = physical_metrics(torch.from_numpy(a.vertices), a.faces, rest, out.vertices, bn)
    m_fix = physical_metrics(torch.from_numpy(b.vertices), b.faces, rest, out.vertices, bn)
    assert m_raw["collision_pct"] > 0.2 and m_fix["collision_pct"] < 0.25 * m_raw["collision_pct"]
    assert m_fix["edge_mm"] < m_raw["edge_mm"] + 0.3
    move = np.linalg.norm(b.vertices - a.vertices, axis=-1)
    assert move.mean() < 0.003 and (move > 0.01).mean() < 0.05 and (move > 0.03).mean() < 0.01
