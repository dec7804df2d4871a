import json

import numpy as np
import pytest
import roma
import torch
import trimesh
from gltf_check import assert_valid, pose_meshes, read_glb
from scipy.spatial import cKDTree

import recon.garment.pbns.model as P
from recon.errors import ReconError
from recon.export.glb import influence_sets, write_glb
from recon.garment import family, losses, mesh, store
from recon.garment.data import pose_set, posed_bodies
from recon.garment.dress import Dresser
from recon.garment.metrics import collision_pct, penetration, physical_metrics
from recon.garment.morph import outfit_animation
from recon.garment.pbns import reference_eval as R
from recon.garment.pbns import train as T
from recon.garment.pbns.garment_model import PBNSGarment
from recon.garment.pbns.model import (
    PBNS,
    PBNSConfig,
    initial_weights,
    mlp_of,
    pose_features,
    pose_mlp,
    remove_yaw,
    widened,
)
from recon.garment.templates import PRESETS, GarmentSpec, RestBody, hangs_free, make_outfit


def _grid(n=6):
    x, y = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    v = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], 1)
    i = np.arange(n * n).reshape(n, n)
    a, b, c, d = i[:-1, :-1].ravel(), i[:-1, 1:].ravel(), i[1:, :-1].ravel(), i[1:, 1:].ravel()
    return v, np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])


def test_cut_is_exact_and_connected():
    v, f = _grid()
    cv, cf = mesh.cut(v, f, v[:, 0] - 0.55)
    assert cv[:, 0].min() == pytest.approx(0.55)  # new boundary exactly on the level set
    loops = mesh.boundary_loops(cf)
    assert len(loops) == 1  # one connected open sheet
    e = mesh.unique_edges(cf)
    tri_count = np.zeros(len(e))  # manifold: every edge in 1 or 2 faces
    key = {tuple(x): k for k, x in enumerate(e)}
    for t in cf:
        for a, b in ((0, 1), (1, 2), (2, 0)):
            tri_count[key[tuple(sorted((t[a], t[b])))]] += 1
    assert set(np.unique(tri_count)) <= {1, 2}


@pytest.mark.parametrize("batch", [1, 3])
def test_take_is_advanced_indexing_with_its_gradient(batch):
    """``mesh.take(v, idx)`` equals ``v[:, idx]`` (B, *idx.shape, C) in value and gradient, for a
    single sample (its 2-D path) and a batch; float64, so the gradients agree to rounding."""
    g = torch.Generator().manual_seed(0)
    v = torch.randn(batch, 7, 3, generator=g, dtype=torch.float64, requires_grad=True)
    idx = torch.randint(0, 7, (5, 2), generator=g)
    out = mesh.take(v, idx)
    assert out.shape == (batch, 5, 2, 3) and torch.equal(out, v[:, idx])
    w = torch.randn(out.shape, generator=g, dtype=torch.float64)
    got, = torch.autograd.grad((out * w).sum(), v)
    want, = torch.autograd.grad((v[:, idx] * w).sum(), v)
    assert torch.allclose(got, want, atol=1e-12)


def test_remove_yaw_keeps_tilt():

    tilt = roma.rotvec_to_rotmat(torch.tensor([0.3, 0.0, 0.0]))
    yaw = roma.rotvec_to_rotmat(torch.tensor([0.0, 1.1, 0.0]))
    r = remove_yaw((yaw @ tilt)[None])[0]
    assert torch.allclose(r, tilt, atol=1e-5)
    # heading does not change the network input; tilt does
    rot = torch.eye(3).expand(1, 24, 3, 3).clone()
    a = rot.clone()
    a[0, 0] = yaw
    assert torch.allclose(pose_features(a), pose_features(rot), atol=1e-6)
    a[0, 0] = tilt
    assert not torch.allclose(pose_features(a), pose_features(rot), atol=1e-3)


def test_pbns_identity_and_gradients():
    v, f = _grid(4)
    w = torch.zeros(len(v), 24)
    w[:, 0] = 1
    m = PBNS(torch.tensor(v), torch.tensor(f), w, PBNSConfig(optimise_weights=True))
    rot = torch.eye(3).expand(2, 24, 3, 3).clone()
    t = torch.cat([torch.eye(3), torch.tensor([[0.0], [1.0], [0.0]])], 1).expand(2, 24, 3, 4)
    out, dt = m(rot, t)
    assert out.shape == (2, len(v), 3) and torch.allclose(dt, torch.zeros_like(dt))  # D starts at 0
    assert torch.allclose(out, torch.tensor(v).float() + torch.tensor([0.0, 1.0, 0.0]), atol=1e-6)
    (out[..., 1].sum() + dt.pow(2).sum()).backward()
    assert m.D.grad is not None and m.weight_logits.grad is not None


def test_apply_blend_is_the_per_vertex_affine_map_and_differentiable():
    """x -> R x + t per vertex (the convention: t (B, N, 3, 4) = [R | t]), for one rest outfit or
    one per frame; float64 gradients by finite differences."""
    g = torch.Generator().manual_seed(0)
    t = torch.randn(2, 5, 3, 4, generator=g, dtype=torch.float64)
    x = torch.randn(5, 3, generator=g, dtype=torch.float64)
    want = (t[..., :3] @ x[None, :, :, None])[..., 0] + t[..., 3]
    assert torch.allclose(P.BlendShapeGarment.apply_blend(x, t), want)
    xb = torch.randn(2, 5, 3, generator=g, dtype=torch.float64)
    assert torch.allclose(P.BlendShapeGarment.apply_blend(xb, t), (t[..., :3] @ xb[..., None])[..., 0] + t[..., 3])
    assert torch.allclose(P.rotate(t, xb), (t[..., :3] @ xb[..., None])[..., 0])
    assert torch.autograd.gradcheck(P.BlendShapeGarment.apply_blend, (xb.requires_grad_(), t.requires_grad_()))


def test_a_widened_network_computes_the_same_and_its_new_units_learn():
    torch.manual_seed(0)
    mlp = pose_mlp(8, 4, 16)
    x = torch.randn(5, 216, dtype=torch.float64)
    wide = widened(mlp.double(), 20)
    assert [m.out_features for m in wide if isinstance(m, torch.nn.Linear)] == [20, 20, 20, 16]
    assert torch.allclose(wide(x), mlp(x), atol=1e-12)
    wide(x).sum().backward()
    assert wide[2].weight.grad[:, 8:].abs().sum() > 0 or wide[6].weight.grad[:, 8:].abs().sum() > 0
    back = mlp_of(wide.state_dict())
    assert torch.equal(back.double()(x), wide(x).detach())
    with pytest.raises(ValueError, match="fewer"):
        widened(mlp, 4)


def test_pbns_weight_cache_follows_changes():
    v, f = _grid(4)
    w = torch.full((len(v), 24), 1 / 24)
    m = PBNS(torch.tensor(v), torch.tensor(f), w, PBNSConfig(optimise_weights=True))
    with torch.no_grad():
        w0 = m.weights
        assert m.weights is w0  # cached outside autograd
        m.weight_logits[0, 3] += 5.0  # an optimiser step / load_state_dict changes it in place
        assert m.weights[0, 3] > 0.5 and torch.allclose(m.weights.sum(-1), torch.ones(len(v)))
    assert m.weights.requires_grad  # training still differentiates through the softmax


def test_inference_form_follows_device_and_batch():
    """Vertex-major on the CPU from VERTEX_MAJOR_MIN_BATCH frames; batch-major on any other device
    (a GPU is fastest batch-major at every batch: eval/results/bench-garment-gpu-h200.md)."""
    n = P.VERTEX_MAJOR_MIN_BATCH
    assert not P.vertex_major(torch.zeros(n - 1, 8)) and P.vertex_major(torch.zeros(n, 8))
    assert not P.vertex_major(torch.zeros(4096, 8, device="meta"))


@pytest.mark.parametrize("batch", [1, 12, 20])
def test_pbns_pose_equals_forward(batch, monkeypatch):
    """The inference path (vertex-major, in chunks of vertices from 12 frames on) gives the
    differentiable forward's vertices, also for per-sample rest outfits and after D changes."""

    monkeypatch.setattr(P, "VERTEX_MAJOR_CHUNK_FLOATS", 12 * batch * 7)  # chunks of 16 vertices: several
    g = torch.Generator().manual_seed(0)
    v, f = _grid(7)
    m = PBNS(torch.tensor(v), torch.tensor(f), torch.rand(len(v), 24, generator=g), PBNSConfig())
    with torch.no_grad():
        m.D.normal_(0, 0.01, generator=g)
        for p in m.mlp.parameters():
            p.normal_(0, 0.3, generator=g)

    rot = roma.rotvec_to_rotmat(torch.randn(batch, 24, 3, generator=g) * 0.5)
    t = torch.cat([roma.rotvec_to_rotmat(torch.randn(batch, 24, 3, generator=g)),
                   torch.randn(batch, 24, 3, 1, generator=g)], -1)
    ref, dt = m(rot, t)
    assert torch.allclose(m.pose(rot, t), ref, atol=1e-5)
    rest = m.rest + 0.01 * torch.randn(batch, len(v), 3, generator=g)  # resized per body
    assert torch.allclose(m.pose(rot, t, rest), m.skin(rest + dt, t), atol=1e-5)
    with torch.no_grad():
        m.D.mul_(2.0)  # an optimiser step / load: the cached layout must follow
    assert torch.allclose(m.pose(rot, t), m(rot, t)[0], atol=1e-5)
    assert not m.pose(rot, t).requires_grad


def test_energies():
    v, f = _grid(5)
    rest = torch.tensor(v).float()
    edge = losses.EdgeLoss(rest, f)
    assert float(edge(rest[None])) == pytest.approx(0.0, abs=1e-12)
    assert float(edge(rest[None] * 1.1)) > 0
    bend = losses.BendLoss(f)
    assert float(bend.energy(rest[None])) == pytest.approx(0.0, abs=1e-10)  # flat sheet
    folded = rest.clone()
    folded[:, 2] = (folded[:, 0] - 0.5).abs()
    assert float(bend.energy(folded[None])) > 0
    # collision: body = the sheet itself with +Z normals; a cloth point below it penetrates
    body_v, body_n = rest[None], torch.tensor([0.0, 0.0, 1.0]).expand(1, len(v), 3)
    cloth = torch.tensor([[[0.5, 0.5, -0.01], [0.5, 0.5, 0.02]]])

    pen = penetration(cloth, body_v, body_n, losses.nearest(body_v, cloth), 0.004)
    assert pen[0, 0] == pytest.approx(-0.014, abs=1e-6) and pen[0, 1] == 0
    cand = losses.nearest(body_v, cloth, k=4)
    assert torch.equal(losses.nearest_among(body_v, cloth, cand), losses.nearest(body_v, cloth))


def test_stiffness_continuation_scales_only_the_edge_energy():

    v, f = _grid(5)
    rest = torch.tensor(v).float()
    edge = losses.EdgeLoss(rest, f)
    full = float(edge(rest[None] * 1.1))
    edge.scale = T.edge_scale(0.1, 0, 100)
    assert float(edge(rest[None] * 1.1)) == pytest.approx(0.1 * full)
    assert T.edge_scale(0.1, 25, 100) == pytest.approx(0.1 ** 0.5)  # geometric rise...
    assert T.edge_scale(0.1, 50, 100) == T.edge_scale(0.1, 99, 100) == 1.0  # ...to full by mid-training
    assert T.edge_scale(1.0, 0, 100) == 1.0


@pytest.fixture(scope="module")
def outfits(body):

    return {name: make_outfit(body, name) for name in PRESETS}


def test_templates_are_clean(body, outfits):

    rb = RestBody(body)
    expected_loops = {"tshirt": 4, "top": 2, "trousers": 3, "shorts": 3, "skirt": 2, "dress": 4, "jumpsuit": 5}
    for name, o in outfits.items():
        for g in o.garments:
            assert len(mesh.boundary_loops(g.faces)) == expected_loops[g.name], (name, g.name)
            el = np.linalg.norm(np.diff(g.vertices[mesh.unique_edges(g.faces)], axis=1)[:, 0], axis=1)
            assert 0.007 < np.median(el) < 0.017, (name, g.name, np.median(el))  # ~1 cm cloth
            # outside the rest body: in front of the nearest body vertex's tangent plane

            _, idx = cKDTree(rb.v).query(g.vertices)
            d = np.einsum("ij,ij->i", g.vertices - rb.v[idx], rb.n[idx])
            assert (d > 0).mean() > 0.995, (name, g.name)
        lower = [g for g in o.garments if g.name in ("trousers", "shorts", "skirt")]
        assert all(g.pinned.any() for g in lower)


def test_outfit_layers_do_not_interpenetrate(outfits):
    o = outfits["tshirt-trousers"]
    inner, outer = o.garments
    n = mesh.vertex_normals(torch.from_numpy(inner.vertices)[None], torch.from_numpy(inner.faces))[0].numpy()

    dist, idx = cKDTree(inner.vertices).query(outer.vertices)
    near = dist < 0.02
    d = np.einsum("ij,ij->i", outer.vertices[near] - inner.vertices[idx[near]], n[idx[near]])
    assert (d > 0).mean() > 0.99


def test_animated_glb_reproduces_body_and_cloth(body, tmp_path):
    """Evaluate the written glTF by hand (node hierarchy, skin, morph targets) at one frame and
    compare with the body model and the dresser: the file means what we think it means."""


    torch.manual_seed(0)
    outfit = make_outfit(body, [GarmentSpec("top", "top", sleeve=0.0)])
    w = initial_weights(RestBody(body), outfit)
    model = PBNS(torch.from_numpy(outfit.vertices), torch.from_numpy(outfit.faces), torch.from_numpy(w), PBNSConfig())
    with torch.no_grad():
        model.D.normal_(0, 1e-3)
    path = tmp_path / "m.pt"

    model.save(path, {"meta_json": json.dumps({"garments": ["top"]}), "layer": torch.zeros(len(w)),
                      "garment_id": torch.zeros(len(w), dtype=torch.long), "shape": body.mean_shape})
    dresser = Dresser(path=path)
    rot = roma.rotvec_to_rotmat(0.3 * torch.randn(3, 24, 3))
    transl = torch.tensor([[0.0, 0.9, 0.0], [0.1, 0.9, 0.2], [0.2, 1.0, 0.4]])
    glb = write_glb(tmp_path / "a.glb", body, body.mean_shape, rot, transl, 30.0,
                    outfit_animation(body, body.mean_shape, rot, transl, dresser, 30.0, influences=None),
                    influences=None)

    assert len(trimesh.load(glb).geometry) == 2
    assert_valid(glb)
    frame = 2
    posed = pose_meshes(glb, frame)
    with torch.no_grad():
        ref = body(rot[frame:frame + 1], body.mean_shape[None], transl=transl[frame:frame + 1]).vertices[0].numpy()
    assert np.abs(posed["body"] - ref).max() < 1e-4  # every influence: anny's skinning exactly
    # a motion's cloth is the network's (the Dresser's post-step is no blend shape)
    raw = Dresser(path=path, resolve_collisions=False)
    cloth = raw(body, rot[frame:frame + 1], body.mean_shape, transl[frame:frame + 1]).vertices[0]
    assert np.abs(posed["outfit"] - cloth).mean() < 2e-4
    still = pose_meshes(glb)  # the nodes' own values hold the first frame
    with torch.no_grad():
        first = body(rot[:1], body.mean_shape[None], transl=transl[:1]).vertices[0].numpy()
    assert np.abs(still["body"] - first).max() < 1e-4
    # the default: each vertex's 4 strongest influences (one set, what engines read), a few mm off at most
    four = write_glb(tmp_path / "b.glb", body, body.mean_shape, rot, transl, 30.0,
                     outfit_animation(body, body.mean_shape, rot, transl, dresser, 30.0))
    assert_valid(four)
    for m in read_glb(four)[0]["meshes"]:
        assert {k for k in m["primitives"][0]["attributes"] if k.startswith(("JOINTS", "WEIGHTS"))} == {"JOINTS_0",
                                                                                                  "WEIGHTS_0"}
    off = np.linalg.norm(pose_meshes(four, frame)["body"] - ref, axis=1)
    assert off.mean() < 1e-3 and off.max() < 0.03  # eval/results/glb-influences.md: 16 mm at most over 300 poses
    assert (off < 1e-4).mean() > 0.9  # a vertex with 4 influences or fewer lands exactly


def test_a_family_registered_at_run_time_dresses_through_the_dresser(body, monkeypatch):
    class Halved(PBNSGarment):  # a family of one's own: PBNS with its pose deformations halved
        name = "halved"

        def dress(self, body, out, rotmats, shape, tightness, post):
            rest = torch.stack([self.rest_for(body, s, tightness=tightness) for s in shape])
            full = self.model.pose(rotmats, out.transforms, rest)
            skinned = self.model.skin(rest, out.transforms)
            return skinned + 0.5 * (full - skinned)

    monkeypatch.setitem(family._RUNTIME, "halved", Halved)
    assert family.family_names()[-1] == "halved" and family.family("halved") is Halved
    torch.manual_seed(3)
    rot = roma.rotvec_to_rotmat(0.3 * torch.randn(1, 24, 3))
    args = (body, rot, body.mean_shape, torch.zeros(1, 3))
    pbns = Dresser("tshirt-trousers", resolve_collisions=False)(*args).vertices
    mine = Dresser("tshirt-trousers", resolve_collisions=False, dynamics=False, garment_model="halved")
    assert mine.garment_model == "halved" and mine.garment.label == "PBNS"
    half = mine(*args).vertices
    with torch.no_grad():
        skinned = mine.model.skin(mine.rest_for(body, body.mean_shape)[None],
                                  body(rot, body.mean_shape[None]).transforms)[0].numpy()
    assert np.allclose(half[0], skinned + 0.5 * (pbns[0] - skinned), atol=1e-5)
    assert np.abs(half[0] - pbns[0]).max() > 1e-3  # the deformations do matter
    with pytest.raises(ReconError, match="unknown garment model 'nope'.*pbns"):
        Dresser("tshirt-trousers", garment_model="nope")
    with pytest.raises(ReconError, match="quasi-static"):
        Dresser("tshirt-trousers", garment_model="taylor", dynamics=True)


def test_influence_sets_keep_the_strongest_and_sum_to_one():
    rng = np.random.default_rng(0)
    w = rng.random((50, 24)) * (rng.random((50, 24)) < 0.3)
    w[0] = 0.0
    w[0, 5] = 1.0  # one influence only
    w /= w.sum(1, keepdims=True)
    (j, v), = influence_sets(w)  # default: 4
    assert j.dtype == np.uint16 and v.dtype == np.float32 and j.shape == v.shape == (50, 4)
    assert np.allclose(v.sum(1), 1.0, atol=1e-6)
    for n in range(50):
        strongest = np.sort(w[n])[::-1][:4]
        kept = v[n] * w[n, j[n]].sum() * (v[n] > 0)
        assert np.allclose(np.sort(w[n, j[n]] * (v[n] > 0))[::-1], strongest * (strongest > 1e-6))
        assert np.allclose(kept[v[n] > 0], w[n, j[n]][v[n] > 0])  # renormalised only
    assert j[0].tolist() == [5, 0, 0, 0] and v[0].tolist() == [1.0, 0.0, 0.0, 0.0]
    every = influence_sets(w, None)
    assert len(every) == int(np.ceil((w > 1e-6).sum(1).max() / 4))
    dense = np.zeros_like(w)
    for jj, vv in every:
        np.add.at(dense, (np.arange(50)[:, None].repeat(4, 1), jj.astype(int)), vv)
    assert np.allclose(dense, w, atol=1e-6)  # all of them: the weights as they were
    six = influence_sets(w, 6)
    assert len(six) == 2 and (six[1][1][:, 2:] == 0).all()


def test_a_photos_glb_holds_the_dressers_post_step(body, tmp_path):
    """One frame (a photo): the Dresser's post-step is one more morph target at weight 1, so the
    file's cloth is the Dresser's, not the network's."""
    dresser = Dresser("top-shorts")
    rot = pose_set("test", 500, 0.5, seed=123)[3:4]
    transl = torch.tensor([[0.1, 0.9, -0.2]])
    glb = write_glb(tmp_path / "p.glb", body, dresser.shape, rot, transl, 30.0,
                    outfit_animation(body, dresser.shape, rot, transl, dresser, 30.0))
    assert_valid(glb)
    posed = pose_meshes(glb)["outfit"]
    want = dresser(body, rot, dresser.shape, transl).vertices[0]
    raw = Dresser("top-shorts", resolve_collisions=False)(body, rot, dresser.shape, transl).vertices[0]
    assert np.abs(raw - want).mean() > 1e-3  # the post-step moved the cloth
    assert np.abs(posed - want).mean() < 1e-4


def test_user_obj_garment(body, outfits, tmp_path):


    g = outfits["top-shorts"].garments[1]
    trimesh.Trimesh(g.vertices, g.faces).export(tmp_path / "top.obj")
    o = make_outfit(body, [GarmentSpec("obj", "mine", path=str(tmp_path / "top.obj"))])
    assert len(o.garments[0].faces) == len(g.faces)
    far = trimesh.Trimesh(g.vertices + 5.0, g.faces)
    far.export(tmp_path / "far.obj")
    with pytest.raises(ReconError, match="not around the rest body"):
        make_outfit(body, [GarmentSpec("obj", "far", path=str(tmp_path / "far.obj"))])


def test_skirt_like_garments_and_waist_pins_are_found_from_the_geometry(body, outfits, tmp_path):
    """hangs_free (more blend-weight smoothing) picks the skirt and the dress among the presets;
    a user mesh is pinned at the waist when it is a lower garment."""


    rb = RestBody(body)
    free = {(name, g.name) for name, o in outfits.items() for g in o.garments if hangs_free(rb, g)}
    assert free == {("tshirt-skirt", "skirt"), ("dress", "dress")}
    shorts, top = outfits["top-shorts"].garments
    for g in (shorts, top):
        trimesh.Trimesh(g.vertices, g.faces).export(tmp_path / f"{g.name}.obj")
    mine = make_outfit(body, [GarmentSpec("obj", "s", path=str(tmp_path / "shorts.obj")),
                              GarmentSpec("obj", "t", path=str(tmp_path / "top.obj"), layer=1)])
    assert mine.garments[0].pinned.sum() > 100 and not mine.garments[1].pinned.any()


@pytest.mark.slow
def test_train_and_dress_your_own_garment_mesh(body, outfits, tmp_path, monkeypatch):
    """`recon garment train --outfit my_shorts.obj`, then `Dresser("my_shorts")`: a tiny run."""


    shorts = outfits["top-shorts"].garments[0]
    mesh_file = tmp_path / "my_shorts.obj"
    trimesh.Trimesh(shorts.vertices, shorts.faces).export(mesh_file)
    monkeypatch.setattr(store, "user_dir", lambda: tmp_path / "garments")
    cfg = T.GarmentTrainConfig(outfit=str(mesh_file), poses=24, epochs=1, batch=8)
    meta = T.train(body, cfg, log=lambda *_: None, progress=False)
    assert meta["outfit"] == "my_shorts" and meta["garments"] == ["my_shorts"]
    own = tmp_path / "garments" / "pbns_my_shorts.pt"
    assert store.pbns_path(str(mesh_file)) == store.pbns_path("my_shorts") == own
    assert store.trained_outfits()[-1] == "my_shorts"
    assert not list((tmp_path / "garments").glob(".*.run"))  # the resumable state goes once the weights are written
    assert (tmp_path / "garments" / "pbns_my_shorts.pt").exists()
    d = Dresser("my_shorts")
    rot = torch.eye(3).expand(2, 24, 3, 3).clone()
    v = d(body, rot, body.mean_shape[None].expand(2, -1)).vertices
    assert v.shape == (2, len(shorts.vertices), 3) and np.isfinite(v).all()
    with pytest.raises(ReconError, match="or a garment mesh"):
        T.build(body, T.GarmentTrainConfig(outfit="no-such-outfit"))
    logs = []  # valid poses only (thesis 5.4.3): fewer training poses, or a clear error when none is left
    T.train(body, T.GarmentTrainConfig(outfit=str(mesh_file), poses=96, epochs=1, batch=4, valid_max_self=1.0),
            out=tmp_path / "v.pt", log=logs.append, progress=False)
    n_train = int(logs[0].split(";")[1].split()[0])
    assert 4 <= n_train < 0.85 * 96 / 2  # about an eighth of the poses are valid
    with pytest.raises(ReconError, match="body self-intersection"):
        T.train(body, T.GarmentTrainConfig(outfit=str(mesh_file), poses=24, batch=8, valid_max_self=-1.0),
                out=tmp_path / "w.pt")


def test_physical_metrics_count_inside_vertices():

    v, f = _grid(5)
    rest = torch.tensor(v).float()
    body_v, body_n = rest[None], torch.tensor([0.0, 0.0, 1.0]).expand(1, len(v), 3)
    cloth = rest[None] + torch.tensor([0.0, 0.0, 0.01])
    m = physical_metrics(cloth, f, rest, body_v, body_n)
    assert m["collision_pct"] == 0 and m["edge_mm"] == pytest.approx(0, abs=1e-4)
    cloth[0, :5, 2] = -0.01  # five of 25 vertices behind the body surface
    m = physical_metrics(cloth, f, rest, body_v, body_n)
    assert m["collision_pct"] == pytest.approx(20.0) and m["edge_mm"] > 0


def test_collision_pct_takes_the_first_of_k_nearest_as_the_nearest():
    """The training terms reuse their loss's k nearest body vertices (sorted, the first the nearest)
    for the % inside: the same count as the exact search, and the indices given are the ones used."""
    g = torch.Generator().manual_seed(0)
    body_v = torch.rand(2, 200, 3, generator=g)
    body_n = torch.nn.functional.normalize(torch.randn(2, 200, 3, generator=g), dim=-1)
    cloth = torch.rand(2, 300, 3, generator=g)
    exact = collision_pct(cloth, body_v, body_n)
    assert 5 < float(exact.mean()) < 95
    assert torch.equal(collision_pct(cloth, body_v, body_n, mesh.nearest(body_v, cloth, 8)[..., 0]), exact)
    far = mesh.nearest(body_v, cloth, 8)[..., -1]  # the 8th nearest: another normal, another count
    assert not torch.equal(collision_pct(cloth, body_v, body_n, far), exact)


def test_diffused_blend_weights_stretch_the_skinned_cloth_less(body, outfits):
    """Nearest-vertex weights jump between bones across the crotch; the shipped diffusion must
    cut the skinned (dT = 0) shorts' edge error on a wide-legged, bent-forward pose."""


    o = outfits["top-shorts"]
    rb = RestBody(body)
    rv = torch.zeros(1, 24, 3)
    rv[0, 1] = torch.tensor([-1.0, 0.0, 0.5])  # left hip: flexed and abducted
    rv[0, 2] = torch.tensor([0.3, 0.0, -0.5])  # right hip: extended and abducted
    rv[0, 3] = torch.tensor([0.4, 0.0, 0.0])  # spine bent forward
    rot = roma.rotvec_to_rotmat(rv)
    with torch.no_grad():
        out = body(rot, body.mean_shape[None])
    bn = mesh.vertex_normals(out.vertices, body.faces)
    edge = {}
    for steps in (0, PBNSConfig().weight_diffusion):
        w = torch.from_numpy(initial_weights(rb, o, steps))
        m = PBNS(torch.from_numpy(o.vertices), torch.from_numpy(o.faces), w)
        with torch.no_grad():
            v = m.skin(m.rest, out.transforms)
        edge[steps] = physical_metrics(v, o.faces, m.rest, out.vertices, bn)["edge_mm"]
    assert edge[PBNSConfig().weight_diffusion] < 0.75 * edge[0], edge


def test_error_to_cached_drapes_lines_up_poses(body, tmp_path, monkeypatch):
    """Scoring a PBNS variant against cached simulator drapes must pair each drape with its pose:
    a 'drape' made of PBNS's own output (shifted 10 mm down) scores 10 mm, skinning more."""

    model, ck = PBNS.load(store.SHIPPED_DIR / "pbns_top-shorts.pt")
    idx = np.array([3, 7])
    rot = pose_set("test", 20, 0.5, seed=123)[torch.from_numpy(idx)]
    rot[:, 0] = remove_yaw(rot[:, 0])
    with torch.no_grad():
        v = model(rot, posed_bodies(body, rot, ck["shape"][None])[2])[0]
    v[..., 1] -= 0.01
    monkeypatch.setattr(R, "drapes_path", lambda outfit: tmp_path / f"{outfit}.npz")
    np.savez(tmp_path / "top-shorts.npz", vertices=v.numpy(), poses=idx, pool_size=20, min_pose_distance=0.5)
    r = R.error_to_drapes(model, "top-shorts", ck["shape"], body)
    assert r["poses"] == 2
    assert r["pbns_mm"] == pytest.approx(10.0, abs=0.01)
    assert r["pbns_height_mm"] == pytest.approx(10.0, abs=0.01)
    assert r["skinning_mm"] > 12.0
    assert R.error_to_drapes(model, "dress", ck["shape"], body) is None  # no drapes cached


def test_rescoring_against_cached_drapes_rewrites_the_pbns_rows_and_checks_the_start(body, tmp_path, monkeypatch):
    """After a retrain, `recon garment reference --rescore` scores the new weights against the
    cached drapes, but only when the drapes' start (the skinned outfit) is still the same."""


    model, ck = PBNS.load(store.SHIPPED_DIR / "pbns_top-shorts.pt")
    idx = np.array([2])
    rot = R.reference_poses(20, 0.5, idx)
    with torch.no_grad():
        bt = posed_bodies(body, rot, ck["shape"][None])[2]
        v, start = model(rot, bt)[0], model.skin(model.rest, bt)
    v[..., 1] -= 0.01  # a "drape" 10 mm under PBNS
    monkeypatch.setattr(R, "drapes_path", lambda outfit: tmp_path / f"{outfit}.npz")
    old_rows = {"newton VBD drape": {"seconds": 123.0}}
    (tmp_path / "garment-reference-top-shorts.json").write_text(json.dumps(
        {"outfit": "top-shorts", "poses": [{"pose": 2, "settled": False, "rows": old_rows}], "frames_cap": 60,
         "settled": 0, "config": {}}))
    np.savez(tmp_path / "top-shorts.npz", vertices=v.numpy(), start=start.numpy(), poses=idx, pool_size=20,
             min_pose_distance=0.5)
    md = R.rescore_reference("top-shorts", tmp_path).read_text()
    r = json.loads((tmp_path / "garment-reference-top-shorts.json").read_text())
    assert r["mean"]["PBNS"]["error_mm"] == pytest.approx(10.0, abs=0.01)
    assert r["mean"]["newton VBD drape"]["error_mm"] == 0.0 and r["mean"]["newton VBD drape"]["seconds"] == 123.0
    assert r["rescored_start_shift_mm"] == [pytest.approx(0.0, abs=1e-3)] and "re-scored" in md
    np.savez(tmp_path / "top-shorts.npz", vertices=v.numpy(), start=start.numpy() + 0.005, poses=idx, pool_size=20,
             min_pose_distance=0.5)
    with pytest.raises(ReconError, match="start moved"):
        R.rescore_reference("top-shorts", tmp_path)
