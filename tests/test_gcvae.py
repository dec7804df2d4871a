"""The GCVAE garment space (thesis 3.4): registration as offsets and mask, the pooling hierarchy,
the network's shapes and gradients, the loss terms, sampling and interpolation."""
import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree

from recon.errors import ReconError
from recon.garment.gcvae.command import sample_command
from recon.garment.gcvae.model import GCVAE, TYPES, BodyGraph, GCVAEConfig, garment_mesh, one_hot, pool, register
from recon.garment.gcvae.sample import decode, interpolate, sample
from recon.garment.gcvae.train import GCVAELossConfig, chamfer, kl_divergence, losses
from recon.garment.templates import GarmentSpec, RestBody, make_outfit

SMALL = GCVAEConfig(channels=(8, 8, 16, 16), latent=8, fc=32)


@pytest.fixture(scope="module")
def rb(body):
    return RestBody(body)


@pytest.fixture(scope="module")
def graph(rb):
    return BodyGraph(rb, SMALL)


@pytest.fixture(scope="module")
def top(body):
    return make_outfit(body, [GarmentSpec("top", "top", sleeve=0.3, subdivide_above=0.04)]).garments[0]


def test_pooling_hierarchy_shrinks_and_never_crosses_a_segment(rb, graph):
    assert graph.sizes[0] == len(graph.index) and all(a > b for a, b in zip(graph.sizes, graph.sizes[1:]))
    seg = rb.owner[graph.index]
    for lvl, assign in enumerate(graph.assign):
        a = assign.numpy()
        assert a.max() + 1 == graph.sizes[lvl + 1] and len(np.unique(a)) == graph.sizes[lvl + 1]
        for c in np.unique(a)[:200]:  # every cluster inside one body segment
            assert len(np.unique(seg[a == c])) == 1
        seg = np.array([seg[a == c][0] for c in range(graph.sizes[lvl + 1])])
    x = torch.randn(2, graph.sizes[0], 3)
    p = pool(x, graph.assign[0], graph.sizes[1])
    assert p.shape == (2, graph.sizes[1], 3) and torch.equal(p[:, 0], x[:, graph.assign[0] == 0].max(1).values)


def test_every_level_averages_its_neighbours_without_self_loops(graph):
    for lvl, adj in enumerate(graph.adj):
        a = adj.coalesce()
        i, v = a.indices(), a.values()
        assert not (i[0] == i[1]).any(), f"level {lvl} has self-loops"
        rows = torch.zeros(a.shape[0]).index_add_(0, i[0], v)  # each row a mean: weights sum to 1
        assert torch.allclose(rows[rows > 0], torch.ones(1)) and (rows > 0).float().mean() > 0.99


def test_registration_reproduces_a_garment_that_follows_the_body(graph, top):
    off, mask = register(graph, top.vertices, top.faces)
    assert off.shape == (graph.sizes[0], 3) and set(np.unique(mask)) <= {0.0, 1.0}
    assert np.all(off[mask == 0] == 0)
    v, f = garment_mesh(graph, off, mask)
    assert len(f) > 0 and chamfer(top.vertices, v) < 8.0  # mm: a t-shirt is a body homotopy
    # garment vertices are outside the body: offsets point along the body normals
    assert (np.einsum("ij,ij->i", off, graph.n.numpy())[mask > 0] > -0.002).mean() > 0.95


def test_network_shapes_and_float64_gradients(graph):
    torch.manual_seed(0)
    m = GCVAE(graph, SMALL).double()
    n = graph.sizes[0]
    o = 0.01 * torch.randn(2, n, 3, dtype=torch.float64)
    mask = (torch.rand(2, n) > 0.5).double()
    kind = one_hot(["top", "dress"]).double()
    out, logit, mu, logvar, tl = m.eval()(o, mask, kind)
    assert out.shape == (2, n, 3) and logit.shape == (2, n) and mu.shape == (2, 8) and tl.shape == (2, len(TYPES))
    z = torch.randn(1, 8, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda z: m.decode(z, kind[:1])[0][:, :50], (z,), atol=1e-6)


def test_loss_terms_and_their_gradients(graph):
    torch.manual_seed(0)
    mu = torch.randn(3, 4, dtype=torch.float64, requires_grad=True)
    lv = torch.randn(3, 4, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(kl_divergence, (mu, lv))
    assert float(kl_divergence(torch.zeros(2, 4), torch.zeros(2, 4))) == 0.0
    m = GCVAE(graph, SMALL)
    n = graph.sizes[0]
    batch = {"offsets": torch.zeros(2, n, 3), "mask": torch.ones(2, n), "onehot": one_hot(["top", "top"])}
    loss, terms = losses(m.train(), batch, GCVAELossConfig())
    loss.backward()
    assert set(terms) == {"offsets", "normals", "mask", "collision", "cvar", "kl"}
    assert all(p.grad is not None for p in m.parameters() if p.requires_grad)


def test_sampling_and_interpolation(graph, top):
    torch.manual_seed(0)
    m = GCVAE(graph, SMALL).eval()
    with pytest.raises(ReconError, match="unknown garment type"):
        sample(m, "cape", 2)
    assert len(sample(m, "dress", 3, seed=1)) == 3
    off, mask = register(graph, top.vertices, top.faces)
    steps = interpolate(m, (off, mask, "top"), (off * 2, mask, "dress"), steps=3)
    with torch.no_grad():
        mu = m.encode(torch.from_numpy(off)[None], torch.from_numpy(mask)[None], one_hot(["top"]))[0]
    first = decode(m, mu, "top")[0]
    assert len(steps) == 3 and np.allclose(steps[0][0], first[0], atol=1e-5)


def test_registered_offsets_find_the_nearest_surface_point(graph, top):
    off, mask = register(graph, top.vertices, top.faces, samples=60000)
    sel = np.flatnonzero(mask)[:300]
    target = graph.v.numpy()[sel] + off[sel]
    d_vertices = cKDTree(top.vertices).query(graph.v.numpy()[sel])[0]
    assert np.all(np.linalg.norm(target - graph.v.numpy()[sel], axis=1) <= d_vertices + 1e-6)


def test_sample_command_writes_garments_an_outfit_takes(body, tmp_path):
    info = sample_command("trousers", 2, tmp_path, seed=3)
    assert info["files"] == ["sample_00.obj", "sample_01.obj"] and (tmp_path / "samples.jpg").exists()
    o = make_outfit(body, str(tmp_path / "sample_00.obj"))
    assert len(o.vertices) > 100
