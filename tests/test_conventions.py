"""Frames, units, left/right and the mirror map (documented in recon/body/skeleton.py)."""
import numpy as np
import torch

from recon.body import lbs, skeleton

J = {n: i for i, n in enumerate(skeleton.JOINT_NAMES)}
L = {n: i for i, n in enumerate(skeleton.LANDMARK_NAMES)}


def test_frame_is_y_up_z_forward_x_left_in_metres(body):
    out = body()
    v, j, lm = out.vertices[0], out.joints[0], out.landmarks[0]
    height = float(v[:, 1].max() - v[:, 1].min())
    assert 1.4 < height < 2.1  # metres
    assert j[J["head"], 1] > j[J["pelvis"], 1] > j[J["left_ankle"], 1]  # +Y up
    assert lm[L["nose"], 2] > j[J["head"], 2] + 0.05  # faces +Z
    assert lm[L["left_toe_tip"], 2] > j[J["left_ankle"], 2]
    for name in skeleton.JOINT_NAMES:
        if name.startswith("left_"):
            assert j[J[name], 0] > 0.01 and j[J[name.replace("left", "right")], 0] < -0.01  # +X left
    assert torch.allclose(j[J["pelvis"]], torch.zeros(3))


def test_rotation_sign_convention(body):
    """Right-hand rule in world-aligned rest axes: +X flexes the knee, +Z raises the left arm."""
    rest = body()
    p = torch.zeros(1, 24, 3)
    p[0, J["left_knee"], 0] = 1.0
    assert body(p).joints[0, J["left_ankle"], 2] < rest.joints[0, J["left_ankle"], 2] - 0.2
    p = torch.zeros(1, 24, 3)
    p[0, J["left_shoulder"], 2] = 1.0
    assert body(p).joints[0, J["left_wrist"], 1] > rest.joints[0, J["left_wrist"], 1] + 0.2


def test_tables_are_consistent():
    assert len(skeleton.JOINT_NAMES) == 24 and len(skeleton.LANDMARK_NAMES) == 18
    assert len(skeleton.KINTREE_PLUS) == 42
    assert all(p < i for i, p in enumerate(skeleton.KINTREE_PLUS))  # parents first
    for mirror, names in ((skeleton.JOINT_MIRROR, skeleton.JOINT_NAMES), (skeleton.POINT_MIRROR, skeleton.POINT_NAMES)):
        assert all(mirror[mirror[i]] == i for i in range(len(mirror)))
        for i, m in enumerate(mirror):
            a, b = names[i], names[m]
            assert a == b or {a.split("_")[0], b.split("_")[0]} == {"left", "right"}
    grouped = sum(skeleton.JOINT_GROUPS.values(), ())
    assert sorted(grouped) == sorted(skeleton.JOINT_NAMES)


def test_mirrored_pose_gives_mirrored_mesh(body):
    mm = torch.as_tensor(body.mirror_vertex_map())
    assert len(torch.unique(mm)) == body.num_vertices
    flip = torch.tensor([-1.0, 1.0, 1.0])
    torch.manual_seed(0)
    rot = lbs.as_rotmats(0.4 * torch.randn(3, 24, 3), 24)
    a = body(rot)
    b = body(lbs.mirror_rotmats(rot, skeleton.JOINT_MIRROR))
    assert (a.vertices[:, mm] * flip - b.vertices).norm(dim=-1).max() < 1e-4
    assert (a.points[:, list(skeleton.POINT_MIRROR)] * flip - b.points).norm(dim=-1).max() < 1e-4


def test_landmarks_are_plausible(body):
    out = body()
    j, lm = out.joints[0], out.landmarks[0]
    for i, (name, parent) in enumerate(skeleton.LANDMARKS):
        assert (lm[i] - j[J[parent]]).norm() < 0.3, name
    for name in ("head_top", "nose", "chest", "upper_back", "belly", "sacrum"):
        assert abs(float(lm[L[name], 0])) < 0.03, name
    assert lm[L["head_top"], 1] >= out.vertices[0, :, 1].max() - 1e-6
    assert lm[L["chest"], 2] > 0 > lm[L["upper_back"], 2]
    assert lm[L["left_knee_front"], 2] > j[J["left_knee"], 2]
    assert len(set(body.landmark_indices.tolist())) == 18
    np.testing.assert_array_equal(body.landmark_indices.numpy(), body.landmark_indices.numpy())
