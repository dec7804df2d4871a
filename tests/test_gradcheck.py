"""float64 gradchecks of every loss and layer gradients train through: skinning (forward
kinematics + LBS, and the body model), the volumetric loss and soft-argmax, the person-mask
term of the fit, and the PBNS energies. Analytical gradients must match finite differences."""
import copy

import numpy as np
import pytest
import roma
import torch
from torch.autograd import gradcheck

from recon.backbone.volumetric import soft_argmax_3d, volumetric_ce
from recon.body import lbs
from recon.fit import SilhouetteTarget
from recon.garment import losses
from recon.garment.mesh import nearest
from recon.garment.metrics import penetration

F64 = torch.float64


def test_forward_kinematics_and_skinning():
    g = torch.Generator().manual_seed(0)
    parents = (-1, 0, 1, 0, 3)
    rest_j = torch.randn(1, 5, 3, dtype=F64, generator=g)
    rest_v = torch.randn(1, 7, 3, dtype=F64, generator=g)
    w = torch.softmax(torch.randn(7, 5, dtype=F64, generator=g), -1)
    rotvec = (0.4 * torch.randn(1, 5, 3, dtype=F64, generator=g)).requires_grad_(True)

    def posed(rv, rj, rv_):
        _, joints, tf = lbs.forward_kinematics(roma.rotvec_to_rotmat(rv), rj, parents)
        return lbs.skin(rv_, w, tf), joints

    assert gradcheck(posed, (rotvec, rest_j.requires_grad_(True), rest_v.requires_grad_(True)))


@pytest.fixture(scope="module")
def body64(body):
    return copy.deepcopy(body).double()


def test_the_body_model_in_pose_and_shape(body64):
    """J+ of the anny body (its 18 landmark vertices skinned) against pose and phenotypes."""
    g = torch.Generator().manual_seed(1)
    pose = (0.3 * torch.randn(1, 24, 3, dtype=F64, generator=g)).requires_grad_(True)
    shape = (0.3 + 0.4 * torch.rand(1, 6, dtype=F64, generator=g)).requires_grad_(True)
    assert gradcheck(lambda p, s: body64(p, s, points_only=True).points, (pose, shape), atol=1e-5)


def test_volumetric_cross_entropy_and_soft_argmax():
    g = torch.Generator().manual_seed(2)
    logits = torch.randn(2, 3, 4, 5, 6, dtype=F64, generator=g, requires_grad=True)
    coords = torch.tensor([[[0.31, 0.52, 0.47], [0.12, 0.88, 0.6], [1.3, 0.5, 0.5]]] * 2, dtype=F64)
    assert gradcheck(lambda x: volumetric_ce(x, coords), (logits,))
    assert gradcheck(soft_argmax_3d, (logits,))


def test_the_person_mask_term():
    mask = np.zeros((40, 50), bool)
    mask[8:32, 15:35] = True
    target = SilhouetteTarget(mask, (15, 8, 35, 32), cover=0.3, dtype=F64)
    # points inside, outside and across the border, off the pixel grid (the sampled distance is bilinear)
    uv = torch.tensor([[20.3, 12.7], [10.4, 20.2], [38.6, 30.3], [24.2, 34.6], [33.7, 9.1]], dtype=F64,
                      requires_grad=True)
    assert gradcheck(target.outside, (uv,))
    assert gradcheck(target, (uv,))


@pytest.fixture(scope="module")
def sheet():
    n = 4
    x, y = np.meshgrid(np.linspace(0, 0.3, n), np.linspace(0, 0.3, n))
    v = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], 1)
    i = np.arange(n * n).reshape(n, n)
    a, b, c, d = i[:-1, :-1].ravel(), i[:-1, 1:].ravel(), i[1:, :-1].ravel(), i[1:, 1:].ravel()
    return torch.tensor(v, dtype=F64), np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])


def test_pbns_energies(sheet):
    rest, faces = sheet
    g = torch.Generator().manual_seed(3)
    v = (rest + 0.02 * torch.randn(2, *rest.shape, dtype=F64, generator=g)).requires_grad_(True)
    dt = (0.01 * torch.randn(2, *rest.shape, dtype=F64, generator=g)).requires_grad_(True)
    for energy in (losses.EdgeLoss(rest, faces), losses.BendLoss(faces), losses.GravityLoss()):
        energy = energy.double()
        assert gradcheck(energy, (v,)), type(energy).__name__
    assert gradcheck(losses.PinLoss(np.arange(len(rest)) < 4).double(), (dt,))


def test_the_collision_energy(sheet):
    """Body = the sheet itself with +Z normals; cloth points clearly in front, inside, or within
    eps of it (the energy's kink at eps is avoided)."""
    rest, faces = sheet
    body_v, body_n = rest[None], torch.tensor([0.0, 0.0, 1.0], dtype=F64).expand(1, len(rest), 3)
    cloth = torch.tensor([[[0.05, 0.05, -0.010], [0.1, 0.2, 0.03], [0.2, 0.1, 0.001], [0.25, 0.25, -0.02]]],
                         dtype=F64, requires_grad=True)
    coll = losses.CollisionLoss(np.zeros(4, int)).double()
    idx = nearest(body_v, cloth)
    assert gradcheck(lambda c: penetration(c, body_v, body_n, idx, 0.004), (cloth,))
    assert gradcheck(lambda c: coll(c, body_v, body_n, torch.from_numpy(faces[:2])), (cloth,))
