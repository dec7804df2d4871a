"""The travelling camera's turn and move (recon.video.camera_travel), on exact matches: points of
the ground and of the far background seen by a camera walking sideways while it pans, each match
from a key frame as ``CameraRotations`` makes them, with a turn-only estimate that is off."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from recon.body import skeleton
from recon.video.camera_motion import TurnEstimate
from recon.video.camera_travel import camera_poses, ground_from_people, travelling_camera

K = np.array([[600.0, 0, 320], [0, 600.0, 240], [0, 0, 1]])
HEIGHT = 1.5  # m: the camera above the ground; the first camera's frame (OpenCV, y down) is the reference
FRAMES, STEP, PAN = 30, 0.03, 0.3  # frames, metres a frame to the right, degrees of pan a frame


def _cameras():
    """(T, 3, 3), (T, 3): X_f = R_f X_ref + t_f."""
    r = np.stack([Rotation.from_euler("y", PAN * f, degrees=True).as_matrix() for f in range(FRAMES)])
    centres = np.outer(np.arange(FRAMES) * STEP, [1.0, 0.0, 0.0])
    return r, -np.einsum("fij,fj->fi", r, centres)


def _project(x, r, t):
    y = x @ r.T + t
    uv = y @ K.T
    return uv[:, :2] / uv[:, 2:], y[:, 2] > 0.1


def _estimate(rng, key_every=8, noise_px=0.3):
    """Matches from key frames to each later frame: ground points (y = HEIGHT, 3-15 m ahead) and far
    points (directions, 1 km away), both in view; turns as a turn-only fit would find them (a
    little off, as when it takes in part of the move)."""
    r, t = _cameras()
    ground = np.stack([rng.uniform(-4, 5, 300), np.full(300, HEIGHT), rng.uniform(3, 15, 300)], 1)
    far = np.stack([rng.uniform(-0.6, 0.8, 100), rng.uniform(-0.4, -0.05, 100), np.ones(100)], 1) * 1000.0
    points = np.concatenate([ground, far])
    matches = []
    for b in range(1, FRAMES):
        a = (b - 1) // key_every * key_every
        pa, ina = _project(points, r[a], t[a])
        pb, inb = _project(points, r[b], t[b])
        keep = ina & inb & (np.abs(pa - [320, 240]) < [320, 240]).all(1) & (np.abs(pb - [320, 240]) < [320, 240]).all(1)
        matches.append((a, b, pa[keep] + rng.normal(0, noise_px, pa[keep].shape),
                        pb[keep] + rng.normal(0, noise_px, pb[keep].shape)))
    off = np.stack([Rotation.from_euler("y", 0.2 * f, degrees=True).as_matrix() for f in range(FRAMES)])
    est = TurnEstimate(off @ r, np.zeros(FRAMES, int), np.ones(FRAMES, bool), matches=matches)
    return est, r, t


def test_a_walking_camera_s_turn_and_move_come_from_the_ground_and_the_far_background():
    est, r_true, t_true = _estimate(np.random.default_rng(0))
    r, t = camera_poses(est, K, (np.array([0.0, -1.0, 0.0]), -HEIGHT))  # n . X = d, n up
    centres, true_centres = -np.einsum("fji,fj->fi", r, t), -np.einsum("fji,fj->fi", r_true, t_true)
    assert np.linalg.norm(centres - true_centres, axis=1).max() < 0.03 * STEP * FRAMES
    error = np.degrees(Rotation.from_matrix(r @ np.swapaxes(r_true, 1, 2)).magnitude())
    assert error.max() < 0.2 and np.degrees(Rotation.from_matrix(est.rotations[-1] @ r_true[-1].T).magnitude()) > 5


def test_the_people_s_feet_give_the_ground_and_so_the_move_s_scale():
    est, r_true, t_true = _estimate(np.random.default_rng(1))
    ref = np.tile([0.0, HEIGHT - 1.0, 4.0], (42, 1))  # someone standing 4 m ahead, pelvis 1 m up
    names = skeleton.JOINT_NAMES
    ref[names.index("neck")] = [0.0, HEIGHT - 1.5, 4.0]
    ref[names.index("left_foot")] = [-0.1, HEIGHT - 0.07, 4.0]
    ref[names.index("right_foot")] = [0.12, HEIGHT - 0.07, 4.3]
    points = np.einsum("fij,nj->fni", r_true, ref) + t_true[:, None]  # in each frame's camera
    n, d = ground_from_people(np.arange(FRAMES), points, r_true, t_true, 0.07, np.arange(FRAMES))
    assert n @ [0.0, -1.0, 0.0] > 0.999 and d == pytest.approx(-HEIGHT, abs=0.01)
    r, t, (n, d) = travelling_camera(est, K, np.arange(FRAMES), points, 0.07)
    assert d == pytest.approx(-HEIGHT, abs=0.05)
    centres, true_centres = -np.einsum("fji,fj->fi", r, t), -np.einsum("fji,fj->fi", r_true, t_true)
    assert np.linalg.norm(centres[-1] - true_centres[-1]) < 0.05 * np.linalg.norm(true_centres[-1])


def test_frames_no_match_reached_are_carried_on():
    est, r_true, t_true = _estimate(np.random.default_rng(2))
    est.matches = [m for m in est.matches if m[1] not in (11, 12)]
    r, t = camera_poses(est, K, (np.array([0.0, -1.0, 0.0]), -HEIGHT))
    assert not np.isnan(t).any() and not np.isnan(r).any()
    assert t[11, 0] == pytest.approx(t_true[11, 0], abs=0.02)
