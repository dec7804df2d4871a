"""Neural Cloth Simulation (thesis ch. 6): descriptors, the bias-free dynamic branch, inertia."""
import numpy as np
import pytest
import roma
import torch

from recon.body import skeleton
from recon.body.lbs import forward_kinematics
from recon.garment import ncs
from recon.garment.pbns import initial_weights
from recon.garment.templates import GarmentSpec, RestBody, make_outfit


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


def test_no_motion_no_dynamic_code(body):
    """A still pose: zero dynamic descriptors, so the bias-free branch gives a zero code and the
    output is the static model's at every frame."""
    rot, glob, joints = _sequence(body, t=1)
    rep = lambda x: x.expand(-1, 5, *x.shape[2:])  # noqa: E731
    s, d = ncs.descriptors(rep(rot), rep(glob), rep(joints))
    assert d.abs().max() == 0
    o = make_outfit(body, [GarmentSpec("skirt", "skirt")])
    w = initial_weights(RestBody(body), o)
    torch.manual_seed(0)
    model = ncs.NCS(torch.from_numpy(o.vertices), torch.from_numpy(o.faces), torch.from_numpy(w))
    with torch.no_grad():
        model.D.normal_(0, 1e-3)
        zs, zd, _ = model.codes(s, d)
        dt, _ = model.deformation(s, d)
    assert zd.abs().max() == 0
    assert torch.allclose(dt[:, 0], dt[:, -1])
    s2, d2 = ncs.descriptors(*_sequence(body))
    with torch.no_grad():
        moving, _ = model.deformation(s2, d2)
        still, _ = model.deformation(s2, d2, motion=0.0)  # motion control 0: the static model
        zs2, zd2, _ = model.codes(s2, d2)
    assert zd2.abs().max() > 0 and not torch.allclose(moving, still)
    assert torch.allclose(still, (zs2 @ model.D).view_as(still), atol=1e-6)


def test_gru_state_fades_when_motion_stops(body):
    o = make_outfit(body, [GarmentSpec("skirt", "skirt")])
    model = ncs.NCS(torch.from_numpy(o.vertices), torch.from_numpy(o.faces),
                    torch.from_numpy(initial_weights(RestBody(body), o)))
    s, d = ncs.descriptors(*_sequence(body, t=4))
    with torch.no_grad():
        _, _, h = model.codes(s, d)
        still = torch.zeros(1, 60, len(ncs.KEPT), 12)
        _, zd, _ = model.codes(s[:, -1:].expand(-1, 60, -1, -1), still, h)
    assert zd[0, -1].norm() < 0.05 * zd[0, 0].norm()


def test_inertia_is_zero_at_constant_velocity_and_never_looks_back():
    m = torch.tensor([0.5, 1.0])
    loss = ncs.InertiaLoss(m, fps=30.0)
    x0, x1 = torch.zeros(1, 2, 3), torch.full((1, 2, 3), 0.01)
    assert loss(2 * x1 - x0, x1, x0).abs().max() < 1e-12
    prev, prev2 = x1.clone().requires_grad_(), x0.clone().requires_grad_()
    x = torch.full((1, 2, 3), 0.05, requires_grad=True)
    v = loss(x, prev, prev2)
    v.sum().backward()
    assert prev.grad is None and prev2.grad is None and x.grad.abs().sum() > 0
    expected = 0.5 * 900 * (m * (3 * 0.03 ** 2)).sum()
    assert v.item() == pytest.approx(expected.item(), rel=1e-5)


def test_inertia_gradcheck_float64():
    m = torch.rand(5, dtype=torch.float64) + 0.1
    loss = ncs.InertiaLoss(m, fps=30.0)
    prev, prev2 = torch.randn(2, 5, 3, dtype=torch.float64), torch.randn(2, 5, 3, dtype=torch.float64)
    x = torch.randn(2, 5, 3, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda y: loss(y, prev, prev2), (x,))


def test_vertex_masses_sum_to_area_times_density():
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    m = ncs.vertex_masses(v, f, density=0.2)
    assert m.sum() == pytest.approx(0.2) and m[0] == pytest.approx(m[2]) and m[0] > m[1]
