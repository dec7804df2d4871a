"""The SMPL-family file loader, on small synthetic models the tests create (never real SMPL)."""
import pickle
import sys
import types

import numpy as np
import pytest
import scipy.sparse
import torch

import recon.body
from recon.body import skeleton
from recon.errors import ReconError

CUBE = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float64)
CUBE_FACES = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                       [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])


def synthetic_model(seed=0, n_betas=10):
    """A cube around each joint of a plausible 24-joint rest skeleton (T-pose-like), with random
    shape/pose blend shapes and weights blended between each joint and its parent."""
    rng = np.random.default_rng(seed)
    joints = np.array([
        [0, 0.9, 0], [0.1, 0.82, 0], [-0.1, 0.82, 0], [0, 1.0, -0.02], [0.11, 0.45, 0], [-0.11, 0.45, 0],
        [0, 1.12, 0], [0.11, 0.08, -0.02], [-0.11, 0.08, -0.02], [0, 1.2, 0], [0.12, 0.02, 0.1], [-0.12, 0.02, 0.1],
        [0, 1.45, 0], [0.08, 1.38, 0], [-0.08, 1.38, 0], [0, 1.55, 0.03], [0.18, 1.4, 0], [-0.18, 1.4, 0],
        [0.45, 1.4, 0], [-0.45, 1.4, 0], [0.7, 1.4, 0], [-0.7, 1.4, 0], [0.78, 1.4, 0], [-0.78, 1.4, 0]])
    verts = (joints[:, None] + 0.03 * CUBE[None]).reshape(-1, 3)
    faces = (np.arange(24)[:, None, None] * 8 + CUBE_FACES[None]).reshape(-1, 3)
    owner = np.repeat(np.arange(24), 8)
    weights = np.zeros((len(verts), 24))
    weights[np.arange(len(verts)), owner] = 0.7
    par = np.array(skeleton.JOINT_PARENTS)
    weights[np.arange(len(verts)), np.maximum(par[owner], 0)] += 0.3
    jreg = np.zeros((24, len(verts)))
    jreg[owner, np.arange(len(verts))] = 1.0 / 8
    kintree = np.stack([np.where(par < 0, 2**32 - 1, par), np.arange(24)]).astype(np.int64)
    return dict(v_template=verts, shapedirs=0.01 * rng.normal(size=(len(verts), 3, n_betas)),
                posedirs=0.005 * rng.normal(size=(len(verts), 3, 207)), J_regressor=jreg,
                weights=weights, kintree_table=kintree, f=faces)


def rodrigues(r):
    th = np.linalg.norm(r)
    if th < 1e-12:
        return np.eye(3)
    k = r / th
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(th) * kx + (1 - np.cos(th)) * kx @ kx


def smpl_reference(m, betas, pose):
    """Plain numpy SMPL (Loper et al. 2015), written independently of recon.body.lbs."""
    v = m["v_template"] + m["shapedirs"] @ betas
    j = m["J_regressor"] @ v
    rots = [rodrigues(p) for p in pose]
    feat = np.concatenate([(r - np.eye(3)).ravel() for r in rots[1:]])
    v = v + (m["posedirs"].reshape(-1, 207) @ feat).reshape(-1, 3)
    world = []
    for k in range(24):
        local = np.eye(4)
        local[:3, :3] = rots[k]
        p = skeleton.JOINT_PARENTS[k]
        local[:3, 3] = j[k] - (j[p] if p >= 0 else 0)
        world.append(local if p < 0 else world[p] @ local)
    posed_j = np.array([w[:3, 3] for w in world])
    skin = []
    for k in range(24):
        a = world[k].copy()
        a[:3, 3] -= a[:3, :3] @ j[k]
        skin.append(a)
    t = np.einsum("vk,kij->vij", m["weights"], np.array(skin))
    out = np.einsum("vij,vj->vi", t[:, :3, :3], v) + t[:, :3, 3]
    return out - posed_j[0], posed_j - posed_j[0]


@pytest.fixture
def model_file(tmp_path):
    m = synthetic_model()
    path = tmp_path / "toy_smpl.npz"
    np.savez(path, **m)
    return m, path


def test_matches_reference_smpl(model_file):
    m, path = model_file
    body = recon.body.create(path)
    assert body.num_shape_params == 10 and body.num_vertices == 24 * 8
    rng = np.random.default_rng(1)
    for _ in range(3):
        betas, pose = rng.normal(size=10), 0.5 * rng.normal(size=(24, 3))
        ref_v, ref_j = smpl_reference(m, betas, pose)
        out = body(torch.tensor(pose[None], dtype=torch.float32), torch.tensor(betas[None], dtype=torch.float32))
        np.testing.assert_allclose(out.vertices[0].numpy(), ref_v, atol=2e-5)
        np.testing.assert_allclose(out.joints[0].numpy(), ref_j, atol=2e-5)
    assert out.landmarks.shape == (1, 18, 3)


def test_pickle_with_chumpy_and_sparse_regressor(tmp_path):
    m = synthetic_model(seed=3)
    # Recreate what an SMPL .pkl looks like: chumpy arrays and a scipy CSC regressor,
    # pickled from a stand-in "chumpy.ch" module that is gone when we load.
    mod = types.ModuleType("chumpy.ch")

    class Ch:
        def __init__(self, x):
            self.x = x

        def __getstate__(self):
            return {"x": self.x}

    Ch.__module__, Ch.__qualname__ = "chumpy.ch", "Ch"
    mod.Ch = Ch
    sys.modules["chumpy"], sys.modules["chumpy.ch"] = types.ModuleType("chumpy"), mod
    try:
        data = dict(m, shapedirs=Ch(m["shapedirs"]), v_template=Ch(m["v_template"]),
                    J_regressor=scipy.sparse.csc_matrix(m["J_regressor"]))
        path = tmp_path / "toy.pkl"
        path.write_bytes(pickle.dumps(data, protocol=2))
    finally:
        del sys.modules["chumpy"], sys.modules["chumpy.ch"]
    body = recon.body.create(path)
    ref_v, _ = smpl_reference(m, np.zeros(10), np.zeros((24, 3)))
    np.testing.assert_allclose(body().vertices[0].numpy(), ref_v, atol=1e-5)


def test_bad_files_give_clear_errors(tmp_path, model_file):
    m, _ = model_file
    p = tmp_path / "nokeys.npz"
    np.savez(p, **{k: v for k, v in m.items() if k != "weights"})
    with pytest.raises(ReconError, match="lacks \\['weights'\\]"):
        recon.body.create(p)
    bad = dict(m, kintree_table=np.stack([np.r_[2**32 - 1, np.zeros(23)], np.arange(24)]).astype(np.int64))
    p = tmp_path / "tree.npz"
    np.savez(p, **bad)
    with pytest.raises(ReconError, match="not SMPL's 24-joint tree"):
        recon.body.create(p)
    with pytest.raises(ReconError, match="unknown body model"):
        recon.body.create(tmp_path / "model.fbx")
    with pytest.raises(FileNotFoundError):
        recon.body.create(tmp_path / "missing.npz")

    class Evil:
        def __reduce__(self):
            import os

            return (os.system, ("echo pwned",))

    p = tmp_path / "evil.pkl"
    p.write_bytes(pickle.dumps({"v_template": Evil()}))
    with pytest.raises(pickle.UnpicklingError, match="refusing"):
        recon.body.create(p)
