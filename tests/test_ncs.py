"""Neural Cloth Simulation (thesis ch. 6): descriptors, the bias-free dynamic branch, inertia, the
integration of the loss and the fitting of the network to it."""
import json

import numpy as np
import pytest
import roma
import torch
import trimesh
from gltf_check import assert_valid, pose_meshes

from recon.body import lbs, skeleton
from recon.body.lbs import forward_kinematics
from recon.errors import ReconError
from recon.export.glb import write_glb
from recon.garment import losses, store
from recon.garment.data import pose_set, posed_bodies
from recon.garment.dress import Dresser
from recon.garment.integrate import IntegrateConfig, Preconditioner, integrate, minimise, settle, unpose
from recon.garment.morph import outfit_animation
from recon.garment.ncs import model as ncs
from recon.garment.ncs.config import NCSTrainConfig
from recon.garment.ncs.data import (
    Motions,
    Teacher,
    ankle_taper,
    chunks_of,
    mirror_map,
    part_outfit,
    rest_joint_height,
    sound_chunks,
)
from recon.garment.ncs.losses import Contact, Fit, FreeMotion, Physics, StaticPoses, gram, principal_fields, project
from recon.garment.ncs.reference_eval import clip_motion, hem_vertices
from recon.garment.ncs.train import train
from recon.garment.pbns.model import PBNS, initial_weights, pose_features, trained_outfit
from recon.garment.templates import Garment, GarmentSpec, Outfit, RestBody, make_outfit
from recon.poses.mocap import MocapPoses


def _sequence(body, t=6, seed=0, yaw=0.0):
    """A random smooth motion (B=1, T) and its FK: local, global rotations, joint locations."""
    g = torch.Generator().manual_seed(seed)
    base, vel = 0.3 * torch.randn(24, 3, generator=g), 0.05 * torch.randn(24, 3, generator=g)
    rv = torch.stack([base + i * vel + 0.02 * i * i * vel for i in range(t)])
    rot = roma.rotvec_to_rotmat(rv)
    turn = roma.rotvec_to_rotmat(torch.tensor([0.0, yaw, 0.0]))
    rot[:, 0] = turn @ rot[:, 0]
    transl = torch.stack([torch.tensor([0.1 * i * i, 0.9, 0.05 * i]) for i in range(t)]) @ turn.T
    with torch.no_grad():
        rest_j = body().joints.expand(t, -1, -1)
    glob, joints, _ = forward_kinematics(rot, rest_j, skeleton.JOINT_PARENTS)
    joints = joints - joints[:, :1] + transl[:, None]
    return rot[None], glob[None], joints[None]


def test_descriptor_shapes_and_gravity(body):
    rot, glob, joints = _sequence(body)
    s, d = ncs.descriptors(rot, glob, joints)
    k = len(ncs.KEPT)
    assert k == 20 and s.shape == (1, 6, k, 9) and d.shape == (1, 6, k, 12)
    assert torch.allclose(s[..., 6:].norm(dim=-1), torch.ones(1, 6, k), atol=1e-5)  # unit gravity
    rest = torch.eye(3).expand(1, 1, 24, 3, 3)
    s0 = ncs.static_descriptors(rest, rest)
    assert torch.allclose(s0[0, 0, 0], torch.tensor([1.0, 0, 0, 0, 1, 0, 0, -1, 0]))  # identity; gravity -Y


def test_descriptors_do_not_see_the_heading(body):
    """Eq. 6.5's point: turning the whole motion about gravity changes no descriptor."""
    a = ncs.descriptors(*_sequence(body))
    b = ncs.descriptors(*_sequence(body, yaw=1.1))
    for x, y in zip(a, b):
        assert torch.allclose(x, y, rtol=1e-4, atol=2e-5 * float(x.abs().max()))


def _pose(rot: torch.Tensor) -> torch.Tensor:
    """PBNS's inputs (B, T, 216) of rotations (B, T, 24, 3, 3)."""
    return pose_features(rot.flatten(0, 1)).view(*rot.shape[:2], -1)


def _skirt_model(body, cfg=None, seed=0):
    o = make_outfit(body, [GarmentSpec("skirt", "skirt")])
    torch.manual_seed(seed)
    model = ncs.NCS(torch.from_numpy(o.vertices), torch.from_numpy(o.faces),
                    torch.from_numpy(initial_weights(RestBody(body), o)), cfg)
    with torch.no_grad():
        model.D.normal_(0, 1e-3)
    return o, model


def test_no_motion_no_dynamic_code(body):
    """A still pose: zero dynamic descriptors, so the bias-free branch gives a zero code and the
    output is the static model's at every frame."""
    rot, glob, joints = _sequence(body, t=1)
    rep = lambda x: x.expand(-1, 5, *x.shape[2:])  # noqa: E731
    s, d = ncs.descriptors(rep(rot), rep(glob), rep(joints))
    assert d.abs().max() == 0
    _, model = _skirt_model(body)
    with torch.no_grad():
        zs, zd, _ = model.codes(s, d, _pose(rep(rot)))
        dt, _ = model.deformation(s, d, _pose(rep(rot)))
    assert zd.abs().max() == 0
    assert torch.allclose(dt[:, 0], dt[:, -1])
    seq = _sequence(body)
    s2, d2 = ncs.descriptors(*seq)
    p2 = _pose(seq[0])
    with torch.no_grad():
        moving, _ = model.deformation(s2, d2, p2)
        still, _ = model.deformation(s2, d2, p2, motion=0.0)  # motion control 0: the static model
        zs2, zd2, _ = model.codes(s2, d2, p2)
    assert zd2.abs().max() > 0 and not torch.allclose(moving, still)
    assert torch.allclose(still, (zs2 @ model.D).view_as(still), atol=1e-6)


def test_the_dynamic_code_reaches_the_rows_after_pbns_only(body):
    """D = PBNS's rows, then ``NCSConfig.dynamic`` rows: the static code reaches all of them, the
    dynamic code (the GRU's width) the new ones alone; from_pbns copies PBNS's D, weights and MLP,
    whose code is the static code on PBNS's rows: NCS at motion control 0 with zero new rows is
    PBNS."""
    o, _ = _skirt_model(body)
    pbns = PBNS(torch.from_numpy(o.vertices), torch.from_numpy(o.faces),
                torch.from_numpy(initial_weights(RestBody(body), o)))
    with torch.no_grad():
        pbns.D.normal_(0, 1e-3)
    model = ncs.NCS.from_pbns(pbns, ncs.NCSConfig(dynamic=8))
    assert model.D.shape == (136, pbns.D.shape[1]) and torch.equal(model.D[:128], pbns.D)
    assert model.D[128:].abs().max() == 0 and model.gru.hidden_size == 8
    assert torch.allclose(model.weights, pbns.weights)
    with torch.no_grad():
        pbns.mlp[-2].bias.normal_()  # PBNS's codes differ from pose to pose
    model = ncs.NCS.from_pbns(pbns, ncs.NCSConfig(dynamic=8))
    seq = _sequence(body)
    s, d = ncs.descriptors(*seq)
    zs, zd, _ = model.codes(s, d, _pose(seq[0]))
    assert zs.shape[-1] == zd.shape[-1] == 136 and zd[..., :128].abs().max() == 0 and zd[..., 128:].abs().max() > 0
    assert torch.equal(zs[0, :, :128], pbns.mlp(pose_features(seq[0][0])))
    with torch.no_grad():
        static, _ = model.deformation(s, d, _pose(seq[0]), motion=0.0)
    assert torch.allclose(static[0], pbns.deformation(seq[0][0]), atol=1e-6)  # D's new rows are zero
    assert all(p.bias is None for m in (model.per_joint, model.dynamic) for p in m if isinstance(p, torch.nn.Linear))


def test_the_static_encoder_width_defaults_to_the_dynamic_one():
    """``static_hidden`` None (the files before it) builds the static encoder as wide as ``hidden``."""
    rest, faces, w = torch.zeros(4, 3), torch.tensor([[0, 1, 2], [0, 2, 3]]), torch.full((4, 24), 1 / 24)
    same = ncs.NCS(rest, faces, w, ncs.NCSConfig(hidden=16, dynamic=3))
    wide = ncs.NCS(rest, faces, w, ncs.NCSConfig(hidden=16, static_hidden=24, dynamic=3))
    assert [m.out_features for m in same.static if isinstance(m, torch.nn.Linear)] == [16, 16, 16, 3]
    assert [m.out_features for m in wide.static if isinstance(m, torch.nn.Linear)] == [24, 24, 24, 3]
    assert same.dynamic[0].out_features == wide.dynamic[0].out_features == 16


def test_decoding_without_gradients_skips_the_columns_the_new_rows_leave_still():
    """Inference applies D's new rows only where they are non-zero: the same displacements as the
    full product, and it follows changes to D."""
    g = torch.Generator().manual_seed(0)
    rest, faces, w = torch.zeros(6, 3), torch.tensor([[0, 1, 2], [3, 4, 5]]), torch.full((6, 24), 1 / 24)
    m = ncs.NCS(rest, faces, w, ncs.NCSConfig(embedding=4, dynamic=3))
    with torch.no_grad():
        m.D.copy_(torch.randn(7, 18, generator=g))
        m.D[4:, :9] = 0  # the first three vertices do not hang
    x = torch.randn(2, 5, 7, generator=g)
    full = (x @ m.D).view(2, 5, 6, 3)
    with torch.no_grad():
        assert torch.allclose(m.decode(x), full, atol=1e-6)
        assert m._new_rows()[0].tolist() == list(range(9, 18))
        m.D[4:, 0] = 1.0  # moved: cached columns follow
        assert torch.allclose(m.decode(x), (x @ m.D).view(2, 5, 6, 3), atol=1e-6)
    assert torch.allclose(m.decode(x), (x @ m.D).view(2, 5, 6, 3), atol=1e-6)  # with gradients: the full product


def test_gru_state_fades_when_motion_stops(body):
    _, model = _skirt_model(body)
    seq = _sequence(body, t=4)
    s, d = ncs.descriptors(*seq)
    p = _pose(seq[0])
    with torch.no_grad():
        _, _, h = model.codes(s, d, p)
        still = torch.zeros(1, 60, len(ncs.KEPT), 12)
        _, zd, _ = model.codes(s[:, -1:].expand(-1, 60, -1, -1), still, p[:, -1:].expand(-1, 60, -1), h)
    assert zd[0, -1].norm() < 0.05 * zd[0, 0].norm()


def test_the_dynamic_branch_keeps_a_gradient_when_every_hidden_unit_is_negative(body):
    """No biases: a hidden unit fed by the per-joint layers (outputs >= 0 under a ReLU) whose weights
    turn negative is off for every input, and with ReLUs the whole branch died in training (every
    hidden unit off, the dynamic code zero for good). The leaky activations keep a gradient."""
    _, model = _skirt_model(body)
    with torch.no_grad():
        model.dynamic[0].weight.copy_(-model.dynamic[0].weight.abs())
    s, d = ncs.descriptors(*_sequence(body, t=4))
    pj = model.per_joint(d).abs().detach()  # what ReLU per-joint layers would feed: >= 0
    assert (model.dynamic[0](pj.reshape(1, 4, -1))[:, 1:] < 0).all()  # every hidden unit below zero (frame 0: at rest)
    model.dynamic(pj.reshape(1, 4, -1)).square().sum().backward()
    assert model.dynamic[0].weight.grad.abs().max() > 0
    acts = [m for m in (*model.per_joint, *model.dynamic) if not isinstance(m, torch.nn.Linear)]
    assert acts and all(isinstance(m, torch.nn.LeakyReLU) for m in acts)


def test_inertia_is_zero_at_constant_velocity_and_never_looks_back():
    m = torch.tensor([0.5, 1.0])
    loss = losses.InertiaLoss(m, fps=30.0, cfg=losses.InertiaConfig(weight=1.0, keep_velocity=1.0))
    x0, x1 = torch.zeros(1, 2, 3), torch.full((1, 2, 3), 0.01)
    assert loss(2 * x1 - x0, x1, x0).abs().max() < 1e-12
    prev, prev2 = x1.clone().requires_grad_(), x0.clone().requires_grad_()
    x = torch.full((1, 2, 3), 0.05, requires_grad=True)
    v = loss(x, prev, prev2)
    v.sum().backward()
    assert prev.grad is None and prev2.grad is None and x.grad.abs().sum() > 0
    expected = 0.5 * 900 * (m / m.mean() * (3 * 0.03 ** 2)).mean()  # masses scaled to a mean of 1
    assert v.item() == pytest.approx(expected.item(), rel=1e-5)


def test_damping_acts_on_the_velocity_relative_to_the_carrying_motion():
    """keep_velocity damps the cloth's velocity relative to where the body carries it: cloth moving
    with the body projects on with it whatever the damping; relative motion keeps ``keep`` of itself;
    without a carrying motion the world frame is the reference."""
    loss = losses.InertiaLoss(torch.ones(1), cfg=losses.InertiaConfig(keep_velocity=0.9))
    x0, carry = torch.zeros(1, 3), torch.tensor([[0.03, 0.0, 0.0]])
    assert torch.allclose(loss.projection(x0 + carry, x0, carry), x0 + 2 * carry)
    swing = torch.tensor([[0.0, 0.0, 0.01]])
    assert torch.allclose(loss.projection(x0 + carry + swing, x0, carry), x0 + 2 * carry + 1.9 * swing)
    assert torch.allclose(loss.projection(x0 + swing, x0), x0 + 1.9 * swing)


def test_inertia_gradcheck_float64():
    m = torch.rand(5, dtype=torch.float64) + 0.1
    loss = losses.InertiaLoss(m, fps=30.0)
    prev, prev2 = torch.randn(2, 5, 3, dtype=torch.float64), torch.randn(2, 5, 3, dtype=torch.float64)
    carry = torch.randn(2, 5, 3, dtype=torch.float64)
    x = torch.randn(2, 5, 3, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda y: loss(y, prev, prev2, carry), (x,))


def test_vertex_masses_sum_to_area_times_density():
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    m = ncs.vertex_masses(v, f, density=0.2)
    assert m.sum() == pytest.approx(0.2) and m[0] == pytest.approx(m[2]) and m[0] > m[1]


def test_smoothing_keeps_still_motion_and_removes_jitter():
    x = torch.zeros(1, 40, 2, 3)
    assert torch.allclose(ncs.smooth_time(x + 1.5, 2.0), x + 1.5)  # constants stay (edges repeated)
    jitter = x.clone()
    jitter[:, ::2] = 0.01
    assert ncs.smooth_time(jitter, 2.0)[:, 5:-5].std() < 0.05 * jitter.std()


# --- the integration of the loss (recon.garment.integrate) -------------------------------------

class _Strip:
    """A hanging strip of cloth, 4 x 6 vertices 2 cm apart in the x-y plane, its top row held; what
    the energies read of an outfit."""

    def __init__(self):
        xs, ys = np.meshgrid(np.arange(4) * 0.02, -np.arange(6) * 0.02)
        self.vertices = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], 1)
        quads = [(r * 4 + c, r * 4 + c + 1, (r + 1) * 4 + c, (r + 1) * 4 + c + 1) for r in range(5) for c in range(3)]
        self.faces = np.array([f for a, b, c, d in quads for f in ((a, c, b), (b, c, d))])
        self.layer = np.zeros(len(self.vertices), np.int64)
        self.pinned = self.vertices[:, 1] > -0.001


def _strip_energies(gravity=5.0):
    o = _Strip()
    rest = torch.from_numpy(o.vertices).float()
    cfg = NCSTrainConfig(gravity=losses.GravityConfig(weight=gravity),
                         collision=losses.CollisionConfig(weight=0.0))
    crit = losses.Criterion(o, rest, cfg)
    inertia = losses.InertiaLoss(torch.from_numpy(ncs.vertex_masses(o.vertices, o.faces)), cfg=cfg.inertia)
    far = 10.0 + torch.rand(1, 20, 3, generator=torch.Generator().manual_seed(0))  # a body far away: no contact
    return o, rest, crit, inertia, far


def _hessian_solve(crit, inertia, x: torch.Tensor, held: torch.Tensor):
    """A random gradient g (zero at the held vertices), the exact Hessian of the edge and inertia
    energies at ``x`` (float64 autograd) applied inversely to it over the free coordinates, and
    those coordinates' indices."""
    def energy(flat):
        v = flat.view(1, -1, 3)
        return (crit.edge(v) + inertia.to_projection(v, x[None])).sum()

    h = torch.autograd.functional.hessian(energy, x.reshape(-1))
    free = np.nonzero(np.repeat(~held.numpy(), 3))[0]
    g = torch.randn(len(x), 3, dtype=torch.float64)
    g[held] = 0
    return g, torch.linalg.solve(h[free][:, free], g.reshape(-1)[free]), free


def test_preconditioner_is_the_springs_and_masses_hessian_when_every_edge_is_stretched():
    """With every edge in tension (and no floor across edges), ``Preconditioner.at`` factorises the
    exact Hessian of the edge and inertia energies (float64 autograd) over the free vertices."""
    o, rest, crit, inertia, _ = _strip_energies()
    held = torch.from_numpy(o.pinned)
    x = (rest * 1.05).double()  # stretched 5 %: every edge longer than its rest length
    pre = Preconditioner(crit, inertia, held.numpy(), across=0.0).at(x)
    crit_d, inertia_d = crit.double(), inertia.double()
    g, expected, free = _hessian_solve(crit_d, inertia_d, x, held)
    assert torch.allclose(pre.solve(g).reshape(-1)[free], expected, rtol=1e-6, atol=1e-12)
    assert pre.solve(g)[held].abs().max() == 0


def test_preconditioner_with_edges_as_stiff_across_is_constant_and_the_zero_length_springs_hessian():
    """``across`` = 1: every edge's block is k I, the Hessian of springs of rest length zero (float64
    autograd), at any state, without factorising again."""
    o, rest, crit, inertia, _ = _strip_energies()
    held = torch.from_numpy(o.pinned)
    pre = Preconditioner(crit, inertia, held.numpy(), across=1.0)
    crit_d, inertia_d = crit.double(), inertia.double()
    crit_d.edge.rest_len.zero_()
    x = rest.double() + 0.01 * torch.randn(rest.shape, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    g, expected, free = _hessian_solve(crit_d, inertia_d, x, held)
    lu = pre.constant
    assert pre.at(x) is pre and pre.at(rest * 1.3).constant is lu  # no new factorisation
    assert torch.allclose(pre.solve(g).reshape(-1)[free], expected, rtol=1e-6, atol=1e-12)
    assert pre.solve(g)[held].abs().max() == 0


def test_minimise_solves_a_quadratic_and_stops():
    """The preconditioned L-BFGS on a strictly convex quadratic reaches its minimum."""
    o, rest, crit, inertia, _ = _strip_energies()
    pre = Preconditioner(crit, inertia, o.pinned).at(rest)
    g = torch.Generator().manual_seed(0)
    a = torch.randn(len(rest) * 3, len(rest) * 3, generator=g, dtype=torch.float64)
    a = a @ a.T + len(a) * torch.eye(len(a), dtype=torch.float64)
    b = torch.randn(len(a), generator=g, dtype=torch.float64)
    free = torch.from_numpy(np.repeat(~o.pinned, 3))

    def energy(u):
        z = u.reshape(-1) * free
        return 0.5 * z @ a @ z - b @ z

    u = minimise(energy, torch.zeros(len(rest), 3, dtype=torch.float64), pre, IntegrateConfig(iterations=200))
    expected = torch.zeros(len(a), dtype=torch.float64)
    expected[free] = torch.linalg.solve(a[free][:, free], b[free])
    assert (u.reshape(-1)[free] - expected[free]).abs().max() < 1e-3 * expected.abs().max()


def test_minimise_takes_the_gradient_at_accepted_steps_only():
    """A line-search trial that is rejected costs the energy alone: on an energy whose full steps
    overshoot (a stiff quartic the preconditioner does not know), the gradient is taken once at the
    start and once per iteration, fewer times than the energy is evaluated."""
    o, rest, crit, inertia, _ = _strip_energies()
    pre = Preconditioner(crit, inertia, o.pinned).at(rest)
    free = torch.from_numpy(~o.pinned).double()[:, None]
    calls = {"energy": 0, "gradient": 0}

    def energy(u):
        calls["energy"] += 1
        f = 1e4 * ((u * free - 0.01) ** 4).sum() + (u * free).sum()
        f.register_hook(lambda g: calls.__setitem__("gradient", calls["gradient"] + 1))
        return f

    cfg = IntegrateConfig(iterations=10, step_tol=0.0)
    minimise(energy, torch.zeros(len(rest), 3, dtype=torch.float64), pre, cfg)
    assert calls["gradient"] == cfg.iterations + 1
    assert calls["energy"] > calls["gradient"]


def test_integration_keeps_momentum_damps_relative_motion_and_settles_under_gravity():
    """No force but inertia: cloth carried at a constant velocity stays with the carrier, and cloth
    at rest stays. Under gravity a held strip settles where the energies' forces balance."""
    o, rest, crit, inertia, far = _strip_energies(gravity=0.0)
    held = torch.from_numpy(o.pinned)
    t = 6
    carry = torch.tensor([0.01, 0.0, 0.0])
    carried = rest[None] + torch.arange(t)[:, None, None] * carry
    body_v, body_n = far.expand(t, -1, -1), torch.tensor([0.0, 1.0, 0.0]).expand(t, 20, 3)
    x = integrate(crit, inertia, held, carried, carried, body_v, body_n)
    assert torch.allclose(x, carried, atol=1e-6)
    still = rest[None].expand(t, -1, -1)
    assert torch.allclose(integrate(crit, inertia, held, still, still, body_v, body_n), still, atol=1e-6)
    o, rest, crit, inertia, far = _strip_energies(gravity=5.0)
    hung = settle(crit, inertia, held, rest, rest, far[0], body_n[0], 60)
    force = torch.autograd.functional.jacobian(
        lambda v: crit(v[None], torch.zeros_like(v)[None], far, body_n[:1]).sum(), hung)
    assert hung[~held, 1].mean() < rest[~held, 1].mean() - 1e-4  # it hangs lower
    assert force[~held].norm(dim=-1).max() < 0.05 * crit.gravity.cfg.weight / len(rest)


def test_unpose_inverts_the_skinning_rotation(body):
    o, model = _skirt_model(body)
    rot = _sequence(body, t=2)[0][0]
    transforms = body(rot, body.mean_shape.expand(2, -1), points_only=True).transforms
    du = 0.01 * torch.randn(len(o.vertices), 3)
    posed = model.skin(model.rest + du, transforms) - model.skin(model.rest, transforms)
    blend = (model.weights @ transforms.reshape(2, 24, 12)).view(2, -1, 3, 4)[..., :3]
    assert torch.allclose(unpose(blend, posed), du.expand(2, -1, -1), atol=1e-6)
    assert torch.allclose(unpose(blend, posed, 0.2), du.expand(2, -1, -1), atol=1e-6)  # no blend near singular


def test_unpose_bounds_a_near_singular_blend():
    """Clamping the singular values keeps an offset through a near-singular blend within 1 / s_min
    of its size (the exact inverse flings it), and inverts the well-conditioned directions exactly."""
    blend = torch.diag(torch.tensor([1.0, 0.5, 1e-5], dtype=torch.float64))
    rot = roma.rotvec_to_rotmat(torch.tensor([0.3, -0.2, 0.5], dtype=torch.float64))
    blend = rot @ blend @ rot.T
    offset = torch.tensor([0.01, 0.02, 0.03], dtype=torch.float64)
    assert unpose(blend, offset).norm() > 100
    du = unpose(blend, offset, 0.2)
    assert du.norm() <= offset.norm() / 0.2 + 1e-12
    good = rot[:, :2] @ (rot[:, :2].T @ offset)  # the offset's part in the well-conditioned plane
    assert torch.allclose(blend @ unpose(blend, good, 0.2), good, atol=1e-12)


# --- fitting the network (recon.garment.ncs.train) ----------------------------------------------

def test_principal_fields_are_mass_orthogonal_and_project_back():
    g = torch.Generator().manual_seed(0)
    n, k = 50, 3
    masses = torch.rand(n, generator=g) + 0.5
    true = torch.randn(k, n, 3, generator=g)
    coef = torch.randn(4, 20, k, generator=g)
    du = torch.einsum("ctk,knj->ctnj", coef, true)
    fields = principal_fields(du, masses, k)
    c = project(du, fields, masses)
    assert torch.allclose(torch.einsum("ctk,knj->ctnj", c, fields), du, atol=1e-4)  # spans the data
    assert c.abs().max() == pytest.approx(0.5, rel=1e-4)
    gm = gram(fields.reshape(k, -1), masses)
    assert (gm - torch.diag(torch.diagonal(gm))).abs().max() < 1e-4 * torch.diagonal(gm).min()


def test_mirror_map_pairs_the_sides_of_a_symmetric_mesh():
    v = np.array([[-0.1, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.5, 0.1], [-0.2, 0.3, 0.0], [0.2, 0.3, 0.0]])
    m = mirror_map(v)
    assert m.tolist() == [1, 0, 2, 4, 3] and (m[m] == np.arange(len(v))).all()


def test_chunks_stay_in_their_clips_and_mirror_back(body):
    chunks = chunks_of("val", 30, 6, seed=0)
    assert len(chunks) == 6 and chunks == chunks_of("val", 30, 6, seed=0)
    m = MocapPoses.load("val")
    for c in chunks:
        assert c.start + c.frames <= (m.clip == c.clip).sum()
    starts = {(c.clip, c.start) for c in chunks}
    assert len(starts) == 6 and all(s % 30 == 0 for _, s in starts)  # non-overlapping
    motions = Motions(body, body.mean_shape, smooth=1.5)
    rot, tr = motions.motion(chunks[0])
    s, d, p = motions.inputs(chunks[0])
    assert rot.shape == (30, 24, 3, 3) and tr[0, [0, 2]].abs().max() == 0
    assert s.shape == (30, len(ncs.KEPT), 9) and d.shape == (30, len(ncs.KEPT), 12)
    assert torch.equal(p, pose_features(rot))  # PBNS's inputs, frame by frame
    stopped = chunks[0]._replace(stop=12)  # the body stops dead at the chunk's frame 12
    rot_s, tr_s = motions.motion(stopped)
    s_s, d_s, p_s = motions.inputs(stopped)
    assert torch.equal(rot_s[:13], rot[:13]) and (rot_s[12:] == rot_s[12]).all() and (tr_s[12:] == tr_s[12]).all()
    assert torch.equal(p_s, pose_features(rot_s))
    assert torch.allclose(s_s[:10], s[:10], atol=1e-5) and d_s[-8:].abs().max() < 1e-4 * d.abs().max()
    assert any(c.stop for c in chunks_of("train", 120, 20, seed=0, stops=0.5, lead=20))
    assert all(30 <= c.stop <= 90 for c in chunks_of("train", 120, 20, seed=0, stops=0.5, lead=20) if c.stop)
    rot_m, tr_m = motions.motion(chunks[0], mirror=True)
    assert torch.allclose(tr_m, tr * torch.tensor([-1.0, 1.0, 1.0]), atol=1e-6)
    again = lbs.mirror_rotmats(rot_m, skeleton.JOINT_MIRROR)
    assert torch.allclose(again, rot, atol=1e-5)


def test_fit_loss_is_zero_at_the_teacher_and_trains_both_branches(body):
    """``Fit``: no miss where the codes on the new rows equal the teacher's coefficients; its
    gradient reaches the static encoder and the dynamic branch."""
    _, model = _skirt_model(body, ncs.NCSConfig(hidden=16, joint_features=4, dynamic=3))
    seq = _sequence(body, t=8)
    inputs = (*ncs.descriptors(*seq), _pose(seq[0]))
    with torch.no_grad():
        zs, zd, _ = model.codes(*inputs)
    coef = (zs + zd)[..., 128:]
    fit = Fit(model, inputs, coef, torch.eye(3), lead=2)
    loss, terms = fit((torch.zeros(1, dtype=torch.long),))
    assert loss.item() < 1e-10
    fit.coef = coef + 0.1
    loss, terms = fit((torch.zeros(1, dtype=torch.long),))
    loss.backward()
    assert terms["teacher_mm"] > 0
    assert model.static[0].weight.grad.abs().sum() > 0 and model.gru.weight_hh_l0.grad.abs().sum() > 0


def _skirt_pbns(body, folder):
    """A skirt's PBNS with small random blend shapes, saved as ``folder``/pbns_skirt.pt: (the model read
    back, the file's extra entries)."""
    torch.manual_seed(0)
    o = make_outfit(body, [GarmentSpec("skirt", "skirt")])
    pbns = PBNS(torch.from_numpy(o.vertices), torch.from_numpy(o.faces),
                torch.from_numpy(initial_weights(RestBody(body), o)))
    with torch.no_grad():
        pbns.D.normal_(0, 1e-3)
    extra = {"meta_json": json.dumps({"garments": ["skirt"]}), "layer": torch.zeros(len(o.vertices)),
             "garment_id": torch.zeros(len(o.vertices), dtype=torch.long), "shape": body.mean_shape}
    pbns.save(folder / "pbns_skirt.pt", extra)
    return PBNS.load(folder / "pbns_skirt.pt")[0], extra


def test_animated_glb_holds_the_dynamic_model(body, tmp_path):
    """A dynamic Dresser: the .glb's morph targets are NCS's D and its weights NCS's codes, so the
    file poses the outfit as ``Dresser.animate`` does (which differs from PBNS frame by frame)."""
    _skirt_pbns(body, tmp_path)
    path = tmp_path / "pbns_skirt.pt"
    dresser = Dresser(path=path, resolve_collisions=False)
    assert not dresser.dynamic
    dresser.garment.ncs = ncs.NCS.from_pbns(dresser.model)
    with torch.no_grad():
        dresser.garment.ncs.D[128:].normal_(0, 1e-3)  # the rows the dynamic code reaches
    rot, glob, joints = _sequence(body, t=5)
    transl = joints[0, :, 0] - joints[0, :1, 0] + torch.tensor([0.0, 0.9, 0.0])
    glb = write_glb(tmp_path / "a.glb", body, body.mean_shape, rot[0], transl, 30.0,
                    outfit_animation(body, body.mean_shape, rot[0], transl, dresser, 30.0, influences=None),
                    influences=None)  # every influence: the file's cloth is the Dresser's exactly
    assert_valid(glb)
    moving = dresser.animate(body, rot[0], body.mean_shape, transl).vertices
    dresser_static = Dresser(path=path, resolve_collisions=False)
    still = dresser_static.animate(body, rot[0], body.mean_shape, transl).vertices
    posed = pose_meshes(glb, 4)["outfit"]
    assert np.abs(posed - moving[4]).max() < 1e-4
    assert np.abs(moving[4] - still[4]).max() > 1e-3  # NCS is not PBNS here


def test_an_ncs_file_keeps_only_what_it_adds_to_its_pbns_and_loads_back_the_same(body, tmp_path):
    """Beside its PBNS file, an NCS file stores its encoders and D's new rows where they are not
    zero; loading completes it from the PBNS file: the same state, bit for bit. A PBNS retrained
    since is refused; an NCS saved elsewhere, or trained apart from its PBNS, is stored whole."""
    pbns, extra = _skirt_pbns(body, tmp_path)
    model = ncs.NCS.from_pbns(pbns, ncs.NCSConfig(dynamic=4))
    with torch.no_grad():
        model.D[128:, :300].normal_(0, 1e-3)  # the new rows move a part only
    model.save(tmp_path / "ncs_skirt.pt", extra, pbns_path=tmp_path / "pbns_skirt.pt")
    raw = torch.load(tmp_path / "ncs_skirt.pt", weights_only=True)
    assert "D" not in raw["state"] and raw["state"]["D_new_rows"].shape == (4, 300)
    assert "rest" not in raw["state"] and "layer" not in raw
    loaded, ck = ncs.NCS.load(tmp_path / "ncs_skirt.pt")
    want = {k: v.half() if k == "D" else v for k, v in model.state_dict().items()}
    got = loaded.state_dict()
    assert want.keys() == got.keys() and all(torch.equal(want[k].to(got[k].dtype), got[k]) for k in want)
    assert torch.equal(ck["garment_id"], extra["garment_id"]) and ck["meta_json"] == extra["meta_json"]
    whole = tmp_path / "elsewhere"
    whole.mkdir()
    model.save(whole / "ncs_skirt.pt", extra, pbns_path=tmp_path / "pbns_skirt.pt")
    assert "D" in torch.load(whole / "ncs_skirt.pt", weights_only=True)["state"]
    with torch.no_grad():
        pbns.D.add_(1e-3)  # PBNS retrained after NCS
    pbns.save(tmp_path / "pbns_skirt.pt", extra)
    with pytest.raises(ReconError, match="trained on another pbns_skirt.pt"):
        ncs.NCS.load(tmp_path / "ncs_skirt.pt")
    model.save(tmp_path / "ncs_skirt.pt", extra, pbns_path=tmp_path / "pbns_skirt.pt")  # D's rows differ now
    assert "D" in torch.load(tmp_path / "ncs_skirt.pt", weights_only=True)["state"]


def test_a_network_trained_at_15_fps_dresses_a_30_fps_motion(body, tmp_path):
    """The Dresser resamples the motion to the network's rate and interpolates its codes back: at
    the shared frames (every second one) the codes are those of the network run at 15 fps."""
    pbns, _ = _skirt_pbns(body, tmp_path)
    dresser = Dresser(path=tmp_path / "pbns_skirt.pt", resolve_collisions=False)
    dresser.garment.ncs = ncs.NCS(pbns.rest, pbns.faces, pbns.weights.detach(), ncs.NCSConfig(fps=15.0))
    rot, _, joints = _sequence(body, t=9)
    transl = joints[0, :, 0] - joints[0, :1, 0]
    _, z30 = dresser.sequence_codes(body, rot[0], body.mean_shape, transl, fps=30.0)
    _, z15 = dresser.sequence_codes(body, rot[0, ::2], body.mean_shape, transl[::2], fps=15.0)
    assert z30.shape == (9, 160) and z15.shape == (5, 160)
    assert torch.allclose(z30[::2], z15, atol=1e-5)
    assert torch.allclose(z30[1], 0.5 * (z15[0] + z15[1]), atol=1e-5)


def test_hem_is_the_lowest_boundary_ring_and_held_clips_stop_dead():
    tube = trimesh.creation.cylinder(radius=0.3, height=0.5, sections=24)
    tube = trimesh.Trimesh(tube.vertices, tube.faces[np.abs(tube.face_normals[:, 2]) < 0.5])  # open ends
    v = tube.vertices[:, [0, 2, 1]]  # the axis along +Y
    hem = hem_vertices(v, tube.faces)
    assert len(hem) == 24 and np.allclose(v[hem, 1], v[:, 1].min())
    rot, tr = clip_motion(MocapPoses.load("test"), "12_01", 10, 5, hold=3)
    assert rot.shape == (8, 24, 3, 3) and torch.equal(rot[4], rot[7]) and torch.equal(tr[4], tr[7])
    assert tr[0, [0, 2]].abs().max() == 0  # the first frame's pelvis above the origin


def test_ankle_taper_holds_the_cuffs_of_trousers_and_nothing_of_a_skirt(body):
    """``ankle_taper``: 0 up to the rest ankles + hold, then linear to 1 over as much again; the
    shipped trousers' cuffs are held, the skirt's hem (above the knees) is untouched; hold 0: all 1."""
    shape = body.mean_shape
    ankle = rest_joint_height(body, shape, "left_ankle", "right_ankle")
    points = np.zeros((5, 3), np.float32)
    points[:, 1] = ankle + np.array([-0.1, 0.05, 0.12, 0.2, 0.5])
    np.testing.assert_allclose(ankle_taper(body, shape, points, 0.08), [0.0, 0.0, 0.5, 1.0, 1.0], atol=1e-4)
    assert (ankle_taper(body, shape, points, 0.0) == 1).all()
    for name, held in (("tshirt-trousers", True), ("tshirt-skirt", False)):
        outfit, s, _ = trained_outfit(body, store.pbns_path(name))
        assert ((ankle_taper(body, s, outfit.vertices, 0.08) == 0).any()) == held


def test_pinned_garments_hang_from_their_pins_an_unpinned_outfit_from_its_top_or_below_its_waist():
    class Stack:  # two garments stacked in y; what ncs.hanging_part reads of an outfit
        vertices = np.stack([np.zeros(8), np.linspace(0.0, 0.7, 8), np.zeros(8)], 1)
        garment_id = np.array([0, 0, 0, 0, 1, 1, 1, 1])
        pinned = np.zeros(8, bool)

    skirt = Stack()
    skirt.pinned = np.array([0, 0, 0, 1, 0, 0, 0, 0], bool)  # garment 0 hangs from a pin
    sub, held = ncs.hanging_part(skirt)
    assert sub.tolist() == [True] * 4 + [False] * 4 and held.tolist() == skirt.pinned.tolist()
    sub, held = ncs.hanging_part(Stack())  # nothing pinned: all of it, held at each garment's top
    top = np.array([3, 7])
    assert sub.all() and np.nonzero(held)[0].tolist() == top.tolist()
    assert np.diff(Stack.vertices[:, 1])[0] > ncs.SHOULDER_BAND  # the next vertex down is free
    sub, held = ncs.hanging_part(Stack(), waist=0.29)  # NCS's: below the waist, held within the band above it
    assert np.nonzero(sub)[0].tolist() == [0, 1, 2, 3] and np.nonzero(held)[0].tolist() == [3]
    assert Stack.vertices[3, 1] < 0.29 + ncs.WAIST_BAND < Stack.vertices[4, 1]
    assert ncs.hanging_part(skirt, waist=0.29)[1].tolist() == skirt.pinned.tolist()  # pins hold what has them


def test_part_outfit_cuts_garments_to_the_vertices_with_their_faces():
    strip = _Strip()  # 4 x 6 vertices, row-major from the top
    outfit = Outfit([Garment("a", strip.vertices, strip.faces, 0, strip.pinned),
                     Garment("b", strip.vertices + 1.0, strip.faces, 1, np.zeros(24, bool))])
    lower = np.arange(8, 24)  # garment a's lowest four rows
    part = part_outfit(outfit, lower)
    assert [g.name for g in part.garments] == ["a"] and np.array_equal(part.vertices, strip.vertices[lower])
    assert len(part.faces) == 3 * 3 * 2 and not part.pinned.any()  # the quads between the rows kept
    assert np.array_equal(lower[part.faces], strip.faces[(strip.faces >= 8).all(1)])  # same triangles
    whole = part_outfit(outfit, np.arange(24, 48))
    assert [g.name for g in whole.garments] == ["b"] and np.array_equal(whole.faces, strip.faces)


def test_motion_codes_run_the_network_at_its_own_rate(body):
    """A 15-fps NCS dressing a 30-fps motion steps at 15 fps: its codes at the even frames are those
    of the network run on every second frame (the motion resampled), the odd ones interpolated."""
    o = make_outfit(body, [GarmentSpec("skirt", "skirt")])
    torch.manual_seed(0)
    model = ncs.NCS(torch.from_numpy(o.vertices), torch.from_numpy(o.faces),
                    torch.from_numpy(initial_weights(RestBody(body), o)), ncs.NCSConfig(fps=15.0))
    rot = _sequence(body, t=9)[0][0]
    shape = body.mean_shape
    z30 = sum(model.motion_codes(body, rot, shape, fps=30.0))
    z15 = sum(model.motion_codes(body, rot[::2], shape, fps=15.0))
    assert z30.shape == (9, 160) and torch.allclose(z30[::2], z15, atol=1e-5)
    assert torch.allclose(z30[1], 0.5 * (z15[0] + z15[1]), atol=1e-5)


def test_physics_is_the_loss_against_the_solved_past_and_trains_the_network(body):
    """``Physics`` on the shipped tshirt-skirt, the previous states solved by the integrator: along
    the line from PBNS's drape through the solved state at a frame, the loss is lowest near the
    solved state (the solver minimised it; its stopping and the nearest-vertex contacts leave it
    inexact). And the loss trains both branches of a network."""
    cfg = NCSTrainConfig(settle=2, integrate=IntegrateConfig(iterations=30))
    teacher = Teacher(body, "tshirt-skirt", cfg)
    chunk = chunks_of("val", 6, 1, seed=0)[0]
    motions = Motions(body, teacher.shape, cfg.smooth_motion)
    rot, tr = motions.motion(chunk)
    off = teacher(rot, tr)[None]  # (1, 6, n, 3): the solved posed offsets from PBNS's drape
    du, _ = teacher.rest_displacement(rot, tr, off[0])
    inputs = motions.inputs(chunk)
    pbns, _ = PBNS.load(store.pbns_path("tshirt-skirt"))
    model = ncs.NCS.from_pbns(pbns, ncs.NCSConfig(hidden=16, joint_features=4, dynamic=1))
    field = torch.zeros(len(pbns.rest), 3)
    field[teacher.idx] = du[5]
    with torch.no_grad():
        model.D[128] = field.reshape(-1)  # one new row: the solved displacement at frame 5
        pbns_code = pbns.mlp(pose_features(rot[5:6]))
    physics = Physics(model, teacher, [(rot, tr)], off, [x[None] for x in inputs])
    one = torch.zeros(1, dtype=torch.long)
    with torch.no_grad():
        energies = [float(physics.energy(one, torch.tensor([5]), torch.cat([pbns_code, torch.tensor([[a]])], 1))[0])
                    for a in (0.0, 0.5, 0.9, 1.0, 1.1, 1.5)]
    assert min(energies[2:5]) < min(energies[0], energies[1], energies[5])
    loss, terms = physics(one, torch.tensor([[3, 5]]))
    loss.backward()
    assert torch.isfinite(loss) and terms["physics_edge_mm"] > 0
    assert model.static[0].weight.grad.abs().sum() > 0 and model.gru.weight_ih_l0.grad.abs().sum() > 0


@pytest.mark.slow
def test_training_writes_a_model_whose_new_rows_move_the_hanging_part(body, tmp_path):
    """``train`` on the shipped tshirt-skirt with a tiny budget: chunks integrated in two worker
    processes, kept for a rerun; the saved model decodes PBNS's D on PBNS's rows, its new rows
    move the skirt's free vertices and nothing else (the physics steps train them, there only),
    and the checkpoint the fitting keeps (with the contact term on; its best on the val chunks: a
    tiny model on two chunks over-fits, so where its last step lands depends on the CPU's last bits)
    beats coding nothing there; the physics steps score the static poses and the free windows."""
    cfg = NCSTrainConfig(chunk=12, settle=2, lead=2, chunks=2, val_chunks=1, integrate=IntegrateConfig(iterations=3),
                         steps=24, model=ncs.NCSConfig(hidden=32, joint_features=8, dynamic=4),
                         contact_weight=100.0, physics_steps=8, static_poses=8, static_batch=2, free_windows=1,
                         free_batch=1, free_frames=2, field_lr=1e-3)
    meta = train(body, cfg, out=tmp_path / "n.pt", log=lambda *_: None, progress=False)
    model, _ = ncs.NCS.load(tmp_path / "n.pt")
    pbns, _ = PBNS.load(store.pbns_path("tshirt-skirt"))
    assert meta["moving_vertices"] < meta["vertices"] == len(model.rest)
    assert torch.equal(model.D[:len(pbns.D)], pbns.D)
    assert all(torch.equal(a, b) for a, b in zip(model.pbns_mlp.state_dict().values(), pbns.mlp.state_dict().values()))
    moved = model.D[len(pbns.D):].view(4, -1, 3).abs().sum((0, 2)) > 0
    hanging, held = map(torch.from_numpy, ncs.hanging_part(trained_outfit(body, store.pbns_path("tshirt-skirt"))[0]))
    assert not moved[~hanging].any() and moved[hanging & ~held].all()  # held (pinned) vertices follow skinning
    assert meta["field_change_mm"] > 0  # the physics steps trained the fields, on the hanging part only
    last = meta["curve"][-1]
    assert meta["best"] == min(c["val_teacher_mm"] for c in meta["curve"])
    assert meta["best"] < last["val_zero_mm"] and 0 <= last["val_contact_pct"] <= 100
    physics = meta["physics_curve"][-1]
    assert 0 <= physics["val_static_collision_pct"] <= 100 and 0 <= physics["free_collision_pct"] <= 100
    assert not (tmp_path / ".n.run").exists()


def test_update_keeps_the_other_outfits_rows(tmp_path, monkeypatch):
    """``evaluate_and_report(update=True)`` replaces the evaluated outfit's rows where they were,
    keeps the rest of the existing table and adds a new outfit's at its end; without it the table
    holds only what was evaluated."""
    from recon.garment.ncs import eval as E
    monkeypatch.setattr(E, "evaluate", lambda body, o, *a, **k: {"outfit": o, "rows": {"new": True}})
    monkeypatch.setattr(E, "ncs_check", lambda names: {n: {} for n in names})
    monkeypatch.setattr(E, "render", lambda data: "table")
    (tmp_path / "garment-ncs.json").write_text(json.dumps({"outfits": [
        {"outfit": "tshirt-skirt", "rows": {"new": False}}, {"outfit": "dress", "rows": {"new": False}}]}))
    E.evaluate_and_report(None, ["top-shorts", "tshirt-skirt"], tmp_path, update=True)
    data = json.loads((tmp_path / "garment-ncs.json").read_text())
    assert [(r["outfit"], r["rows"]["new"]) for r in data["outfits"]] == [
        ("tshirt-skirt", True), ("dress", False), ("top-shorts", True)]
    assert sorted(data["check"]["values"]) == ["dress", "top-shorts", "tshirt-skirt"]
    E.evaluate_and_report(None, ["tshirt-skirt"], tmp_path)
    assert [r["outfit"] for r in json.loads((tmp_path / "garment-ncs.json").read_text())["outfits"]] == ["tshirt-skirt"]


def test_a_failed_solved_chunk_is_told_apart(body):
    """``Teacher.rest_displacement`` gives a chunk's largest edge strain: a cloth whose vertex is
    flung 10 cm out of the mesh strains its edges past ``max_strain``; PBNS's drape itself does
    not. Training drops a chunk past the limit, or NaN."""
    cfg = NCSTrainConfig()
    teacher = Teacher(body, "tshirt-skirt", cfg)
    rot, tr = Motions(body, teacher.shape, cfg.smooth_motion).motion(chunks_of("val", 3, 1, seed=0)[0])
    offset = torch.zeros(3, len(teacher.idx), 3)
    _, calm = teacher.rest_displacement(rot, tr, offset)
    offset[1, 100] = torch.tensor([0.0, -0.1, 0.0])
    du, torn = teacher.rest_displacement(rot, tr, offset)
    assert calm < cfg.max_strain < torn and du.shape == offset.shape
    assert sound_chunks([calm, torn, float("nan")], cfg.max_strain) == [True, False, False]


def test_contact_measures_how_far_the_new_rows_push_the_cloth_into_the_body():
    """``Contact``: the new rows' displacement posed on PBNS's drape, against the nearest of the
    body vertices given per cloth vertex (their normal). A drape 1 cm out costs nothing; a code pushing one of two
    vertices 2 cm in (through a blend that turns rest x into posed y) costs (eps + 1 cm)^2 / 2 and counts
    50 % inside, with a gradient that pulls the code back; the same code on the field turned outwards costs
    nothing (the fields are read as they are at each call)."""
    static = torch.tensor([[0.0, 0.01, 0.0], [0.0, 0.01, 0.0]]).expand(1, 1, 2, 3)
    turn = torch.tensor([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # rest x -> posed y
    blend = turn.expand(1, 1, 2, 3, 3)
    body_v = torch.tensor([[0.0, 0.0, 0.0], [5.0, 0.0, 0.0]]).expand(1, 1, 2, 3)  # the second far away
    body_n = torch.tensor([0.0, 1.0, 0.0]).expand(1, 1, 2, 3)
    candidates = torch.tensor([0, 1]).expand(1, 1, 2, 2)
    field = torch.tensor([[[-0.02, 0.0, 0.0], [0.0, 0.0, 0.0]]])  # rest -x: posed -y, into the body
    now = {"fields": field}  # what D's new rows are at the time of the call
    contact = Contact(torch.tensor([3]), static, blend, body_v, body_n, candidates, lambda: now["fields"], eps=0.004)
    i, slots = torch.zeros(1, dtype=torch.long), torch.zeros(1, 1, dtype=torch.long)
    z = torch.zeros(1, 5, 1)
    pen, inside = contact(i, slots, z)
    assert pen == 0 and inside == 0
    z = torch.zeros(1, 5, 1)
    z[0, 3] = 1.0
    z.requires_grad_(True)
    pen, inside = contact(i, slots, z)
    assert torch.isclose(pen, torch.tensor((0.004 + 0.01) ** 2 / 2)) and inside == 50
    pen.backward()
    assert z.grad[0, 3, 0] > 0 and z.grad[0, :3].abs().sum() == 0
    # the fields are read at each call (the physics steps train them): pushed out, nothing inside
    now["fields"] = -field
    pen, inside = contact(i, slots, z.detach())
    assert pen == 0 and inside == 0


def _inward_row(model, teacher, depth=0.03):
    """A new row of D that shrinks the skirt's free vertices ``depth`` m towards the vertical axis
    through its waist's centre, in the rest pose: a code of 1 on it pushes the skirt into the legs."""
    e = model.cfg.embedding
    rest = model.rest[teacher.idx]
    radial = rest - rest.mean(0)
    radial[:, 1] = 0
    row = torch.zeros_like(model.rest)
    row[teacher.idx] = -depth * radial / radial.norm(dim=1, keepdim=True).clamp_min(1e-6)
    row[teacher.idx[teacher.held]] = 0
    with torch.no_grad():
        model.D[e] = row.reshape(-1)
    return e


def test_static_poses_score_the_static_part_by_pbns_loss(body):
    """``StaticPoses``: PBNS's loss (the whole outfit's energies) of NCS's static prediction, exact
    nearest contacts up to the candidates' search; a static code pushing the skirt into the legs
    raises the loss and the collision %, and the loss reaches the static encoder only."""
    torch.manual_seed(0)
    cfg = NCSTrainConfig()
    teacher = Teacher(body, "tshirt-skirt", cfg)
    outfit, _, _ = trained_outfit(body, store.pbns_path("tshirt-skirt"))
    pbns, _ = PBNS.load(store.pbns_path("tshirt-skirt"))
    model = ncs.NCS.from_pbns(pbns, ncs.NCSConfig(hidden=16, joint_features=4, dynamic=1))
    row = _inward_row(model, teacher) - model.cfg.embedding  # a new row for the static encoder's code to move
    rot = pose_set("train", 4, 0.5, 0)
    still = StaticPoses(model, outfit, cfg, body, teacher.shape, rot, unit=2.0)
    i = torch.arange(4)
    loss, terms = still(i)
    with torch.no_grad():
        dt = model.decode(model.static_code(still.static, still.pose))
        v = model.skin(model.rest + dt, still.bt)
        expected = still.crit(v, dt, still.bv, still.bn, still.body_c, still.cloth_c).mean() / 2.0
        exact = still.crit(v, dt, still.bv, still.bn).mean() / 2.0
    assert torch.isclose(loss, expected, rtol=1e-4) and torch.isclose(loss, exact, rtol=0.02)
    loss.backward()
    assert model.static[0].weight.grad.abs().sum() > 0 and model.gru.weight_ih_l0.grad is None
    with torch.no_grad():  # PBNS's drape, then the row's code 1
        model.static[-1].weight.zero_()
        model.static[-1].bias.zero_()
        loss, terms = still(i)
        model.static[-1].bias[row] = 1.0
        pushed, pushed_terms = still(i)
    assert pushed > loss and pushed_terms["static_collision_pct"] > terms["static_collision_pct"] + 1


def test_free_motion_holds_any_motion_to_collision_edge_and_pins(body):
    """``FreeMotion`` on a window no teacher solved: the collision, edge and pin energies of the
    whole prediction (no gravity: lowering the cloth rigidly changes nothing but the contacts); a
    code pushing the skirt into the legs raises it, and it trains the dynamic branch."""
    torch.manual_seed(0)
    cfg = NCSTrainConfig()
    teacher = Teacher(body, "tshirt-skirt", cfg)
    pbns, _ = PBNS.load(store.pbns_path("tshirt-skirt"))
    model = ncs.NCS.from_pbns(pbns, ncs.NCSConfig(hidden=16, joint_features=4, dynamic=1))
    chunk = chunks_of("train", 8, 1, seed=3)[0]
    motions = Motions(body, teacher.shape, cfg.smooth_motion)
    inputs = [x[None] for x in motions.inputs(chunk)]
    free = FreeMotion(model, teacher, inputs, [motions.motion(chunk)], unit=2.0)
    row = _inward_row(model, teacher) - model.cfg.embedding  # set before the loss: the dynamic code moves the cloth
    one, frames = torch.zeros(1, dtype=torch.long), torch.tensor([[4, 7]])
    loss, terms = free(one, frames)
    with torch.no_grad():
        zs, zd, _ = model.codes(*inputs)
        dt = model.decode((zs + zd)[0, [4, 7]])
        rot, tr = motions.motion(chunk)
        bv, bn, transforms = posed_bodies(body, rot[[4, 7]], teacher.shape, transl=tr[[4, 7]])
        x = model.skin(model.rest + dt, transforms)[:, teacher.idx]
        crit = teacher.crit
        expected = (crit.edge(x) + crit.collision(x, bv, bn, crit.faces) + crit.pin(dt[:, teacher.idx])).mean() / 2
    assert torch.isclose(loss, expected, rtol=1e-3)
    assert 0 <= terms["free_collision_pct"] <= 100 and terms["free_edge_mm"] > 0
    loss.backward()
    assert model.gru.weight_ih_l0.grad.abs().sum() > 0
    with torch.no_grad():  # PBNS's drape, then the row's code 1
        model.dynamic[-1].weight.zero_()
        model.static[-1].weight.zero_()
        model.static[-1].bias.zero_()
        loss, terms = free(one, frames)
        model.static[-1].bias[row] = 1.0
        pushed, pushed_terms = free(one, frames)
    assert pushed > loss and pushed_terms["free_collision_pct"] > terms["free_collision_pct"] + 1
