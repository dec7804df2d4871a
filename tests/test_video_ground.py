"""A clip's people on one ground, in one world frame (recon.video.ground, recon.video.world)."""
import numpy as np
import pytest

from recon.body import skeleton
from recon.video.ground import FOOT_POINTS, NECK, common_ground, ground_height, planted_feet
from recon.video.smooth import TrackMotion
from recon.video.world import FittedTrack, one_world

CAMERA_HEIGHT = 1.5  # the ground is y = +1.5 in the camera frame (OpenCV: y down)
SOLE = 0.06
FOOT = skeleton.JOINT_NAMES.index("left_foot")


def _standing(x: float, z: float, frames: int = 20, depth_off: float = 1.0) -> TrackMotion:
    """A person standing at (x, z), feet planted every frame, placed ``depth_off`` times too far
    (as a wrong body size places them)."""
    pts = np.zeros((frames, 42, 3))
    pts[:, :, :] = [x, CAMERA_HEIGHT - 0.9, z]  # every point at the pelvis ...
    pts[:, NECK, 1] = CAMERA_HEIGHT - 1.4  # ... the neck above it ...
    for side in ("left", "right"):
        for j in FOOT_POINTS[side]:
            pts[:, j, 1] = CAMERA_HEIGHT - SOLE  # ... the feet on the ground
    pts *= depth_off
    ground = (np.array([0.0, -1.0, 0.0]), -depth_off * (CAMERA_HEIGHT - SOLE) - SOLE)
    rot = np.tile(np.eye(3), (frames, 24, 1, 1))
    return TrackMotion(rot, pts[:, 0].copy(), pts[:, :24], pts, np.ones((frames, 2), bool), ground, SOLE)


def _fitted(track_id: int, m: TrackMotion) -> FittedTrack:
    return FittedTrack(track_id, 0, np.ones(len(m.points), bool), np.zeros(3), m, None, None)


def _feet_height(m, src: TrackMotion) -> np.ndarray:
    """The world height of ``src``'s left foot joint, its body placed as the world motion ``m`` says."""
    r, o = m.to_world
    placed = src.points[:, FOOT] - src.translation + m.to_reference(m.translation)  # a rigid body moved
    return ((placed - o) @ r.T)[:, 1]


def test_planted_feet_are_the_foot_joints_of_the_planted_frames():
    m = _standing(0.0, 5.0, frames=4)
    m.planted[1:, 0] = False
    feet = planted_feet(m.points, m.planted)
    assert len(feet) == 1 + 4  # the left foot in frame 0, the right one in all four
    assert np.allclose(feet[:, 1], CAMERA_HEIGHT - SOLE)


def test_the_common_ground_lies_between_the_tracks_own_grounds():
    near, far = _standing(-1.0, 5.0), _standing(1.0, 5.0, depth_off=1.1)
    n, d = common_ground([(m.points, m.planted, m.ground) for m in (near, far)], [SOLE, SOLE])
    assert n == pytest.approx([0, -1, 0], abs=1e-6)
    assert far.ground[1] < d < near.ground[1]  # the far one's own ground lies lower (y down)
    over = [ground_height(m.points, m.planted, (n, d), SOLE) for m in (near, far)]
    assert over[0] > 0 > over[1]
    assert over[0] - over[1] == pytest.approx(near.ground[1] - far.ground[1], abs=1e-9)
    assert ground_height(near.points, np.zeros_like(near.planted), (n, d), SOLE) == 0.0  # nothing planted
    assert common_ground([(near.points[:1], near.planted[:1] & [True, False], near.ground)], [SOLE]) is None


def test_every_track_is_written_in_one_world_frame_standing_on_one_ground():
    a, b = _standing(-1.0, 5.0), _standing(1.0, 5.0, depth_off=1.1)
    motions = one_world([_fitted(1, a), _fitted(2, b)])
    (r1, o1), (r2, o2) = (m.to_world for m in motions)
    assert np.array_equal(r1, r2) and np.array_equal(o1, o2)
    assert r1[1] == pytest.approx([0, -1, 0], abs=1e-6)  # +Y up
    for m, src in zip(motions, (a, b), strict=True):  # each foot joint its sole's height over the ground
        assert _feet_height(m, src) == pytest.approx(SOLE, abs=1e-6)
    # moved up or down only: across and in depth they stand where they were placed
    between = motions[1].translation[0] - motions[0].translation[0]
    truth = b.translation[0] - a.translation[0]
    assert between[[0, 2]] == pytest.approx((truth @ r1.T)[[0, 2]], abs=1e-9)
    assert motions[0].translation[0, [0, 2]] == pytest.approx([0, 0], abs=1e-9)  # the origin under the first


def test_a_lone_track_keeps_its_own_ground_and_placement():
    a = _standing(0.3, 4.0, depth_off=1.2)
    (m,) = one_world([_fitted(1, a)])
    r, o = m.to_world
    assert np.array_equal(m.to_reference(m.translation), a.translation) or \
        np.allclose(m.to_reference(m.translation), a.translation, atol=1e-12)
    assert o @ r[1] == pytest.approx(a.ground[1])
    assert _feet_height(m, a) == pytest.approx(SOLE, abs=1e-6)
    assert one_world([]) == []
