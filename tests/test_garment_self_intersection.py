import numpy as np
import pytest
import roma
import torch

from recon.body import JOINT_NAMES
from recon.garment.metrics import physical_metrics
from recon.garment.pbns import eval as E
from recon.garment.self_intersection import SkinSelfIntersection


@pytest.fixture(scope="module")
def self_intersection(body):
    return SkinSelfIntersection(body)


def _posed(body, rotvecs: dict[str, list[float]], batch_of=None):
    r = body.identity_pose(1).clone()
    for name, rv in rotvecs.items():
        r[0, JOINT_NAMES.index(name)] = roma.rotvec_to_rotmat(torch.tensor(rv))
    return body(r, body.mean_shape[None]).vertices


def test_rest_pose_is_free_and_deep_flexion_is_not(body, self_intersection):
    rest = _posed(body, {})
    assert self_intersection.percent(rest).item() == 0.0  # rest contacts are excluded by construction
    # thigh raised into the belly: about -X, the leg swings to +Z, the front (recon.body.skeleton frames)
    flexed = _posed(body, {"left_hip": [-2.3, 0.0, 0.0]})
    mild = _posed(body, {"left_hip": [-0.4, 0.0, 0.0]})
    both = torch.cat([flexed, mild])
    p_flexed, p_mild = self_intersection.percent(both).tolist()
    assert p_flexed > 1.0 and p_mild < p_flexed
    assert (self_intersection._inside(both, chunk=1) == self_intersection._inside(both)).all()  # chunks are independent
    mask = self_intersection(flexed)[0]
    assert mask.shape == (body.num_vertices,) and mask.dtype == torch.bool
    # the intersecting skin is around the left hip / pelvis, not the head or the right arm
    bone = body.weights.argmax(1)
    names = {JOINT_NAMES[j] for j in bone[mask].unique().tolist()}
    assert names & {"left_hip", "pelvis", "spine1"} and not names & {"head", "right_elbow"}


def test_collision_is_binned_by_body_self_intersection():
    rest = torch.tensor([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    faces = [[0, 1, 2], [1, 3, 2]]
    body_v, body_n = rest[None].repeat(3, 1, 1), torch.tensor([0.0, 0.0, 1.0]).expand(3, 4, 3)
    cloth = body_v + torch.tensor([0.0, 0.0, 0.01])
    cloth[2, :2, 2] = -0.01  # half the cloth inside the body in the third pose only
    m = physical_metrics(cloth, np.array(faces), rest, body_v, body_n, torch.tensor([0.0, 0.5, 7.0]))
    bins = m["by_body_self_intersection"]
    assert bins["0-1"]["poses"] == 2 and bins["0-1"]["collision_pct"] == 0.0
    assert bins["1-3"] == {"poses": 0, "collision_pct": None, "edge_mm": None}
    assert bins["3-100"]["poses"] == 1 and bins["3-100"]["collision_pct"] == 50.0
    assert bins["0-1"]["edge_mm"] == pytest.approx(0, abs=1e-4) and bins["3-100"]["edge_mm"] > 0
    assert m["collision_pct"] == pytest.approx(50.0 / 3)


def test_eval_computes_the_body_self_intersection_once_per_shape_and_poses(body, monkeypatch):
    calls = []
    real = E.SkinSelfIntersection.percent
    monkeypatch.setattr(E.SkinSelfIntersection, "percent", lambda self, v: calls.append(1) or real(self, v))
    monkeypatch.setattr(E, "_self_cache", {})
    rot = body.identity_pose(2).clone()
    rot[1, JOINT_NAMES.index("left_hip")] = roma.rotvec_to_rotmat(torch.tensor([-2.3, 0.0, 0.0]))
    shape = body.mean_shape[None]
    with torch.no_grad():
        bv = body(rot, shape.expand(2, -1)).vertices
    a = E.body_self_intersection(body, shape, rot, bv)
    b = E.body_self_intersection(body, shape, rot, bv)  # the next outfit: same shape and poses
    assert len(calls) == 1 and b is a and a[0] == 0.0 and a[1] > 1.0
    E.body_self_intersection(body, shape, rot[:1], bv[:1])  # other poses: computed again
    assert len(calls) == 2


def test_valid_test_poses_drop_the_poses_where_the_body_passes_through_itself(body, monkeypatch):
    rot = body.identity_pose(3).clone()
    rot[1, JOINT_NAMES.index("left_hip")] = roma.rotvec_to_rotmat(torch.tensor([-2.3, 0.0, 0.0]))  # thigh in belly
    rot[2, JOINT_NAMES.index("left_elbow")] = roma.rotvec_to_rotmat(torch.tensor([0.0, 0.3, 0.0]))  # harmless
    monkeypatch.setattr(E, "pose_set", lambda split, n, d, seed: rot)
    monkeypatch.setattr(E, "_self_cache", {})
    shape = body.mean_shape[None]
    kept, (bv, bn, bt) = E.valid_test_poses(body, shape)
    assert torch.equal(kept, rot[[0, 2]])
    assert bv.shape == (2, body.num_vertices, 3) and bn.shape == bv.shape and len(bt) == 2
    with torch.no_grad():
        # float noise only: a batch of 3 and one of 2 take other kernel paths (measured 2e-7 m on an Intel Xeon)
        assert torch.allclose(bv, body(kept, shape.expand(2, -1)).vertices, atol=1e-6)
