"""DeePSD (thesis ch. 4) and the outfit distribution it learns from: invariance to vertex order,
any topology, the physics losses' gradients, the export as W and D (a PBNS, a valid .glb), and the
held-out split of the generator."""
import json

import numpy as np
import pytest
import roma
import torch
import trimesh
from gltf_check import assert_valid, pose_meshes

from recon.errors import ReconError
from recon.export.glb import write_glb
from recon.garment import store
from recon.garment.data import posed_bodies
from recon.garment.deepsd.data import shuffled
from recon.garment.deepsd.model import DeePSD, DeePSDConfig, OutfitGraph, mean_adjacency
from recon.garment.deepsd.train import PhysicsConfig, Sample, collision_loss, physics_loss
from recon.garment.dress import Dresser
from recon.garment.morph import outfit_animation
from recon.garment.outfits import HELD_OUT_BANDS, HELD_OUT_FAMILIES, OutfitSampler
from recon.garment.templates import GarmentSpec, Outfit, RestBody, make_outfit

SMALL = DeePSDConfig(local=16, global_=16, hidden=32, keys=8, pose_hidden=16)


def random_model(cfg=SMALL, seed=0) -> DeePSD:
    torch.manual_seed(seed)
    m = DeePSD(cfg)
    with torch.no_grad():  # the zero-initialised heads too, so every output depends on the input
        for p in m.parameters():
            p.add_(0.05 * torch.randn_like(p))
    return m.eval()


@pytest.fixture(scope="module")
def top(body):
    return make_outfit(body, [GarmentSpec("top", "top", sleeve=0.2, subdivide_above=0.05)])


@pytest.fixture(scope="module")
def rb(body):
    return RestBody(body)


def test_outputs_follow_any_vertex_order(rb, top):
    m = random_model()
    o2 = shuffled(top, np.random.default_rng(3))
    g1, g2 = OutfitGraph.of(rb, top), OutfitGraph.of(rb, o2)
    # where each vertex of the shuffled outfit came from
    src = torch.from_numpy(np.asarray(trimesh.Trimesh(top.vertices, process=False).kdtree.query(o2.vertices)[1]))
    assert torch.equal(g2.rest, g1.rest[src])
    with torch.no_grad():
        d1, d2 = m.descriptors(g1), m.descriptors(g2)
        assert torch.allclose(d2, d1[src], atol=1e-5)
        p1, p2 = m.outfit(g1), m.outfit(g2)
    assert torch.allclose(p2.weights, p1.weights[src], atol=1e-5)
    assert torch.allclose(p2.D.view(8, -1, 3), p1.D.view(8, -1, 3)[:, src], atol=1e-5)


def test_any_topology_layers_and_sizes(body, rb, top):
    """One model for a cut garment, a layered outfit, a ring-grid skirt and a closed sphere."""
    m = random_model()
    sphere = trimesh.creation.icosphere(2, 0.2)
    ball = Outfit([make_outfit(body, [GarmentSpec("skirt", "skirt", skirt_step=0.03)]).garments[0]])
    layered = make_outfit(body, [GarmentSpec("trousers", "t", leg=0.4, layer=0, subdivide_above=0.05),
                                 GarmentSpec("top", "top", layer=1, subdivide_above=0.05)])
    rot = roma.rotvec_to_rotmat(0.3 * torch.randn(2, 24, 3))
    _, _, tr = posed_bodies(body, rot, body.mean_shape[None])
    graphs = [OutfitGraph.of(rb, top), OutfitGraph.of(rb, layered), OutfitGraph.of(rb, ball),
              OutfitGraph(np.asarray(sphere.vertices) + rb.j[0], np.asarray(sphere.faces),
                          np.full((len(sphere.vertices), 24), 1 / 24), rb.v, rb.n)]
    for g in graphs:
        with torch.no_grad():
            v = m(g, rot, tr)
            raw, smoothed = m.outfit(g, smooth=0), m.outfit(g)
        n = len(g.rest)
        assert v.shape == (2, n, 3) and torch.isfinite(v).all()
        for pb in (raw, smoothed):
            assert pb.weights.shape == (n, 24) and torch.allclose(pb.weights.sum(1), torch.ones(n), atol=1e-5)
        assert torch.allclose(raw.pose(rot, tr), v, atol=1e-4)  # the export is the model (eq. 4.1)
        assert (smoothed.pose(rot, tr) - v).norm(dim=-1).mean() < 0.05


def test_graph_convolution_and_heads_gradcheck_in_float64(rb, top):
    m = random_model().double()
    g = OutfitGraph.of(rb, Outfit([top.garments[0]]))
    idx = torch.arange(0, len(g.rest), max(1, len(g.rest) // 40))
    x = g.features.double()[idx].clone().requires_grad_(True)
    adj = mean_adjacency(np.array([[0, 1, 2], [1, 2, 3]]), 4)
    conv = m.phi[0]
    assert torch.autograd.gradcheck(lambda y: conv(y[:4], adj), (x,))
    assert torch.autograd.gradcheck(lambda y: m.omega(torch.cat([y, y, y, y], 1)[:, :m.cfg.descriptor]), (x[:6],))


def test_physics_losses_gradcheck_in_float64(body):
    torch.manual_seed(0)
    bv = torch.randn(1, 30, 3, dtype=torch.float64)
    bn = torch.nn.functional.normalize(torch.randn(1, 30, 3, dtype=torch.float64), dim=-1)
    v = (bv[:, :12] + 0.004 * torch.randn(1, 12, 3, dtype=torch.float64)).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda x: collision_loss(x, bv, bn, 0.005), (v,))
    # inside the body (behind the normal) costs, outside beyond epsilon does not
    inside = bv[:, :1] - 0.01 * bn[:, :1]
    outside = bv[:, :1] + 0.01 * bn[:, :1]
    assert float(collision_loss(inside, bv, bn, 0.005)) == pytest.approx(0.015 ** 2)
    assert float(collision_loss(outside, bv, bn, 0.005)) == 0.0


def test_physics_loss_trains_chi_only_and_is_zero_where_nothing_is_wrong(body, rb, top):
    m = DeePSD(SMALL)
    rot = roma.rotvec_to_rotmat(torch.zeros(1, 24, 3))
    bv, bn, tr = posed_bodies(body, rot, body.mean_shape[None])
    g = OutfitGraph.of(rb, top)
    rec = {"rest": g.rest, "faces": torch.from_numpy(top.faces), "lbs_weights": g.lbs_weights,
           "rotvec": torch.zeros(1, 24, 3), "drapes": g.rest[None], "family": "top", "split": "test"}
    s = Sample(rec, body, rb)
    with torch.no_grad():
        desc = m.descriptors(g)
        cached = (desc, m.weights(g.lbs_weights, desc), torch.zeros(len(desc), SMALL.keys, 3))
    loss, terms = physics_loss(m, s, cached, rot, tr, bv, bn, PhysicsConfig())
    # rest pose, chi starts at zero: no strain, no displacement; the template clears the body
    assert terms["edge"] < 1e-9 and terms["displacement"] == 0.0 and terms["collision"] < 1e-3
    loss.backward()
    assert all(p.grad is None for n, p in m.named_parameters() if not n.startswith("chi."))


def test_sampler_keeps_the_held_out_styles_out_of_training():
    train, test = OutfitSampler(False), OutfitSampler(True)
    rng = np.random.default_rng(0)
    drawn = [train(rng) for _ in range(300)]
    assert not {f for f, _ in drawn} & set(HELD_OUT_FAMILIES)
    for _, specs in drawn:
        for s in specs:
            if s.kind in ("top", "jumpsuit", "dress") and s.sleeve > 0:
                assert not HELD_OUT_BANDS["sleeve"][0] <= s.sleeve <= HELD_OUT_BANDS["sleeve"][1]
            if s.kind in ("trousers", "jumpsuit"):
                assert not HELD_OUT_BANDS["leg"][0] <= s.leg <= HELD_OUT_BANDS["leg"][1]
            if s.kind == "skirt":
                assert not HELD_OUT_BANDS["skirt_length"][0] <= s.skirt_length <= HELD_OUT_BANDS["skirt_length"][1]
    held = [test(rng) for _ in range(100)]
    assert {f for f, _ in held} & set(HELD_OUT_FAMILIES)
    banded = [s for f, specs in held if f not in HELD_OUT_FAMILIES for s in specs if s.kind == "trousers"]
    assert banded and all(HELD_OUT_BANDS["leg"][0] <= s.leg <= HELD_OUT_BANDS["leg"][1] for s in banded)


def test_shuffling_keeps_the_surface(top):
    o2 = shuffled(top, np.random.default_rng(1))
    a = np.sort(np.sort(top.vertices[top.faces].reshape(-1, 9), axis=1), axis=0)
    b = np.sort(np.sort(o2.vertices[o2.faces].reshape(-1, 9), axis=1), axis=0)
    assert np.array_equal(a, b) and not np.array_equal(top.vertices, o2.vertices)


def test_save_load_roundtrip(tmp_path):
    m = random_model()
    m.save(tmp_path / "d.pt", {"meta_json": json.dumps({})})
    m2, ck = DeePSD.load(tmp_path / "d.pt")
    assert m2.cfg == SMALL
    for (n, a), (_, b) in zip(m.state_dict().items(), m2.state_dict().items()):
        assert torch.allclose(a, b, atol=1e-2 * float(a.abs().max()) + 1e-4), n  # float16 on disk


@pytest.mark.skipif(not store.deepsd_path().exists(), reason="no shipped DeePSD weights")
def test_an_untrained_garment_mesh_is_dressed_by_deepsd_into_a_valid_glb(body, tmp_path):
    mesh = "demos/garments/tube-dress.obj"
    dresser = Dresser(mesh)
    assert dresser.garment_model == "deepsd" and not dresser.dynamic
    with pytest.raises(ReconError, match="quasi-static"):
        Dresser(mesh, garment_model="deepsd", dynamics=True)
    rot = roma.rotvec_to_rotmat(0.3 * torch.randn(3, 24, 3))
    rot[:, 0] = torch.eye(3)
    transl = torch.tensor([[0.0, 0.9, 0.0], [0.1, 0.9, 0.2], [0.2, 1.0, 0.4]])
    glb = write_glb(tmp_path / "a.glb", body, body.mean_shape, rot, transl, 30.0,
                    outfit_animation(body, body.mean_shape, rot, transl, dresser, 30.0))
    assert_valid(glb)
    posed = pose_meshes(glb, 2)
    # the network's cloth (the post-step is no blend shape): W as skin weights, D as morph targets
    cloth = Dresser(mesh, resolve_collisions=False)(body, rot[2:3], body.mean_shape, transl[2:3]).vertices[0]
    assert np.abs(posed["outfit"] - cloth).mean() < 2e-4
