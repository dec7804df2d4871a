"""The example-based Taylor garment model (recon.garment.taylor.model, taylor.train, drape): the Taylor
term at an anchor, separability on a toy, the blending, the shape model, sensitivity by finite
differences against autograd, the drape solver, and the model behind Dresser and the .glb."""
import json
from types import SimpleNamespace

import numpy as np
import pytest
import roma
import torch
import trimesh
from gltf_check import assert_valid

from recon.export.glb import write_glb
from recon.garment import store
from recon.garment.data import posed_bodies
from recon.garment.drape import DrapeSolver, DrapeSolverConfig
from recon.garment.dress import Dresser
from recon.garment.morph import outfit_animation
from recon.garment.pbns.model import PBNS, PBNSConfig, initial_weights, pose_features
from recon.garment.resize import Transfer
from recon.garment.taylor import eval as taylor_eval
from recon.garment.taylor.config import PoseFitConfig, TaylorBuildConfig
from recon.garment.taylor.data import fit_only_poses, pose_key, unposed
from recon.garment.taylor.model import (
    BlendConfig,
    TaylorGarment,
    blend_weights,
    fit_shape_model,
    pose_vector,
    region_weights,
    shape_features,
)
from recon.garment.taylor.train import (
    build,
    cluster_anchors,
    database_shapes,
    fit_pose_model,
    perturbed,
    read_meta,
    region_sensitivity,
    sensitivity,
)
from recon.garment.templates import PRESETS, GarmentSpec, RestBody, make_outfit


@pytest.fixture(scope="module")
def top(body):
    """A small sleeveless top with a PBNS of random pose deformations."""
    torch.manual_seed(0)
    outfit = make_outfit(body, [GarmentSpec("top", "top", sleeve=0.0)])
    w = initial_weights(RestBody(body), outfit, diffusion=5)
    model = PBNS(torch.from_numpy(outfit.vertices), torch.from_numpy(outfit.faces), torch.from_numpy(w), PBNSConfig())
    with torch.no_grad():
        model.D.normal_(0, 1e-3)
    return outfit, model.eval()


def poses(n, scale=0.3, seed=0):
    g = torch.Generator().manual_seed(seed)
    r = roma.rotvec_to_rotmat(scale * torch.randn(n, 24, 3, generator=g))
    r[:, 0] = torch.eye(3)
    return r


def graded(body, model, shapes):
    """(K, N, 3) the template graded to each body (its own body: the template)."""
    return torch.from_numpy(Transfer(body, model.rest.numpy(), model.faces.numpy(), body.mean_shape).resize(shapes))


def toy_model(body, model, anchors, shapes, unposed_of, ridge=1e-6, cfg=None):
    """A Taylor model whose database holds ``unposed_of(shape, anchor)`` (N, 3) at each anchor
    (its shape models fitted, as the build's, to the departures from the graded outfit)."""
    basis, maps = [], []
    for a in anchors:
        u = torch.stack([unposed_of(s, a) for s in shapes]) - graded(body, model, shapes)
        _, b, m = fit_shape_model(shapes, u, components=5, ridge=ridge)
        basis.append(b)
        maps.append(m)
    q = torch.rand(7, 72, generator=torch.Generator().manual_seed(1))
    return TaylorGarment(model, anchors, q / q.sum(1, keepdim=True), torch.stack(basis), torch.stack(maps), shapes[0],
                         cfg or BlendConfig())


def shifted_drape(model, amplitude=0.02):
    """A toy 'drape' in the rest pose, linear in (beta, beta^2) (5 independent fields) and depending
    on the anchor."""
    g = torch.Generator().manual_seed(3)
    fields = torch.einsum("fc,cnk->fnk", torch.randn(13, 5, generator=g),
                          amplitude * torch.randn(5, model.rest.shape[0], 3, generator=g))

    def unposed_of(shape, anchor):
        tilt = float(roma.rotmat_to_rotvec(anchor[1]).norm())
        return model.rest + torch.einsum("f,fnk->nk", shape_features(shape[None])[0], fields) * (1 + tilt)
    return unposed_of


def test_taylor_term_is_exact_at_an_anchor_and_vanishes_on_the_pose_models_body(body, top):
    _, model = top
    anchors = poses(3)
    shapes = torch.cat([body.mean_shape[None], database_shapes(5, seed=1)])
    unposed_of = shifted_drape(model)
    m = toy_model(body, model, anchors, shapes, unposed_of)
    for k in (1, 3):  # a database body, at its anchor, with the simulation as pose model: the drape itself
        _, _, bt = posed_bodies(body, anchors[2:3], shapes[k][None])
        m.set_shape(body, shapes[k])
        w = torch.zeros(1, 7, 3)
        w[..., 2] = 1.0
        x = m.pose(anchors[2:3], bt, pose_model=unposed_of(shapes[0], anchors[2])[None], weights=w)
        assert (x - model.skin(unposed_of(shapes[k], anchors[2]), bt)).norm(dim=-1).max() < 1e-4
    # PBNS as the pose model, corrected at the anchors: the drape itself there, on any database body
    with torch.no_grad():
        pbns_at = model.rest + model.decode(model.mlp(pose_features(anchors)))
    m.pose_residual = torch.stack([unposed_of(shapes[0], a) for a in anchors]) - pbns_at
    for k in (0, 2):
        _, _, bt = posed_bodies(body, anchors[1:2], shapes[k][None])
        m.set_shape(body, shapes[k])
        w = torch.zeros(1, 7, 3)
        w[..., 1] = 1.0
        x = m.pose(anchors[1:2], bt, weights=w)
        assert (x - model.skin(unposed_of(shapes[k], anchors[1]), bt)).norm(dim=-1).max() < 1e-4
    m.pose_residual = None
    # the pose model's own body: no shape term whatever the pose, the pose model's cloth exactly
    m.set_shape(body, shapes[0])
    rot = poses(4, seed=5)
    _, _, bt = posed_bodies(body, rot, shapes[0][None])
    assert torch.equal(m.pose(rot, bt), model.pose(rot, bt))


def test_pose_examples_correct_the_pose_model_with_weights_of_their_own(body, top, tmp_path):
    """Pose examples (drapes on the pose model's body alone, beyond the anchors): at an example the
    model is PBNS plus that example's residual plus the shape term; saved, loaded, animated and as
    blend shapes alike."""
    _, model = top
    anchors, extra = poses(3), poses(4, seed=9)
    shapes = torch.cat([body.mean_shape[None], database_shapes(5, seed=1)])
    m = toy_model(body, model, anchors, shapes, shifted_drape(model))
    g = torch.Generator().manual_seed(5)
    examples = torch.cat([anchors, extra])
    m.pose_examples, m.example_vec = examples, pose_vector(examples)
    m.pose_residual = 1e-3 * torch.randn(len(examples), model.rest.shape[0], 3, generator=g)
    assert m.separate_examples
    rot = extra[2:3]
    for k in (0, 3):
        _, _, bt = posed_bodies(body, rot, shapes[k][None])
        m.set_shape(body, shapes[k])
        w = blend_weights(m.distances(rot), m.cfg)
        with torch.no_grad():
            want = model.skin(model.rest + model.deformation(rot) + m.graded - model.rest
                              + m.blend(w, m.delta_t)[0] + m.pose_residual[5], bt)
        assert (m.pose(rot, bt) - want).norm(dim=-1).max() < 1e-5
        m.correct_pose = False  # PBNS alone as the pose model: no example's residual
        assert (m.pose(rot, bt) - want).norm(dim=-1).mean() > 5e-4
        m.correct_pose = True
    m.save(tmp_path / "t.pt", "{}")
    loaded = TaylorGarment.load(tmp_path / "t.pt", model)[0].set_shape(body, shapes[3])
    assert torch.equal(loaded.pose_examples, examples) and loaded.separate_examples
    assert (loaded.pose(rot, bt) - m.pose(rot, bt)).norm(dim=-1).mean() < 5e-5  # float16 storage
    motion = poses(6, seed=11)
    with torch.no_grad():
        out = body(motion, shapes[3][None].expand(6, -1))
    ref = m.pose(motion, out.transforms, distance=m.damped_distances(motion),
                 example_distance=m.damped_distances(motion, examples=True))
    assert (m.animate(motion, out.transforms) - ref).norm(dim=-1).max() < 1e-6
    d, codes = m.sequence_codes(motion)
    posed = model.skin(m.graded + (codes @ d).view(6, -1, 3), out.transforms)
    assert (posed - ref).norm(dim=-1).max() < 1e-4


def test_fit_only_poses_are_train_poses_that_are_not_examples_and_grow_by_prefix():
    train = poses(40, seed=3)
    examples = train[[1, 5, 7, 20]]
    more = fit_only_poses(train, examples, 12, seed=4)
    assert more.shape == (12, 24, 3, 3)
    taken, drawn = {pose_key(e) for e in examples}, [pose_key(r) for r in more]
    assert len(set(drawn)) == 12 and not taken & set(drawn) and set(drawn) <= {pose_key(r) for r in train}
    assert torch.equal(fit_only_poses(train, examples, 30, seed=4)[:12], more)  # a larger draw begins the same
    with pytest.raises(ValueError, match="36 train poses"):
        fit_only_poses(train, examples, 37)


def test_a_fitted_pose_model_nears_the_drapes_and_the_database_keeps_meeting_them(body, top, tmp_path):
    """fit_pose_model trains a copy of PBNS (network and blend shapes; not its skinning) towards the
    examples' drapes; the database on either pose model meets the drapes at the examples; a fitted
    pose model is saved with the database and loaded as a copy, leaving the outfit's PBNS alone."""
    _, model = top
    anchors, extra = poses(3), poses(5, seed=9)
    examples = torch.cat([anchors, extra])
    g = torch.Generator().manual_seed(2)
    with torch.no_grad():  # toy drapes: PBNS's cloth plus a smooth pose-dependent sag
        sag = 0.01 * torch.randn(1, model.rest.shape[0], 3, generator=g)
        drapes = model.rest + model.deformation(examples) + sag * (1 + pose_vector(examples)[:, 3:4, None])
    before = model.D.detach().clone()
    width = model.mlp[0].out_features + 8  # the network widened as it is fitted: saved and loaded so
    fitted = fit_pose_model(model, examples, drapes, PoseFitConfig(steps=60, lr=1e-3, batch=4, hidden=width))
    assert torch.equal(model.D, before) and torch.equal(fitted.weights, model.weights)
    assert fitted.mlp[0].out_features == width
    torch.manual_seed(123)  # the widened units' start comes from the config's seed, not the global draws
    again = fit_pose_model(model, examples, drapes, PoseFitConfig(steps=60, lr=1e-3, batch=4, hidden=width))
    assert torch.equal(again.mlp[0].weight, fitted.mlp[0].weight) and torch.equal(again.D, fitted.D)
    with torch.no_grad():
        def miss(m):
            return float((m.rest + m.deformation(examples) - drapes).norm(dim=-1).mean())
        assert miss(fitted) < 0.5 * miss(model)
        refit = fit_pose_model(model, examples, drapes, PoseFitConfig(method="ridge", ridge=1e-6))
        assert miss(refit) < 0.5 * miss(model) and torch.equal(refit.mlp[0].weight, model.mlp[0].weight)
    with pytest.raises(ValueError, match="adam or ridge"):
        fit_pose_model(model, examples, drapes, PoseFitConfig(method="sgd"))
    with torch.no_grad():
        residual = drapes - model.rest - model.deformation(examples)
    shapes = torch.cat([body.mean_shape[None], database_shapes(5, seed=1)])
    m = toy_model(body, model, anchors, shapes, shifted_drape(model))
    m.pose_examples, m.example_vec, m.pose_residual = examples, pose_vector(examples), residual
    f = m.with_pose_model(fitted, fitted=True)
    rot = extra[1:2]
    _, _, bt = posed_bodies(body, rot, shapes[0][None])
    f.set_shape(body, shapes[0])
    m.set_shape(body, shapes[0])
    want = model.skin(drapes[4], bt)  # the drape at this example on the pose model's body
    assert (m.pose(rot, bt) - want).norm(dim=-1).max() < 1e-5
    assert (f.pose(rot, bt) - want).norm(dim=-1).max() < 1e-5
    f.save(tmp_path / "t.pt", "{}")
    loaded = TaylorGarment.load(tmp_path / "t.pt", model)[0].set_shape(body, shapes[3])
    assert loaded.fitted and loaded.pbns is not model and torch.equal(model.D, before)
    assert (loaded.pbns.D - fitted.D).abs().max() < 1e-3 * fitted.D.abs().max()  # float16 storage
    rot = poses(2, seed=4)
    _, _, bt = posed_bodies(body, rot, shapes[3][None])
    assert (loaded.pose(rot, bt) - f.set_shape(body, shapes[3]).pose(rot, bt)).norm(dim=-1).mean() < 5e-5
    assert not TaylorGarment.load(tmp_path / "t.pt", model)[0].with_pose_model(model).fitted
    # without the examples' corrections, on the pose model's body: the fitted network's cloth; kept so
    f.set_shape(body, shapes[0])
    _, _, bt = posed_bodies(body, rot, shapes[0][None])
    with f.corrections(False):
        assert (f.pose(rot, bt) - fitted.pose(rot, bt)).norm(dim=-1).max() < 1e-6
        f.save(tmp_path / "u.pt", "{}")
    assert f.correct_pose and not TaylorGarment.load(tmp_path / "u.pt", model)[0].correct_pose


def test_separability_on_a_toy_function(body, top):
    """f(beta, theta) = a(theta) + b(beta) + c(beta) d(theta): the first-order Taylor model is exact
    without the cross term and its error shrinks with the square of the distance with it."""
    _, model = top
    n = model.rest.shape[0]
    g = torch.Generator().manual_seed(4)
    fa, fb, fc = (0.02 * torch.randn(n, 3, generator=g) for _ in range(3))
    beta0 = body.mean_shape
    anchor = poses(1, seed=9)

    def f(shape, rot, cross):
        theta = pose_features(rot[None])[0][9:12].sum()  # a smooth scalar of the pose
        b = (shape - beta0).sum()  # beyond the grading, the shape part lies in the span of eq. 6's features
        return graded(body, model, shape[None])[0] + fa * theta + fb * (b + (shape ** 2).sum()) + cross * fc * b * theta

    errors = {}
    for cross in (0.0, 20.0):
        shapes = torch.cat([beta0[None], database_shapes(15, seed=2)])  # more bodies than features: exact
        m = toy_model(body, model, anchor, shapes, lambda s, a, cross=cross: f(s, a, cross))
        w = torch.ones(1, 7, 1)
        for r in (0.2, 0.1, 0.05):
            direction = torch.randn(78, generator=torch.Generator().manual_seed(0))
            direction = r * direction / direction.norm()
            rot = anchor[0] @ roma.rotvec_to_rotmat(direction[:72].view(24, 3))
            shape = beta0 + direction[72:]
            m.set_shape(body, shape)
            _, _, bt = posed_bodies(body, rot[None], shape[None])
            x = m.pose(rot[None], bt, pose_model=f(beta0, rot, cross)[None], weights=w)
            errors[cross, r] = float((x - model.skin(f(shape, rot, cross), bt)).detach().norm(dim=-1).mean())
    assert max(errors[0.0, r] for r in (0.2, 0.1, 0.05)) < 1e-5
    assert errors[20.0, 0.2] > 1e-4
    assert 2.5 < errors[20.0, 0.2] / errors[20.0, 0.1] < 6 and 2.5 < errors[20.0, 0.1] / errors[20.0, 0.05] < 6


def test_blending_weights_sum_to_one_on_the_nearest_anchors():
    g = torch.Generator().manual_seed(0)
    d = torch.rand(3, 7, 20, generator=g)
    d[0, 2, 11] = 0.0
    w = blend_weights(d, BlendConfig(nearest=5, power=2.0))
    assert torch.allclose(w.sum(-1), torch.ones(3, 7))
    assert ((w > 0).sum(-1) == 5).all()
    nearest = d.topk(5, -1, largest=False).indices
    assert torch.equal(torch.gather(w, -1, nearest) > 0, torch.ones_like(nearest, dtype=torch.bool))
    assert w[0, 2, 11] > 0.999  # an anchor at distance 0 takes (nearly) all of its region
    assert (w.argmax(-1) == d.argmin(-1)).all()


def test_region_weights_cover_every_vertex(top):
    _, model = top
    r = region_weights(model.weights.detach())
    assert r.shape == (model.rest.shape[0], 7)
    assert torch.allclose(r.sum(1), torch.ones(len(r)), atol=1e-5)


def test_shape_model_reproduces_a_quadratic_family_and_generalises(body, top):
    _, model = top
    shapes = torch.cat([body.mean_shape[None], database_shapes(15, seed=3)])  # more bodies than features
    unposed_of = shifted_drape(model)
    a = poses(1)[0]
    u = torch.stack([unposed_of(s, a) for s in shapes])
    mean, basis, m = fit_shape_model(shapes, u, components=5, ridge=1e-6)
    test = database_shapes(4, seed=11)
    for s in test:  # bodies not in the set, as exactly
        pred = mean + torch.einsum("c,cnk->nk", m @ shape_features(s[None])[0], basis)
        assert (pred - unposed_of(s, a)).norm(dim=-1).max() < 2e-4
    for k, s in enumerate(shapes):  # the bodies it was fitted on: back within float noise
        pred = mean + torch.einsum("c,cnk->nk", m @ shape_features(s[None])[0], basis)
        assert (pred - u[k]).norm(dim=-1).max() < 2e-4


def test_sensitivity_finite_differences_match_autograd(body, top):
    _, model = top
    rot = poses(1, seed=2)[0]
    shape = body.mean_shape
    fd = sensitivity(model, body, rot, shape, model.rest, step=1e-3)  # (N, 72)
    ids = torch.tensor([10, 500, len(model.rest) - 7])
    delta = torch.zeros(72, requires_grad=True)

    def cloth(d):
        r = rot[None] @ roma.rotvec_to_rotmat(d.view(1, 24, 3))
        t = body(r, shape[None]).transforms
        return model.skin(model.rest + model.decode(model.mlp(pose_features(r))), t)[0, ids]

    x = cloth(delta)
    jac = torch.stack([torch.autograd.grad(x[i, c], delta, retain_graph=True)[0] for i in range(3) for c in range(3)])
    auto = jac.view(3, 3, 72).norm(dim=1)  # (3 vertices, 72)
    assert torch.allclose(fd[ids], auto, rtol=2e-2, atol=2e-3)
    assert perturbed(rot, 0.1).shape == (144, 24, 3, 3)


def test_region_sensitivity_and_clustering():
    s = torch.rand(50, 72)
    regions = torch.softmax(torch.randn(50, 7), 1)
    q, joints = region_sensitivity(s, regions)
    assert torch.allclose(q.sum(1), torch.ones(7)) and joints.shape == (24,)
    rot = poses(200, seed=1)
    idx = cluster_anchors(rot, torch.ones(24), 12)
    assert len(set(idx.tolist())) == len(idx) and 8 <= len(idx) <= 12


def test_drape_solver_hangs_a_pinned_sheet(body):
    """A 20 cm sheet pinned along its top edge, far from the body: it hangs (lower, its edge lengths
    kept within 2 %), the pins stay."""
    n = 8
    u, v = np.meshgrid(np.linspace(0, 0.2, n), np.linspace(0, 0.2, n))
    verts = np.stack([u.ravel(), 2.0 + np.zeros(n * n), v.ravel()], 1).astype(np.float32)  # horizontal
    quads = [(i * n + j, i * n + j + 1, (i + 1) * n + j) for i in range(n - 1) for j in range(n - 1)]
    quads += [(i * n + j + 1, (i + 1) * n + j + 1, (i + 1) * n + j) for i in range(n - 1) for j in range(n - 1)]
    faces = np.array(quads)
    pinned = np.zeros(n * n, bool)
    pinned[:n] = True
    sheet = SimpleNamespace(vertices=verts, faces=faces, layer=np.zeros(n * n, int), pinned=pinned)
    solver = DrapeSolver(sheet, DrapeSolverConfig(rounds=3, iterations=60, tether=1.0))
    with torch.no_grad():
        bv = body(poses(1), body.mean_shape[None]).vertices[0]
    bn = torch.nn.functional.normalize(bv, dim=-1)
    x = torch.from_numpy(verts)
    out = solver(x, x, bv, bn)
    assert torch.equal(out[:n], x[:n])
    assert float(out[n:, 1].mean()) < 2.0 - 0.03  # fell
    e = solver.crit.edge.edges
    length = lambda p: (p[e[:, 0]] - p[e[:, 1]]).norm(dim=-1)  # noqa: E731
    assert ((length(out) - length(x)).abs() / length(x)).mean() < 0.02


def test_dresser_with_the_taylor_model_poses_animates_and_exports(body, top, tmp_path, monkeypatch):
    monkeypatch.setenv("RECON_CACHE_DIR", str(tmp_path / "cache"))
    outfit, model = top
    path = tmp_path / "mytop.pt"
    model.save(path, {"meta_json": json.dumps({"garments": ["top"]}), "layer": torch.zeros(len(outfit.vertices)),
                      "garment_id": torch.zeros(len(outfit.vertices), dtype=torch.long), "shape": body.mean_shape})
    with pytest.raises(Exception, match="recon garment train --model taylor"):
        Dresser(path=path, garment_model="taylor")
    shapes = torch.cat([body.mean_shape[None], database_shapes(6, seed=1)])
    m = toy_model(body, model, poses(4), shapes, shifted_drape(model))
    m.save(store.taylor_path(str(path)), json.dumps({"outfit": "mytop"}))
    dresser = Dresser(path=path, garment_model="taylor", resolve_collisions=False, drape_iterations=0)
    shape = shapes[3]
    rot = poses(5, seed=7)
    transl = torch.zeros(5, 3)
    one = dresser(body, rot[:2], shape[None].expand(2, -1), transl[:2]).vertices
    with torch.no_grad():
        out = body(rot[:2], shape[None].expand(2, -1))
    direct = m.set_shape(body, shape).pose(rot[:2], out.transforms, out.vertices)
    assert np.abs(one - direct.numpy()).mean() < 1e-4  # float16 storage (a push-out may flip: the mean)
    # by default the Dresser's post-step follows, with the outfit graded to the body as its rest
    posted = Dresser(path=path, garment_model="taylor", drape_iterations=0)
    got = posted(body, rot[:2], shape[None].expand(2, -1), transl[:2]).vertices
    ref = posted.resolver(torch.from_numpy(one), out.vertices, body.faces, rest=m.graded)
    assert np.abs(got - ref.numpy()).mean() < 1e-4 and np.abs(got - one).mean() > 1e-6
    photo = write_glb(tmp_path / "p.glb", body, shape, rot[:1], transl[:1], 30.0,
                      outfit_animation(body, shape, rot[:1], transl[:1], posted, 30.0))  # post-step as a target
    assert_valid(photo)
    loaded = TaylorGarment.load(store.taylor_path(str(path)), dresser.model)[0].set_shape(body, shape)
    assert np.abs(one - loaded.pose(rot[:2], out.transforms, out.vertices).numpy()).max() < 1e-5
    motion = dresser.animate(body, rot, shape, transl).vertices
    assert motion.shape == (5, len(outfit.vertices), 3) and np.isfinite(motion).all()
    glb = write_glb(tmp_path / "a.glb", body, shape, rot, transl + torch.tensor([0.0, 0.9, 0.0]), 30.0,
                    outfit_animation(body, shape, rot, transl + torch.tensor([0.0, 0.9, 0.0]), dresser, 30.0))
    assert_valid(glb)
    scene = trimesh.load(glb)
    assert len(scene.geometry) == 2
    with pytest.raises(Exception, match="tightness"):
        dresser(body, rot[:1], shape, tightness=(0.1, 0.0))
    # the blend-shape form of the export is the model without its penetration handling
    d, codes = dresser.sequence_codes(body, rot, shape)
    with torch.no_grad():
        out = body(rot, shape[None].expand(5, -1))
    posed = model.skin(dresser.rest_for(body, shape) + (codes @ d).view(5, -1, 3), out.transforms)
    ref = m.set_shape(body, shape).pose(rot, out.transforms, distance=m.damped_distances(rot))
    assert (posed - ref).norm(dim=-1).max() < 1e-4
    assert unposed(model, ref, out.transforms).shape == ref.shape


def test_dresser_continues_a_taylor_pose_with_the_drape_solver_in_the_gravity_frame(body, top, tmp_path, monkeypatch):
    """``drape_iterations``: a single pose's Taylor cloth continued by the database's drape solver,
    which brings it nearer the drape; solved with gravity along -Y and moved with the body to the
    camera frame."""
    monkeypatch.setenv("RECON_CACHE_DIR", str(tmp_path / "cache"))
    outfit, model = top
    path = tmp_path / "mytop.pt"
    model.save(path, {"meta_json": json.dumps({"garments": ["top"]}), "layer": torch.zeros(len(outfit.vertices)),
                      "garment_id": torch.zeros(len(outfit.vertices), dtype=torch.long), "shape": body.mean_shape})
    monkeypatch.setattr("recon.garment.taylor.garment_model.trained_outfit",
                        lambda b, p: (outfit, body.mean_shape, "mytop"))
    shapes = torch.cat([body.mean_shape[None], database_shapes(6, seed=1)])
    m = toy_model(body, model, poses(4), shapes, shifted_drape(model, amplitude=0.01))
    m.save(store.taylor_path(str(path)), json.dumps({"outfit": "mytop"}))
    refined = Dresser(path=path, garment_model="taylor", resolve_collisions=False, drape_iterations=15)
    shape, rot = shapes[2], poses(1, scale=0.2, seed=3)
    got = torch.from_numpy(refined(body, rot, shape[None]).vertices[0])
    bv, bn, bt = posed_bodies(body, rot, shape[None])
    taylor = m.set_shape(body, shape).pose(rot, bt, bv)[0]
    skinned = model.skin(m.graded[None], bt)[0]
    # on its way from the model's cloth to where the same solver, run on, takes it
    further = DrapeSolver(outfit, DrapeSolverConfig(rounds=1, iterations=150))(m.graded, taylor, bv[0], bn[0],
                                                                              carried=skinned)
    assert (got - further).norm(dim=-1).mean() < 0.7 * (taylor - further).norm(dim=-1).mean()
    assert (got - taylor).norm(dim=-1).mean() > 1e-3
    # in a camera frame (the root turned upside down, translated): the same cloth, moved with the body
    up = torch.diag(torch.tensor([1.0, -1.0, -1.0]))
    cam = rot.clone()
    cam[:, 0] = up.T @ rot[:, 0]
    transl = torch.tensor([[0.3, -0.2, 2.5]])
    moved = torch.from_numpy(refined(body, cam, shape[None], transl, up=up).vertices[0])
    with torch.no_grad():
        body_cam = body(cam, shape[None], transl=transl).vertices[0]
    r, t = roma.rigid_points_registration(bv[0], body_cam)
    assert (body_cam - (bv[0] @ r.T + t)).norm(dim=-1).max() < 1e-4  # the two bodies: one rigid motion apart
    assert (moved - (got @ r.T + t)).norm(dim=-1).max() < 1e-4


@pytest.mark.slow
@pytest.mark.parametrize("outfit", [o for o in PRESETS if o != "tshirt-skirt"])
def test_build_makes_a_database_for_every_preset(outfit, tmp_path, monkeypatch, body):
    """The one build command works for each preset (layers, pins, sizes of their own; tshirt-skirt
    is the test below): a toy database that loads and poses every vertex of its outfit."""
    monkeypatch.setenv("RECON_CACHE_DIR", str(tmp_path / "cache"))
    cfg = TaylorBuildConfig(outfit=outfit, anchors=2, shapes=2, pose_examples=2, components=2, sensitivity_poses=1,
                            workers=1, drape=DrapeSolverConfig(rounds=1, iterations=2),
                            pose_fit=PoseFitConfig(steps=3, batch=4, poses=2, hidden=64))
    out = build(cfg, tmp_path / "taylor.pt", log=lambda *_: None, progress=False)
    pbns, ck = PBNS.load(store.pbns_path(outfit))
    model, _ = TaylorGarment.load(out, pbns)
    rot = poses(2)
    _, _, transforms = posed_bodies(body, rot, ck["shape"][None].expand(2, -1))
    x = model.set_shape(body, ck["shape"]).pose(rot, transforms)
    assert x.shape == (2, len(pbns.rest), 3) and torch.isfinite(x).all()


@pytest.mark.slow
def test_build_end_to_end_resumes_from_its_kept_drapes(tmp_path, monkeypatch, body):
    """``recon garment train --model taylor``'s build at a toy size: a database that loads and poses,
    its drapes kept per pose, and a rerun after a lost drape makes only that one again."""
    monkeypatch.setenv("RECON_CACHE_DIR", str(tmp_path / "cache"))
    cfg = TaylorBuildConfig(anchors=2, shapes=2, pose_examples=2, components=2, sensitivity_poses=1, workers=1,
                            drape=DrapeSolverConfig(rounds=1, iterations=2),
                            pose_fit=PoseFitConfig(steps=3, batch=4, poses=2, hidden=64))
    out = tmp_path / "taylor.pt"
    build(cfg, out, log=lambda *_: None, progress=False)
    meta = json.loads(read_meta(out))
    assert (meta["anchors"], meta["pose_examples"], meta["fit_poses"]) == (2, 4, 2)
    kept = sorted((tmp_path / "cache" / "taylor-drapes").glob("*/*.npz"))
    assert len(kept) == 2 + 2 + 2  # anchors (on 3 bodies), pose examples and fit poses (PBNS's body)
    pbns, ck = PBNS.load(store.pbns_path(cfg.outfit))
    first, _ = TaylorGarment.load(out, pbns)
    assert first.pbns.mlp[0].out_features == 64 and not first.correct_pose

    lost, stamps = kept[-1], {p: p.stat().st_mtime_ns for p in kept[:-1]}
    lost.unlink()
    build(cfg, out, log=lambda *_: None, progress=False)
    assert lost.exists() and all(p.stat().st_mtime_ns == t for p, t in stamps.items())
    again, _ = TaylorGarment.load(out, pbns)
    rot = poses(2)
    shape = ck["shape"]
    _, _, transforms = posed_bodies(body, rot, shape[None].expand(2, -1))
    x = first.set_shape(body, shape).pose(rot, transforms)
    assert x.shape == (2, len(pbns.rest), 3) and torch.isfinite(x).all()
    torch.testing.assert_close(again.set_shape(body, shape).pose(rot, transforms), x)


def test_an_evaluation_keeps_the_tables_of_outfits_it_did_not_evaluate(tmp_path, monkeypatch):
    """``recon garment eval --model taylor --outfit B`` adds B's table beside A's from an earlier
    run (and replaces B's own), the newton comparison of A kept too."""
    a, b = "tshirt-skirt", "top-shorts"
    (tmp_path / "garment-taylor.json").write_text(json.dumps(
        {"outfits": {a: {"run": 1}, b: {"run": 1}}, "speed": {}, "newton": {a: [{"pose": 0}]}}))
    monkeypatch.setattr(taylor_eval, "evaluate", lambda o, *args, **kw: {"run": 2})
    monkeypatch.setattr(taylor_eval, "speed", lambda *args, **kw: {"timed": True})
    monkeypatch.setattr(taylor_eval, "render", lambda data: json.dumps(data))
    taylor_eval.evaluate_and_report([b], out_dir=tmp_path, newton=False)
    data = json.loads((tmp_path / "garment-taylor.json").read_text())
    assert data["outfits"] == {a: {"run": 1}, b: {"run": 2}} and data["newton"] == {a: [{"pose": 0}]}
    assert data["speed"] == {b: {"timed": True}}
