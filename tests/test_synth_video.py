"""The synthetic clips' moving cameras (recon.synth.video): their truth is the camera the frames
were drawn by, and the background turns with it."""
import numpy as np
import pytest

from recon import camera
from recon.synth.video import CAMERAS, Actor, ClipRenderer, ClipSpec, ClipTruth, camera_path, far_background
from recon.video.camera_motion import CameraRotations


@pytest.mark.parametrize("kind", CAMERAS)
def test_each_camera_path_is_a_world_to_camera_per_frame(kind):
    n = 30
    path = np.stack([np.linspace(-1, 1, n), np.full(n, 0.9), np.zeros(n)], 1)
    spec = ClipSpec("c", (Actor("x"),), n, 0, camera=kind)
    r, t = camera_path(spec, np.array([0.0, 1.5, 5.0]), np.array([0.0, 1.0, 0.0]), path, np.random.default_rng(0))
    assert r.shape == (n, 3, 3) and t.shape == (n, 3)
    assert np.allclose(r @ np.swapaxes(r, 1, 2), np.eye(3), atol=1e-9) and np.allclose(np.linalg.det(r), 1)
    centres = -np.einsum("fji,fj->fi", r, t)  # each frame's camera centre in the world
    moved = np.linalg.norm(centres - centres[0], axis=1).max()
    turned = np.degrees(np.arccos(np.clip((np.trace(r @ r[0].T, axis1=1, axis2=2) - 1) / 2, -1, 1))).max()
    low, high = {"walk": (1.4, 1.6), "handheld": (0.005, 0.07)}.get(kind, (0.0, 1e-9))  # metres the camera moved
    assert low <= moved <= high, moved
    assert (turned < 1e-6) if kind == "static" else (turned > 1.0), turned
    with pytest.raises(ValueError):
        camera_path(ClipSpec("c", (Actor("x"),), n, 0, camera="dolly"), np.zeros(3), np.ones(3), path,
                    np.random.default_rng(0))


def test_the_far_background_turns_with_the_camera():
    """A point of the canvas seen in two frames lies where the turn between them takes it."""
    rng = np.random.default_rng(1)
    canvas = (rng.random((2000, 2000, 3)) * 255).astype(np.uint8)
    k = np.array([[600.0, 0, 320], [0, 600.0, 240], [0, 0, 1]])
    r0 = np.eye(3)
    r1 = np.array([[np.cos(0.1), 0, np.sin(0.1)], [0, 1, 0], [-np.sin(0.1), 0, np.cos(0.1)]])
    a, b = far_background(canvas, k, r0, r0), far_background(canvas, k, r0, r1)
    assert np.array_equal(a, canvas[760:1240, 680:1320])  # the canvas's middle, unturned
    d = np.linalg.inv(k) @ [300.0, 200.0, 1.0]  # a direction in frame 0's camera
    uv = camera.project((r1 @ d)[None], k)[0]
    x, y = np.round(uv).astype(int)
    assert np.abs(b[y, x].astype(int) - a[200, 300].astype(int)).max() <= 40  # bilinear sampling, near


def test_a_moving_clip_s_truth_matches_its_frames(body):
    spec = ClipSpec("t", (Actor("12_01", 20),), 8, seed=7, distance=3.5, camera="handheld")
    frames, truth = ClipRenderer(body).render(spec)
    assert truth.R.shape == (8, 3, 3) and truth.t.shape == (8, 3)
    world = truth.joints_world[0]
    assert np.allclose(np.einsum("fij,fnj->fni", truth.R, world) + truth.t[:, None], truth.joints[0], atol=1e-9)
    found = CameraRotations(truth.K)((f, None) for f in frames).rotations  # the person is small: left in
    err = [np.degrees(np.arccos(np.clip((np.trace(a @ (r @ truth.R[0].T).T) - 1) / 2, -1, 1)))
           for a, r in zip(found, truth.R, strict=True)]
    assert max(err) < 0.5, err


def test_a_clip_truth_stored_with_one_camera_loads_with_one_per_frame(tmp_path):
    f = 3
    truth = ClipTruth(K=np.eye(3), R=np.eye(3), t=np.ones(3), joints=np.zeros((1, f, 24, 3)),
                      points=np.zeros((1, f, 42, 3)), vertices=np.zeros((1, f, 5, 3), np.float16),
                      joints_world=np.zeros((1, f, 24, 3)), pose=np.zeros((1, f, 24, 3), np.float32),
                      shape=np.zeros((1, 4), np.float32), visible=np.ones((1, f), bool))
    truth.save(tmp_path / "old.npz")
    back = ClipTruth.load(tmp_path / "old.npz")
    assert back.R.shape == (f, 3, 3) and np.allclose(back.t, 1.0)
