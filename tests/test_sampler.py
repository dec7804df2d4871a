"""Pose and shape samplers, joint limits and the self-intersection test."""
import numpy as np
import pytest
import torch

from recon.body import lbs, skeleton
from recon.poses.collision import SelfIntersection
from recon.poses.sampler import JointLimits, PoseSampler, ShapeSampler

J = {n: i for i, n in enumerate(skeleton.JOINT_NAMES)}


@pytest.fixture(scope="module")
def sampler(body, mocap):
    return PoseSampler(body, mocap=mocap, seed=3)


def test_self_intersection_detects_arm_through_chest(body):
    si = SelfIntersection(body)
    assert si.penetration(torch.zeros(1, 24, 3)).item() == 0.0
    pose = torch.zeros(2, 24, 3)
    pose[0, J["left_shoulder"]] = torch.tensor([0.0, 0.0, -2.2])  # arm swung into the chest
    pose[1, J["left_hip"]] = torch.tensor([0.0, 0.0, -0.3])  # left thigh into the right one
    pose[1, J["right_hip"]] = torch.tensor([0.0, 0.0, 0.3])
    assert (~si.check(pose)).all()


def test_samples_are_float32_poses_inside_the_joint_limits(body, sampler):
    x = sampler.sample(300)
    assert x.shape == (300, 24, 3) and x.dtype == torch.float32
    assert sampler.limits.inside(x.double().numpy()).all()


def test_colliding_draws_are_redrawn_and_never_returned(body, sampler, monkeypatch):
    """The rejection loop: draws that self-intersect are replaced by later draws, in place."""
    bad = np.zeros((1, 24, 3))
    bad[0, J["left_shoulder"]] = [0.0, 0.0, -2.2]  # the arm through the chest
    good = np.zeros((1, 24, 3))
    good[0, J["left_elbow"]] = [0.0, 0.3, 0.0]
    draws = iter([np.concatenate([good, bad, good * 2]), bad, np.concatenate([good * 3])])
    monkeypatch.setattr(sampler, "_draw", lambda n: next(draws)[:n])
    x = sampler.sample(3).double().numpy()
    np.testing.assert_allclose(x, np.concatenate([good, good * 3, good * 2]), atol=1e-6)
    stuck = PoseSampler(body, mocap=sampler.poses, seed=0, max_rounds=2)
    monkeypatch.setattr(stuck, "_draw", lambda n: np.repeat(bad, n, 0))
    with pytest.raises(RuntimeError, match="still self-intersect"):
        stuck.sample(2)


def test_sampler_is_deterministic_by_seed(body, mocap):
    a = PoseSampler(body, mocap=mocap, seed=7).sample(50)
    b = PoseSampler(body, mocap=mocap, seed=7).sample(50)
    c = PoseSampler(body, mocap=mocap, seed=8).sample(50)
    assert torch.equal(a, b) and not torch.equal(a, c)


def test_limits_hold_out_test_subjects(mocap):
    """Limits come from train subjects only; held-out test frames must mostly respect them."""
    lim = JointLimits.from_poses(mocap.split("train").rotvec)
    inside = lim.inside(mocap.split("test").rotvec.astype(np.float64)).all(1)
    assert inside.mean() > 0.95
    rv = np.zeros((1, 24, 3))
    rv[0, J["left_knee"], 0] = np.radians(-90)  # knee bent forward: outside
    assert not lim.inside(rv)[0, J["left_knee"]]
    assert lim.inside(lim.clamp(rv)).all()


def test_mirror_is_an_involution():
    torch.manual_seed(0)
    r = lbs.as_rotmats(torch.randn(2, 24, 3), 24)
    assert torch.allclose(lbs.mirror_rotmats(lbs.mirror_rotmats(r, skeleton.JOINT_MIRROR), skeleton.JOINT_MIRROR), r)


def test_shape_sampler(body):
    s = ShapeSampler(body, seed=0).sample(500)
    assert s.shape == (500, 6) and (s >= 0).all() and (s <= 1).all()
    assert set(s[:, 0].unique().tolist()) == {0.0, 1.0}
    assert 0.4 < s[:, 0].mean() < 0.6
    assert torch.equal(s, ShapeSampler(body, seed=0).sample(500))
    dist = ShapeSampler(body, seed=0)._dist
    age = dist.morphological_age_mapping.anny_to_morphological_age(s[:, 1])
    assert age.min() >= 18 - 0.5 and age.max() <= 70 + 0.5
    heights = [float(o[:, 1].max() - o[:, 1].min()) for o in body(shape=s[:32]).vertices]
    assert 1.4 < min(heights) and max(heights) < 2.1
