"""Hand-checkable cases for the pose metrics."""
import math

import pytest
import roma
import torch

from recon import metrics


def test_mpjpe_root_aligned_known_value():
    gt = torch.zeros(1, 3, 3)
    gt[0, 1, 0], gt[0, 2, 1] = 1.0, 1.0
    pred = gt + torch.tensor([5.0, 5.0, 5.0])  # pure translation: zero after root alignment
    assert metrics.mpjpe(pred, gt) == pytest.approx(0.0, abs=1e-6)
    pred = gt.clone()
    pred[0, 2, 1] = 1.3  # one of three points off by 0.3
    assert metrics.mpjpe(pred, gt) == pytest.approx(0.1, abs=1e-6)


def test_procrustes_removes_rotation_scale_translation():
    torch.manual_seed(0)
    gt = torch.randn(4, 24, 3)
    r = roma.rotvec_to_rotmat(torch.tensor([[0.0, 0.0, math.pi / 3]] * 4))
    pred = 2.5 * gt @ r.transpose(-1, -2) + torch.tensor([1.0, -2.0, 0.5])
    assert metrics.pa_mpjpe(pred, gt) == pytest.approx(0.0, abs=1e-4)
    assert metrics.mpjpe(pred, gt) > 0.5


def test_group_errors_and_shape_check():
    err = torch.zeros(2, 24)
    err[:, 4] = 10.0  # left knee
    g = metrics.group_errors(err)
    assert g["knee"] == pytest.approx(5.0) and g["head"] == 0.0
    with pytest.raises(ValueError, match="must both be"):
        metrics.mpjpe(torch.zeros(1, 3, 3), torch.zeros(1, 4, 3))


def test_bone_length_error_per_sample():
    gt = torch.zeros(2, 24, 3)
    gt[:, 1:, 1] = torch.arange(1, 24, dtype=torch.float32)  # a vertical chain-like skeleton
    pred = gt.clone()
    pred[1] *= 2.0  # second sample: every joint twice as far from the origin
    per = metrics.bone_length_error(pred, gt, per_sample=True)
    assert per.shape == (2,) and per[0] == 0 and per[1] > 0
    assert metrics.bone_length_error(pred, gt) == pytest.approx(float(per.mean()))


def _walk(t=250, n=5, seed=0):
    """A person walking 3 m along x in the world: (T, N, 3) float64."""
    g = torch.Generator().manual_seed(seed)
    pose = torch.randn(n, 3, generator=g, dtype=torch.float64) * 0.3
    path = torch.stack([torch.linspace(0, 3, t, dtype=torch.float64), torch.zeros(t, dtype=torch.float64),
                        torch.zeros(t, dtype=torch.float64)], 1)
    return pose[None] + path[:, None]


def test_world_metrics_are_zero_up_to_a_similarity_and_see_drift_that_wa_aligns_away():
    gt = _walk()
    r = roma.rotvec_to_rotmat(torch.tensor([0.1, 0.7, -0.2], dtype=torch.float64))
    moved = 1.3 * gt @ r.T + torch.tensor([1.0, 2.0, -3.0], dtype=torch.float64)
    for f in (metrics.wa_mpjpe, metrics.w_mpjpe):
        err = f(moved, gt)
        assert err.shape == (250,) and err.dtype == torch.float64 and err.max() < 1e-9
    # a drift growing along the track: W-MPJPE (aligned on each chunk's first two frames) sees it
    # grow through every chunk; WA-MPJPE (each chunk aligned as a whole) removes most of it
    drift = gt + torch.linspace(0, 0.5, 250, dtype=torch.float64)[:, None, None] * torch.tensor([0.0, 0.0, 1.0],
                                                                                              dtype=torch.float64)
    w, wa = metrics.w_mpjpe(drift, gt), metrics.wa_mpjpe(drift, gt)
    assert w[99] > w[50] > w[2] and w[100] < w[99]  # each chunk starts aligned again
    assert wa.mean() < 0.5 * w.mean()


def test_root_trajectory_error_is_rigid_and_in_units_of_the_distance_travelled():
    gt = _walk()[:, 0]
    r = roma.rotvec_to_rotmat(torch.tensor([0.0, 1.2, 0.0], dtype=torch.float64))
    assert metrics.root_trajectory_error(gt @ r.T + 5.0, gt) < 1e-9  # rotated and moved: no error
    half = metrics.root_trajectory_error(0.5 * gt, gt)  # half the speed: scale is not aligned away
    # the best rigid fit centres the halved path on the true one: errors 0.75 m at the ends, 0 mid-way
    assert abs(float(half) - 0.75 / 2 / 3.0) < 0.01
    with pytest.raises(ValueError, match="root paths"):
        metrics.root_trajectory_error(gt[:, None], gt[:, None])
