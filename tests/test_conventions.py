"""Frames, units, left/right and the mirror map (documented in recon/body/skeleton.py), and the
camera frames (recon/camera.py)."""
import numpy as np
import pytest
import roma
import torch

from recon import camera
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
    # left and right landmarks are each other's mirror vertices; midline ones are their own
    mm = body.mirror_vertex_map()
    idx = body.landmark_indices.numpy()
    for i, m in enumerate(skeleton.POINT_MIRROR[24:]):
        assert mm[idx[i]] == idx[m - 24], skeleton.LANDMARK_NAMES[i]


def test_the_view_frame_is_the_opencv_frame_turned_half_about_x():
    x = np.array([[0.3, -0.2, 2.0], [-1.0, 0.5, 4.0]])
    v = camera.to_view(x)
    np.testing.assert_array_equal(v, x * [1, -1, -1])  # y up, z towards the viewer
    np.testing.assert_array_equal(camera.to_opencv(v), x)  # its own inverse
    t = torch.tensor(x, dtype=torch.float32)
    assert torch.equal(camera.to_view(t), torch.tensor(v, dtype=torch.float32))
    half = roma.rotvec_to_rotmat(torch.tensor([np.pi, 0.0, 0.0], dtype=torch.float64)).numpy()
    np.testing.assert_allclose(camera.HALF_TURN_X, half, atol=1e-12)
    # a rotation into the view frame, turned into the OpenCV frame, maps body points to to_opencv(view points)
    r = roma.rotvec_to_rotmat(torch.tensor([0.3, -1.1, 0.2], dtype=torch.float64)).numpy()
    np.testing.assert_allclose(x @ camera.rotation_to_opencv(r).T, camera.to_opencv(x @ r.T), atol=1e-12)


def test_a_subject_facing_the_camera_stands_upright_in_the_image(body):
    """Body frame -> OpenCV camera for a camera in front of the subject: its head projects
    above its feet, its left hand to the image's right (the subject faces us)."""
    out = body()
    pts = (out.points[0].double().numpy() @ camera.HALF_TURN_X.T) + [0.0, 0.0, 3.0]
    uv = camera.project(pts, camera.default_intrinsics(480, 640))
    j = {n: uv[i] for i, n in enumerate(skeleton.JOINT_NAMES)}
    assert j["head"][1] < j["pelvis"][1] < j["left_ankle"][1]  # rows grow downwards
    assert j["left_hand"][0] > j["right_hand"][0]


def test_projection_placement_and_bone_depth_are_consistent():
    k = np.array([[500.0, 0, 320], [0, 450.0, 240], [0, 0, 1]])
    rng = np.random.default_rng(0)
    pts = rng.normal(0, 0.3, (42, 3)) + [0.2, -0.1, 4.0]
    uv = camera.project(pts, k)
    np.testing.assert_allclose(uv, (pts @ k.T)[:, :2] / pts[:, 2:], atol=1e-9)
    np.testing.assert_allclose(camera.unproject(uv, pts[:, 2], k), pts, atol=1e-12)
    # placing the pelvis-relative points by their projections recovers the translation
    t = camera.place(pts - pts[:1], uv, k)
    np.testing.assert_allclose(t, pts[0], atol=1e-9)
    assert camera.default_intrinsics(480, 640)[0, 0] == 640 and camera.default_intrinsics(480, 640, 2.0)[1, 1] == 1280
    w = camera.in_image_weights(np.array([[10.0, 10.0], [-5.0, 10.0], [639.0, 479.0], [640.0, 0.0]]), (480, 640))
    assert w.tolist() == [1.0, 0.1, 1.0, 0.1]


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_projection_is_differentiable_and_batched(dtype):
    k = torch.tensor([[[500.0, 0, 320], [0, 450.0, 240], [0, 0, 1]]] * 2, dtype=dtype)
    p = (torch.rand(2, 5, 3, dtype=dtype) + torch.tensor([0.0, 0.0, 2.0], dtype=dtype)).requires_grad_(True)
    uv = camera.project(p, k)
    assert uv.shape == (2, 5, 2) and uv.dtype == dtype
    uv.sum().backward()
    assert torch.isfinite(p.grad).all() and (p.grad[..., 2] < 0).all()  # farther points move towards the centre
    torch.testing.assert_close(camera.unproject(uv, p[..., 2], k), p)
