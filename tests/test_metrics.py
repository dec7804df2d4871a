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
